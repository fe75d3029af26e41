"""DCP packages and patch prediction over the C ABI."""
from __future__ import annotations

import ctypes
import os
import pathlib
from typing import Iterable

import numpy as np

from ._ffi import as_f64, check, lib, ptr
from .geometry import Camera, CcpPose, Pose


class _CcpDcp(ctypes.Structure):
    pass


class DcpExportOptions(ctypes.Structure):
    """CcpDcpExportOptions; the keyword options of :meth:`DcpPackage.export`."""
    _fields_ = [
        ("name", ctypes.c_char_p), ("date", ctypes.c_char_p), ("source", ctypes.c_char_p),
        ("chip_size", ctypes.c_uint32), ("interval_px", ctypes.c_double), ("interest_level", ctypes.c_uint32),
        ("max_coplanarity", ctypes.c_double), ("min_photos", ctypes.c_uint32),
        ("accuracy_plan_m", ctypes.c_double), ("accuracy_height_m", ctypes.c_double),
        ("lidar_cell_m", ctypes.c_double),
    ]


_DcpP = ctypes.POINTER(_CcpDcp)
_dp = ctypes.POINTER(ctypes.c_double)
_sz = ctypes.c_size_t

lib.ccp_dcp_open.argtypes = [ctypes.c_char_p, ctypes.POINTER(_DcpP)]
lib.ccp_dcp_open.restype = ctypes.c_int
lib.ccp_dcp_free.argtypes = [_DcpP]
lib.ccp_dcp_free.restype = ctypes.c_int
lib.ccp_dcp_point_count.argtypes = [_DcpP, ctypes.POINTER(_sz)]
lib.ccp_dcp_point_count.restype = ctypes.c_int
lib.ccp_dcp_points.argtypes = [_DcpP, _dp, _dp, _sz]
lib.ccp_dcp_points.restype = ctypes.c_int
lib.ccp_dcp_query_polygon.argtypes = [_DcpP, _dp, _sz, ctypes.POINTER(ctypes.c_uint64), _sz, ctypes.POINTER(_sz)]
lib.ccp_dcp_query_polygon.restype = ctypes.c_int
lib.ccp_dcp_export_options_default.argtypes = [ctypes.POINTER(DcpExportOptions)]
lib.ccp_dcp_export_options_default.restype = ctypes.c_int
lib.ccp_dcp_export.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.POINTER(ctypes.c_char_p), _sz, ctypes.c_char_p,
                               ctypes.POINTER(DcpExportOptions), ctypes.POINTER(_DcpP)]
lib.ccp_dcp_export.restype = ctypes.c_int
lib.ccp_dcp_import.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.POINTER(_DcpP)]
lib.ccp_dcp_import.restype = ctypes.c_int
lib.ccp_dcp_from_orthophoto.argtypes = [ctypes.c_char_p] * 8 + [ctypes.POINTER(_DcpP)]
lib.ccp_dcp_from_orthophoto.restype = ctypes.c_int
lib.ccp_dcp_path.argtypes = [_DcpP, ctypes.POINTER(ctypes.c_void_p)]
lib.ccp_dcp_path.restype = ctypes.c_int
lib.ccp_string_free.argtypes = [ctypes.c_void_p]
lib.ccp_string_free.restype = ctypes.c_int
lib.ccp_predict.argtypes = [ctypes.c_void_p, ctypes.POINTER(CcpPose), _dp, _dp, _dp, _sz, _dp, _sz, _dp, _sz]
lib.ccp_predict.restype = ctypes.c_int


