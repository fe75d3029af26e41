#!/usr/bin/env python3
"""Benchmark (not a timed test): our point-to-plane ICP vs Open3D's registration_icp with
TransformationEstimationPointToPlane on the same synthetic LiDAR and source points, LAS/LAZ
read throughput vs laspy, and peak memory per LiDAR point.

    cargo build --release
    /work/main/.venv/bin/python benches/lidar_open3d.py [--sizes 1e6 1e7] [--sources 1e4 1e5]

Our side runs the `cloudcontrol` binary (`--json icp --rigid`, `lidar catalogue`) and reads
its timings; Open3D runs in this process on the same points, shifted by the same local
origin (as our library does) so float64 precision is equal. Open3D estimates rigid
transforms only, so the comparison uses our rigid mode; the similarity mode is reported
separately on a source with a 1 % scale error. Ratios > 1 mean we are faster / smaller.
"""
from __future__ import annotations

import argparse
import json
import pathlib
import subprocess
import sys
import tempfile
import time

import laspy
import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
BIN = ROOT / "target" / "release" / "cloudcontrol"
E0, N0, Z0 = 500_000.0, 4_400_000.0, 100.0
DENSITY = 8.0  # pts/m²
NOISE = 0.05


def surface(x, y):
    """Terrain relief, flat and gable roofs on a 50 m grid, tree crowns (local coordinates)."""
    terrain = 8.0 * np.sin(x / 60.0) * np.cos(y / 75.0) + 0.03 * x + 0.02 * y
    gx, gy = np.floor(x / 50.0), np.floor(y / 50.0)
    lx, ly = x - gx * 50.0 - 25.0, y - gy * 50.0 - 25.0
    building = (np.abs(lx) < 10.0) & (np.abs(ly) < 7.0)
    base = 8.0 * np.sin(gx * 50.0 / 60.0) * np.cos(gy * 50.0 / 75.0)
    roof = np.where((gx + gy) % 2 == 0, 9.0, 12.0 - 0.6 * np.abs(ly))
    tx, ty = x - gx * 50.0, y - gy * 50.0
    d = np.hypot(tx - 5.0, ty - 5.0)
    tree = (d < 4.0) & ~building
    z = np.where(building, base + roof, terrain)
    z = np.where(tree, terrain + 6.0 + np.sqrt(np.clip(16.0 - d * d, 0, None)), z)
    return z, tree, building


def make_lidar(n, path, rng, laz=False):
    half = np.sqrt(n / DENSITY) / 2.0
    x = rng.uniform(-half, half, n)
    y = rng.uniform(-half, half, n)
    z, tree, building = surface(x, y)
    z = z - np.where(tree, rng.uniform(0, 3, n), 0.0) + rng.normal(0, NOISE, n)
    hdr = laspy.LasHeader(point_format=1, version="1.2")
    hdr.scales = np.array([0.001, 0.001, 0.001])
    hdr.offsets = np.array([E0, N0, 0.0])
    keys = np.array([1, 1, 0, 2, 1024, 0, 1, 1, 3072, 0, 1, 32650], dtype="<u2")
    hdr.vlrs.append(laspy.VLR(user_id="LASF_Projection", record_id=34735, record_data=keys.tobytes()))
    las = laspy.LasData(hdr)
    las.x, las.y, las.z = x + E0, y + N0, z + Z0
    las.classification = np.where(tree, 5, np.where(building, 6, 2)).astype(np.uint8)
    las.point_source_id = np.where(x < 0, 1, 2).astype(np.uint16)
    las.gps_time = np.linspace(3e8, 3e8 + 3600, n)
    las.write(str(path))
    return half


def rot(axis, deg):
    a = np.asarray(axis, float)
    a /= np.linalg.norm(a)
    t = np.radians(deg)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(t) * k + (1 - np.cos(t)) * k @ k


