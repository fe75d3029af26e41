"""Bundle adjustment and single-photo resection over the C ABI."""
from __future__ import annotations

import ctypes
import json

import numpy as np

from ._ffi import as_f64, check, lib, ptr
from .geometry import Camera, CcpPose, Pose, _CameraP


class _CcpBlock(ctypes.Structure):
    pass


class AdjustOptions(ctypes.Structure):
    """loss: 0 none, 1 Huber, 2 Cauchy; rejection: 0 none, 1 k·σ0 threshold, 2 data snooping."""
    _fields_ = [("loss", ctypes.c_uint32), ("loss_scale", ctypes.c_double), ("rejection", ctypes.c_uint32),
                ("k", ctypes.c_double), ("max_iterations", ctypes.c_uint32), ("max_rounds", ctypes.c_uint32)]


class AdjustSummary(ctypes.Structure):
    _fields_ = [("sigma0", ctypes.c_double), ("rmse_px", ctypes.c_double), ("iterations", ctypes.c_uint32),
                ("rounds", ctypes.c_uint32), ("converged", ctypes.c_uint32), ("rejected", ctypes.c_uint32),
                ("photos", ctypes.c_uint32), ("points", ctypes.c_uint32), ("observations", ctypes.c_uint64),
                ("time_s", ctypes.c_double), ("check_count", ctypes.c_uint32), ("check_rmse_plan_m", ctypes.c_double),
                ("check_rmse_height_m", ctypes.c_double), ("check_max_m", ctypes.c_double)]

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k, _ in self._fields_}


_BlockP = ctypes.POINTER(_CcpBlock)
_dp = ctypes.POINTER(ctypes.c_double)
_u64p = ctypes.POINTER(ctypes.c_uint64)
_u32p = ctypes.POINTER(ctypes.c_uint32)

_sig = {
    "ccp_block_new": [_dp, ctypes.POINTER(_BlockP)],
    "ccp_block_add_camera": [_BlockP, ctypes.c_uint32, _CameraP, ctypes.c_char_p],
    "ccp_block_add_photo": [_BlockP, ctypes.c_uint32, ctypes.c_uint32, ctypes.POINTER(CcpPose)],
    "ccp_block_set_pos_prior": [_BlockP, ctypes.c_uint32, _dp, _dp, _dp, ctypes.c_double],
    "ccp_block_add_points": [_BlockP, ctypes.c_size_t, _u64p, _u32p, _dp, _dp],
    "ccp_block_add_observations": [_BlockP, ctypes.c_size_t, _u64p, _u32p, _dp, _dp],
    "ccp_block_add_planes": [_BlockP, ctypes.c_size_t, _u64p, _dp, _dp, _dp],
    "ccp_block_set_lidar_datum_sigma": [_BlockP, ctypes.c_double],
    "ccp_block_adjust": [_BlockP, ctypes.POINTER(AdjustOptions), ctypes.POINTER(AdjustSummary)],
    "ccp_block_get_photo": [_BlockP, ctypes.c_uint32, ctypes.POINTER(CcpPose), _dp],
    "ccp_block_get_point": [_BlockP, ctypes.c_uint64, _dp],
    "ccp_block_report_json": [_BlockP, ctypes.c_char_p, ctypes.c_size_t, ctypes.POINTER(ctypes.c_size_t)],
    "ccp_resect": [_CameraP, ctypes.c_size_t, _dp, _dp, ctypes.c_double, ctypes.c_double, ctypes.c_uint32,
                   ctypes.POINTER(CcpPose), ctypes.POINTER(ctypes.c_uint8), _dp],
}
for _n, _a in _sig.items():
    getattr(lib, _n).argtypes = _a
    getattr(lib, _n).restype = ctypes.c_int
lib.ccp_block_free.argtypes = [_BlockP]
lib.ccp_block_free.restype = ctypes.c_int

TIE, CONTROL, CHECK = 0, 1, 2
LOSS = {"none": 0, "huber": 1, "cauchy": 2}
REJECTION = {"none": 0, "threshold": 1, "snooping": 2}


def _ids(a, dtype):
    return np.ascontiguousarray(a, dtype=dtype)


