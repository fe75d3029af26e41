"""DCP packages and patch prediction from Python."""
import json
import pathlib
import shutil

import numpy as np
import pytest

import cloudcontrol as cc

SAMPLE = pathlib.Path(__file__).resolve().parents[3] / "formats" / "dcp" / "sample.dcp"


def test_sample_package_points_match_its_manifest():
    pkg = cc.DcpPackage(SAMPLE)
    manifest = json.loads((SAMPLE / "manifest.json").read_text())
    xyz, sig = pkg.points()
    assert len(pkg) == len(manifest["points"]) == 4
    np.testing.assert_array_equal(xyz, [p["xyz"] for p in manifest["points"]])
    np.testing.assert_array_equal(sig, [p["sigma"] for p in manifest["points"]])
    # A square around the first two points (12 m apart in x).
    x, y = xyz[0, 0], xyz[0, 1]
    hits = pkg.query_polygon([[x - 1, y - 1], [x + 13, y - 1], [x + 13, y + 1], [x - 1, y + 1]])
    assert hits.tolist() == [0, 1]


def test_corrupted_package_is_refused(tmp_path):
    bad = tmp_path / "bad.dcp"
    shutil.copytree(SAMPLE, bad)
    chip = sorted((bad / "chips").iterdir())[0]
    data = bytearray(chip.read_bytes())
    data[-20] ^= 0xFF
    chip.write_bytes(bytes(data))
    with pytest.raises(cc.CloudControlError, match="checksum mismatch") as e:
        cc.DcpPackage(bad)
    assert e.value.status_name == "FORMAT"
    with pytest.raises(cc.CloudControlError, match="not a DCP package"):
        cc.DcpPackage(tmp_path)


def test_prediction_covariance_matches_monte_carlo():
    cam = cc.Camera(3000, 3000, 3000.0, 3000.0, 1500.0, 1500.0)
    pose = cc.Pose.from_opk(0.0, 0.0, 0.0, [0.0, 0.0, 1500.0])
    s_ang, s_pos = np.radians(3.0), 10.0
    cov = np.diag([s_ang**2] * 3 + [s_pos**2] * 3)
    pts = np.array([[100.0, 50.0, 0.0], [-300.0, 200.0, 20.0]])
    px, pc = cc.predict(cam, pose, cov, pts)
    np.testing.assert_allclose(px, cam.project(pose, pts), atol=1e-9)
    assert np.all(np.linalg.eigvalsh(pc) > 0)
    # Monte Carlo over perturbed orientations: small rotation vector applied on the left.
    rng = np.random.default_rng(3)
    samples = []
    for _ in range(3000):
        w = rng.normal(0, s_ang, 3)
        th = np.linalg.norm(w)
        k = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
        r = np.eye(3) + np.sin(th) / th * k + (1 - np.cos(th)) / th**2 * k @ k
        p = cc.Pose(r @ pose.rotation, pose.center + rng.normal(0, s_pos, 3))
        samples.append(cam.project(p, pts[:1])[0])
    mc = np.cov(np.array(samples).T)
    np.testing.assert_allclose(np.sqrt(np.diag(mc)), np.sqrt(np.diag(pc[0])), rtol=0.1)
