"""Orientation of one photo from DCP packages over the C ABI (``ccp_orient_photo``).

The library orients a single photo as `cloudcontrol orient` does for each photo of an
epoch (fiducial interior orientation of a film scan, footprint on the DEM, iterative
prediction / chip matching / resection), without the epoch's block adjustment; so
photos can be oriented one by one or in parallel processes.
"""
from __future__ import annotations

import ctypes
import json
import os
from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np

from ._ffi import CloudControlError, as_f64, check, last_error, lib, ptr
from .control import DcpPackage, _DcpP
from .geometry import Pose

NOT_ORIENTED = 9  # CCP_STATUS_NOT_ORIENTED


class NotOriented(CloudControlError):
    """The photo could not be oriented (``CCP_STATUS_NOT_ORIENTED``). ``reason`` is the
    library's explanation, e.g. "no control point predicted inside the photo (0 in the
    footprint)" or "3 of 40 control patches matched; …"; the message starts with the
    image path."""

    def __init__(self, message: str, image: str | os.PathLike | None = None):
        super().__init__(NOT_ORIENTED, message)
        self.status_name = "NOT_ORIENTED"
        self.args = (f"[NOT_ORIENTED] {message}",)
        # The library writes "<image path>: <reason>".
        prefix = f"{os.fsdecode(image)}: " if image is not None else None
        self.reason = message[len(prefix):] if prefix and message.startswith(prefix) else message


class _CcpPhotoOrientation(ctypes.Structure):
    pass


_OrientP = ctypes.POINTER(_CcpPhotoOrientation)
_dp = ctypes.POINTER(ctypes.c_double)
_sz = ctypes.c_size_t

lib.ccp_orient_photo.argtypes = [ctypes.POINTER(_DcpP), _sz, ctypes.c_char_p, ctypes.c_double, ctypes.c_char_p,
                                 ctypes.c_char_p, _dp, _dp, ctypes.POINTER(_OrientP)]
lib.ccp_orient_photo.restype = ctypes.c_int
lib.ccp_photo_orientation_pose.argtypes = [_OrientP, _dp, _dp]
lib.ccp_photo_orientation_pose.restype = ctypes.c_int
lib.ccp_photo_orientation_covariance.argtypes = [_OrientP, _dp]
lib.ccp_photo_orientation_covariance.restype = ctypes.c_int
lib.ccp_photo_orientation_match_count.argtypes = [_OrientP, ctypes.POINTER(_sz)]
lib.ccp_photo_orientation_match_count.restype = ctypes.c_int
lib.ccp_photo_orientation_matches.argtypes = [_OrientP, _dp, _dp, _dp, _sz]
lib.ccp_photo_orientation_matches.restype = ctypes.c_int
lib.ccp_photo_orientation_report_json.argtypes = [_OrientP, ctypes.POINTER(ctypes.c_void_p)]
lib.ccp_photo_orientation_report_json.restype = ctypes.c_int
lib.ccp_photo_orientation_free.argtypes = [_OrientP]
lib.ccp_photo_orientation_free.restype = ctypes.c_int
lib.ccp_string_free.argtypes = [ctypes.c_void_p]
lib.ccp_string_free.restype = ctypes.c_int


@dataclass(frozen=True)
class PhotoOrientation:
    """An oriented photo, in world coordinates of the packages' CRS.

    ``rotation`` (3, 3) world→camera (X_cam = R (X − C)), ``center`` (3,) projection
    centre (m); ``covariance`` (6, 6) of the pose, rotation vector (rad) then centre (m),
    as :func:`cloudcontrol.predict` takes it; ``matches`` the control patches that support
    the pose: ``xyz`` (n, 3) world, ``pixel`` (n, 2) image (top-left pixel corner = 0, 0),
    ``sigma_px`` (n,); ``report`` the per-photo report (iterations, matching statistics,
    film scan interior orientation under ``io``)."""
    rotation: np.ndarray
    center: np.ndarray
    covariance: np.ndarray
    xyz: np.ndarray
    pixel: np.ndarray
    sigma_px: np.ndarray
    report: dict

    @property
    def pose(self) -> Pose:
        return Pose(self.rotation, self.center)

    @property
    def matches(self) -> list[tuple[np.ndarray, np.ndarray, float]]:
        """(xyz, pixel, σ px) per match."""
        return [(self.xyz[k], self.pixel[k], float(self.sigma_px[k])) for k in range(len(self.sigma_px))]


