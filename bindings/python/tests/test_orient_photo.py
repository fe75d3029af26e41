"""One photo oriented through the C ABI (``ccp_orient_photo``): each film scan of the small
synthetic block, from the reference epoch's DCP package, its POS and a LiDAR ground DEM,
compared with the true exterior orientation and with the pose `cloudcontrol orient`
gives the same photo; a far-off approximate orientation and a missing image are refused
with the problem named.

Why the small block and how close a pose can be: its film scans (42 µm pixel, 5714 px,
f = 3640 px, 0.5 m ground pixel from 1.8 km) see the whole 300 × 220 m scene in only
about 600 × 440 px near the scan centre, so a resection from its control points
determines the rays through that area (to a fraction of a pixel) far better than the
centre and the tilt apart: a tilt error of 1–2 mrad is taken up by the centre over the
1.8 km lever arm, and the library's own covariance gives σ ≈ 2–4 m for the centre. So
the test asserts (1) the pose error against the reported covariance, (2) how far the
pose moves the control area in the image, in ground pixels, and (3) that the covariance
has the size this geometry gives (angles ≤ 3 mrad, the centre within that tilt times the
flying height).
"""
import csv
import json
import math
import pathlib
import subprocess
import time

import numpy as np
import pytest

import cloudcontrol as cc

ROOT = pathlib.Path(__file__).resolve().parents[3]
BIN = ROOT / "target" / "release" / "cloudcontrol"
EPOCH = "film_1978"
# χ²(6) at 99.9 %: a pose error beyond it is not explained by the reported covariance.
CHI2_6_999 = 22.46


def _rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(line for line in f if not line.lstrip().startswith("#")))


def _truth_eo(path):
    """truth/epochs/<epoch>/eo.csv: photo stem → (world→camera R, world centre)."""
    out = {}
    for r in _rows(path):
        rot = np.array([float(r[f"r{i}{j}"]) for i in (1, 2, 3) for j in (1, 2, 3)]).reshape(3, 3)
        out[r["photo"]] = (rot, np.array([float(r[k]) for k in "xyz"]))
    return out


def _rotation_vector(r):
    """Axis × angle of a rotation matrix (rad)."""
    th = math.acos(min(1.0, max(-1.0, (np.trace(r) - 1.0) / 2.0)))
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    return v * (0.5 if th < 1e-12 else th / (2.0 * math.sin(th)))


def _mahalanobis2(o, rotation, center):
    """Squared Mahalanobis distance of a pose from ``o`` under ``o.covariance`` (rotation
    vector of the left perturbation R_o = exp([δ]×) R, as Pose::perturbed; centre in m)."""
    d = np.concatenate([_rotation_vector(o.rotation @ rotation.T), o.center - center])
    return float(d @ np.linalg.solve(o.covariance, d))


def _displacement_px(r1, c1, r2, c2, xyz, f_px):
    """Image displacement (px) of object points between two poses of one pinhole camera."""
    a = (r1 @ (xyz - c1).T).T
    b = (r2 @ (xyz - c2).T).T
    return f_px * np.linalg.norm(a[:, :2] / a[:, 2:] - b[:, :2] / b[:, 2:], axis=1)


def _angle_mrad(r1, r2):
    return 1e3 * np.linalg.norm(_rotation_vector(r1 @ r2.T))


