#!/usr/bin/env python3
"""Fiducial interior orientation of film scans: `cloudcontrol io` against an OpenCV template
search (cv2.matchTemplate, TM_CCOEFF_NORMED, ±6 mm windows around the predicted marks, the
peak refined by a parabola per axis) on the same synthetic scans in the same run.

    nice cargo build --release --bin cloudcontrol
    python3 -m venv .venv && .venv/bin/pip install -q -r benches/requirements.txt
    .venv/bin/python benches/fiducial_opencv.py [--pixel-um 21 42] [--seeds 0 1 2 3]
        [--scans DIR] [--repeat 5]

Scans: 8-bit grey uncompressed TIFF (strips of 8 rows) of a 240 mm square around the Wild
RC10 frame of formats/cameras/wild_rc10.json (eight crosses, a dot in the corner ones),
marks drawn by 5×5 supersampling through a random scanner affine (±0.2 % scale, ±0.1 %
shear, ±0.6° film rotation, ±1.5 mm off centre, as src/synth/film.rs's
random_scan_affine) in an orientation the seed picks (upright, rotated, mirrored), on a
textured photograph and the opaque frame with film grain. They are drawn here with numpy,
independently of the library's mark shapes, and kept in --scans (default: a folder in the
system's temporary folder) for the next run; `<scan>.json` beside each holds its true mark
centres (pixels, corner origin: the first pixel's centre is (0.5, 0.5)). 5.7k² pixels
(31 MiB) at 42 µm, 11.4k² (125 MiB) at 21 µm.

Ours: `cloudcontrol --json io --camera wild_rc10.json scan.tif` in its own process, as a
user runs it: the scan orientation searched among all eight (each hypothesis measures the
eight marks), ±10 mm wide search; timed from outside (wall clock from spawning the process
to its end, so start-up and reading are in); peak memory its maximum resident set under
/usr/bin/time, in a run of its own.
OpenCV: in this process, cv2.imread of the whole scan (OpenCV reads no windows) and one
matchTemplate per mark in a ±6 mm window around its prediction from the nominal pixel size
and the true orientation (given to it), the template drawn from the camera definition's
mark at the nominal pixel. The two alternate and each time is the best of --repeat runs
(the machine is shared). Accuracy: RMS and largest distance (px) of the eight marks to
the truth. Ratio = OpenCV's time / ours (> 1: we are faster).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import pathlib
import subprocess
import tempfile
import time

import cv2
import numpy as np
import tifffile

ROOT = pathlib.Path(__file__).resolve().parents[1]
BIN = ROOT / "target" / "release" / "cloudcontrol"
CAMERA = ROOT / "formats" / "cameras" / "wild_rc10.json"
SCAN_MM = 240.0
SEARCH_MM = 6.0
SS = 5

# The square's rotations and reflections (as ScanOrientation: pixel → mm rotated
# counter-clockwise by `rot` and, when mirrored, reflected in the y axis first).
ORIENTATIONS = [(0, False), (90, False), (180, False), (270, True), (0, True), (270, False)]


def orientation_linear(rot, mirrored, s):
    base = np.array([[s, 0.0], [0.0, -s]])
    m = np.diag([-1.0, 1.0]) if mirrored else np.eye(2)
    c, si = {0: (1, 0), 90: (0, 1), 180: (-1, 0), 270: (0, -1)}[rot]
    return np.array([[c, -si], [si, c]]) @ m @ base


def covers(shape, x, y):
    """The camera definition's primitive cross (with its optional dot), mm from the mark."""
    h, l = shape["size_mm"] / 2.0, shape["line_mm"] / 2.0
    hit = ((np.abs(x) <= l) & (np.abs(y) <= h)) | ((np.abs(y) <= l) & (np.abs(x) <= h))
    if shape.get("dot_mm"):
        hit |= np.hypot(x, y) <= shape["dot_mm"] / 2.0
    return hit


