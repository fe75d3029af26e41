"""OpenCV's side of benches/dense_sgbm.rs: StereoSGBM on the rectified pairs the Rust bench
wrote, in its documented settings, timed with cv2.setNumThreads(1) and (2).

    python benches/dense_sgbm_opencv.py MANIFEST.json   (run by `cargo bench --bench dense_sgbm`)

Per pair the manifest gives the folder (left.f32 and right.f32, float32 row-major images of
width x height), the disparity range [min_disparity, max_disparity] and the shift to add to
OpenCV's disparities to get the pair's. Settings, from OpenCV's documentation of
StereoSGBM: P1 = 8·cn·blockSize², P2 = 32·cn·blockSize², uniquenessRatio 10,
speckleWindowSize 100, speckleRange 2, disp12MaxDiff 1, preFilterCap 63; modes SGBM_3WAY,
SGBM and HH with blockSize 3 and 5. Writes each run's disparity (float32, NaN where
invalid) beside the images and prints JSON {folder: [runs]} with the best wall time of
`repeat` runs of compute() per thread count, and the best process CPU time with one thread.
"""
import json
import pathlib
import sys
import time

import cv2
import numpy as np

CONFIGS = [
    ("SGBM_3WAY bs5", cv2.STEREO_SGBM_MODE_SGBM_3WAY, 5),
    ("SGBM_3WAY bs3", cv2.STEREO_SGBM_MODE_SGBM_3WAY, 3),
    ("SGBM bs5", cv2.STEREO_SGBM_MODE_SGBM, 5),
    ("HH bs5", cv2.STEREO_SGBM_MODE_HH, 5),
    ("HH bs3", cv2.STEREO_SGBM_MODE_HH, 3),
]


def matcher(mode, bs, min_d, num_d):
    return cv2.StereoSGBM_create(
        minDisparity=min_d,
        numDisparities=num_d,
        blockSize=bs,
        P1=8 * bs * bs,
        P2=32 * bs * bs,
        disp12MaxDiff=1,
        preFilterCap=63,
        uniquenessRatio=10,
        speckleWindowSize=100,
        speckleRange=2,
        mode=mode,
    )


def main():
    manifest = json.loads(pathlib.Path(sys.argv[1]).read_text())
    out = {}
    for case in manifest:
        d = pathlib.Path(case["dir"])
        w, h = case["width"], case["height"]
        left = np.fromfile(d / "left.f32", dtype=np.float32).reshape(h, w)
        right = np.fromfile(d / "right.f32", dtype=np.float32).reshape(h, w)
        left8 = np.clip(np.rint(left), 0, 255).astype(np.uint8)
        right8 = np.clip(np.rint(right), 0, 255).astype(np.uint8)
        min_d = int(case["min_disparity"])
        span = int(case["max_disparity"]) - min_d + 1
        num_d = (span + 15) // 16 * 16
        runs = []
        for label, mode, bs in CONFIGS:
            m = matcher(mode, bs, min_d, num_d)
            times = []
            cpu1 = float("inf")
            disp = None
            for threads in (1, 2):
                cv2.setNumThreads(threads)
                best = float("inf")
                for _ in range(case["repeat"]):
                    t0, c0 = time.perf_counter(), time.process_time()
                    disp = m.compute(left8, right8)
                    best = min(best, time.perf_counter() - t0)
                    if threads == 1:
                        cpu1 = min(cpu1, time.process_time() - c0)
                times.append(best)
            f = disp.astype(np.float32) / 16.0
            f[disp < min_d * 16] = np.nan
            path = d / f"opencv_{label.replace(' ', '_')}.f32"
            f.astype("<f4").tofile(path)
            runs.append(
                {"label": label, "disparity": str(path), "shift": case["shift"], "t1": times[0], "t2": times[1], "cpu1": cpu1}
            )
        out[str(d)] = runs
    print(json.dumps(out))


if __name__ == "__main__":
    main()
