"""Bundle adjustment and resection: cloudcontrol vs pycolmap (Ceres) on the same data.

Generates synthetic nadir aerial blocks (strips, 60/30 % overlap, 0.5 px noise, perturbed
start) as COLMAP text models, runs pycolmap.bundle_adjustment and `cloudcontrol adjust`
on the same model (with its default options, as a user runs it, and as plain least squares),
and reports wall time and final reprojection RMS with ratios, our peak memory (per
observation) and the size of our report.json; then
single-photo resection against pycolmap.estimate_and_refine_absolute_pose.

    CLOUDCONTROL_BIN=target/release/cloudcontrol CLOUDCONTROL_LIB=target/release/libcloudcontrol.so \
    PYTHONPATH=bindings/python python benches/adjust_pycolmap.py [--sizes 50 200 800]

With --control-run: the robust run with control, check points and blunders (1 % of the
rays displaced 5–30 px, a tenth of the control wrong by 1–3 m): `cloudcontrol adjust
--control --check`, which must find the wrong control and rays itself, against pycolmap's
procedure told which control is good (the good control held constant, Cauchy loss, rays
beyond 2 px deleted, solved again; TOLD_ITERATIONS sets its iterations, default Ceres's
100): time ratio and check point RMSE of both.
"""
from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import tempfile
import time

import numpy as np
import pycolmap

W, H, F = 6000, 4000, 5000.0
BIN = os.environ.get("CLOUDCONTROL_BIN", str(pathlib.Path(__file__).resolve().parents[1] / "target/release/cloudcontrol"))


def quat_wxyz(r):
    q = pycolmap.Rotation3d(r).quat  # x, y, z, w
    q = np.array([q[3], q[0], q[1], q[2]])
    return q if q[0] >= 0 else -q


def rot_vec(v):
    th = np.linalg.norm(v)
    if th < 1e-15:
        return np.eye(3)
    k = v / th
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * kx + (1 - np.cos(th)) * kx @ kx


def synth(n_photos, pts_per_photo=250, seed=1):
    rng = np.random.default_rng(seed)
    hgt = 1000.0
    gsd = hgt / F
    base, spacing = 0.4 * H * gsd, 0.7 * W * gsd
    strips = max(2, int(round(np.sqrt(n_photos / 4))))
    per = int(np.ceil(n_photos / strips))
    nadir = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])
    flip = np.diag([-1.0, -1.0, 1.0])
    poses = []
    for s in range(strips):
        for i in range(per):
            if len(poses) == n_photos:
                break
            c = np.array([i * base, s * spacing, hgt]) + rng.uniform(-5, 5, 3)
            r0 = flip @ nadir if s % 2 else nadir
            poses.append((rot_vec(rng.normal(0, 0.02, 3)) @ r0, c))
    xs = np.array([p[1] for p in poses])
    x0, x1 = xs[:, 0].min() - 0.4 * H * gsd, xs[:, 0].max() + 0.4 * H * gsd
    y0, y1 = xs[:, 1].min() - 0.4 * W * gsd, xs[:, 1].max() + 0.4 * W * gsd
    n_pts = pts_per_photo * n_photos // 3
    P = np.column_stack([rng.uniform(x0, x1, 3 * n_pts), rng.uniform(y0, y1, 3 * n_pts), np.zeros(3 * n_pts)])
    P[:, 2] = 60 * (0.6 * np.sin(P[:, 0] / 700) * np.cos(P[:, 1] / 500) + 0.4 * np.sin(P[:, 0] / 230 + 1) * np.sin(P[:, 1] / 310 + 0.5))
    obs = [[] for _ in range(len(P))]
    for j, (r, c) in enumerate(poses):
        xc = (P - c) @ r.T
        u = F * xc[:, 0] / xc[:, 2] + W / 2
        v = F * xc[:, 1] / xc[:, 2] + H / 2
        ok = (xc[:, 2] > 0) & (u > 20) & (v > 20) & (u < W - 20) & (v < H - 20)
        for k in np.nonzero(ok)[0]:
            obs[k].append((j, u[k] + rng.normal(0, 0.5), v[k] + rng.normal(0, 0.5)))
    keep = [k for k in range(len(P)) if len(obs[k]) >= 2][:n_pts]
    # Perturbed start: 0.3° attitude, 3 m centres, 1 m points.
    start = [(rot_vec(rng.normal(0, 0.005, 3)) @ r, c + rng.normal(0, 3, 3)) for r, c in poses]
    P0 = P[keep] + rng.normal(0, 1, (len(keep), 3))
    return poses, start, P[keep], P0, [obs[k] for k in keep]


