#!/usr/bin/env python3
"""Benchmark (not a timed test): the workflow on Dask against `cloudcontrol run`, on one
synthetic block, in the same run: wall time with 1 and with 2 worker processes of a
LocalCluster, the time of each round of per-photo tasks (what runs in parallel) against
the time in the client process (what is global: the reference epoch, the DCP export, the
epoch adjustments, the products), and whether the products are byte-identical.

    cargo build --release
    .venv/bin/python benches/distributed_dask.py --block /tmp/m1/block [--workers 1 2]

`--block` is a folder `cloudcontrol synth` wrote (its project.toml is used, with the
output redirected); without it the block is generated with `--preset` and `--seed`.
"""
from __future__ import annotations

import argparse
import filecmp
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
BIN = pathlib.Path(os.environ.get("CLOUDCONTROL_BIN", ROOT / "target" / "release" / "cloudcontrol"))
sys.path.insert(0, str(ROOT / "bindings" / "python"))


def project_with_output(block: pathlib.Path, name: str) -> pathlib.Path:
    text = (block / "project.toml").read_text()
    assert 'output = "../run"' in text, "not a project synth wrote"
    p = block / f"bench_{name}.toml"
    p.write_text(text.replace('output = "../run"', f'output = "bench_{name}"'))
    return p


def _peak_rss_kib() -> float:
    """This process's peak resident memory since `_reset_peak` (VmHWM, KiB). Not
    ru_maxrss: a worker process inherits its parent's peak through fork and exec."""
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return float(line.split()[1])
    raise RuntimeError("no VmHWM in /proc/self/status")


def _reset_peak() -> None:
    # Linux >= 4.0: writing 5 resets the peak resident set size to the current one.
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")


def product_files(root: pathlib.Path, products: dict) -> list[str]:
    out = []
    for paths in products.values():
        for p in map(pathlib.Path, paths):
            files = [p] if p.is_file() else sorted(f for f in p.rglob("*") if f.is_file())
            out += [str(f.relative_to(root)) for f in files]
    return sorted(out)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--block", type=pathlib.Path)
    ap.add_argument("--preset", default="medium")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--json", type=pathlib.Path, help="write the results here too")
    ap.add_argument("--reuse-plain", action="store_true",
                    help="take the plain run's products from an earlier run of this script")
    a = ap.parse_args()

    from dask.distributed import Client, LocalCluster
    from cloudcontrol import distributed

    block = a.block
    if block is None:
        block = pathlib.Path(tempfile.mkdtemp(prefix="cc-dask-")) / "block"
        subprocess.run([str(BIN), "synth", "--preset", a.preset, "--seed", str(a.seed),
                        "--out", str(block)], check=True)
    block = block.resolve()

    results = {"block": str(block), "runs": []}
    # The plain run: one process, per-photo tasks on its own threads.
    plain = project_with_output(block, "plain")
    if not a.reuse_plain:
        subprocess.run(["rm", "-rf", str(block / "bench_plain")], check=True)
    t = time.perf_counter()
    # With --reuse-plain every stage is found finished and skipped: the summary only.
    out = subprocess.run([str(BIN), "--json", "run", str(plain)], check=True,
                         capture_output=True, text=True).stdout
    wall = time.perf_counter() - t
    summary = json.loads(out)
    import resource
    plain_mib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    results["runs"].append({"how": "cloudcontrol run", "wall_s": wall, "peak_mib": plain_mib,
                            "stage_seconds": summary["stage_seconds"]})
    print(f"cloudcontrol run: {wall:.1f} s, peak RSS {plain_mib:.0f} MiB")
    for stage, s in summary["stage_seconds"]:
        print(f"  {stage:<28} {s:8.1f} s")

    for n in a.workers:
        proj = project_with_output(block, f"dask{n}")
        subprocess.run(["rm", "-rf", str(block / f"bench_dask{n}")], check=True)
        # Dask's own default for a LocalCluster: the machine's cores shared out among the
        # workers (1 worker: 2 threads on 2 cores, as the plain run has; 2 workers: 1 each).
        threads = max(1, (os.cpu_count() or 1) // n)
        with LocalCluster(n_workers=n, threads_per_worker=threads, processes=True,
                          dashboard_address=None) as cluster, Client(cluster) as client:
            client.run(_reset_peak)
            _reset_peak()
            t = time.perf_counter()
            res = distributed.run(proj, client)
            wall = time.perf_counter() - t
            # Peak resident memory of each worker process (MiB; ru_maxrss is KiB on Linux).
            worker_mib = sorted(v / 1024 for v in client.run(_peak_rss_kib).values())
        client_mib = _peak_rss_kib() / 1024
        tasks_wall = sum(r["wall_seconds"] for r in res["rounds"])
        a_files = product_files(block / "bench_plain", summary["products"])
        b_files = product_files(block / f"bench_dask{n}", res["products"])
        same = a_files == b_files and all(
            filecmp.cmp(block / "bench_plain" / f, block / f"bench_dask{n}" / f, shallow=False)
            for f in a_files)
        results["runs"].append({"how": f"dask, {n} worker process(es)", "threads_per_worker": threads,
                                "wall_s": wall, "ratio_to_plain": wall / results["runs"][0]["wall_s"],
                                "tasks_wall_s": tasks_wall, "client_s": wall - tasks_wall,
                                "rounds": res["rounds"], "identical_products": same,
                                "worker_peak_mib": worker_mib, "client_peak_mib": client_mib,
                                "product_files": len(a_files)})
        print(f"dask, {n} worker(s) x {threads} thread(s): {wall:.1f} s = {tasks_wall:.1f} s in task rounds "
              f"+ {wall - tasks_wall:.1f} s in the client; products identical: {same} "
              f"({len(a_files)} files); peak RSS per worker {', '.join(f'{m:.0f}' for m in worker_mib)} MiB, "
              f"client {client_mib:.0f} MiB; {wall / results['runs'][0]['wall_s']:.2f}x the plain run")
        for r in res["rounds"]:
            print(f"  {r['stage']:<22} {r['kind']:<7} {r['tasks']:>4} tasks  "
                  f"{r['wall_seconds']:7.1f} s wall  {r['task_seconds']:7.1f} s summed  "
                  f"{len(r['failed'])} failed")
    if a.json:
        a.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
