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
    5: "FORMAT", 6: "NUMERIC", 7: "NOT_FOUND", 8: "BUFFER_TOO_SMALL", 9: "NOT_ORIENTED", 10: "INVALID_HANDLE", 11: "BUSY", 12: "PARTIAL",
    99: "PANIC",
}


class CloudControlError(Exception):
    """A failed C ABI call: ``status`` is the CcpStatus code, the message names the problem.

    Calls raise the subclass that matches Python's own exception where one fits, so that
    ``except FileNotFoundError`` or ``except ValueError`` work as a Python user expects:
    :class:`InputNotFoundError` (a ``FileNotFoundError``), :class:`InvalidInputError` (a
    ``ValueError``), :class:`InputOutputError` (an ``OSError``).
    """

    def __init__(self, status: int, message: str):
        self.status = status
        self.status_name = _STATUS_NAMES.get(status, str(status))
        self.message = message
        super().__init__(f"[{self.status_name}] {message}")

    def __str__(self) -> str:
        return f"[{self.status_name}] {self.message}"


class InputNotFoundError(CloudControlError, FileNotFoundError):
    """A file or folder named as an input does not exist (status NOT_FOUND)."""


class InvalidInputError(CloudControlError, ValueError):
    """An argument or an input file's content is invalid (INVALID_ARGUMENT, NOT_FINITE,
    FORMAT, NULL_POINTER, BUFFER_TOO_SMALL)."""


class InputOutputError(CloudControlError, OSError):
    """Reading or writing failed for another reason than a missing file (IO)."""


_STATUS_CLASSES = {
    1: InvalidInputError, 2: InvalidInputError, 3: InvalidInputError, 4: InputOutputError,
    5: InvalidInputError, 7: InputNotFoundError, 8: InvalidInputError,
}


def error_for(status: int, message: str) -> CloudControlError:
    """The exception for a failed call's status and message."""
    return _STATUS_CLASSES.get(status, CloudControlError)(status, message)


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


def _int_range(t) -> tuple[int, int]:
    bits = 8 * ctypes.sizeof(t)
    signed = t(-1).value == -1
    return (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)


_INT_RANGES = {t: _int_range(t) for t in (
    ctypes.c_uint8, ctypes.c_uint16, ctypes.c_uint32, ctypes.c_uint64, ctypes.c_size_t,
    ctypes.c_int8, ctypes.c_int16, ctypes.c_int32, ctypes.c_int64, ctypes.c_int)}


class _Library(ctypes.CDLL):
    """The shared library, with integer arguments range-checked before every call: ctypes
    converts ``-1`` for a ``uint32_t`` to 4294967295 without a word, so ``Camera(-1, …)``
    would reach the library as a camera four billion pixels wide."""

    def __init__(self, name: str):
        super().__init__(name)
        base = self._FuncPtr

        class _CheckedFunction(base):
            _flags_ = base._flags_
            _restype_ = base._restype_

            def __call__(self, *args):
                for i, (a, t) in enumerate(zip(args, self.argtypes or ())):
                    r = _INT_RANGES.get(t)
                    if r is not None and isinstance(a, int) and not r[0] <= a <= r[1]:
                        raise InvalidInputError(
                            2, f"{self.__name__}: argument {i + 1} is {a}, outside "
                               f"{t.__name__}'s range {r[0]}..{r[1]}")
                return super().__call__(*args)

        self._FuncPtr = _CheckedFunction


lib = _Library(str(_library_path()))

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
        raise error_for(status, last_error())


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
