"""Format adapters over the C ABI: block conversion (COLMAP <-> BlocksExchange),
orthophotos and DEM GeoTIFFs."""
from __future__ import annotations

import ctypes
import os

import numpy as np

from ._ffi import CloudControlError, check, lib

_cs = ctypes.c_char_p
_sz = ctypes.c_size_t
_dp = ctypes.POINTER(ctypes.c_double)
_fp = ctypes.POINTER(ctypes.c_float)

lib.ccp_convert.argtypes = [_cs, _cs, ctypes.c_int32, ctypes.c_int32]
lib.ccp_convert.restype = ctypes.c_int
lib.ccp_orthophoto.argtypes = [_cs, _cs, _cs, _cs, ctypes.c_double, ctypes.c_int32,
                               ctypes.POINTER(_sz), ctypes.POINTER(_sz)]
lib.ccp_orthophoto.restype = ctypes.c_int
lib.ccp_dem_write.argtypes = [_cs, _sz, _sz, _dp, _fp, _sz, _cs]
lib.ccp_dem_write.restype = ctypes.c_int
lib.ccp_dem_read.argtypes = [_cs, ctypes.POINTER(_sz), ctypes.POINTER(_sz), _dp, _fp, _sz]
lib.ccp_dem_read.restype = ctypes.c_int
lib.ccp_block_summary.argtypes = [_cs, ctypes.POINTER(ctypes.c_uint64)]
lib.ccp_block_summary.restype = ctypes.c_int


def _b(path) -> bytes:
    return os.fsencode(os.fspath(path))


def convert(src, dst, *, text: bool = False, legacy: bool = False) -> None:
    """Converts a block between a COLMAP model folder and a BlocksExchange ``.xml``
    (format by path). COLMAP output is binary unless ``text``, COLMAP 4 layout (with
    rigs/frames) unless ``legacy``."""
    check(lib.ccp_convert(_b(src), _b(dst), int(text), int(legacy)))


def summary(path) -> dict:
    """Reads a block (COLMAP folder or BlocksExchange .xml) and returns its size."""
    c = (ctypes.c_uint64 * 4)()
    check(lib.ccp_block_summary(_b(path), c))
    return dict(zip(("cameras", "photos", "points", "observations"), map(int, c)))


def orthophoto(block, dem, images_dir, out, *, gsd: float = 0.0, cog: bool = False) -> tuple[int, int]:
    """Writes the true orthophoto (RGB + alpha GeoTIFF) of a block on a DEM GeoTIFF and
    returns its (width, height). ``gsd`` <= 0 picks the photos' median ground pixel."""
    w, h = _sz(), _sz()
    check(lib.ccp_orthophoto(_b(block), _b(dem), _b(images_dir), _b(out), float(gsd), int(cog),
                             ctypes.byref(w), ctypes.byref(h)))
    return w.value, h.value


def write_dem(path, heights, geotransform, crs: str) -> None:
    """Writes a float32 DEM GeoTIFF; ``heights`` is (rows, cols), NaN for no data;
    ``geotransform`` is GDAL's north-up 6-tuple."""
    z = np.ascontiguousarray(heights, dtype=np.float32)
    if z.ndim != 2:
        raise ValueError(f"heights must be 2-D, got shape {z.shape}")
    gt = np.ascontiguousarray(geotransform, dtype=np.float64)
    if gt.shape != (6,):
        raise ValueError(f"geotransform must have 6 values, got {gt.shape}")
    check(lib.ccp_dem_write(_b(path), z.shape[1], z.shape[0], gt.ctypes.data_as(_dp),
                            z.ctypes.data_as(_fp), z.size, crs.encode()))


def read_dem(path) -> tuple[np.ndarray, np.ndarray]:
    """Reads a DEM GeoTIFF: (heights (rows, cols) float32 with NaN for nodata, geotransform)."""
    w, h = _sz(), _sz()
    gt = np.zeros(6)
    status = lib.ccp_dem_read(_b(path), ctypes.byref(w), ctypes.byref(h), gt.ctypes.data_as(_dp), None, 0)
    if status != 8:  # BUFFER_TOO_SMALL is the expected answer to the size query
        check(status)
    z = np.empty((h.value, w.value), dtype=np.float32)
    check(lib.ccp_dem_read(_b(path), ctypes.byref(w), ctypes.byref(h), gt.ctypes.data_as(_dp),
                           z.ctypes.data_as(_fp), z.size))
    return z, gt


__all__ = ["convert", "summary", "orthophoto", "write_dem", "read_dem", "CloudControlError"]
