"""The workflow on Dask: the per-tile tasks of the LiDAR cleaning, the reference epoch's
tie matching photo by photo (``pairs``), the per-photo tasks of the archive epochs and the
products' film resampling and orthophoto tiles fan out to the
workers of a ``dask.distributed.Client``, and so do the per-photo rounds of an epoch's
second pass, tie pass and tie points (``cut``, ``match``, ``reorient``) and the chips of
each DCP package, photo by photo (``chips``); the rest of each
stage (the strip offsets, what a round's results add up to, the epoch-wide adjustment, the
files written from the tasks' results) runs in this process.

A run alternates between :func:`cloudcontrol.pipeline.plan`, which runs every stage it can
and stops at the first one whose tasks have not all run, and a round of those
tasks on the cluster. Between the calls the run waits suspended in this process's copy of
the library, so a stage's global part is computed once, not replayed on each call. Each task reads its inputs from the output folder and the project's
files and writes its result there, atomically, so the folder must be on storage every
worker sees. A task whose worker dies is retried by Dask (``retries``), and a retried task
writes the same result; the products do not depend on which worker ran what, or how many
there were (byte-identical to ``cloudcontrol run``).
"""
from __future__ import annotations

import os
import time

from .pipeline import plan, run_task

__all__ = ["run", "run_task", "plan"]


def run(project: str | os.PathLike, client, retries: int = 3, on_round=None,
        partial_ok: bool = False) -> dict:
    """Runs ``project`` with its per-photo tasks on ``client``'s workers; returns what
    :func:`cloudcontrol.run` returns, plus ``"rounds"``: per round of tasks the stage,
    the number of tasks, the wall time of the round and the summed task time, and the
    items whose task reported a failure (``item``, the photo, and reason; the epoch goes
    on without them). ``on_round(stage, futures)`` is called with each round's futures as they are
    submitted (progress bars, tests). A run in which an epoch oriented fewer photos than
    it has raises :class:`cloudcontrol.PartialRunError` as :func:`cloudcontrol.run` does,
    unless ``partial_ok``."""
    rounds = []
    project = os.fspath(project)
    while True:
        t0 = time.perf_counter()
        res = plan(project, partial_ok=partial_ok)
        local_s = time.perf_counter() - t0
        pending = res.get("pending")
        if pending is None:
            res["rounds"] = rounds
            res["local_seconds_last"] = local_s
            return res
        tasks = pending["tasks"]
        t1 = time.perf_counter()
        # Keys name the stage, kind (and round) and item: a rerun of the same task is the
        # same key.
        futures = client.map(run_task, tasks, key=[_key(t) for t in tasks],
                             retries=retries, pure=False)
        if on_round is not None:
            on_round(pending["stage"], futures)
        done = client.gather(futures)
        rounds.append({
            "stage": pending["stage"],
            "kind": tasks[0]["kind"],
            "tasks": len(tasks),
            "local_seconds": local_s,
            "wall_seconds": time.perf_counter() - t1,
            "task_seconds": sum(d["seconds"] for d in done),
            "failed": [{"item": d["item"], "reason": d["reason"]} for d in done if not d["ok"]],
        })


def _key(task: dict) -> str:
    kind = task["kind"] if task.get("round") is None else f"{task['kind']}-{task['round']}"
    return f"cloudcontrol:{task['stage']}/{kind}/{task['item']}:{task['folder']}"
