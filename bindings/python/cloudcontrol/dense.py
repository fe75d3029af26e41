"""Dense matching of one stereo pair over the C ABI (``ccp_match_pair``)."""
from __future__ import annotations

import ctypes

import numpy as np

from ._ffi import check, lib
from .geometry import Camera, CcpPose, Pose, _CameraP


class CcpPairPhoto(ctypes.Structure):
    _fields_ = [
        ("camera", _CameraP),
        ("pose", CcpPose),
        ("pixels", ctypes.POINTER(ctypes.c_float)),
        ("width", ctypes.c_uint32),
        ("height", ctypes.c_uint32),
    ]


_dpp = ctypes.POINTER(ctypes.POINTER(ctypes.c_double))
lib.ccp_match_pair.argtypes = [ctypes.POINTER(CcpPairPhoto), ctypes.POINTER(CcpPairPhoto),
                               ctypes.c_double, ctypes.c_double, _dpp,
                               ctypes.POINTER(ctypes.c_size_t)]
lib.ccp_match_pair.restype = ctypes.c_int
lib.ccp_points_free.argtypes = [ctypes.POINTER(ctypes.c_double), ctypes.c_size_t]
lib.ccp_points_free.restype = ctypes.c_int


def _photo(camera: Camera, pose: Pose, image, name: str):
    arr = np.ascontiguousarray(image, dtype=np.float32)
    if arr.ndim != 2:
        raise ValueError(f"{name} image must be a 2-D grey array, got shape {arr.shape}")
    p = CcpPairPhoto()
    p.camera = camera._h
    p.pose = pose._c()
    p.pixels = arr.ctypes.data_as(ctypes.POINTER(ctypes.c_float))
    p.height, p.width = arr.shape
    return p, arr


def match_pair(left: tuple, right: tuple, z_range: tuple[float, float]) -> np.ndarray:
    """Object points (n, 3) of one stereo pair by semi-global matching: ``left`` and
    ``right`` are ``(Camera, Pose, image)`` with 2-D grey images of the cameras' sizes;
    heights are searched within ``z_range = (z_min, z_max)`` (the poses' frame). Every
    matched pixel of the left photo gives one point; an empty array when none matched."""
    lp, lkeep = _photo(*left, "left")
    rp, rkeep = _photo(*right, "right")
    pts = ctypes.POINTER(ctypes.c_double)()
    n = ctypes.c_size_t(0)
    check(lib.ccp_match_pair(ctypes.byref(lp), ctypes.byref(rp), float(z_range[0]),
                             float(z_range[1]), ctypes.byref(pts), ctypes.byref(n)))
    del lkeep, rkeep
    if n.value == 0:
        return np.empty((0, 3))
    try:
        return np.ctypeslib.as_array(pts, shape=(n.value * 3,)).reshape(-1, 3).copy()
    finally:
        lib.ccp_points_free(pts, n.value)
