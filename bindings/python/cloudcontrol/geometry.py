"""Cameras, poses, projection and back-projection over the C ABI."""
from __future__ import annotations

import ctypes

import numpy as np

from ._ffi import as_f64, check, lib, ptr


class CcpPose(ctypes.Structure):
    _fields_ = [("rotation", ctypes.c_double * 9), ("center", ctypes.c_double * 3)]


class _CcpCamera(ctypes.Structure):
    pass


_CameraP = ctypes.POINTER(_CcpCamera)
_dp = ctypes.POINTER(ctypes.c_double)

lib.ccp_camera_new_frame.argtypes = [ctypes.c_uint32, ctypes.c_uint32, _dp, ctypes.c_size_t, ctypes.POINTER(_CameraP)]
lib.ccp_camera_new_frame.restype = ctypes.c_int
lib.ccp_camera_free.argtypes = [_CameraP]
lib.ccp_camera_free.restype = ctypes.c_int
lib.ccp_pose_from_opk.argtypes = [ctypes.c_double, ctypes.c_double, ctypes.c_double, _dp, ctypes.POINTER(CcpPose)]
lib.ccp_pose_from_opk.restype = ctypes.c_int
for _f in (lib.ccp_project, lib.ccp_back_project):
    _f.argtypes = [_CameraP, ctypes.POINTER(CcpPose), _dp, ctypes.c_size_t, _dp, ctypes.c_size_t]
    _f.restype = ctypes.c_int


class Pose:
    """Exterior orientation: X_cam = R (X - C), R world->camera (x right, y down, z forward)."""

    def __init__(self, rotation, center):
        self.rotation = np.asarray(rotation, dtype=np.float64).reshape(3, 3)
        self.center = np.asarray(center, dtype=np.float64).reshape(3)

    @classmethod
    def from_opk(cls, omega: float, phi: float, kappa: float, center) -> "Pose":
        c = as_f64(center)
        out = CcpPose()
        check(lib.ccp_pose_from_opk(omega, phi, kappa, ptr(c), ctypes.byref(out)))
        return cls(np.array(out.rotation[:]).reshape(3, 3), np.array(out.center[:]))

    def _c(self) -> CcpPose:
        p = CcpPose()
        p.rotation[:] = [float(v) for v in self.rotation.ravel()]
        p.center[:] = [float(v) for v in self.center]
        return p


class Camera:
    """A digital frame camera (pinhole or Brown), owned by the library."""

    def __init__(self, width: int, height: int, fx: float, fy: float, cx: float, cy: float,
                 k1=0.0, k2=0.0, k3=0.0, p1=0.0, p2=0.0, brown: bool | None = None):
        use_brown = brown if brown is not None else any(v != 0.0 for v in (k1, k2, k3, p1, p2))
        params = [fx, fy, cx, cy] + ([k1, k2, k3, p1, p2] if use_brown else [])
        arr = as_f64(params)
        handle = _CameraP()
        check(lib.ccp_camera_new_frame(width, height, ptr(arr), arr.size, ctypes.byref(handle)))
        self._h = handle

    def __del__(self):
        h = getattr(self, "_h", None)
        if h:
            lib.ccp_camera_free(h)
            self._h = None

    def project(self, pose: Pose, points) -> np.ndarray:
        """Pixels (n, 2) of object points (n, 3)."""
        pts = as_f64(points, 3, "points")
        out = np.empty((pts.shape[0], 2))
        check(lib.ccp_project(self._h, ctypes.byref(pose._c()), ptr(pts), pts.shape[0], ptr(out), out.size))
        return out

    def back_project(self, pose: Pose, pixels) -> np.ndarray:
        """Unit ray directions (n, 3) in object space through pixels (n, 2); rays start at pose.center."""
        px = as_f64(pixels, 2, "pixels")
        out = np.empty((px.shape[0], 3))
        check(lib.ccp_back_project(self._h, ctypes.byref(pose._c()), ptr(px), px.shape[0], ptr(out), out.size))
        return out