def make_source(m, half, rng, scale=1.0):
    """Source points on the true surface (no trees), misaligned by a known transform about
    the block centre; returns the misaligned points (world) and the true points (world)."""
    x = rng.uniform(-half + 15, half - 15, m)
    y = rng.uniform(-half + 15, half - 15, m)
    z, tree, _ = surface(x, y)
    keep = ~tree
    p = np.column_stack([x[keep], y[keep], z[keep] + rng.normal(0, NOISE, keep.sum())])
    r = rot([0.3, -0.5, 1.0], 1.0)
    t = np.array([1.2, -1.5, 0.8])  # |t| = 2.1 m
    mis = scale * p @ r.T + t
    c = np.array([E0, N0, Z0])
    return mis + c, p + c


def write_ply(path, pts):
    with open(path, "wb") as f:
        f.write(f"ply\nformat binary_little_endian 1.0\nelement vertex {len(pts)}\n"
                "property double x\nproperty double y\nproperty double z\nend_header\n".encode())
        f.write(np.ascontiguousarray(pts, dtype="<f8").tobytes())


def apply(m, pts):
    return pts @ m[:3, :3].T + m[:3, 3]


def run_ours(src_ply, lidar, rigid, gate):
    cmd = ["/usr/bin/time", "-f", "%M", str(BIN), "--json", "icp", "--source", str(src_ply), "--target", str(lidar),
           "--initial-gate", str(gate)] + (["--rigid"] if rigid else [])
    t = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t
    if r.returncode != 0:
        raise RuntimeError(r.stderr)
    rss_kb = int(r.stderr.strip().splitlines()[-1])
    out = json.loads(r.stdout)
    return out, wall, rss_kb


def run_open3d(o3d, lidar_path, src, origin, gate, max_iter=30):
    t0 = time.perf_counter()
    las = laspy.read(str(lidar_path))
    xyz = np.column_stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)]) - origin
    t_read = time.perf_counter() - t0
    t0 = time.perf_counter()
    tgt = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))
    tgt.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=12))
    t_normals = time.perf_counter() - t0
    s = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(src - origin))
    t0 = time.perf_counter()
    res = o3d.pipelines.registration.registration_icp(
        s, tgt, gate, np.eye(4),
        o3d.pipelines.registration.TransformationEstimationPointToPlane(),
        o3d.pipelines.registration.ICPConvergenceCriteria(relative_fitness=1e-6, relative_rmse=1e-6,
                                                          max_iteration=max_iter))
    t_icp = time.perf_counter() - t0
    m = np.array(res.transformation)
    # Back to world: x_w = M (x_w − o) + o.
    mw = m.copy()
    mw[:3, 3] = m[:3, 3] + origin - m[:3, :3] @ origin
    return mw, dict(read=t_read, normals=t_normals, icp=t_icp, rmse=res.inlier_rmse, fitness=res.fitness)


def error(m, mis, truth):
    d = apply(m, mis) - truth
    return float(np.sqrt((d ** 2).sum(1).mean()))


