"""The workflow over the C ABI: run a project file and load its results."""
from __future__ import annotations

import ctypes
import json
import os
from pathlib import Path

from ._ffi import CloudControlError, check, last_error, lib

lib.ccp_project_run.argtypes = [ctypes.c_char_p, ctypes.POINTER(ctypes.c_void_p)]
lib.ccp_project_run.restype = ctypes.c_int
lib.ccp_string_free.argtypes = [ctypes.c_void_p]
lib.ccp_string_free.restype = ctypes.c_int
lib.ccp_project_plan.argtypes = [ctypes.c_char_p, ctypes.POINTER(ctypes.c_void_p)]
lib.ccp_project_plan.restype = ctypes.c_int
lib.ccp_task_run.argtypes = [ctypes.c_char_p, ctypes.POINTER(ctypes.c_void_p)]
lib.ccp_task_run.restype = ctypes.c_int


#: CcpStatus of a run that finished with an epoch orienting fewer photos than it has.
PARTIAL = 12


class PartialRunError(CloudControlError):
    """A run finished, but an epoch oriented fewer photos than it has (status PARTIAL; the
    CLI's exit status 3). The products of what was oriented are written. ``summary`` is
    what :func:`run` returns, and ``partial`` its ``summary["partial"]``: per such epoch
    ``epoch``, ``oriented``, ``total`` and ``not_oriented`` (each ``photo`` with its
    ``reason``). Pass ``partial_ok=True`` to :func:`run` to get the summary returned
    instead."""

    def __init__(self, status: int, message: str, summary: dict):
        super().__init__(status, message)
        self.summary = summary
        self.partial = summary.get("partial", [])


def _json_call(fn, arg: bytes, partial_ok: bool = False) -> dict:
    out = ctypes.c_void_p()
    status = fn(arg, ctypes.byref(out))
    if status != PARTIAL or not out.value:
        check(status)
    message = last_error() if status == PARTIAL else ""
    try:
        res = json.loads(ctypes.string_at(out.value).decode())
    finally:
        lib.ccp_string_free(out)
    if status == PARTIAL and not partial_ok:
        raise PartialRunError(status, message, res)
    return res


def run(project: str | os.PathLike, partial_ok: bool = False) -> dict:
    """Runs a project (TOML, formats/project/README.md); finished stages whose inputs did
    not change are skipped. Returns ``{"output", "ran", "skipped", "products", "partial",
    "report"}``; ``report["epochs"]`` holds per epoch ``name``, ``gsd_m``, ``photos_total``,
    ``photos_oriented``, ``check_rmse_plan_m``, ``check_rmse_height_m``, ``time_s``, the
    checkpoint errors and per-photo summaries. Raises CloudControlError naming the key of
    an invalid project file before any work starts, and :class:`PartialRunError` (with the
    summary) when an epoch oriented fewer photos than it has, unless ``partial_ok``: then
    the summary is returned and its ``partial`` lists those epochs."""
    return _json_call(lib.ccp_project_run, os.fsencode(project), partial_ok)


def plan(project: str | os.PathLike, partial_ok: bool = False) -> dict:
    """Runs a project as :func:`run` does, except for its tasks (the LiDAR cleaning per
    tile, the archive epochs' per-photo orientation, the products' film resampling and
    orthophoto tiles): the run stops at the first stage whose tasks have not all run and returns ``{"pending": {"stage": ..., "tasks": [...]}}``. Run each task with :func:`run_task`
    (anywhere the output folder is shared), then call again; with nothing pending it
    returns what :func:`run` returns (or raises :class:`PartialRunError` as it does)."""
    return _json_call(lib.ccp_project_plan, os.fsencode(project), partial_ok)


def run_task(task: dict) -> dict:
    """Runs one task of :func:`plan` and writes its result file (atomically) into the
    run's output folder. Returns ``{"task", "item", "ok", "reason", "seconds"}`` (``item``:
    the photo, the LiDAR tile or the run of orthophoto tiles); a photo that could not be oriented is ``ok: False`` with its
    reason, not an exception."""
    return _json_call(lib.ccp_task_run, json.dumps(task).encode())


def load_report(output: str | os.PathLike) -> dict:
    """The report of a finished run, from its output folder (``report/report.json``)."""
    return json.loads((Path(output) / "report" / "report.json").read_text())