def write_model(d, poses, P, obs):
    d.mkdir(parents=True, exist_ok=True)
    (d / "cameras.txt").write_text(f"1 PINHOLE {W} {H} {F} {F} {W/2} {H/2}\n")
    per_img = [[] for _ in poses]
    tracks = []
    for k, ob in enumerate(obs):
        tr = []
        for j, u, v in ob:
            tr.append((j + 1, len(per_img[j])))
            per_img[j].append((u, v, k + 1))
        tracks.append(tr)
    lines = []
    for j, (r, c) in enumerate(poses):
        q = quat_wxyz(r)
        t = -r @ c
        lines.append(f"{j+1} {q[0]} {q[1]} {q[2]} {q[3]} {t[0]} {t[1]} {t[2]} 1 img{j+1:04d}.tif")
        lines.append(" ".join(f"{u} {v} {k}" for u, v, k in per_img[j]))
    (d / "images.txt").write_text("\n".join(lines) + "\n")
    (d / "points3D.txt").write_text("".join(
        f"{k+1} {p[0]} {p[1]} {p[2]} 128 128 128 0 " + " ".join(f"{i} {x}" for i, x in tracks[k]) + "\n"
        for k, p in enumerate(P)))


def rms_of(rec):
    s, n = 0.0, 0
    for img in rec.images.values():
        cam = rec.cameras[img.camera_id]
        for p2 in img.points2D:
            if not p2.has_point3D():
                continue
            xyz = rec.points3D[p2.point3D_id].xyz
            xc = img.cam_from_world() * xyz
            uv = cam.img_from_cam(xc)
            s += float(np.sum((np.asarray(uv).ravel()[:2] - p2.xy) ** 2))
            n += 2
    return np.sqrt(s / n)


# Option sets of `cloudcontrol adjust`: as a user runs it (a-priori σ 1 px, the CLI's
# default), the defaults with the true noise as a-priori σ (the rejection test then runs
# at its nominal level: the strict case for "no over-rejection"), plain least squares.
MODES = {
    "default": [],
    "sigma0.5": ["--sigma-px", "0.5"],
    "plain": ["--robust", "none", "--reject", "0"],
}


def bench_ba(n, mode, repeat):
    """Median wall time over `repeat` runs of each tool on the same start model (the VM's
    run-to-run spread is ±30 % on one run)."""
    poses, start, P, P0, obs = synth(n)
    with tempfile.TemporaryDirectory() as td:
        td = pathlib.Path(td)
        write_model(td / "start", start, P0, obs)
        t_colmap, t_cli, t_solver, peak = [], [], [], []
        for _ in range(repeat):
            rec = pycolmap.Reconstruction(str(td / "start"))
            o = pycolmap.BundleAdjustmentOptions()
            o.refine_focal_length = False
            o.refine_principal_point = False
            o.refine_extra_params = False
            t = time.perf_counter()
            pycolmap.bundle_adjustment(rec, o)
            t_colmap.append(time.perf_counter() - t)
            rms_colmap = rms_of(rec)
            t = time.perf_counter()
            # Default options: Huber loss, Baarda data snooping, EO covariance, as a user runs it.
            code, stderr, rss = run_measured([BIN, "-q", "adjust", "--model", str(td / "start"), "--out", str(td / "ours"),
                                              *MODES[mode], "--report", str(td / "r.json")])
            t_cli.append(time.perf_counter() - t)
            if code != 0:
                raise RuntimeError(stderr)
            peak.append(rss)
            report_bytes = (td / "r.json").stat().st_size
            rep = json.loads((td / "r.json").read_text())
            t_solver.append(rep["adjust_time_s"])
        rms_ours = rms_of(pycolmap.Reconstruction(str(td / "ours")))
        return dict(photos=n, points=len(P), observations=sum(len(o) for o in obs),
                    colmap_s=float(np.median(t_colmap)), ours_solver_s=float(np.median(t_solver)),
                    ours_cli_s=float(np.median(t_cli)),
                    colmap_rms=rms_colmap, ours_rms=rms_ours, iterations=rep["iterations"],
                    rejected=rep["rejected"]["count"], peak_mib=max(peak) / 1024,
                    report_mb=report_bytes / 1e6)


