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
lib.ccp_string_free.restype = ctypes.c_int
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


class IcpStats(ctypes.Structure):
    _fields_ = [
        ("scale", ctypes.c_double),
        ("rmse_m", ctypes.c_double),
        ("sigma0_m", ctypes.c_double),
        ("inliers", ctypes.c_size_t),
        ("iterations", ctypes.c_size_t),
        ("converged", ctypes.c_int32),
    ]

    def as_dict(self) -> dict:
        d = {name: getattr(self, name) for name, _ in self._fields_}
        d["converged"] = bool(d["converged"])
        return d


class _CcpLidarSource(ctypes.Structure):
    pass


_SourceP = ctypes.POINTER(_CcpLidarSource)
lib.ccp_lidar_source_open.argtypes = [_cpp, ctypes.c_size_t, ctypes.c_char_p, _dp, ctypes.c_uint32, ctypes.c_double,
                                      ctypes.c_uint64, ctypes.POINTER(_SourceP)]
lib.ccp_lidar_source_open.restype = ctypes.c_int
lib.ccp_lidar_source_free.argtypes = [_SourceP]
lib.ccp_lidar_source_free.restype = ctypes.c_int
lib.ccp_lidar_source_len.argtypes = [_SourceP, ctypes.POINTER(ctypes.c_uint64)]
lib.ccp_lidar_source_len.restype = ctypes.c_int
lib.ccp_lidar_planes.argtypes = [_SourceP, _dp, ctypes.c_size_t, _dp, ctypes.c_size_t]
lib.ccp_lidar_planes.restype = ctypes.c_int
lib.ccp_lidar_icp.argtypes = [_SourceP, _dp, ctypes.c_size_t, ctypes.c_int32, ctypes.c_double, ctypes.c_double,
                              ctypes.c_uint32, _dp, ctypes.POINTER(IcpStats)]
lib.ccp_lidar_icp.restype = ctypes.c_int


class LidarSource:
    """LiDAR points of a region with their local-plane index (owned by the library).

    ``bbox`` = (min_x, min_y, max_x, max_y) or None for every tile; ``k`` neighbours per
    plane fit (0: 12), ``max_coplanarity`` (<= 0: 0.02), ``max_points`` bound (0: 2e8)."""

    def __init__(self, paths, bbox=None, assume_crs: str | None = None, k: int = 0,
                 max_coplanarity: float = 0.0, max_points: int = 0):
        arr, n = _paths(paths)
        b = None if bbox is None else as_f64(bbox)
        h = _SourceP()
        check(lib.ccp_lidar_source_open(arr, n, _crs(assume_crs), None if b is None else ptr(b), int(k),
                                        float(max_coplanarity), int(max_points), ctypes.byref(h)))
        self._h = h

    def __del__(self):
        h = getattr(self, "_h", None)
        if h:
            lib.ccp_lidar_source_free(h)
            self._h = None

    def __len__(self) -> int:
        n = ctypes.c_uint64()
        check(lib.ccp_lidar_source_len(self._h, ctypes.byref(n)))
        return int(n.value)

    def planes(self, points) -> dict:
        """Local planes at points (n, 3): dict of ``normal`` (n, 3), ``centroid`` (n, 3),
        ``weight`` (n,), ``distance`` (n,) signed point-to-plane distance; NaN rows where
        the surface is not planar."""
        pts = as_f64(points, 3, "points")
        out = np.empty((pts.shape[0], 8))
        check(lib.ccp_lidar_planes(self._h, ptr(pts), pts.shape[0], ptr(out), out.size))
        return {"normal": out[:, 0:3], "centroid": out[:, 3:6], "weight": out[:, 6], "distance": out[:, 7]}

    def icp(self, points, rigid: bool = False, initial_gate: float = 0.0, min_gate: float = 0.0,
            max_iterations: int = 0) -> tuple[np.ndarray, dict]:
        """Point-to-plane ICP of points (n, 3) onto the LiDAR: the 4x4 matrix mapping them
        onto it and statistics (scale, rmse_m, sigma0_m, inliers, iterations, converged)."""
        pts = as_f64(points, 3, "points")
        m = np.empty(16)
        st = IcpStats()
        check(lib.ccp_lidar_icp(self._h, ptr(pts), pts.shape[0], int(bool(rigid)), float(initial_gate),
                                float(min_gate), int(max_iterations), ptr(m), ctypes.byref(st)))
        return m.reshape(4, 4), st.as_dict()
