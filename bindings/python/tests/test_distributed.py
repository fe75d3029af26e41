"""The workflow on Dask (cloudcontrol.distributed): the small preset run on a LocalCluster
of two worker processes, one of them killed while it orients an archive photo, gives the
products of `cloudcontrol run` byte for byte; a scan that cannot be read is reported with
its photo and reason and the epoch goes on without it. The same run planned from processes
of their own (each call replays the run from the results on disk, where the Dask run's
calls resume the run this process keeps suspended) gives the same products too."""
import filecmp
import json
import os
import pathlib
import signal
import subprocess
import sys
import threading
import time

import pytest

import cloudcontrol
from cloudcontrol import distributed, pipeline

dd = pytest.importorskip("dask.distributed")

BAD_SCAN = "film_s02_003"


def _block(shared_block, dest):
    # Seed 9: its digital epoch orients photo s01_001 only through tie points, then finds
    # its control patches from that pose, so every kind of round runs as tasks.
    d = shared_block("small", 9, "rough", dest)
    # The project synth writes, twice, with the outputs inside the copy: products name the
    # photos by their paths, so both runs read the same block.
    text = (d / "project.toml").read_text()
    assert 'output = "../run"' in text
    # The change analysis runs in the calling process (no tasks) after the surfaces: not
    # what this test is about, and a fifth of each run.
    text += "\n[outputs]\nchange = false\n"
    for name in ("plain", "dask", "replay"):
        (d / f"{name}.toml").write_text(text.replace('output = "../run"', f'output = "run_{name}"'))
    # A scan cut short, as a failed transfer leaves it.
    scan = d / "epochs" / "film_1978" / "images" / f"{BAD_SCAN}.png"
    scan.write_bytes(scan.read_bytes()[:4096])
    return d


def _files(root: pathlib.Path, products: dict) -> list[str]:
    out = []
    for paths in products.values():
        for p in map(pathlib.Path, paths):
            files = [p] if p.is_file() else sorted(f for f in p.rglob("*") if f.is_file())
            out += [str(f.relative_to(root)) for f in files]
    return sorted(out)


def _replayed(project: pathlib.Path) -> tuple[dict, int]:
    """Runs `project` with each planning call in a new process (no suspended run to
    resume: it replays from the result files) and the tasks here; the summary and the
    number of calls."""
    code = ("import json, sys; from cloudcontrol import pipeline; "
            "print(json.dumps(pipeline.plan(sys.argv[1], partial_ok=True)))")
    calls = 0
    while True:
        out = subprocess.run([sys.executable, "-c", code, str(project)], check=True,
                             capture_output=True, text=True).stdout
        calls += 1
        res = json.loads(out)
        if res.get("pending") is None:
            return res, calls
        for t in res["pending"]["tasks"]:
            pipeline.run_task(t)


def test_dask_run_with_a_killed_worker_gives_the_products_of_a_plain_run(shared_block, tmp_path):
    block = _block(shared_block, tmp_path / "block")
    # The bad scan leaves the film epoch partial: the summary is wanted, not the error.
    ours = cloudcontrol.run(block / "plain.toml", partial_ok=True)
    killed = {}

    with dd.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                         dashboard_address=None) as cluster, dd.Client(cluster) as client:
        pids = client.run(os.getpid)

        def kill_when_busy(folder: pathlib.Path):
            # Once the first photo of the round is done, both workers are orienting the
            # next ones: kill one mid-task.
            deadline = time.time() + 300
            while time.time() < deadline and not list(folder.glob("orient-*.msgpack")):
                time.sleep(0.05)
            addr, pid = sorted(pids.items())[0]
            os.kill(pid, signal.SIGKILL)
            killed.update(address=addr, pid=pid, at=time.time())

        def on_round(stage, futures):
            if stage == "epoch-digital_2012" and not killed:
                tasks = block / "run_dask" / "tasks" / stage
                folder = next(tasks.iterdir())
                threading.Thread(target=kill_when_busy, args=(folder,), daemon=True).start()

        res = distributed.run(block / "dask.toml", client, on_round=on_round, partial_ok=True)
        assert killed, "no worker was killed"
        # The nanny restarted the killed worker process.
        assert killed["pid"] not in client.run(os.getpid).values()

    # Every round of tasks ran; the bad scan is reported, photo and reason, and the
    # epoch went on.
    # The reference epoch matched each photo's pairs as tasks. The archive epochs' global
    # passes ran their per-photo rounds as tasks too: the digital epoch's second pass
    # (chips of its oriented photos, then s01_001 tried with them), tie pass (chips, s01_001
    # oriented from them, its tracks extended) and control patches searched from the tie
    # pose; the film epoch's second pass (the bad scan tried with its oriented photos'
    # chips; no tie pass, since ties cannot help a scan that cannot be read); both epochs'
    # tie points (chips, tracks on the DEM, tracks beyond it). Each DCP export cut its
    # chips photo by photo; each epoch's surface matched its stereo pairs.
    kinds = [(r["stage"], r["kind"]) for r in res["rounds"]]
    ties = ["cut", "match", "match"]
    digital = ["orient", "cut", "reorient", "cut", "reorient", "match", "reorient", *ties]
    assert kinds == [("sources", "screen"), ("sources", "clean"),
                     ("epoch-reference_2024", "pairs"),
                     ("dcp-reference_2024", "chips"),
                     *[("epoch-digital_2012", k) for k in digital],
                     ("dcp-digital_2012", "chips"),
                     ("epoch-film_1978", "scan"), ("epoch-film_1978", "orient"),
                     ("epoch-film_1978", "cut"), ("epoch-film_1978", "reorient"),
                     *[("epoch-film_1978", k) for k in ties],
                     # Each epoch's surface, a stereo pair a task, then its products.
                     ("surface-reference_2024", "stereo"), ("surface-digital_2012", "stereo"),
                     ("surface-film_1978", "stereo"),
                     ("outputs-reference_2024", "ortho"),
                     ("outputs-digital_2012", "ortho"), ("outputs-film_1978", "resample"),
                     ("outputs-film_1978", "ortho")]
    film = [r for r in res["rounds"] if r["stage"] == "epoch-film_1978"]
    assert [f["item"] for f in film[0]["failed"]] == [BAD_SCAN]
    assert "read" in film[0]["failed"][0]["reason"]
    retried = film[3]
    assert retried["tasks"] == 1 and [f["item"] for f in retried["failed"]] == [BAD_SCAN]
    film = {e["name"]: e for e in res["report"]["epochs"]}["film_1978"]
    assert film["photos_oriented"] == film["photos_total"] - 1
    assert not (block / "run_dask" / "tasks").exists()

    # The same products, file for file and byte for byte.
    plain, dask = block / "run_plain", block / "run_dask"
    a, b = _files(plain, ours["products"]), _files(dask, res["products"])
    assert a == b and len(a) > 20
    differ = [f for f in a if not filecmp.cmp(plain / f, dask / f, shallow=False)]
    assert differ == []
    # Planned call by call from new processes, each replaying the run: the same products.
    replay, calls = _replayed(block / "replay.toml")
    assert calls == len(res["rounds"]) + 1
    c = _files(block / "run_replay", replay["products"])
    assert c == a
    differ = [f for f in a if not filecmp.cmp(plain / f, block / "run_replay" / f, shallow=False)]
    assert differ == []
    # The photo the tie pass oriented holds control patches found from its tie pose.
    photos = json.loads((dask / "epoch-digital_2012" / "result.json").read_text())["photos"]
    s01 = {p["name"]: p for p in photos}["digital_s01_001"]
    assert s01["tie_pass"] and s01["control_matches"] >= 4, s01
