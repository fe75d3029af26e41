#!/usr/bin/env python3
"""Builds fuzz/corpus/task_files/: real task files of a planned run, one small seed per
file name of fuzz/src/lib.rs `TASK_FILES`.

A run of the small synthetic block (seed 9: every kind of task, as
bindings/python/tests/test_distributed.py) is planned through the C ABI
(cloudcontrol.pipeline.plan) and its tasks run one by one (run_task); every task file is
copied before its stage removes its folder. Each seed is its file with every array of more
than 64 elements (16 where the file stays over 16 KB) cut to its first 4 and every byte
string over 256 bytes to 64 (chips, points of a strip sample, tile pixels), so the seeds
stay a few KB; it is prefixed with its name's index in TASK_FILES (the target's
first byte).

    .venv/bin/python fuzz/make_task_corpus.py [WORK]   # needs target/release (the CLI
                                                       # and libcloudcontrol.so), msgpack
WORK (default /tmp/cloudcontrol-task-corpus) keeps the block and the copied files; a
second call reuses them.
"""
import os, pathlib, re, shutil, subprocess, sys

import msgpack

FUZZ = pathlib.Path(__file__).resolve().parent
ROOT = FUZZ.parent
WORK = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else "/tmp/cloudcontrol-task-corpus")
LIB = os.environ.get("CLOUDCONTROL_LIB", str(ROOT / "target" / "release" / "libcloudcontrol.so"))
CLI = os.environ.get("CLOUDCONTROL_CLI", str(ROOT / "target" / "release" / "cloudcontrol"))

# fuzz/src/lib.rs TASK_FILES, in its order.
src = (FUZZ / "src" / "lib.rs").read_text()
names = re.findall(r'"([a-z_0-9-]+\.msgpack)"', src[src.index("pub const TASK_FILES"):])[:17]
assert len(names) == 17, names


def collect():
    os.environ["CLOUDCONTROL_LIB"] = LIB
    sys.path.insert(0, str(ROOT / "bindings" / "python"))
    from cloudcontrol.pipeline import plan, run_task
    block = WORK / "block"
    if not (block / "project.toml").exists():
        subprocess.run([CLI, "synth", "-q", "--preset", "small", "--pos", "rough", "--seed", "9",
                        "--out", str(block)], check=True)
    text = (block / "project.toml").read_text()
    (block / "tasks.toml").write_text(text.replace('output = "../run"', 'output = "run_tasks"'))
    files = WORK / "files"

    def grab():
        for f in (block / "run_tasks" / "tasks").rglob("*.msgpack"):
            dst = files / f.parent.parent.name / f.name
            if not dst.exists():
                dst.parent.mkdir(parents=True, exist_ok=True)
                shutil.copy(f, dst)

    while True:
        res = plan(block / "tasks.toml")
        grab()
        pending = res.get("pending")
        if pending is None:
            return
        for t in pending["tasks"]:
            run_task(t)
        grab()


def pattern(name):
    """The file names of a TASK_FILES name: its numbers any numbers."""
    return re.compile("^" + re.sub(r"[0-9]+", "[0-9]+", re.escape(name)) + "$")


def cut(v, most):
    """Arrays of more than `most` elements cut to their first 4, byte strings of more than
    256 bytes (PNG chips) to their first 64; a chip's grey values (`width`, `height`,
    `grey`) to its top-left 8 x 8, an orthophoto tile's pixels (`bands`) to 16 and its
    counts of cells with them, so the cut files still pass the reading checks."""
    if isinstance(v, list):
        return [cut(x, most) for x in (v[:4] if len(v) > most else v)]
    if isinstance(v, dict):
        if {"width", "height", "grey"} <= v.keys() and isinstance(v["grey"], dict):
            w, h = v["width"], v["height"]
            if w >= 8 and h >= 8:
                (kind, values), = v["grey"].items()
                top_left = [values[r * w + c] for r in range(8) for c in range(8)]
                return dict(v, width=8, height=8, grey={kind: top_left})
        if isinstance(v.get("bands"), bytes) and len(v["bands"]) > 64:
            n = len(v["bands"]) // 4
            bands = b"".join(v["bands"][k * n:k * n + 16] for k in range(4))
            per = v.get("per_photo") or {}
            return dict({k: cut(x, most) for k, x in v.items()}, bands=bands,
                        filled=min(v.get("filled", 0), 16), occluded=min(v.get("occluded", 0), 16),
                        per_photo={k: min(x, 16 // max(1, len(per))) for k, x in per.items()})
        return {k: cut(x, most) for k, x in v.items()}
    if isinstance(v, bytes) and len(v) > 256:
        return v[:64]
    return v


def small(raw):
    """The file cut (arrays of > 64, then of > 16 elements while over 16 KB)."""
    v = msgpack.unpackb(raw, raw=False, strict_map_key=False)
    for most in (64, 16):
        data = msgpack.packb(cut(v, most), use_bin_type=True)
        if len(data) <= 16384:
            break
    return data


if not (WORK / "files").is_dir():
    collect()
every = sorted((WORK / "files").rglob("*.msgpack"))
out = FUZZ / "corpus" / "task_files"
out.mkdir(parents=True, exist_ok=True)
for k, name in enumerate(names):
    found = [f for f in every if pattern(name).match(f.name)]
    if not found and name.startswith("round-"):
        # A whole round's file is the type of a photo's part of it (a planned run writes
        # the parts).
        found = [f for f in every if pattern(name[:-len(".msgpack")] + "-0.msgpack").match(f.name)]
    if not found:
        print(f"no {name} in the run", file=sys.stderr)
        continue
    # The smallest after cutting, of each stage the kind occurs in.
    by_stage = {}
    for f in found:
        data = small(f.read_bytes())
        stage = re.sub(r"[-_][0-9a-z]*$", "", f.parent.name)
        if stage not in by_stage or len(data) < len(by_stage[stage][1]):
            by_stage[stage] = (f, data)
    for stage, (f, data) in sorted(by_stage.items()):
        seed = out / f"{k:02d}-{f.parent.name}-{f.name}"
        seed.write_bytes(bytes([k]) + data)
        print(f"{seed.name}: {len(data)} bytes (from {f.stat().st_size})")
