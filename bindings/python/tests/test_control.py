"""DCP packages and patch prediction from Python."""
import csv
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


# --- Export from an oriented block and import into a store (tiny synthetic block) -------

@pytest.fixture(scope="module")
def oriented(tmp_path_factory):
    """The tiny block's reference epoch at its true orientation, written as the workflow
    writes an oriented epoch: block.json (block-local poses, origin, CRS) and images.json."""
    from cloudcontrol import synth

    root = tmp_path_factory.mktemp("dcp")
    block_dir = root / "block"
    m = synth.generate(block_dir, preset="tiny", seed=2, pos="good")
    epoch = next(e for e in m["epochs"] if e["name"] == "reference_2024")
    origin = np.array(m["origin"])
    camera = json.loads((block_dir / "truth/epochs/reference_2024/camera.json").read_text())
    truth = {}
    photos, images = {}, {}
    with open(block_dir / "truth/epochs/reference_2024/eo.csv") as f:
        for row in csv.DictReader(f):
            pid = epoch["photos"].index(row["photo"]) + 1
            r = np.array([float(row[f"r{i}{j}"]) for i in (1, 2, 3) for j in (1, 2, 3)]).reshape(3, 3)
            c = np.array([float(row[k]) for k in "xyz"])
            truth[pid] = (r, c)
            # block.json writes a rotation as three rows (formats/cameras/README.md).
            photos[str(pid)] = {"id": pid, "name": row["photo"], "camera": 1, "status": "oriented",
                                "pose": {"rotation": r.tolist(), "center": (c - origin).tolist()}}
            images[str(pid)] = str(block_dir / epoch["images_dir"] / f"{row['photo']}.png")
    block = {"crs": m["crs"], "origin": origin.tolist(), "points": {},
             "cameras": {"1": {"id": 1, "name": "reference", "model": camera}}, "photos": photos}
    (root / "block.json").write_text(json.dumps(block))
    (root / "images.json").write_text(json.dumps(images))
    return root, block_dir / "lidar", camera, truth


def _project(camera, r, c, xyz):
    """Collinearity with Brown distortion (OpenCV), independent of the library."""
    x = r @ (np.asarray(xyz) - c)
    u, v = x[0] / x[2], x[1] / x[2]
    d = camera["distortion"]
    r2 = u * u + v * v
    radial = 1 + d["k1"] * r2 + d["k2"] * r2**2 + d["k3"] * r2**3
    ud = u * radial + 2 * d["p1"] * u * v + d["p2"] * (r2 + 2 * u * u)
    vd = v * radial + d["p1"] * (r2 + 2 * v * v) + 2 * d["p2"] * u * v
    return np.array([camera["fx"] * ud + camera["cx"], camera["fy"] * vd + camera["cy"]])


def _ground_height(ground, x, y, radius=1.5):
    """Least-squares plane through the LiDAR ground returns within ``radius`` at (x, y)."""
    near = ground[(ground[:, 0] - x) ** 2 + (ground[:, 1] - y) ** 2 <= radius**2]
    assert len(near) >= 6
    a = np.column_stack([np.ones(len(near)), near[:, 0] - x, near[:, 1] - y])
    return np.linalg.lstsq(a, near[:, 2], rcond=None)[0][0]


TINY = dict(interval_px=40, chip_size=129, interest_level=1, max_coplanarity=0.02)


def test_export_writes_points_that_agree_with_the_truth(oriented, tmp_path):
    laspy = pytest.importorskip("laspy")
    root, lidar, camera, truth = oriented
    out = tmp_path / "reference.dcp"
    pkg = cc.DcpPackage.export(root / "block.json", root / "images.json", lidar, out,
                               name="reference_2024", date="2024-05-29", **TINY)
    assert pkg.path == out
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["epoch"] == {"name": "reference_2024", "date": "2024-05-29"}
    xyz, sig = pkg.points()
    assert len(pkg) >= 15
    np.testing.assert_array_equal(xyz, [p["xyz"] for p in manifest["points"]])
    np.testing.assert_allclose(sig, 0.05)
    ground = np.vstack([
        (lambda las: np.column_stack([las.x, las.y, las.z])[np.asarray(las.classification) == 2])(laspy.read(t))
        for t in sorted(lidar.glob("*.las"))
    ])
    worst_px, worst_dz = 0.0, 0.0
    for p in manifest["points"]:
        assert len(p["measurements"]) >= 2
        for ms in p["measurements"]:
            r, c = truth[ms["photo"]]
            worst_px = max(worst_px, np.linalg.norm(_project(camera, r, c, p["xyz"]) - ms["pixel"]))
        worst_dz = max(worst_dz, abs(p["xyz"][2] - _ground_height(ground, *p["xyz"][:2])))
    print(f"{len(pkg)} points: max reprojection {worst_px:.2e} px, max |z - LiDAR ground| {worst_dz:.3f} m")
    assert worst_px <= 0.5
    assert worst_dz <= 0.2


