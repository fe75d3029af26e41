"""Loading of the cloudcontrol shared library and the error convention of its C ABI.

Every C function returns a status (0 = OK); on failure the thread-local message from
``ccp_last_error`` is raised as :class:`CloudControlError`.
"""
from __future__ import annotations

import ctypes
import os
import pathlib
import sys

import numpy as np

_STATUS_NAMES = {
    0: "OK", 1: "NULL_POINTER", 2: "INVALID_ARGUMENT", 3: "NOT_FINITE", 4: "IO",
    5: "FORMAT", 6: "NUMERIC", 7: "NOT_FOUND", 8: "BUFFER_TOO_SMALL", 9: "NOT_ORIENTED", 10: "INVALID_HANDLE", 99: "PANIC",
}


class CloudControlError(RuntimeError):
    """A failed C ABI call: ``status`` is the CcpStatus code, the message names the problem."""

    def __init__(self, status: int, message: str):
        self.status = status
        self.status_name = _STATUS_NAMES.get(status, str(status))
        super().__init__(f"[{self.status_name}] {message}")


def _library_path() -> pathlib.Path:
    env = os.environ.get("CLOUDCONTROL_LIB")
    if env:
        return pathlib.Path(env)
    name = {"darwin": "libcloudcontrol.dylib", "win32": "cloudcontrol.dll"}.get(sys.platform, "libcloudcontrol.so")
    here = pathlib.Path(__file__).resolve()
    candidates = [here.parent / name]
    # Editable install inside the repository: bindings/python/cloudcontrol -> repo root.
    for up in here.parents:
        candidates.append(up / "target" / "release" / name)
    for c in candidates:
        if c.exists():
            return c
    raise OSError(f"cannot find {name}: build it with `cargo build --release` or set CLOUDCONTROL_LIB")


lib = ctypes.CDLL(str(_library_path()))

lib.ccp_version.restype = ctypes.c_char_p
lib.ccp_version.argtypes = []
lib.ccp_last_error.restype = ctypes.c_size_t
lib.ccp_last_error.argtypes = [ctypes.c_char_p, ctypes.c_size_t]

c_double_p = ctypes.POINTER(ctypes.c_double)


def last_error() -> str:
    n = lib.ccp_last_error(None, 0)
    buf = ctypes.create_string_buffer(max(n, 1))
    lib.ccp_last_error(buf, n)
    return buf.value.decode("utf-8", "replace")


def check(status: int) -> None:
    """Raises CloudControlError for a non-zero status."""
    if status != 0:
        raise CloudControlError(status, last_error())


def as_f64(a, cols: int | None = None, name: str = "array") -> np.ndarray:
    """C-contiguous float64 copy/view of ``a``; with ``cols`` it is reshaped to (n, cols)."""
    arr = np.ascontiguousarray(a, dtype=np.float64)
    if cols is not None:
        if arr.ndim == 1 and arr.size == cols:
            arr = arr.reshape(1, cols)
        if arr.ndim != 2 or arr.shape[1] != cols:
            raise ValueError(f"{name} must have shape (n, {cols}), got {arr.shape}")
    return arr


def ptr(a: np.ndarray):
    return a.ctypes.data_as(c_double_p)


def version() -> str:
    return lib.ccp_version().decode()
