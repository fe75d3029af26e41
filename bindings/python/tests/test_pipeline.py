"""The workflow from Python: a project on the small synthetic block is run through the C
ABI, its report meets the checkpoint targets, pycolmap reads the reference epoch's COLMAP
model with the orientations of our block and every epoch's with the tie points and control
the report counts, the film epoch's model in its fiducial-frame images projects the true
checkpoints onto their measurements, its BlocksExchange converts back to the same
projections, and a bad project file fails naming the key."""
import collections
import csv
import json
import pathlib

import cv2
import numpy as np
import pycolmap
import pytest

import cloudcontrol
from cloudcontrol import formats

PROJECT = """
name = "python-run"
crs = "EPSG:4547"
output = "../run"
[control]
lidar = ["lidar"]
checkpoints = "checkpoints.csv"
checkpoint_images = "truth/checkpoint_images.csv"
[reference]
name = "reference_2024"
date = "2024-05-29"
photos = "epochs/reference_2024/images"
camera = "epochs/reference_2024/camera.json"
pos = "epochs/reference_2024/pos.csv"
[[archive]]
name = "film_1978"
date = "1978-06-06"
photos = "epochs/film_1978/images"
camera = "epochs/film_1978/camera.json"
pos = "epochs/film_1978/pos.csv"
[thresholds]
control_interval_px = 120
chip_size_px = 193
[outputs]
orthophoto = false
"""


@pytest.fixture(scope="module")
def block(tmp_path_factory, shared_block):
    d = shared_block("small", 7, "rough", tmp_path_factory.mktemp("pipeline") / "block")
    (d / "project.toml").write_text(PROJECT)
    return d


def test_run_meets_the_checkpoint_targets_and_pycolmap_reads_the_model(block):
    res = cloudcontrol.run(block / "project.toml", partial_ok=True)
    epochs = {e["name"]: e for e in res["report"]["epochs"]}
    ref, film = epochs["reference_2024"], epochs["film_1978"]
    assert ref["photos_oriented"] == ref["photos_total"] == 12
    assert ref["check_rmse_plan_m"] <= ref["gsd_m"] and ref["check_rmse_height_m"] <= ref["gsd_m"]
    assert film["photos_oriented"] / film["photos_total"] >= 0.9
    # Film from reference DCPs directly: within a ground pixel in plan, 1.5 in height.
    assert film["check_rmse_plan_m"] <= film["gsd_m"]
    assert film["check_rmse_height_m"] <= 1.5 * film["gsd_m"]
    assert cloudcontrol.load_report(res["output"]) == json.loads(
        (pathlib.Path(res["output"]) / "report" / "report.json").read_text())

    out = pathlib.Path(res["output"])
    model = out / "outputs-reference_2024" / "colmap"
    rec = pycolmap.Reconstruction(str(model))
    origin = np.array(json.loads((model / "cloudcontrol_georef.json").read_text())["origin"])
    ours = json.loads((out / "epoch-reference_2024" / "block.json").read_text())
    centres = {p["name"]: np.array(p["pose"]["center"]) + np.array(ours["origin"])
               for p in ours["photos"].values()}
    assert len(rec.images) == 12
    for img in rec.images.values():
        c = img.projection_center() + origin
        assert np.linalg.norm(c - centres[pathlib.Path(img.name).stem]) < 1e-6

    # The report's tie statistics are what pycolmap reads in each epoch's COLMAP model:
    # tie points by the number of images in their track, and the control points measured.
    for name, e in epochs.items():
        model = out / f"outputs-{name}" / "colmap"
        rec = pycolmap.Reconstruction(str(model))
        kinds = {p["id"]: p["kind"] for p in
                 json.loads((model / "cloudcontrol_georef.json").read_text())["points"]}
        tracks = {i: len({el.image_id for el in p.track.elements})
                  for i, p in rec.points3D.items()}
        ties = collections.Counter(n for i, n in tracks.items() if i not in kinds)
        assert {str(k): v for k, v in ties.items()} == e["ties"]["multiplicity"], name
        control = [i for i, n in tracks.items() if kinds.get(i) == "control" and n > 0]
        assert len(control) == e["ties"]["control_points"], name
        assert sum(len(rec.points3D[i].track.elements) for i in control) \
            == e["ties"]["control_observations"], name
    assert ref["ties"]["points"] > 100 and film["ties"]["control_points"] > 10

    # A second run skips every finished stage.
    again = cloudcontrol.run(block / "project.toml", partial_ok=True)
    assert again["ran"] == []