def true_affine(rng, n, s, rot, mirrored):
    """Pixel → mm: mm = lin · (px − centre) + shift (px corner origin)."""
    sx = 1.0 + rng.uniform(-2e-3, 2e-3)
    sy = 1.0 + rng.uniform(-2e-3, 2e-3)
    shear = rng.uniform(-1e-3, 1e-3)
    a = math.radians(rng.uniform(-0.6, 0.6))
    r = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    lin = r @ orientation_linear(rot, mirrored, s) @ np.array([[sx, shear], [0.0, sy]])
    shift = rng.uniform(-1.5, 1.5, 2)
    return lin, np.array([n / 2.0, n / 2.0]), shift


def render(path, cam, pixel_um, seed):
    s = pixel_um / 1000.0
    n = int(round(SCAN_MM / s))
    rng = np.random.default_rng(1000 + seed)
    rot, mirrored = ORIENTATIONS[seed % len(ORIENTATIONS)]
    lin, centre, shift = true_affine(rng, n, s, rot, mirrored)
    inv = np.linalg.inv(lin)
    img = np.empty((n, n), np.uint8)
    cols = np.arange(n) + 0.5 - centre[0]
    for r0 in range(0, n, 256):
        rows = np.arange(r0, min(n, r0 + 256)) + 0.5 - centre[1]
        x = lin[0, 0] * cols[None, :] + lin[0, 1] * rows[:, None] + shift[0]
        y = lin[1, 0] * cols[None, :] + lin[1, 1] * rows[:, None] + shift[1]
        inside = (np.abs(x) < 114.0) & (np.abs(y) < 114.0)
        photo = (np.abs(x) < 100.0) & (np.abs(y) < 100.0)
        v = np.where(inside, 24.0, 14.0)
        tex = 110.0 + 45.0 * np.sin(x / 3.1) * np.cos(y / 4.7) + 20.0 * np.sin(x * 1.7 + y * 0.9)
        v = np.where(photo, tex, v) + rng.normal(0.0, 4.0, x.shape)
        img[r0 : r0 + len(rows)] = np.clip(np.rint(v), 0, 255).astype(np.uint8)
    truth = {}
    sub = (np.arange(SS) + 0.5) / SS
    for f in cam["fiducials"]:
        mm = np.array([f["x_mm"], f["y_mm"]])
        c = inv @ (mm - shift) + centre
        truth[f["id"]] = [float(c[0]), float(c[1])]
        half = int(math.ceil(0.8 / s)) + 2
        c0, r0 = int(c[0]) - half, int(c[1]) - half
        pc = c0 + np.arange(2 * half)[None, :, None, None] + sub[None, None, None, :]
        pr = r0 + np.arange(2 * half)[:, None, None, None] + sub[None, None, :, None]
        dx, dy = pc - centre[0], pr - centre[1]
        x = lin[0, 0] * dx + lin[0, 1] * dy + shift[0] - mm[0]
        y = lin[1, 0] * dx + lin[1, 1] * dy + shift[1] - mm[1]
        cov = covers(f["shape"], x, y).mean(axis=(2, 3))
        patch = img[r0 : r0 + 2 * half, c0 : c0 + 2 * half].astype(np.float64)
        img[r0 : r0 + 2 * half, c0 : c0 + 2 * half] = np.clip(
            np.rint(patch + 190.0 * cov), 0, 255
        ).astype(np.uint8)
    tifffile.imwrite(path, img, photometric="minisblack", rowsperstrip=8)
    meta = {
        "pixel_um": pixel_um,
        "seed": seed,
        "size": n,
        "orientation": [rot, mirrored],
        "marks": truth,
    }
    path.with_suffix(".json").write_text(json.dumps(meta, indent=1))
    return meta


