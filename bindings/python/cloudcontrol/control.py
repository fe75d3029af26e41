"""DCP packages and patch prediction over the C ABI."""
from __future__ import annotations

import ctypes
import os

import numpy as np

from ._ffi import as_f64, check, lib, ptr
from .geometry import Camera, CcpPose, Pose


class _CcpDcp(ctypes.Structure):
    pass


_DcpP = ctypes.POINTER(_CcpDcp)
_dp = ctypes.POINTER(ctypes.c_double)
_sz = ctypes.c_size_t

lib.ccp_dcp_open.argtypes = [ctypes.c_char_p, ctypes.POINTER(_DcpP)]
lib.ccp_dcp_open.restype = ctypes.c_int
lib.ccp_dcp_free.argtypes = [_DcpP]
lib.ccp_dcp_free.restype = None
lib.ccp_dcp_point_count.argtypes = [_DcpP, ctypes.POINTER(_sz)]
lib.ccp_dcp_point_count.restype = ctypes.c_int
lib.ccp_dcp_points.argtypes = [_DcpP, _dp, _dp, _sz]
lib.ccp_dcp_points.restype = ctypes.c_int
lib.ccp_dcp_query_polygon.argtypes = [_DcpP, _dp, _sz, ctypes.POINTER(ctypes.c_uint64), _sz, ctypes.POINTER(_sz)]
lib.ccp_dcp_query_polygon.restype = ctypes.c_int
lib.ccp_predict.argtypes = [ctypes.c_void_p, ctypes.POINTER(CcpPose), _dp, _dp, _dp, _sz, _dp, _sz, _dp, _sz]
lib.ccp_predict.restype = ctypes.c_int


class DcpPackage:
    """A verified Digital Control Photo package (see formats/dcp/README.md)."""

    def __init__(self, path: str | os.PathLike):
        h = _DcpP()
        check(lib.ccp_dcp_open(os.fsencode(path), ctypes.byref(h)))
        self._h = h

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