class Block:
    """A block (cameras, photos, object points, observations) to adjust; coordinates block-local."""

    def __init__(self, origin=None):
        self._h = _BlockP()
        o = None if origin is None else as_f64(origin)
        check(lib.ccp_block_new(None if o is None else ptr(o), ctypes.byref(self._h)))
        self._cameras = []

    def __del__(self):
        h = getattr(self, "_h", None)
        if h:
            lib.ccp_block_free(h)
            self._h = None

    def add_camera(self, camera_id: int, camera: Camera, free_params: list[str] | None = None):
        fp = ",".join(free_params).encode() if free_params else None
        check(lib.ccp_block_add_camera(self._h, camera_id, camera._h, fp))
        self._cameras.append(camera)

    def add_photo(self, photo_id: int, camera_id: int, pose: Pose):
        check(lib.ccp_block_add_photo(self._h, photo_id, camera_id, ctypes.byref(pose._c())))

    def set_pos_prior(self, photo_id: int, center, center_sigma, rotation=None, rotation_sigma_rad: float = 0.0):
        c, s = as_f64(center), as_f64(center_sigma)
        r = None if rotation is None else as_f64(np.asarray(rotation).ravel())
        check(lib.ccp_block_set_pos_prior(self._h, photo_id, ptr(c), ptr(s), None if r is None else ptr(r), rotation_sigma_rad))

    def add_points(self, ids, kinds, xyz, sigmas=None):
        ids, kinds = _ids(ids, np.uint64), _ids(kinds, np.uint32)
        x = as_f64(xyz, 3, "xyz")
        s = None if sigmas is None else as_f64(sigmas, 3, "sigmas")
        check(lib.ccp_block_add_points(self._h, len(ids), ids.ctypes.data_as(_u64p), kinds.ctypes.data_as(_u32p), ptr(x),
                                       None if s is None else ptr(s)))

    def add_observations(self, point_ids, photo_ids, pixels, sigma_px):
        p, ph = _ids(point_ids, np.uint64), _ids(photo_ids, np.uint32)
        px = as_f64(pixels, 2, "pixels")
        s = as_f64(np.broadcast_to(np.asarray(sigma_px, dtype=np.float64), (len(p),)))
        check(lib.ccp_block_add_observations(self._h, len(p), p.ctypes.data_as(_u64p), ph.ctypes.data_as(_u32p), ptr(px), ptr(s)))

    def add_planes(self, point_ids, normals, d, weights):
        p = _ids(point_ids, np.uint64)
        n, dd, w = as_f64(normals, 3, "normals"), as_f64(d), as_f64(weights)
        check(lib.ccp_block_add_planes(self._h, len(p), p.ctypes.data_as(_u64p), ptr(n), ptr(dd), ptr(w)))

    def set_lidar_datum_sigma(self, sigma_m: float):
        """Adjust the planes' common shift (the LiDAR's datum error) with a zero prior of
        sigma_m per axis (m); 0 makes the planes the datum as they stand (the default)."""
        check(lib.ccp_block_set_lidar_datum_sigma(self._h, float(sigma_m)))

    def adjust(self, loss: str = "huber", loss_scale: float = 2.0, rejection: str = "snooping", k: float = 3.2905,
               max_iterations: int = 50, max_rounds: int = 10) -> dict:
        """Robust bundle adjustment. The default is the library's: Baarda data snooping against
        the a-priori σ with k = 3.2905 (α0 = 0.1 % per test); "threshold" rejects standardised
        residuals above k·σ0 re-estimated each round (it erodes the tails of clean data)."""
        o = AdjustOptions(LOSS[loss], loss_scale, REJECTION[rejection], k, max_iterations, max_rounds)
        s = AdjustSummary()
        check(lib.ccp_block_adjust(self._h, ctypes.byref(o), ctypes.byref(s)))
        return s.as_dict()

    def photo(self, photo_id: int) -> tuple[Pose, np.ndarray]:
        """Adjusted pose and EO standard deviations (rotation vector rad, centre m)."""
        p = CcpPose()
        sig = np.empty(6)
        check(lib.ccp_block_get_photo(self._h, photo_id, ctypes.byref(p), ptr(sig)))
        return Pose(np.array(p.rotation[:]).reshape(3, 3), np.array(p.center[:])), sig

    def point(self, point_id: int) -> np.ndarray:
        out = np.empty(3)
        check(lib.ccp_block_get_point(self._h, point_id, ptr(out)))
        return out

    def report(self) -> dict:
        n = ctypes.c_size_t()
        check(lib.ccp_block_report_json(self._h, None, 0, ctypes.byref(n)))
        buf = ctypes.create_string_buffer(n.value)
        check(lib.ccp_block_report_json(self._h, buf, n.value, ctypes.byref(n)))
        return json.loads(buf.value.decode())


def resect(camera: Camera, pixels, points, sigma_px: float = 1.0, threshold_px: float = 4.0, lmeds: bool = False):
    """Single-photo resection: (pose, inlier mask, 6×6 covariance of rotation vector and centre)."""
    px = as_f64(pixels, 2, "pixels")
    x = as_f64(points, 3, "points")
    if px.shape[0] != x.shape[0]:
        raise ValueError(f"{px.shape[0]} pixels but {x.shape[0]} points")
    pose = CcpPose()
    inl = np.zeros(px.shape[0], dtype=np.uint8)
    cov = np.empty(36)
    check(lib.ccp_resect(camera._h, px.shape[0], ptr(px), ptr(x), sigma_px, threshold_px, int(lmeds), ctypes.byref(pose),
                         inl.ctypes.data_as(ctypes.POINTER(ctypes.c_uint8)), ptr(cov)))
    return Pose(np.array(pose.rotation[:]).reshape(3, 3), np.array(pose.center[:])), inl.astype(bool), cov.reshape(6, 6)