def mark_template(shape, s):
    """The mark drawn at the nominal pixel `s` (mm), 4×4 supersampled, with a border of
    a quarter of its size; odd side, the mark's point at the centre."""
    half = int(math.ceil((0.75 * shape["size_mm"]) / s))
    n = 2 * half + 1
    sub = (np.arange(4) + 0.5) / 4
    p = (np.arange(n)[:, None] + sub[None, :]).ravel() - n / 2.0
    x = p[None, :] * s
    y = -p[:, None] * s
    cov = covers(shape, x, y).astype(np.float32)
    return cov.reshape(n, 4, n, 4).mean(axis=(1, 3))


def peak_offset(m1, m0, p1):
    """Vertex of the parabola through three samples, relative to the middle one."""
    d = m1 - 2.0 * m0 + p1
    return 0.0 if d >= 0.0 else 0.5 * (m1 - p1) / d


def opencv_marks(path, cam, meta):
    """OpenCV's measurement: imread, then per mark matchTemplate in a ±6 mm window around
    its prediction, the peak refined by a parabola per axis. Mark centres, corner origin."""
    s = meta["pixel_um"] / 1000.0
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    h, w = img.shape
    lin = orientation_linear(*meta["orientation"], s)
    inv = np.linalg.inv(lin)
    out = {}
    templates = {}
    for f in cam["fiducials"]:
        key = json.dumps(f["shape"], sort_keys=True)
        if key not in templates:
            templates[key] = (mark_template(f["shape"], s) * 255.0).astype(np.uint8)
        tpl = templates[key]
        t = tpl.shape[0]
        p = inv @ np.array([f["x_mm"], f["y_mm"]]) + np.array([w / 2.0, h / 2.0])
        half = SEARCH_MM / s + t / 2.0
        c0, r0 = max(0, int(p[0] - half)), max(0, int(p[1] - half))
        c1, r1 = min(w, int(math.ceil(p[0] + half))), min(h, int(math.ceil(p[1] + half)))
        res = cv2.matchTemplate(img[r0:r1, c0:c1], tpl, cv2.TM_CCOEFF_NORMED)
        _, _, _, (i, j) = cv2.minMaxLoc(res)
        dx = dy = 0.0
        if 0 < i < res.shape[1] - 1:
            dx = peak_offset(res[j, i - 1], res[j, i], res[j, i + 1])
        if 0 < j < res.shape[0] - 1:
            dy = peak_offset(res[j - 1, i], res[j, i], res[j + 1, i])
        out[f["id"]] = [c0 + i + dx + t / 2.0, r0 + j + dy + t / 2.0]
    return out


def rms_to_truth(marks, truth):
    d = [math.hypot(marks[k][0] - truth[k][0], marks[k][1] - truth[k][1]) for k in truth]
    return math.sqrt(sum(v * v for v in d) / len(d)), max(d)


def ours(path, repeat):
    """Best wall time of `cloudcontrol --json io` and its marks."""
    best, doc = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        run = subprocess.run(
            [str(BIN), "--json", "io", "--camera", str(CAMERA), str(path)], capture_output=True
        )
        best = min(best, time.perf_counter() - t0)
        if run.returncode != 0:
            raise SystemExit(f"cloudcontrol io {path} failed: {run.stderr.decode()}")
        doc = json.loads(run.stdout)
    marks = {m["id"]: [m["x"], m["y"]] for m in doc["marks"] if m["used"]}
    return best, marks, doc


def peak_memory(path):
    """Maximum resident set (KiB) of `cloudcontrol io` under /usr/bin/time (the child of a
    small process: a child forked from this one would count this one's pages)."""
    run = subprocess.run(
        ["/usr/bin/time", "-f", "%M", str(BIN), "--json", "io", "--camera", str(CAMERA), str(path)],
        capture_output=True,
        text=True,
    )
    return int(run.stderr.strip().splitlines()[-1])