@pytest.fixture(scope="module")
def film(tmp_path_factory, shared_block):
    """The small block; its reference epoch at the true orientation exported as a DCP
    package; a ground DEM GeoTIFF in world coordinates (`cloudcontrol lidar dem`); and
    `cloudcontrol orient` run on the film epoch with the same package, POS and DEM."""
    t0 = time.perf_counter()
    root = tmp_path_factory.mktemp("orient_photo")
    block = root / "block"
    shared_block("small", 2, "good", block)
    m = json.loads((block / "manifest.json").read_text())
    ref = next(e for e in m["epochs"] if e["name"] == "reference_2024")
    film = next(e for e in m["epochs"] if e["name"] == EPOCH)
    origin = np.array(m["origin"])
    # block.json and images.json as the workflow writes an oriented epoch (block-local
    # centres, rotations as three rows).
    photos, images = {}, {}
    for name, (r, c) in _truth_eo(block / "truth/epochs/reference_2024/eo.csv").items():
        pid = ref["photos"].index(name) + 1
        photos[str(pid)] = {"id": pid, "name": name, "camera": 1, "status": "oriented",
                            "pose": {"rotation": r.tolist(), "center": (c - origin).tolist()}}
        images[str(pid)] = str(block / ref["images_dir"] / f"{name}.png")
    camera = json.loads((block / "truth/epochs/reference_2024/camera.json").read_text())
    (root / "block.json").write_text(json.dumps({
        "crs": m["crs"], "origin": origin.tolist(), "points": {},
        "cameras": {"1": {"id": 1, "name": "reference", "model": camera}}, "photos": photos}))
    (root / "images.json").write_text(json.dumps(images))
    pkg = cc.DcpPackage.export(root / "block.json", root / "images.json", block / "lidar", root / "reference.dcp",
                               name="reference_2024", interval_px=40, chip_size=129, interest_level=1,
                               max_coplanarity=0.02)
    dem = root / "dem.tif"
    subprocess.run([str(BIN), "--quiet", "lidar", "dem", "--lidar", str(block / "lidar"), "--cell", "1",
                    "--out", str(dem)], check=True)
    out = root / "cli"
    subprocess.run([str(BIN), "--quiet", "orient", "--dcp", str(pkg.path), "--camera", str(block / film["camera"]),
                    "--images", str(block / film["images_dir"]), "--name", EPOCH,
                    "--pos", str(block / film["navigation"]), "--dem", str(dem), "--out", str(out)], check=True)
    # block.json: world = local + origin.
    b = json.loads((out / "block.json").read_text())
    cli = {p["name"]: (np.array(p["pose"]["rotation"]), np.array(p["pose"]["center"]) + np.array(b["origin"]))
           for p in b["photos"].values() if p["status"] == "oriented"}
    print(f"\nsmall block, DCP package ({len(pkg)} points), DEM and `cloudcontrol orient`: "
          f"{time.perf_counter() - t0:.1f} s")
    return dict(block=block, epoch=film, pkg=pkg, dem=dem, cli=cli,
                # formats/pos/: names may carry an image extension; angles in degrees.
                pos={pathlib.Path(r["name"]).stem: r for r in _rows(block / film["navigation"])},
                truth=_truth_eo(block / "truth/epochs" / EPOCH / "eo.csv"),
                # The scanner's true pixel (µm): √|det| of its pixel → mm affine.
                scan_um={r["photo"]: 1e3 * math.sqrt(abs(float(r["a11"]) * float(r["a22"])
                                                         - float(r["a12"]) * float(r["a21"])))
                         for r in _rows(block / "truth/epochs" / EPOCH / "scan_affine.csv")},
                certificate=json.loads((block / film["camera"]).read_text()))


def _orient(film, name, approximate=None, image=None):
    p = film["pos"][name]
    if approximate is None:
        approximate = [float(p[k]) for k in ("x", "y", "z", "omega", "phi", "kappa")]
    if image is None:
        image = film["block"] / film["epoch"]["images_dir"] / f"{name}.png"
    return cc.orient_photo(film["pkg"], film["block"] / film["epoch"]["camera"], image, approximate,
                           [float(p["sigma_xyz"]), float(p["sigma_angle"])], film["dem"])


