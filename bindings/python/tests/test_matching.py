"""Python binding of the matching module: template matching with known sub-pixel truth,
bad input, and fiducial interior orientation of a synthetic scan."""
import json
import pathlib

import numpy as np
import pytest

import cloudcontrol as cc

ROOT = pathlib.Path(__file__).resolve().parents[3]


def texture(x, y, seed=4):
    rng = np.random.default_rng(seed)
    out = np.full(np.broadcast(x, y).shape, 100.0)
    for _ in range(24):
        lam = rng.uniform(7, 30)
        th = rng.uniform(0, np.pi)
        k = 2 * np.pi / lam
        out += rng.uniform(4, 12) * np.sin(k * np.cos(th) * x + k * np.sin(th) * y + rng.uniform(0, 6.3))
    return out


def test_match_template_recovers_a_subpixel_shift():
    truth = (61.3, 40.8)
    yy, xx = np.mgrid[0:120, 0:128] + 0.5
    image = texture(xx - truth[0], yy - truth[1]).astype(np.float32)
    ty, tx = np.mgrid[0:31, 0:31] + 0.5
    template = texture(tx - 15.5, ty - 15.5).astype(np.float32)
    m = cc.match_template(image, template, window=(20, 10, 90, 70))
    assert m.accepted, m.reason
    assert abs(m.x - truth[0]) < 0.02 and abs(m.y - truth[1]) < 0.02
    assert m.lsm_converged and m.sigma_x < 0.05
    assert m.ncc > 0.99


def test_bad_input_is_a_clear_error_or_no_match():
    image = texture(*np.meshgrid(np.arange(64.0), np.arange(64.0))).astype(np.float32)
    with pytest.raises(cc.CloudControlError, match="no texture"):
        cc.match_template(image, np.full((21, 21), 7.0, np.float32))
    with pytest.raises(cc.CloudControlError, match="smaller than the template"):
        cc.match_template(image[:10, :10], image[:21, :21])
    with pytest.raises(cc.CloudControlError, match="outside"):
        cc.match_template(image, image[:21, :21], window=(50, 50, 40, 40))
    bad = image.copy()
    bad[3, 3] = np.nan
    with pytest.raises(cc.CloudControlError, match="not finite"):
        cc.match_template(bad, image[:21, :21])
    other = texture(*np.meshgrid(np.arange(64.0), np.arange(64.0)), seed=99).astype(np.float32)
    m = cc.match_template(other, image[10:31, 10:31])
    assert not m.accepted and m.reason


def test_fiducial_io_of_a_synthetic_scan():
    cam = json.loads((ROOT / "formats/cameras/wild_rc10.json").read_text())
    for f in cam["fiducials"]:
        f["shape"] = {"type": "circle", "size_mm": 1.0}
    s, n = 0.1, 2400
    # pixel -> mm: slight scale difference and shear, origin off the scan centre.
    lin = np.array([[s * 1.002, s * 0.001], [0.0, -s * 0.999]])
    origin = np.array([n / 2 + 2.4, n / 2 - 1.7])
    inv = np.linalg.inv(lin)
    rng = np.random.default_rng(0)
    scan = (40 + rng.normal(0, 5, (n, n))).astype(np.float32)
    truth = {}
    for f in cam["fiducials"]:
        c = origin + inv @ np.array([f["x_mm"], f["y_mm"]])
        truth[f["id"]] = c
        r0, c0 = int(c[1]) - 12, int(c[0]) - 12
        yy, xx = np.mgrid[r0:r0 + 24, c0:c0 + 24]
        acc = np.zeros(xx.shape)
        for sy in range(4):
            for sx in range(4):
                p = np.stack([xx + (sx + 0.5) / 4 - origin[0], yy + (sy + 0.5) / 4 - origin[1]])
                mm = np.einsum("ij,jkl->ikl", lin, p)
                acc += np.hypot(mm[0] - f["x_mm"], mm[1] - f["y_mm"]) <= 0.5
        scan[r0:r0 + 24, c0:c0 + 24] += 150 * acc / 16
    io = cc.fiducial_io(cam, scan, rotation_deg=0)
    assert io["transform"]["type"] == "affine"
    assert io["rmse_um"] < 10
    for m in io["marks"]:
        assert m["used"], m
        assert np.hypot(m["x"] - truth[m["id"]][0], m["y"] - truth[m["id"]][1]) < 0.15
    h = np.array(io["transform"]["pixel_to_mm"]).reshape(3, 3)
    assert np.allclose(h[:2, :2], lin, rtol=0, atol=2e-5)
    with pytest.raises(cc.CloudControlError, match="fiducial"):
        cc.fiducial_io(cam, np.full((300, 300), 5.0, np.float32), rotation_deg=0)