def bench_read(path, rows, label):
    # Ours: a full scan (every point decoded, bounds/classes/strips/GPS statistics), minus
    # the process start (GDAL/PROJ initialisation and header + CRS: `lidar info`).
    t = time.perf_counter()
    subprocess.run([str(BIN), "-q", "lidar", "info", str(path)], check=True)
    start = time.perf_counter() - t
    t = time.perf_counter()
    subprocess.run([str(BIN), "-q", "lidar", "catalogue", str(path)], check=True)
    wall = time.perf_counter() - t
    ours = max(wall - start, 1e-6)
    t = time.perf_counter()
    las = laspy.read(str(path))
    _ = (np.asarray(las.x), np.asarray(las.y), np.asarray(las.z), np.asarray(las.classification),
         np.asarray(las.point_source_id), np.asarray(las.gps_time))
    theirs = time.perf_counter() - t
    n = len(las.points)
    rows.append(f"read {label:<22} ours {n / ours / 1e6:7.1f} Mpts/s ({ours:6.2f} s + start {start:.2f} s)  laspy {n / theirs / 1e6:7.1f} Mpts/s "
                f"({theirs:6.2f} s)  ratio {theirs / ours:5.2f}x")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=float, nargs="+", default=[1e6, 1e7])
    ap.add_argument("--sources", type=float, nargs="+", default=[1e4, 1e5])
    ap.add_argument("--gate", type=float, default=5.0, help="initial / max correspondence distance (m)")
    ap.add_argument("--seed", type=int, default=7)
    args = ap.parse_args()
    if not BIN.exists():
        sys.exit(f"{BIN} missing: run cargo build --release")
    import open3d as o3d
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    rng = np.random.default_rng(args.seed)
    import os
    rows = [f"machine: {os.cpu_count()} cores, load average at start {os.getloadavg()[0]:.2f}"]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        for size in args.sizes:
            n = int(size)
            lidar = tmp / f"lidar_{n}.las"
            half = make_lidar(n, lidar, rng)
            label = f"{n / 1e6:g}M"
            bench_read(lidar, rows, f"LAS {label}")
            if n <= 2_000_000:
                laz = tmp / f"lidar_{n}.laz"
                laspy.read(str(lidar)).write(str(laz))
                bench_read(laz, rows, f"LAZ {label}")
            for m in args.sources:
                m = int(m)
                mis, truth = make_source(m, half, rng)
                ply = tmp / f"src_{m}.ply"
                write_ply(ply, mis)
                ours, wall, rss = run_ours(ply, lidar, True, args.gate)
                mo = np.array(ours["matrix"])
                e_ours = error(mo, mis, truth)
                t = ours["timing_s"]
                origin = np.array([E0, N0, Z0])
                mo3, o = run_open3d(o3d, lidar, mis, origin, args.gate)
                e_o3d = error(mo3, mis, truth)
                ours_reg = t["index"] + t["icp"]
                o3d_reg = o["normals"] + o["icp"]
                rows.append(
                    f"ICP rigid  {label:>4} LiDAR, {m / 1e3:>5g}k src: ours {ours_reg:6.2f} s (index {t['index']:.2f} + icp "
                    f"{t['icp']:.2f}, {ours['iterations']} it) err {e_ours * 100:5.2f} cm | Open3D {o3d_reg:6.2f} s (normals "
                    f"{o['normals']:.2f} + icp {o['icp']:.2f}) err {e_o3d * 100:5.2f} cm | speed ratio {o3d_reg / ours_reg:5.2f}x, "
                    f"ICP-only {o['icp'] / max(t['icp'], 1e-9):5.2f}x; end-to-end incl. LAS read: ours {wall:.2f} s vs "
                    f"{o3d_reg + o['read']:.2f} s")
                rows.append(f"memory     {label:>4} LiDAR, {m / 1e3:>5g}k src: peak RSS {rss / 1024:7.1f} MiB = "
                            f"{rss * 1024 / n:6.1f} B per LiDAR point (whole process)")
            # Similarity mode separately (Open3D has none): 1 % scale error on the first source size.
            m = int(args.sources[0])
            mis, truth = make_source(m, half, rng, scale=1.01)
            ply = tmp / f"src_sim_{m}.ply"
            write_ply(ply, mis)
            ours, wall, _ = run_ours(ply, lidar, False, args.gate)
            mo = np.array(ours["matrix"])
            t = ours["timing_s"]
            rows.append(f"ICP simil. {label:>4} LiDAR, {m / 1e3:>5g}k src, 1% scale: ours {t['index'] + t['icp']:6.2f} s, "
                        f"err {error(mo, mis, truth) * 100:5.2f} cm, scale {ours['scale']:.6f} (truth {1 / 1.01:.6f})")
            print("\n".join(rows[-(len(args.sources) * 2 + 1):]), flush=True)
            lidar.unlink()
    print("\n== summary ==")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
