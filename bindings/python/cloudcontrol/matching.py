"""Template matching (NCC over the pyramid + least-squares matching) and fiducial
interior orientation of film scans, over the C ABI."""
from __future__ import annotations

import ctypes
import json
import os
from dataclasses import dataclass

import numpy as np

from ._ffi import CloudControlError, check, lib

_fp = ctypes.POINTER(ctypes.c_float)


class CcpMatchResult(ctypes.Structure):
    _fields_ = [
        ("accepted", ctypes.c_int32),
        ("lsm_converged", ctypes.c_int32),
        ("lsm_iterations", ctypes.c_uint32),
        ("x", ctypes.c_double),
        ("y", ctypes.c_double),
        ("ncc", ctypes.c_double),
        ("ncc_x", ctypes.c_double),
        ("ncc_y", ctypes.c_double),
        ("ambiguity", ctypes.c_double),
        ("sigma_x", ctypes.c_double),
        ("sigma_y", ctypes.c_double),
        ("affine", ctypes.c_double * 4),
        ("reason", ctypes.c_char * 200),
    ]


lib.ccp_match_template.argtypes = [
    _fp, ctypes.c_uint32, ctypes.c_uint32, _fp, ctypes.c_uint32, ctypes.c_uint32,
    ctypes.POINTER(ctypes.c_uint32), ctypes.c_double, ctypes.c_double, ctypes.POINTER(CcpMatchResult),
]
lib.ccp_match_template.restype = ctypes.c_int
lib.ccp_fiducial_io.argtypes = [
    ctypes.c_char_p, _fp, ctypes.c_uint32, ctypes.c_uint32, ctypes.c_double, ctypes.c_int32,
    ctypes.c_int32, ctypes.c_char_p, ctypes.c_size_t, ctypes.POINTER(ctypes.c_size_t),
]
lib.ccp_fiducial_io.restype = ctypes.c_int


def _grey(a, name: str) -> np.ndarray:
    arr = np.ascontiguousarray(a, dtype=np.float32)
    if arr.ndim != 2:
        raise ValueError(f"{name} must be a 2-D grey image, got shape {arr.shape}")
    return arr


@dataclass
class Match:
    """A template match: (x, y) is the template centre in image pixels (origin at the
    top-left corner of the top-left pixel); ``reason`` says why it was rejected."""

    accepted: bool
    x: float
    y: float
    ncc: float
    ncc_x: float
    ncc_y: float
    ambiguity: float
    sigma_x: float
    sigma_y: float
    lsm_converged: bool
    lsm_iterations: int
    affine: tuple
    reason: str | None


def match_template(image, template, window=None, ncc_threshold: float = 0.7,
                   agreement_px: float = 1.0) -> Match:
    """Coarse-to-fine NCC then LSM; ``window`` = (col, row, width, height) or None."""
    img = _grey(image, "image")
    tpl = _grey(template, "template")
    win = None
    if window is not None:
        w = np.ascontiguousarray(window, dtype=np.uint32)
        if w.shape != (4,):
            raise ValueError("window must be (col, row, width, height)")
        win = w.ctypes.data_as(ctypes.POINTER(ctypes.c_uint32))
    out = CcpMatchResult()
    check(lib.ccp_match_template(
        img.ctypes.data_as(_fp), img.shape[1], img.shape[0],
        tpl.ctypes.data_as(_fp), tpl.shape[1], tpl.shape[0],
        win, float(ncc_threshold), float(agreement_px), ctypes.byref(out)))
    reason = out.reason.decode("utf-8", "replace") or None
    return Match(bool(out.accepted), out.x, out.y, out.ncc, out.ncc_x, out.ncc_y, out.ambiguity,
                 out.sigma_x, out.sigma_y, bool(out.lsm_converged), out.lsm_iterations,
                 tuple(out.affine), reason)



def fiducial_io(camera, scan, pixel_mm: float | None = None, projective: bool = False,
                rotation_deg: int | None = None, mirrored: bool = False) -> dict:
    """Fiducial interior orientation of a scan (2-D grey array). ``camera`` is a camera
    definition dict, JSON text or a path to formats/cameras/*.json. Returns the io.json
    document (marks, transform pixel -> mm, rmse_um)."""
    if isinstance(camera, dict):
        text = json.dumps(camera)
    elif isinstance(camera, (str, os.PathLike)) and os.path.exists(camera):
        with open(camera, encoding="utf-8") as f:
            text = f.read()
    else:
        text = str(camera)
    img = _grey(scan, "scan")
    orientation = -1 if rotation_deg is None else (int(rotation_deg) // 90) % 4 + (4 if mirrored else 0)
    needed = ctypes.c_size_t(0)
    args = [text.encode("utf-8"), img.ctypes.data_as(_fp), img.shape[1], img.shape[0],
            float(pixel_mm or 0.0), int(bool(projective)), orientation]
    size = 1 << 16
    for _ in range(2):
        buf = ctypes.create_string_buffer(size)
        status = lib.ccp_fiducial_io(*args, buf, size, ctypes.byref(needed))
        if status == 8 and needed.value > size:  # BUFFER_TOO_SMALL: retry with the size asked for
            size = needed.value
            continue
        check(status)
        return json.loads(buf.value.decode("utf-8"))
    raise CloudControlError(8, "io.json did not fit the buffer")


# Plain addresses (c_void_p) rather than data_as(POINTER(c_float)): building the pointer
# objects costs several microseconds per argument, comparable to a small correlation.
lib.ccp_ncc_surface.argtypes = [ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint32, ctypes.c_void_p,
                                ctypes.c_uint32, ctypes.c_uint32, ctypes.c_void_p, ctypes.c_size_t]
lib.ccp_ncc_surface.restype = ctypes.c_int
lib.ccp_lsm.argtypes = [_fp, ctypes.c_uint32, ctypes.c_uint32, _fp, ctypes.c_uint32, ctypes.c_uint32,
                        ctypes.c_double, ctypes.c_double, ctypes.POINTER(CcpMatchResult)]
lib.ccp_lsm.restype = ctypes.c_int


def ncc_surface(image, template) -> np.ndarray:
    """Full NCC surface (as OpenCV matchTemplate TM_CCOEFF_NORMED)."""
    img = _grey(image, "image")
    tpl = _grey(template, "template")
    h, w = img.shape[0] - tpl.shape[0] + 1, img.shape[1] - tpl.shape[1] + 1
    if h <= 0 or w <= 0:
        raise ValueError("image is smaller than the template")
    out = np.empty((h, w), np.float32)
    # img, tpl and out stay referenced here for the duration of the call.
    check(lib.ccp_ncc_surface(img.ctypes.data, img.shape[1], img.shape[0],
                              tpl.ctypes.data, tpl.shape[1], tpl.shape[0],
                              out.ctypes.data, out.size))
    return out


def lsm(image, template, x: float, y: float) -> Match:
    """Least-squares matching alone from the template centre (x, y)."""
    img = _grey(image, "image")
    tpl = _grey(template, "template")
    out = CcpMatchResult()
    check(lib.ccp_lsm(img.ctypes.data_as(_fp), img.shape[1], img.shape[0],
                      tpl.ctypes.data_as(_fp), tpl.shape[1], tpl.shape[0],
                      float(x), float(y), ctypes.byref(out)))
    reason = out.reason.decode("utf-8", "replace") or None
    return Match(bool(out.accepted), out.x, out.y, out.ncc, out.ncc_x, out.ncc_y, out.ambiguity,
                 out.sigma_x, out.sigma_y, bool(out.lsm_converged), out.lsm_iterations,
                 tuple(out.affine), reason)