def _read(h) -> PhotoOrientation:
    r, c, cov = np.empty(9), np.empty(3), np.empty(36)
    check(lib.ccp_photo_orientation_pose(h, ptr(r), ptr(c)))
    check(lib.ccp_photo_orientation_covariance(h, ptr(cov)))
    n = _sz()
    check(lib.ccp_photo_orientation_match_count(h, ctypes.byref(n)))
    n = n.value
    # One spare row: the library refuses a null buffer even for no matches.
    xyz, px, sig = np.empty((n + 1, 3)), np.empty((n + 1, 2)), np.empty(n + 1)
    check(lib.ccp_photo_orientation_matches(h, ptr(xyz), ptr(px), ptr(sig), n + 1))
    text = ctypes.c_void_p()
    check(lib.ccp_photo_orientation_report_json(h, ctypes.byref(text)))
    try:
        report = json.loads(ctypes.string_at(text.value).decode("utf-8"))
    finally:
        lib.ccp_string_free(text)
    return PhotoOrientation(r.reshape(3, 3), c, cov.reshape(6, 6), xyz[:n], px[:n], sig[:n], report)


def _path(p) -> bytes | None:
    # None goes through as NULL: the library names the argument in its error.
    return None if p is None else os.fsencode(p)


def orient_photo(dcps: DcpPackage | Iterable[DcpPackage], camera: str | os.PathLike, image: str | os.PathLike,
                 approximate: Sequence[float], sigma: Sequence[float], dem: str | os.PathLike,
                 scan_pixel_um: float | None = None) -> PhotoOrientation:
    """Orients one photo from the control points of DCP packages (all in one CRS).

    ``camera`` is a camera file (formats/cameras/: a frame camera JSON, or a film camera
    certificate with fiducials, whose interior orientation is found in the scan);
    ``image`` the photo or scan; ``approximate`` = (x, y, z, omega, phi, kappa): world
    centre (m) and angles in degrees as in formats/pos/; ``sigma`` = (centre m, angle
    deg), the 1σ of the approximate orientation; ``dem`` a ground DEM GeoTIFF in the
    packages' CRS; ``scan_pixel_um`` the film scan's pixel size (None: estimated from the
    format and the scan size).

    Raises :class:`NotOriented` (with ``reason``) when the photo cannot be oriented, and
    :class:`CloudControlError` for bad input (e.g. status NOT_FOUND naming a missing image).
    """
    packages = [dcps] if isinstance(dcps, DcpPackage) else list(dcps)
    if not packages:
        raise ValueError("orient_photo needs at least one DCP package")
    handles = (_DcpP * len(packages))(*[p._h for p in packages])
    approx = as_f64(approximate).reshape(-1)
    sig = as_f64(sigma).reshape(-1)
    if approx.size != 6:
        raise ValueError(f"approximate must hold x, y, z, omega, phi, kappa (6 values), got {approx.size}")
    if sig.size != 2:
        raise ValueError(f"sigma must hold the centre σ (m) and the angle σ (deg), got {sig.size} values")
    h = _OrientP()
    status = lib.ccp_orient_photo(handles, len(packages), _path(camera),
                                  0.0 if scan_pixel_um is None else float(scan_pixel_um),
                                  _path(image), _path(dem), ptr(approx), ptr(sig), ctypes.byref(h))
    if status == NOT_ORIENTED:
        raise NotOriented(last_error(), image)
    check(status)
    try:
        return _read(h)
    finally:
        lib.ccp_photo_orientation_free(h)


__all__ = ["NotOriented", "PhotoOrientation", "orient_photo"]
