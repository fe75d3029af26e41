"""LiDAR sources over the C ABI: the source catalogue and checkpoint evaluation."""
from __future__ import annotations

import ctypes
import json
import os
from typing import Iterable, Sequence

import numpy as np

from ._ffi import as_f64, check, lib, ptr


class CheckpointStats(ctypes.Structure):
    _fields_ = [
        ("count", ctypes.c_size_t),
        ("skipped", ctypes.c_size_t),
        ("mean_m", ctypes.c_double),
        ("std_m", ctypes.c_double),
        ("rmse_m", ctypes.c_double),
        ("max_abs_m", ctypes.c_double),
        ("outliers", ctypes.c_size_t),
    ]

    def as_dict(self) -> dict:
        return {name: getattr(self, name) for name, _ in self._fields_}


_dp = ctypes.POINTER(ctypes.c_double)
_cpp = ctypes.POINTER(ctypes.c_char_p)

lib.ccp_lidar_catalogue_json.argtypes = [_cpp, ctypes.c_size_t, ctypes.c_char_p, ctypes.POINTER(ctypes.c_void_p)]
lib.ccp_lidar_catalogue_json.restype = ctypes.c_int
lib.ccp_string_free.argtypes = [ctypes.c_void_p]
lib.ccp_string_free.restype = None
lib.ccp_lidar_eval_checkpoints.argtypes = [
    _cpp, ctypes.c_size_t, ctypes.c_char_p, _dp, ctypes.c_size_t, ctypes.c_int32, ctypes.c_double,
    ctypes.c_uint64, _dp, ctypes.c_size_t, ctypes.POINTER(CheckpointStats),
]
lib.ccp_lidar_eval_checkpoints.restype = ctypes.c_int


def _paths(paths: str | os.PathLike | Iterable[str | os.PathLike]):
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    enc = [os.fsencode(p) for p in paths]
    arr = (ctypes.c_char_p * len(enc))(*enc)
    return arr, len(enc)


def _crs(assume_crs: str | None):
    return assume_crs.encode() if assume_crs else None


def catalogue(paths, assume_crs: str | None = None) -> dict:
    """Scans LAS/LAZ files or folders (or loads a catalogue .json); returns the catalogue
    as a dict (schema in formats/lidar/README.md). All tiles must share one CRS;
    ``assume_crs`` (e.g. "EPSG:32650") is used for files without one."""
    arr, n = _paths(paths)
    out = ctypes.c_void_p()
    check(lib.ccp_lidar_catalogue_json(arr, n, _crs(assume_crs), ctypes.byref(out)))
    try:
        return json.loads(ctypes.string_at(out.value).decode("utf-8"))
    finally:
        lib.ccp_string_free(out)


def evaluate_checkpoints(paths, checkpoints: Sequence[Sequence[float]], ground_class: int | None = 2,
                         radius: float = 3.0, assume_crs: str | None = None,
                         max_points: int = 0) -> tuple[np.ndarray, dict]:
    """LiDAR minus checkpoint heights (n,) (NaN where skipped) and statistics
    (count, skipped, mean_m, std_m, rmse_m, max_abs_m, outliers) for checkpoints (n, 3)
    in the LiDAR CRS. ``ground_class=None`` uses every point."""
    arr, n = _paths(paths)
    xyz = as_f64(checkpoints, 3, "checkpoints")
    dz = np.empty(xyz.shape[0])
    stats = CheckpointStats()
    cls = -1 if ground_class is None else int(ground_class)
    check(lib.ccp_lidar_eval_checkpoints(arr, n, _crs(assume_crs), ptr(xyz), xyz.shape[0], cls, float(radius),
                                         int(max_points), ptr(dz), dz.size, ctypes.byref(stats)))
    return dz, stats.as_dict()