@pytest.mark.parametrize("index", [0, 1])
def test_film_photo_is_oriented_to_the_truth_and_to_the_pipelines_pose(film, index):
    name = film["epoch"]["photos"][index]
    gsd = film["epoch"]["gsd_m"]
    t = time.perf_counter()
    o = _orient(film, name)
    secs = time.perf_counter() - t
    rt, ct = film["truth"][name]
    # Pinhole of the scan: certificate focal length over the scan pixel the library found.
    assert o.report["io"]["pixel_um"] == pytest.approx(film["scan_um"][name], rel=2e-3), o.report["io"]
    f_px = film["certificate"]["focal_mm"] / (o.report["io"]["pixel_um"] / 1000.0)

    # The result is a proper pose with its covariance and the matches that carry it.
    np.testing.assert_allclose(o.rotation @ o.rotation.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(o.rotation) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(o.covariance, o.covariance.T, rtol=1e-9, atol=1e-15)
    assert np.all(np.linalg.eigvalsh(o.covariance) > 0)
    n = len(o.sigma_px)
    assert n >= 50 and o.report["oriented"] and o.report["control_matches"] == n
    assert o.xyz.shape == (n, 3) and o.pixel.shape == (n, 2) and len(o.matches) == n
    assert np.all((o.sigma_px > 0) & (o.sigma_px < 2.0))
    # Every match is a point of the package, seen where the truth puts it (≤ 1 px).
    pts, _ = film["pkg"].points()
    assert all(np.any(np.all(pts == x, axis=1)) for x in o.xyz)
    true_px = _displacement_px(o.rotation, o.center, rt, ct, o.xyz, f_px)
    sig_c = np.sqrt(np.diag(o.covariance)[3:])
    sig_a = 1e3 * np.sqrt(np.diag(o.covariance)[:3])
    m2_truth = _mahalanobis2(o, rt, ct)
    # The approximate pose, for scale.
    p = film["pos"][name]
    a = cc.Pose.from_opk(*(math.radians(float(p[k])) for k in ("omega", "phi", "kappa")),
                         [float(p[k]) for k in "xyz"])
    approx_px = _displacement_px(a.rotation, a.center, rt, ct, o.xyz, f_px)
    print(f"\n{name}: {n} matches in {secs:.2f} s, σ0 {o.report['sigma_px']:.2f} px; σ centre {sig_c.round(2)} m,"
          f" σ angles {sig_a.round(2)} mrad\n"
          f"  vs truth: centre {np.linalg.norm(o.center - ct):.2f} m ({np.linalg.norm(o.center - ct) / gsd:.1f} GSD),"
          f" angle {_angle_mrad(o.rotation, rt):.2f} mrad, Mahalanobis² {m2_truth:.1f};"
          f" control area moved max {true_px.max():.2f} px (rms {np.sqrt(np.mean(true_px ** 2)):.2f});"
          f" approximate pose: max {approx_px.max():.1f} px")

    # (1) The error is the one the covariance states, and that covariance is the size
    # this geometry gives (a few ground pixels, 1–2 mrad; see the module docstring).
    assert m2_truth <= CHI2_6_999
    lever_m = 3e-3 * (ct[2] - o.xyz[:, 2].mean())  # 3 mrad of tilt over the flying height
    assert np.all(sig_c <= lever_m) and np.all(sig_a <= 3.0)
    assert np.linalg.norm(o.center - ct) <= 2 * lever_m and _angle_mrad(o.rotation, rt) <= 7.0
    # (2) Where the pose matters, it is right to well within a ground pixel: the control
    # area lands within 1 px (0.5 m) of where the truth puts it, from tens of px off.
    assert true_px.max() <= 1.0
    assert approx_px.max() >= 10.0

    # (3) The pipeline's pose for the same photo. It adjusts both scans together (ties
    # and control), so it differs from this single-photo resection by the resection's
    # own uncertainty: within its covariance, and within a ground pixel over the
    # control area.
    assert name in film["cli"], f"`cloudcontrol orient` did not orient {name}"
    rc, cc_ = film["cli"][name]
    cli_px = _displacement_px(o.rotation, o.center, rc, cc_, o.xyz, f_px)
    m2_cli = _mahalanobis2(o, rc, cc_)
    print(f"  vs `cloudcontrol orient`: centre {np.linalg.norm(o.center - cc_):.2f} m,"
          f" angle {_angle_mrad(o.rotation, rc):.2f} mrad, Mahalanobis² {m2_cli:.1f};"
          f" control area moved max {cli_px.max():.2f} px;"
          f" pipeline vs truth: centre {np.linalg.norm(cc_ - ct):.2f} m, angle {_angle_mrad(rc, rt):.2f} mrad")
    assert m2_cli <= CHI2_6_999
    assert cli_px.max() <= 1.0


def test_far_off_approximate_orientation_is_not_oriented_with_the_reason(film):
    name = film["epoch"]["photos"][0]
    p = film["pos"][name]
    # Two frame widths east: the whole footprint misses the control area.
    frame_m = film["epoch"]["image_size"][0] * film["epoch"]["gsd_m"]
    far = [float(p["x"]) + 2 * frame_m] + [float(p[k]) for k in ("y", "z", "omega", "phi", "kappa")]
    with pytest.raises(cc.NotOriented) as e:
        _orient(film, name, approximate=far)
    assert isinstance(e.value, cc.CloudControlError)
    assert e.value.status == 9 and e.value.status_name == "NOT_ORIENTED"
    assert e.value.reason.startswith("no control point predicted inside the photo (0 in the footprint)"), e.value
    assert f"{name}.png" in str(e.value)


def test_missing_or_null_image_is_named(film, tmp_path):
    name = film["epoch"]["photos"][0]
    missing = tmp_path / "scans" / "film_s09_009.png"
    with pytest.raises(cc.CloudControlError) as e:
        _orient(film, name, image=missing)
    assert e.value.status_name == "NOT_FOUND" and not isinstance(e.value, cc.NotOriented)
    assert str(missing) in str(e.value)
    p = film["pos"][name]
    approx = [float(p[k]) for k in ("x", "y", "z", "omega", "phi", "kappa")]
    with pytest.raises(cc.CloudControlError, match="image_path is a null pointer") as e:
        cc.orient_photo(film["pkg"], film["block"] / film["epoch"]["camera"], None, approx, [1.0, 0.5], film["dem"])
    assert e.value.status_name == "NULL_POINTER"
    with pytest.raises(ValueError, match="6 values"):
        cc.orient_photo(film["pkg"], film["block"] / film["epoch"]["camera"], missing, approx[:5], [1.0, 0.5],
                        film["dem"])
    with pytest.raises(cc.CloudControlError, match="sigma") as e:
        cc.orient_photo(film["pkg"], film["block"] / film["epoch"]["camera"], missing, approx, [1.0, 0.0],
                        film["dem"])
    assert e.value.status_name == "INVALID_ARGUMENT"