def run_measured(cmd):
    """Runs `cmd`; its exit status, stderr and peak resident memory (KiB). The peak comes
    from GNU time, which forks the command itself: a child forked from this Python process
    would count Python's own pages in its ru_maxrss (0.6 GiB with an 800-photo block held
    here, more than our adjustment of it needs)."""
    with tempfile.TemporaryDirectory() as td:
        peak_file = os.path.join(td, "peak")
        with open(os.path.join(td, "err"), "w+b") as err:
            p = subprocess.run(["/usr/bin/time", "-f", "%M", "-o", peak_file] + list(cmd),
                               stdout=subprocess.DEVNULL, stderr=err)
            err.seek(0)
            text = err.read().decode(errors="replace")
        peak = open(peak_file).read().split()
        return p.returncode, text, int(peak[-1]) if peak and peak[-1].isdigit() else 0


def control_block(n, seed=1):
    """The bench block with what a robust run with control must survive: 1 % of the image
    observations displaced 5–30 px, control points (every photo's worth: n/4, at least 8)
    surveyed to 2 cm of which a tenth (at least one) is wrong by 1–3 m, as many check
    points given at their true coordinates."""
    poses, start, P, P0, obs = synth(n, seed=seed)
    rng = np.random.default_rng(seed + 1000)
    bad_obs = 0
    for ob in obs:
        for k, (j, u, v) in enumerate(ob):
            if rng.random() < 0.01:
                a, m = rng.uniform(0, 2 * np.pi), rng.uniform(5, 30)
                ob[k] = (j, u + m * np.cos(a), v + m * np.sin(a))
                bad_obs += 1
    rays = np.array([len(o) for o in obs])
    candidates = rng.permutation(np.nonzero(rays >= 3)[0])
    m = max(8, n // 4)
    ctl, chk = candidates[:m], candidates[m:2 * m]
    wrong = set(rng.choice(ctl, max(1, m // 10), replace=False).tolist())
    surveyed = P[ctl] + rng.normal(0, 0.02, (m, 3))
    for i, k in enumerate(ctl):
        if k in wrong:
            a = rng.uniform(0, 2 * np.pi)
            surveyed[i] += rng.uniform(1, 3) * np.array([np.cos(a), np.sin(a), rng.choice([-1, 1])])
    return poses, start, P, P0, obs, ctl, chk, wrong, surveyed, bad_obs


MAX_ITERATIONS_TOLD = int(os.environ.get("TOLD_ITERATIONS", "100"))


def colmap_told(model, out, P, ctl, wrong, surveyed, chk):
    """pycolmap's robust procedure when told which control is good: the good control points
    at their surveyed coordinates held constant (the datum), the wrong ones left out, Cauchy
    loss (scale 1 px), every observation whose reprojection error then exceeds 2 px deleted,
    and the adjustment solved again. Returns the check points' errors (m)."""
    rec = pycolmap.Reconstruction(str(model))
    for i, k in enumerate(ctl):
        if k not in wrong:
            rec.points3D[int(k) + 1].xyz = surveyed[i]
    def solve():
        config = pycolmap.BundleAdjustmentConfig()
        for image_id in rec.reg_image_ids():
            config.add_image(image_id)
        for k in ctl:
            if k not in wrong:
                config.add_constant_point(int(k) + 1)
        o = pycolmap.BundleAdjustmentOptions()
        o.refine_focal_length = False
        o.refine_principal_point = False
        o.refine_extra_params = False
        o.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
        o.ceres.loss_function_scale = 1.0
        o.print_summary = False
        o.ceres.solver_options.max_num_iterations = MAX_ITERATIONS_TOLD
        pycolmap.create_default_bundle_adjuster(o, config, rec).solve()
    solve()
    for image_id in list(rec.reg_image_ids()):
        img = rec.images[image_id]
        cam = rec.cameras[img.camera_id]
        for idx, p2 in enumerate(img.points2D):
            if not p2.has_point3D() or p2.point3D_id not in rec.points3D:
                continue
            uv = cam.img_from_cam(img.cam_from_world() * rec.points3D[p2.point3D_id].xyz)
            if np.linalg.norm(np.asarray(uv).ravel()[:2] - p2.xy) > 2.0:
                rec.delete_observation(image_id, idx)
    solve()
    return np.array([rec.points3D[int(k) + 1].xyz - P[k] if int(k) + 1 in rec.points3D
                     else [np.nan] * 3 for k in chk])


def bench_control(n, repeat):
    """The robust run with control, check points and blunders: `cloudcontrol adjust
    --control --check` (it must find the wrong control and the displaced rays itself)
    against pycolmap's procedure told which control is good. Median wall time of each,
    check point RMSE in plan and height."""
    poses, start, P, P0, obs, ctl, chk, wrong, surveyed, bad_obs = control_block(n)
    with tempfile.TemporaryDirectory() as td:
        td = pathlib.Path(td)
        write_model(td / "start", start, P0, obs)
        (td / "control.csv").write_text("id,x,y,z,sigma_xy,sigma_z\n" + "".join(
            f"{int(k) + 1},{x},{y},{z},0.02,0.02\n" for k, (x, y, z) in zip(ctl, surveyed)))
        (td / "check.csv").write_text("id,x,y,z\n" + "".join(
            f"{int(k) + 1},{P[k][0]},{P[k][1]},{P[k][2]}\n" for k in chk))
        t_ours, t_colmap = [], []
        for _ in range(repeat):
            t = time.perf_counter()
            code, stderr, _ = run_measured([BIN, "-q", "adjust", "--model", str(td / "start"), "--out", str(td / "ours"),
                                            "--control", str(td / "control.csv"), "--check", str(td / "check.csv"),
                                            "--sigma-px", "0.5", "--report", str(td / "r.json")])
            t_ours.append(time.perf_counter() - t)
            if code != 0:
                raise RuntimeError(stderr)
            t = time.perf_counter()
            err = colmap_told(td / "start", td / "colmap", P, ctl, wrong, surveyed, chk)
            t_colmap.append(time.perf_counter() - t)
        rep = json.loads((td / "r.json").read_text())
        ok = np.all(np.isfinite(err), axis=1)
        return dict(photos=n, observations=sum(len(o) for o in obs), bad_obs=bad_obs,
                    control=len(ctl), wrong=len(wrong), check=len(chk),
                    ours_s=float(np.median(t_ours)), colmap_s=float(np.median(t_colmap)),
                    ours_plan=rep["check"]["rmse_plan_m"], ours_height=rep["check"]["rmse_height_m"],
                    colmap_plan=float(np.sqrt(np.mean(np.sum(err[ok, :2] ** 2, axis=1)))),
                    colmap_height=float(np.sqrt(np.mean(err[ok, 2] ** 2))),
                    rejected=rep["rejected"]["count"])


def bench_resection(trials=30, n=30, outlier_rate=0.3, seed=3):
    rng = np.random.default_rng(seed)
    cam = pycolmap.Camera(model="PINHOLE", width=W, height=H, params=[F, F, W / 2, H / 2])
    from cloudcontrol.adjust import resect as cc_resect
    from cloudcontrol.geometry import Camera as CcCamera
    ours_cam = CcCamera(W, H, F, F, W / 2, H / 2)
    res = {"ours_err_m": [], "colmap_err_m": [], "ours_s": 0.0, "colmap_s": 0.0}
    with tempfile.TemporaryDirectory() as td:
        for t in range(trials):
            r = rot_vec(rng.normal(0, 0.03, 3)) @ np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])
            c = np.array([rng.uniform(-100, 100), rng.uniform(-100, 100), 1000.0])
            X = np.column_stack([rng.uniform(-500, 500, n), rng.uniform(-400, 400, n), rng.uniform(-50, 80, n)])
            xc = (X - c) @ r.T
            uv = np.column_stack([F * xc[:, 0] / xc[:, 2] + W / 2, F * xc[:, 1] / xc[:, 2] + H / 2]) + rng.normal(0, 0.5, (n, 2))
            bad = rng.random(n) < outlier_rate
            uv[bad] += rng.uniform(20, 200, (bad.sum(), 2)) * rng.choice([-1, 1], (bad.sum(), 2))
            t0 = time.perf_counter()
            out = pycolmap.estimate_and_refine_absolute_pose(uv, X, cam)
            res["colmap_s"] += time.perf_counter() - t0
            if out is None:
                res["colmap_err_m"].append(np.inf)
            else:
                cw = out["cam_from_world"]
                res["colmap_err_m"].append(float(np.linalg.norm(cw.inverse().translation - c)))
            t0 = time.perf_counter()
            try:
                pose, _, _ = cc_resect(ours_cam, uv, X, sigma_px=0.5)
                res["ours_s"] += time.perf_counter() - t0
                res["ours_err_m"].append(float(np.linalg.norm(pose.center - c)))
            except Exception:
                res["ours_s"] += time.perf_counter() - t0
                res["ours_err_m"].append(np.inf)
    return res


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", type=int, nargs="+", default=[50, 200, 800])
    ap.add_argument("--skip-resection", action="store_true")
    ap.add_argument("--control-run", action="store_true",
                    help="only the robust run with control, check points and blunders against pycolmap told the good control")
    ap.add_argument("--repeat", type=int, default=3, help="runs per tool and size (median time)")
    a = ap.parse_args()
    print(f"pycolmap {pycolmap.__version__}, cloudcontrol CLI {BIN}")
    if a.control_run:
        print("robust run with control: photos  obs  blunders  control (wrong)  check  ours_s  colmap_told_s  speedup  ours plan/height m  colmap plan/height m  rejected")
        for n in a.sizes:
            r = bench_control(n, a.repeat)
            print(f"{r['photos']:6d} {r['observations']:8d} {r['bad_obs']:6d} {r['control']:5d} ({r['wrong']}) {r['check']:5d}"
                  f"  {r['ours_s']:7.2f}  {r['colmap_s']:7.2f}  {r['colmap_s'] / r['ours_s']:6.2f}"
                  f"  {r['ours_plan']:.4f}/{r['ours_height']:.4f}  {r['colmap_plan']:.4f}/{r['colmap_height']:.4f}  {r['rejected']:6d}", flush=True)
        return
    print("options   photos  points    obs      colmap_s  ours_solver_s  ours_cli_s  speedup(solver)  speedup(cli)  colmap_rms  ours_rms  rms_ratio  rejected  peak_MiB  B/obs  report_MB")
    for n in a.sizes:
        for mode in MODES:
            r = bench_ba(n, mode, a.repeat)
            print(f"{mode:8s} {r['photos']:6d} {r['points']:7d} {r['observations']:8d}  {r['colmap_s']:8.2f}  {r['ours_solver_s']:13.2f}  {r['ours_cli_s']:10.2f}"
                  f"  {r['colmap_s']/r['ours_solver_s']:15.2f}  {r['colmap_s']/r['ours_cli_s']:12.2f}  {r['colmap_rms']:10.4f}  {r['ours_rms']:8.4f}  {r['ours_rms']/r['colmap_rms']:9.4f}  {r['rejected']:8d}"
                  f"  {r['peak_mib']:8.0f}  {r['peak_mib'] * 2**20 / r['observations']:5.0f}  {r['report_mb']:9.3f}", flush=True)
    if not a.skip_resection:
        r = bench_resection()
        oe, ce = np.array(r["ours_err_m"]), np.array(r["colmap_err_m"])
        print(f"resection (30 trials, 30 points, 30 % outliers): median centre error ours {np.median(oe):.3f} m, "
              f"pycolmap {np.median(ce):.3f} m; failures ours {np.sum(~np.isfinite(oe) | (oe > 5))}, pycolmap {np.sum(~np.isfinite(ce) | (ce > 5))}; "
              f"time ours {r['ours_s']:.3f} s (Python binding), pycolmap {r['colmap_s']:.3f} s, ratio {r['colmap_s']/r['ours_s']:.2f}")


if __name__ == "__main__":
    main()