def test_export_refuses_bad_options_and_missing_inputs(oriented, tmp_path):
    root, lidar, _, _ = oriented
    args = (root / "block.json", root / "images.json", lidar, tmp_path / "x.dcp")
    with pytest.raises(TypeError, match="chipsize"):
        cc.DcpPackage.export(*args, chipsize=129)
    with pytest.raises(ValueError, match="chip_size"):
        cc.DcpPackage.export(*args, chip_size=-1)
    with pytest.raises(cc.CloudControlError, match="chip_size 128") as e:
        cc.DcpPackage.export(*args, chip_size=128)
    assert e.value.status_name == "INVALID_ARGUMENT"
    with pytest.raises(cc.CloudControlError, match="missing.json") as e:
        cc.DcpPackage.export(root / "missing.json", *args[1:], **TINY)
    assert e.value.status_name == "NOT_FOUND"
    assert not (tmp_path / "x.dcp").exists()


def test_import_copies_a_valid_package_and_refuses_an_edited_one(oriented, tmp_path):
    root, lidar, _, _ = oriented
    src = cc.DcpPackage.export(root / "block.json", root / "images.json", [lidar], tmp_path / "src" / "ref.dcp", **TINY)
    store = tmp_path / "store"
    stored = cc.DcpPackage.import_(src.path, store)
    assert stored.path == store / "ref.dcp"
    assert len(stored) == len(src)
    for f in sorted(p.relative_to(src.path) for p in src.path.rglob("*") if p.is_file()):
        assert (stored.path / f).read_bytes() == (src.path / f).read_bytes(), f
    bad = tmp_path / "bad" / "edited.dcp"
    shutil.copytree(src.path, bad)
    manifest = json.loads((bad / "manifest.json").read_text())
    chip = manifest["points"][0]["measurements"][0]["chip"]["file"]
    data = bytearray((bad / chip).read_bytes())
    data[-20] ^= 0xFF
    (bad / chip).write_bytes(bytes(data))
    for target in (store, tmp_path / "new_store"):
        with pytest.raises(cc.CloudControlError, match="checksum mismatch") as e:
            cc.DcpPackage.import_(bad, target)
        assert e.value.status_name == "FORMAT"
        assert chip in str(e.value) and "edited.dcp" in str(e.value)
    assert sorted(p.name for p in store.iterdir()) == ["ref.dcp"]
    assert not (tmp_path / "new_store").exists()


# --- A package from an orthophoto with a DEM (the tiny block's orthophoto/) -----------

def test_package_from_orthophoto_has_points_on_chip_centres_at_dem_heights(oriented, tmp_path):
    """The tiny block's true orthophoto and DEM as a control source: every point, taken into
    the orthophoto through the geotransform gdalinfo reads, lies on its chip's centre, and
    its height is the DEM's there (read with OpenCV)."""
    import subprocess
    cv2 = pytest.importorskip("cv2")
    block_dir = oriented[1].parent
    ortho, dem = block_dir / "orthophoto/orthophoto.tif", block_dir / "orthophoto/dem.tif"
    pkg = cc.DcpPackage.from_orthophoto(ortho, dem, "EPSG:4547", tmp_path / "ortho.dcp",
                                        name="ortho", date="2024")
    m = json.loads((pkg.path / "manifest.json").read_text())
    assert m["epoch"] == {"name": "ortho", "date": "2024"}
    # 400 × 300 px at 0.3 m: room for a few 193-px chips only.
    assert len(m["points"]) >= 3
    gt = json.loads(subprocess.run(["gdalinfo", "-json", str(ortho)], capture_output=True,
                                   check=True).stdout)["geoTransform"]
    dgt = json.loads(subprocess.run(["gdalinfo", "-json", str(dem)], capture_output=True,
                                    check=True).stdout)["geoTransform"]
    heights = cv2.imread(str(dem), cv2.IMREAD_UNCHANGED)
    for p in m["points"]:
        x, y, z = p["xyz"]
        col, row = (x - gt[0]) / gt[1], (y - gt[3]) / gt[5]
        ch = p["measurements"][0]["chip"]
        assert abs(col - (ch["x0"] + ch["width"] / 2)) < 1e-6
        assert abs(row - (ch["y0"] + ch["height"] / 2)) < 1e-6
        c, r = int((x - dgt[0]) / dgt[1]), int((y - dgt[3]) / dgt[5])
        assert abs(heights[r, c] - z) < 0.3, (p["name"], heights[r, c], z)
    # A raster without any CRS in its file, and none given, is refused naming it.
    plain = tmp_path / "plain.png"
    cv2.imwrite(str(plain), cv2.imread(str(ortho), cv2.IMREAD_GRAYSCALE))
    with pytest.raises(cc.CloudControlError, match="plain.png"):
        cc.DcpPackage.from_orthophoto(plain, dem, "EPSG:4547", tmp_path / "plain.dcp")
