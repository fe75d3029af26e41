"""Read and write a 1 M-point binary COLMAP model: cloudcontrol vs pycolmap, same files,
same run; prints times and ratios (pycolmap time / ours: > 1 means we are faster).

    CLOUDCONTROL_LIB=target/release/libcloudcontrol.so PYTHONPATH=bindings/python \\
        python benches/formats_colmap.py [--points 1000000] [--images 200]

The model is synthetic: tracks of length 3 over a ring of images, random pixels, written
directly in COLMAP's binary layout (legacy 3 files, which both readers accept).
"""
from __future__ import annotations

import argparse
import pathlib
import shutil
import tempfile
import time

import numpy as np
import pycolmap

from cloudcontrol import formats


def write_model(d: pathlib.Path, n_points: int, n_images: int, seed: int = 1) -> None:
    rng = np.random.default_rng(seed)
    track = 3
    per_res = n_points // n_images  # points per residue class
    assert per_res * n_images == n_points, "points must be a multiple of images"
    w, h = 6000, 4000
    cam = np.zeros(1, dtype=np.dtype([("id", "<u4"), ("model", "<i4"), ("w", "<u8"), ("h", "<u8"), ("p", "<f8", 4)]))
    cam[0] = (1, 1, w, h, (5000.0, 5000.0, w / 2, h / 2))  # PINHOLE
    with open(d / "cameras.bin", "wb") as f:
        f.write(np.uint64(1).tobytes())
        f.write(cam.tobytes())
    # Image i holds, for m in range(per_res), j in range(3): point 200m + ((i - j) mod n) + 1.
    p2d = np.dtype([("x", "<f8"), ("y", "<f8"), ("id", "<u8")])
    with open(d / "images.bin", "wb") as f:
        f.write(np.uint64(n_images).tobytes())
        m = np.arange(per_res)[:, None]
        j = np.arange(track)[None, :]
        for i in range(n_images):
            ang = 2 * np.pi * i / n_images
            q = np.array([np.cos(ang / 2), 0, 0, np.sin(ang / 2)])
            t = np.array([np.cos(ang) * 50, np.sin(ang) * 50, 300.0])
            f.write(np.uint32(i + 1).tobytes() + q.tobytes() + t.tobytes() + np.uint32(1).tobytes())
            f.write(f"img_{i:05d}.jpg".encode() + b"\0")
            pts = np.zeros(per_res * track, dtype=p2d)
            pts["x"] = rng.uniform(0, w, pts.size)
            pts["y"] = rng.uniform(0, h, pts.size)
            pts["id"] = (n_images * m + (i - j) % n_images + 1).ravel()
            f.write(np.uint64(pts.size).tobytes())
            f.write(pts.tobytes())
    rec = np.dtype([("id", "<u8"), ("xyz", "<f8", 3), ("rgb", "u1", 3), ("err", "<f8"), ("n", "<u8"),
                    ("track", [("im", "<u4"), ("idx", "<u4")], track)])
    with open(d / "points3D.bin", "wb") as f:
        f.write(np.uint64(n_points).tobytes())
        k = np.arange(n_points)
        pts = np.zeros(n_points, dtype=rec)
        pts["id"] = k + 1
        pts["xyz"] = rng.normal(0, 100, (n_points, 3))
        pts["rgb"] = rng.integers(0, 256, (n_points, 3))
        pts["err"] = 0.5
        pts["n"] = track
        res, mm = k % n_images, k // n_images
        for jj in range(track):
            pts["track"]["im"][:, jj] = (res + jj) % n_images + 1
            pts["track"]["idx"][:, jj] = 3 * mm + jj
        f.write(pts.tobytes())


def best(f, repeat):
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t0)
    return min(ts)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--images", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    tmp = pathlib.Path(tempfile.mkdtemp(prefix="ccp_bench_"))
    try:
        src = tmp / "src"
        src.mkdir()
        write_model(src, a.points, a.images)
        size = sum(p.stat().st_size for p in src.iterdir()) / 1e6
        s = formats.summary(src)
        r = pycolmap.Reconstruction(str(src))
        assert s["points"] == r.num_points3D() == a.points and s["photos"] == r.num_images()
        assert s["observations"] == sum(p.track.length() for p in r.points3D.values())
        del r
        out_p, out_o = tmp / "out_pycolmap", tmp / "out_ours"
        out_p.mkdir()

        t_read_p = best(lambda: pycolmap.Reconstruction(str(src)), a.repeat)
        t_read_o = best(lambda: formats.summary(src), a.repeat)

        def py_rw():
            pycolmap.Reconstruction(str(src)).write_binary(str(out_p))

        t_rw_p = best(py_rw, a.repeat)
        t_rw_o = best(lambda: formats.convert(src, out_o, legacy=False), a.repeat)
        # Both outputs read back by pycolmap with the same content size.
        assert pycolmap.Reconstruction(str(out_o)).num_points3D() == a.points
        print(f"model: {a.points} points, {a.images} images, {s['observations']} observations, {size:.0f} MB")
        print(f"read           pycolmap {t_read_p:7.3f} s   cloudcontrol {t_read_o:7.3f} s   ratio {t_read_p / t_read_o:5.2f}x")
        print(f"read + write   pycolmap {t_rw_p:7.3f} s   cloudcontrol {t_rw_o:7.3f} s   ratio {t_rw_p / t_rw_o:5.2f}x")
        print(f"write (diff)   pycolmap {t_rw_p - t_read_p:7.3f} s   cloudcontrol {t_rw_o - t_read_o:7.3f} s   "
              f"ratio {(t_rw_p - t_read_p) / max(t_rw_o - t_read_o, 1e-9):5.2f}x")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