class DcpPackage:
    """A verified Digital Control Photo package (see formats/dcp/README.md)."""

    def __init__(self, path: str | os.PathLike):
        h = _DcpP()
        check(lib.ccp_dcp_open(os.fsencode(path), ctypes.byref(h)))
        self._h = h

    @classmethod
    def _adopt(cls, h) -> "DcpPackage":
        obj = cls.__new__(cls)
        obj._h = h
        return obj

    @classmethod
    def export(cls, block_json: str | os.PathLike, images_json: str | os.PathLike,
               lidar: str | os.PathLike | Iterable[str | os.PathLike], out_dir: str | os.PathLike,
               **options) -> "DcpPackage":
        """Writes a package at ``out_dir`` from an oriented block and returns it opened.

        ``block_json`` and ``images_json`` are the files the workflow writes per epoch (the
        block; photo id → image path), ``lidar`` LAS/LAZ files or folders of them. Options
        (library defaults when left out): ``name``, ``date``, ``source``, ``chip_size``,
        ``interval_px``, ``interest_level``, ``max_coplanarity``, ``min_photos``,
        ``accuracy_plan_m``, ``accuracy_height_m``, ``lidar_cell_m``.
        """
        opts = DcpExportOptions()
        check(lib.ccp_dcp_export_options_default(ctypes.byref(opts)))
        fields = dict(DcpExportOptions._fields_)
        for key, value in options.items():
            if key not in fields:
                raise TypeError(f"unknown option {key!r}; expected one of {sorted(fields)}")
            if fields[key] is ctypes.c_char_p:
                value = None if value is None else str(value).encode()
            elif fields[key] is ctypes.c_uint32:
                # ctypes would wrap a negative value silently into a huge one.
                if int(value) != value or not 0 <= value < 2**32:
                    raise ValueError(f"{key} must be a non-negative integer, got {value!r}")
                value = int(value)
            else:
                value = float(value)
            setattr(opts, key, value)
        paths = [lidar] if isinstance(lidar, (str, os.PathLike)) else list(lidar)
        enc = [os.fsencode(p) for p in paths]
        arr = (ctypes.c_char_p * max(len(enc), 1))(*enc)
        h = _DcpP()
        check(lib.ccp_dcp_export(os.fsencode(block_json), os.fsencode(images_json), arr, len(enc),
                                 os.fsencode(out_dir), ctypes.byref(opts), ctypes.byref(h)))
        return cls._adopt(h)

    @classmethod
    def from_orthophoto(cls, orthophoto: str | os.PathLike, dem: str | os.PathLike, crs: str,
                        out_dir: str | os.PathLike, *, orthophoto_crs: str | None = None,
                        dem_crs: str | None = None, name: str | None = None,
                        date: str | None = None) -> "DcpPackage":
        """Writes a package at ``out_dir`` from a georeferenced orthophoto (GeoTIFF, or an
        image with a world file: then give ``orthophoto_crs``) and a DEM GeoTIFF, in the
        projected CRS ``crs`` (rasters in another CRS are reprojected); returns it opened."""
        enc = lambda v: None if v is None else str(v).encode()  # noqa: E731
        h = _DcpP()
        check(lib.ccp_dcp_from_orthophoto(os.fsencode(orthophoto), enc(orthophoto_crs),
                                          os.fsencode(dem), enc(dem_crs), enc(crs),
                                          os.fsencode(out_dir), enc(name), enc(date),
                                          ctypes.byref(h)))
        return cls._adopt(h)

    @classmethod
    def import_(cls, package: str | os.PathLike, store: str | os.PathLike) -> "DcpPackage":
        """Verifies ``package`` in full and copies it into the store folder as
        ``store/<package folder name>``; returns the stored copy. A damaged package, or one
        of another CRS than the store's packages, raises and leaves the store untouched."""
        h = _DcpP()
        check(lib.ccp_dcp_import(os.fsencode(package), os.fsencode(store), ctypes.byref(h)))
        return cls._adopt(h)

    @property
    def path(self) -> pathlib.Path:
        """The package folder."""
        out = ctypes.c_void_p()
        check(lib.ccp_dcp_path(self._h, ctypes.byref(out)))
        try:
            return pathlib.Path(ctypes.string_at(out.value).decode())
        finally:
            lib.ccp_string_free(out)

    def __del__(self):
        h = getattr(self, "_h", None)
        if h:
            lib.ccp_dcp_free(h)
            self._h = None

    def __len__(self) -> int:
        n = _sz()
        check(lib.ccp_dcp_point_count(self._h, ctypes.byref(n)))
        return n.value

    def points(self) -> tuple[np.ndarray, np.ndarray]:
        """World coordinates (n, 3) and their σ (n, 3)."""
        n = len(self)
        xyz, sig = np.empty((n, 3)), np.empty((n, 3))
        check(lib.ccp_dcp_points(self._h, ptr(xyz), ptr(sig), xyz.size))
        return xyz, sig

    def query_polygon(self, polygon) -> np.ndarray:
        """Indices of the control points inside a world-XY polygon (m, 2)."""
        poly = as_f64(polygon, 2, "polygon")
        count = _sz()
        cap = len(self)
        out = np.empty(max(cap, 1), dtype=np.uint64)
        check(lib.ccp_dcp_query_polygon(self._h, ptr(poly), poly.shape[0],
                                        out.ctypes.data_as(ctypes.POINTER(ctypes.c_uint64)), cap, ctypes.byref(count)))
        return out[: count.value].astype(np.int64)


def predict(camera: Camera, pose: Pose, eo_covariance, points, point_sigma=None):
    """Predicted pixels (n, 2) and their covariances (n, 2, 2) for object points (n, 3).

    ``eo_covariance`` is 6×6: rotation vector (rad) then projection centre (m).
    """
    cov = as_f64(np.asarray(eo_covariance).reshape(36))
    pts = as_f64(points, 3, "points")
    sig = None if point_sigma is None else as_f64(point_sigma, 3, "point_sigma")
    n = pts.shape[0]
    px, pc = np.empty((n, 2)), np.empty((n, 2, 2))
    check(lib.ccp_predict(camera._h, ctypes.byref(pose._c()), ptr(cov), ptr(pts),
                          None if sig is None else ptr(sig), n, ptr(px), px.size, ptr(pc), pc.size))
    return px, pc
