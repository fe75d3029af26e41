"""The workflow over the C ABI: run a project file and load its results."""
from __future__ import annotations

import ctypes
import json
import os
from pathlib import Path

from ._ffi import check, lib

lib.ccp_project_run.argtypes = [ctypes.c_char_p, ctypes.POINTER(ctypes.c_void_p)]
lib.ccp_project_run.restype = ctypes.c_int
lib.ccp_string_free.argtypes = [ctypes.c_void_p]
lib.ccp_string_free.restype = ctypes.c_int
lib.ccp_project_plan.argtypes = [ctypes.c_char_p, ctypes.POINTER(ctypes.c_void_p)]
lib.ccp_project_plan.restype = ctypes.c_int
lib.ccp_task_run.argtypes = [ctypes.c_char_p, ctypes.POINTER(ctypes.c_void_p)]
lib.ccp_task_run.restype = ctypes.c_int


def _json_call(fn, arg: bytes) -> dict:
    out = ctypes.c_void_p()
    check(fn(arg, ctypes.byref(out)))
    try:
        return json.loads(ctypes.string_at(out.value).decode())
    finally:
        lib.ccp_string_free(out)


def run(project: str | os.PathLike) -> dict:
    """Runs a project (TOML, formats/project/README.md); finished stages whose inputs did
    not change are skipped. Returns ``{"output", "ran", "skipped", "products", "report"}``;
    ``report["epochs"]`` holds per epoch ``name``, ``gsd_m``, ``photos_total``,
    ``photos_oriented``, ``check_rmse_plan_m``, ``check_rmse_height_m``, ``time_s``, the
    checkpoint errors and per-photo summaries. Raises CloudControlError naming the key of
    an invalid project file before any work starts."""
    return _json_call(lib.ccp_project_run, os.fsencode(project))


def plan(project: str | os.PathLike) -> dict:
    """Runs a project as :func:`run` does, except for its tasks (the LiDAR cleaning per
    tile, the archive epochs' per-photo orientation, the products' film resampling and
    orthophoto tiles): the run stops at the first stage whose tasks have not all run and returns ``{"pending": {"stage": ..., "tasks": [...]}}``. Run each task with :func:`run_task`
    (anywhere the output folder is shared), then call again; with nothing pending it
    returns what :func:`run` returns."""
    return _json_call(lib.ccp_project_plan, os.fsencode(project))


def run_task(task: dict) -> dict:
    """Runs one task of :func:`plan` and writes its result file (atomically) into the
    run's output folder. Returns ``{"task", "item", "ok", "reason", "seconds"}`` (``item``:
    the photo, the LiDAR tile or the run of orthophoto tiles); a photo that could not be oriented is ``ok: False`` with its
    reason, not an exception."""
    return _json_call(lib.ccp_task_run, json.dumps(task).encode())


def load_report(output: str | os.PathLike) -> dict:
    """The report of a finished run, from its output folder (``report/report.json``)."""
    return json.loads((Path(output) / "report" / "report.json").read_text())
