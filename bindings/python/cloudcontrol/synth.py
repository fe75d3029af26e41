"""Synthetic aerial blocks with ground truth over the C ABI (layout: formats/synth/README.md)."""
from __future__ import annotations

import ctypes
import json
import os
import pathlib

from ._ffi import check, lib

lib.ccp_synth_generate.argtypes = [
    ctypes.c_char_p, ctypes.c_uint32, ctypes.c_uint64, ctypes.c_double, ctypes.c_uint32, ctypes.c_uint32,
]
lib.ccp_synth_generate.restype = ctypes.c_int

_PRESETS = {"tiny": 0, "small": 1, "medium": 2, "large": 3}
_POS = {"good": 0, "rough": 1, "none": 2}


def generate(out_dir: str | os.PathLike, preset: str = "small", seed: int = 1, change: float = 0.5,
             pos: str = "rough", laz: bool = False) -> dict:
    """Writes a block into ``out_dir`` and returns its manifest (parsed manifest.json)."""
    if preset not in _PRESETS:
        raise ValueError(f"preset must be one of {sorted(_PRESETS)}, got {preset!r}")
    if pos not in _POS:
        raise ValueError(f"pos must be one of {sorted(_POS)}, got {pos!r}")
    out = pathlib.Path(out_dir)
    check(lib.ccp_synth_generate(os.fsencode(out), _PRESETS[preset], int(seed), float(change), _POS[pos], int(laz)))
    return json.loads((out / "manifest.json").read_text())