def _projections(rec, origin, world):
    """Pixel of every world point in every image of a COLMAP model (None behind it)."""
    out = {}
    for iid, img in rec.images.items():
        cam, pose = rec.cameras[img.camera_id], img.cam_from_world()
        for k, x in world.items():
            p = cam.img_from_cam(pose * (x - origin))
            out[iid, k] = None if p is None else np.asarray(p)
    return out


def test_film_products_are_in_fiducial_frame_images(block, tmp_path):
    """Resampled film scans (formats/workflow/README.md, "Resampled film scans"): the true
    checkpoints projected through pycolmap's reading of the film COLMAP model land on
    their measurements in the scans moved into the frame images by the epoch's own
    interior orientation and the documented frame (x_mm = (u - W/2) p, y_mm = (H/2 - v) p)
    within the film target, with our exterior orientations unchanged and, for the true
    orientation, within 0.01 px; the BlocksExchange converts back to COLMAP with the same
    projections; OpenCV's affine warp of a scan agrees with our frame image."""
    res = cloudcontrol.run(block / "project.toml", partial_ok=True)
    out = pathlib.Path(res["output"])
    odir = out / "outputs-film_1978"
    assert json.loads((odir / "skipped.json").read_text()) == {}
    frames = json.loads((odir / "resampled" / "frames.json").read_text())
    p, w, h = (frames["frame"][k] for k in ("pixel_mm", "width", "height"))
    assert frames["format_mm"] == [230.0, 230.0] and (w, h) == (round(230 / p), round(230 / p))

    ours = json.loads((out / "epoch-film_1978" / "block.json").read_text())
    oriented = {ph["name"]: ph for ph in ours["photos"].values() if ph["status"] == "oriented"}
    io = {n: np.array(ours["cameras"][str(ph["camera"])]["model"]["interior"]["pixel_to_mm"])
          for n, ph in oriented.items()}
    truth = {r["id"]: np.array([float(r["x"]), float(r["y"]), float(r["z"])])
             for r in csv.DictReader(open(block / "truth" / "checkpoints.csv"))}
    measured = [r for r in csv.DictReader(open(block / "truth" / "checkpoint_images.csv"))
                if r["epoch"] == "film_1978"]

    rec = pycolmap.Reconstruction(str(odir / "colmap"))
    origin = np.array(json.loads((odir / "colmap" / "cloudcontrol_georef.json").read_text())["origin"])
    assert len(rec.images) == len(oriented)
    proj = _projections(rec, origin, truth)
    errors = []
    for iid, img in rec.images.items():
        stem = pathlib.Path(img.name).stem
        assert (rec.cameras[img.camera_id].width, rec.cameras[img.camera_id].height) == (w, h)
        for m in (m for m in measured if m["photo"] == stem):
            v = io[stem] @ np.array([float(m["col"]), float(m["row"]), 1.0])
            want = np.array([w / 2 + v[0] / v[2] / p, h / 2 - v[1] / v[2] / p])
            errors.append(np.linalg.norm(proj[iid, m["id"]] - want))
    rms = float(np.sqrt(np.mean(np.square(errors))))
    print(f"film checkpoints in the frame images: {len(errors)} measurements, RMS {rms:.3f} px")
    # This RMS is the epoch's orientation error, not the export's (the chain itself is
    # exact, below): the 0.5 px. With this project (film from the reference DCPs
    # directly) over small seeds 1-10: 0.095-0.379 px, seed 6 the worst, this seed (7)
    # 0.284; it was 0.534 here before the film epoch had its tie points. The film frame
    # (2.7 km) is far wider than the LiDAR area (300 x 220 m), so every checkpoint outside
    # a photo's control box is an extrapolation.
    assert len(errors) >= 20 and rms <= 0.5

    # The model carries our orientation unchanged: every image's projection centre is its
    # photo's in our block.
    centres = {n: np.array(ph["pose"]["center"]) + np.array(ours["origin"])
               for n, ph in oriented.items()}
    for img in rec.images.values():
        c = img.projection_center() + origin
        assert np.linalg.norm(c - centres[pathlib.Path(img.name).stem]) < 1e-6

    # The chain scan -> frame image ->
    # frame camera itself is exact: with the true exterior orientation and the true scan
    # affine (truth/epochs/film_1978/), the film model's camera puts every checkpoint on
    # its measurement.
    t = block / "truth" / "epochs" / "film_1978"
    true_io = {r["photo"]: np.array([[float(r["a11"]), float(r["a12"]), float(r["a13"])],
                                     [float(r["a21"]), float(r["a22"]), float(r["a23"])],
                                     [0.0, 0.0, 1.0]])
               for r in csv.DictReader(open(t / "scan_affine.csv"))}
    true_eo = {r["photo"]: (np.array([[float(r[f"r{i}{j}"]) for j in "123"] for i in "123"]),
                            np.array([float(r["x"]), float(r["y"]), float(r["z"])]))
               for r in csv.DictReader(open(t / "eo.csv"))}
    worst = 0.0
    for img in rec.images.values():
        stem = pathlib.Path(img.name).stem
        rot, centre = true_eo[stem]
        for m in (m for m in measured if m["photo"] == stem):
            v = true_io[stem] @ np.array([float(m["col"]), float(m["row"]), 1.0])
            want = np.array([w / 2 + v[0] / p, h / 2 - v[1] / p])
            got = rec.cameras[img.camera_id].img_from_cam(rot @ (truth[m["id"]] - centre))
            worst = max(worst, float(np.linalg.norm(np.asarray(got) - want)))
    assert worst < 0.01, f"true orientation through the frame camera: {worst} px"

    # BlocksExchange -> COLMAP (our reader) projects every checkpoint alike.
    conv = tmp_path / "from_bx"
    formats.convert(odir / "blocks_exchange.xml", conv)
    back = pycolmap.Reconstruction(str(conv))
    origin_b = np.array(json.loads((conv / "cloudcontrol_georef.json").read_text())["origin"])
    proj_b = _projections(back, origin_b, truth)
    assert proj.keys() == proj_b.keys()
    diff = max(np.linalg.norm(a - proj_b[k]) for k, a in proj.items() if a is not None)
    print(f"BlocksExchange round trip: max {diff:.2e} px")
    assert diff <= 1e-6

    # The frame image against OpenCV's cubic warp of the scan through the same transform
    # (OpenCV's pixel centres are integers, ours at +0.5).
    name = sorted(oriented)[0]
    # block.json names the scan relative to its own folder (formats/workflow).
    scan_path = out / "epoch-film_1978" / oriented[name]["image"]
    assert not pathlib.Path(oriented[name]["image"]).is_absolute() and scan_path.is_file()
    scan = cv2.imread(str(scan_path), cv2.IMREAD_GRAYSCALE).astype(np.float32)
    frame_to_mm = np.array([[p, 0, -p * w / 2], [0, -p, p * h / 2], [0, 0, 1]])
    shift = lambda d: np.array([[1, 0, d], [0, 1, d], [0, 0, 1]])
    m = shift(-0.5) @ np.linalg.inv(io[name]) @ frame_to_mm @ shift(0.5)
    cv = cv2.warpAffine(scan, m[:2], (w, h), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP)
    img = cv2.imread(str(odir / "resampled" / f"{name}.png"), cv2.IMREAD_UNCHANGED)
    assert img.shape == (h, w) and img.dtype == np.uint8
    c = slice(h // 8, h - h // 8)
    mad = float(np.mean(np.abs(img[c, c].astype(np.float32) - cv[c, c])))
    print(f"frame image vs OpenCV warp: mean |difference| {mad:.2f} grey levels")
    assert mad < 1.5


def test_a_bad_project_fails_naming_the_key(block):
    bad = block / "bad.toml"
    bad.write_text(PROJECT.replace('chip_size_px = 193', 'chip_size_px = 193\nnot_a_key = 1'))
    with pytest.raises(cloudcontrol.CloudControlError, match="not_a_key"):
        cloudcontrol.run(bad)


def test_each_epoch_surface_read_with_gdal_matches_its_truth(block):
    """Every epoch's dsm.tif, read with GDAL (rasterio), against the epoch's true surface
    (truth/epochs/<epoch>/dsm.tif) sampled at the DSM's cell centres, away from height
    edges: the run's own orientations, so their datum error is in the median."""
    import rasterio

    res = cloudcontrol.run(block / "project.toml", partial_ok=True)
    out = pathlib.Path(res["output"])
    for name in ("reference_2024", "film_1978"):
        with rasterio.open(out / f"surface-{name}" / "dsm.tif") as ds:
            assert ds.crs.to_epsg() == 4547
            z = ds.read(1, masked=True)
            transform = ds.transform
        with rasterio.open(block / "truth" / "epochs" / name / "dsm.tif") as ts:
            truth = ts.read(1)
            tinv = ~ts.transform
        gsd = json.loads((out / f"surface-{name}" / "dsm.json").read_text())["ground_pixel_m"]
        rows, cols = np.nonzero(~np.ma.getmaskarray(z))
        xs, ys = rasterio.transform.xy(transform, rows, cols)
        tc, tr = tinv @ (np.asarray(xs), np.asarray(ys))
        tc, tr = np.floor(tc).astype(int), np.floor(tr).astype(int)
        inside = (tc >= 2) & (tr >= 2) & (tc < truth.shape[1] - 2) & (tr < truth.shape[0] - 2)
        tc, tr, zz = tc[inside], tr[inside], z.data[rows[inside], cols[inside]]
        t = truth[tr, tc]
        # Away from height edges: the truth's 5 x 5 neighbourhood spans less than 0.5 m.
        win = np.stack([truth[tr + a, tc + b] for a in range(-2, 3) for b in range(-2, 3)])
        flat = win.max(0) - win.min(0) < 0.5
        dz = (zz[flat] - t[flat]) / gsd
        med = float(np.median(dz))
        nmad = float(1.4826 * np.median(np.abs(dz - med)))
        assert len(dz) > 10000, (name, len(dz))
        assert abs(med) <= 0.3 and nmad <= 1.0, (name, med, nmad)


def test_every_raster_is_on_one_lattice_and_subtracts_without_resampling(block):
    """Issue 53's one project grid: every GeoTIFF of the run (read with rasterio) starts at
    the same corner with a cell of 1 m times a power of two, so numpy subtracts any two by
    averaging the finer one's k x k blocks, no resampling: the reference DSM (0.125 m)
    averaged onto the LiDAR's surface (1 m) and subtracted gives, on the change stage's
    stable terrain, the median dh the change stage computed by its own sampling."""
    import rasterio

    res = cloudcontrol.run(block / "project.toml", partial_ok=True)
    out = pathlib.Path(res["output"])
    tifs = [p for p in out.rglob("*.tif") if "resampled" not in p.parts]
    assert any(p.name == "lidar_dsm.tif" for p in tifs) and any(p.name == "dh.tif" for p in tifs)
    corners = set()
    for p in tifs:
        with rasterio.open(p) as ds:
            t = ds.transform
        assert t.b == 0 and t.d == 0 and t.a == -t.e, p
        assert np.log2(t.a) == round(np.log2(t.a)), (p, t.a)
        corners.add((t.c, t.f))
    assert len(corners) == 1, corners

    def read(path):
        with rasterio.open(path) as ds:
            return ds.read(1, masked=True).filled(np.nan).astype(float), ds.transform.a

    lidar, big = read(out / "control" / "lidar_dsm.tif")
    dsm, small = read(out / "surface-reference_2024" / "dsm.tif")
    k = int(round(big / small))
    assert k * small == big
    h, w = min(lidar.shape[0], dsm.shape[0] // k), min(lidar.shape[1], dsm.shape[1] // k)
    blocks = dsm[: h * k, : w * k].reshape(h, k, w, k)
    # A coarse cell whose k x k fine cells all have a height: their mean (else NaN).
    coarse = blocks.mean(axis=(1, 3))
    dh = coarse - lidar[:h, :w]
    stable, _ = read(out / "change-reference_2024" / "stable.tif")
    use = (stable[:h, :w] == 1) & np.isfinite(dh)
    assert use.sum() > 1000
    ours = json.loads((out / "change-reference_2024" / "change.json").read_text())
    median = ours["control"]["change"]["statistics"]["median_m"]
    assert abs(float(np.median(dh[use])) - median) < 0.02, (float(np.median(dh[use])), median)