def theirs(path, cam, meta, repeat):
    best, marks = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        marks = opencv_marks(path, cam, meta)
        best = min(best, time.perf_counter() - t0)
    return best, marks


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pixel-um", type=float, nargs="+", default=[21.0, 42.0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    ap.add_argument("--scans", type=pathlib.Path, default=pathlib.Path(tempfile.gettempdir()) / "cloudcontrol_fiducial_scans")
    ap.add_argument("--repeat", type=int, default=5)
    a = ap.parse_args()
    if not BIN.exists():
        raise SystemExit(f"{BIN} missing: cargo build --release --bin cloudcontrol")
    cam = json.loads(CAMERA.read_text())
    a.scans.mkdir(parents=True, exist_ok=True)
    threads = os.cpu_count()
    print(f"cloudcontrol: {BIN} (rayon default threads); OpenCV {cv2.__version__}, {cv2.getNumThreads()} threads; {threads} CPUs")
    print(f"scans in {a.scans}; best of {a.repeat} runs each, alternating")
    print(f"{'µm':>4} {'seed':>4} {'orientation':>12} {'ours s':>7} {'OpenCV s':>8} {'ratio':>6} {'ours px':>8} {'OpenCV px':>9} {'ours max':>8} {'OpenCV max':>10} {'peak MiB':>8} {'scan MiB':>8}")
    rows = []
    for um in a.pixel_um:
        for seed in a.seeds:
            path = a.scans / f"rc10_{um:g}um_seed{seed}.tif"
            meta_path = path.with_suffix(".json")
            if path.exists() and meta_path.exists():
                meta = json.loads(meta_path.read_text())
            else:
                meta = render(path, cam, um, seed)
            truth = meta["marks"]
            # Alternate the two, so that the load of the shared machine falls on both.
            t_ours, t_cv = float("inf"), float("inf")
            for _ in range(a.repeat):
                t, m_ours, doc = ours(path, 1)
                t_ours = min(t_ours, t)
                t, m_cv = theirs(path, cam, meta, 1)
                t_cv = min(t_cv, t)
            peak = peak_memory(path)
            if len(m_ours) != len(truth):
                raise SystemExit(f"{path}: ours used {len(m_ours)} of {len(truth)} marks")
            rms_o, max_o = rms_to_truth(m_ours, truth)
            rms_c, max_c = rms_to_truth(m_cv, truth)
            o = f"{meta['orientation'][0]}{'m' if meta['orientation'][1] else ''}"
            if doc["orientation"]["rotation_deg"] != meta["orientation"][0] or doc["orientation"]["mirrored"] != meta["orientation"][1]:
                raise SystemExit(f"{path}: ours found orientation {doc['orientation']}, truth {o}")
            ratio = t_cv / t_ours
            rows.append((um, seed, ratio, t_ours, t_cv, rms_o, rms_c, peak))
            print(
                f"{um:>4g} {seed:>4} {o:>12} {t_ours:>7.3f} {t_cv:>8.3f} {ratio:>6.2f} {rms_o:>8.4f} {rms_c:>9.4f} "
                f"{max_o:>8.4f} {max_c:>10.4f} {peak / 1024:>8.1f} {path.stat().st_size / 2**20:>8.1f}",
                flush=True,
            )
    print()
    for um in a.pixel_um:
        r = [x for x in rows if x[0] == um]
        gm = math.exp(sum(math.log(x[2]) for x in r) / len(r))
        worst = min(r, key=lambda x: x[2])
        print(
            f"{um:g} µm: ratio OpenCV/ours geometric mean {gm:.2f}, worst {worst[2]:.2f} (seed {worst[1]}); "
            f"accuracy RMS ours {max(x[5] for x in r):.4f} px at worst vs OpenCV {max(x[6] for x in r):.4f} px; "
            f"peak memory ours {max(x[7] for x in r) / 1024:.1f} MiB"
        )
    worst = min(rows, key=lambda x: x[2])
    print(f"worst case: {worst[0]:g} µm seed {worst[1]}: ratio {worst[2]:.2f} ({worst[3]:.3f} s ours, {worst[4]:.3f} s OpenCV)")


if __name__ == "__main__":
    main()
