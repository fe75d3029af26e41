"""Independent readers agree with our writers: pycolmap reads every COLMAP model we write
(text and binary, legacy and COLMAP 4 layouts) with the same cameras, poses and points;
we read pycolmap-written models of every supported camera model equal; gdalinfo reports
the CRS, geotransform, nodata and overviews of our orthophotos and DEMs."""
from __future__ import annotations

import json
import pathlib
import shutil
import subprocess

import cv2
import numpy as np
import pycolmap
import pytest

from cloudcontrol import CloudControlError
from cloudcontrol import formats

ROOT = pathlib.Path(__file__).resolve().parents[3]
SAMPLES = ROOT / "formats" / "colmap"


def _pose(image):
    """Unit quaternion (w >= 0) and translation. The real sample stores quaternions to 6-7
    digits, |q| - 1 up to 4e-7; COLMAP uses them unnormalised, we normalise on read."""
    p = image.cam_from_world()
    q = np.asarray(p.rotation.quat, dtype=float)
    q = q / np.linalg.norm(q)
    return (q if q[3] >= 0 else -q), np.asarray(p.translation)


def assert_same(a: pycolmap.Reconstruction, b: pycolmap.Reconstruction, tol=1e-9):
    assert set(a.cameras) == set(b.cameras)
    for cid, ca in a.cameras.items():
        cb = b.cameras[cid]
        assert (ca.model.name, ca.width, ca.height) == (cb.model.name, cb.width, cb.height)
        np.testing.assert_allclose(ca.params, cb.params, rtol=0, atol=tol)
    assert set(a.images) == set(b.images)
    for iid, ia in a.images.items():
        ib = b.images[iid]
        assert (ia.name, ia.camera_id) == (ib.name, ib.camera_id)
        (ra, ta), (rb, tb) = _pose(ia), _pose(ib)
        np.testing.assert_allclose(ra, rb, atol=tol)
        np.testing.assert_allclose(ta, tb, atol=tol)
        assert ia.num_points2D() == ib.num_points2D()
    assert set(a.points3D) == set(b.points3D)
    for pid, pa in a.points3D.items():
        pb = b.points3D[pid]
        np.testing.assert_allclose(pa.xyz, pb.xyz, atol=tol)
        assert tuple(pa.color) == tuple(pb.color)
        ta = sorted((e.image_id, *a.images[e.image_id].points2D[e.point2D_idx].xy) for e in pa.track.elements)
        tb = sorted((e.image_id, *b.images[e.image_id].points2D[e.point2D_idx].xy) for e in pb.track.elements)
        np.testing.assert_allclose(np.array(ta), np.array(tb), atol=tol)


@pytest.mark.parametrize("text", [False, True])
@pytest.mark.parametrize("legacy", [False, True])
def test_pycolmap_reads_what_we_write(tmp_path, text, legacy):
    ref = pycolmap.Reconstruction(str(SAMPLES / "kapture_maupertuis_colmap4_bin"))
    out = tmp_path / "model"
    formats.convert(SAMPLES / "kapture_maupertuis_colmap4_bin", out, text=text, legacy=legacy)
    assert (out / "rigs.bin").exists() == (not legacy and not text)
    assert (out / "rigs.txt").exists() == (not legacy and text)
    ours = pycolmap.Reconstruction(str(out))
    assert ours.num_points3D() == 1039
    assert_same(ref, ours, tol=1e-12)


CAMERAS = [
    ("SIMPLE_PINHOLE", [1847.53, 959.5, 539.5]),
    ("PINHOLE", [1847.53, 1850.1, 959.5, 539.5]),
    ("SIMPLE_RADIAL", [1847.53, 959.5, 539.5, -0.05]),
    ("RADIAL", [1847.53, 959.5, 539.5, -0.05, 0.01]),
    ("OPENCV", [1847.53, 1850.1, 959.5, 539.5, -0.05, 0.01, 1e-4, -2e-4]),
    ("FULL_OPENCV", [1847.53, 1850.1, 959.5, 539.5, -0.05, 0.01, 1e-4, -2e-4, 0.002, 0, 0, 0]),
]


@pytest.mark.parametrize("model,params", CAMERAS)
def test_we_read_pycolmap_models_of_every_camera_model_equal(tmp_path, model, params):
    rec = pycolmap.Reconstruction(str(SAMPLES / "kapture_maupertuis_txt"))
    cam = rec.cameras[1]
    rec.cameras[1] = pycolmap.Camera(camera_id=1, model=model, width=cam.width, height=cam.height, params=params)
    src = tmp_path / "pycolmap"
    src.mkdir()
    rec.write_binary(str(src))
    src_ref = pycolmap.Reconstruction(str(src))
    for text in (False, True):
        out = tmp_path / f"ours_{text}"
        formats.convert(src, out, text=text)
        assert_same(src_ref, pycolmap.Reconstruction(str(out)), tol=1e-12)


def _projections(rec):
    """Pixels of every track element: rotation from the normalised quaternion (the sample's
    are not unit to 4e-7, which pycolmap would carry into a non-orthonormal matrix), then
    pycolmap's own camera model (distortion included)."""
    out = []
    for pid in sorted(rec.points3D):
        p = rec.points3D[pid]
        for e in sorted(p.track.elements, key=lambda e: e.image_id):
            im = rec.images[e.image_id]
            x, y, z, w = np.asarray(im.cam_from_world().rotation.quat) / np.linalg.norm(im.cam_from_world().rotation.quat)
            r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                          [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                          [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
            xc = r @ p.xyz + np.asarray(im.cam_from_world().translation)
            out.append(rec.cameras[im.camera_id].img_from_cam(xc))
    return np.array(out)


def test_colmap_to_blocks_exchange_and_back_keeps_projections(tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    rec = pycolmap.Reconstruction(str(SAMPLES / "kapture_maupertuis_txt"))
    rec.cameras[1] = pycolmap.Camera(camera_id=1, model="FULL_OPENCV", width=1919, height=1079,
                                     params=CAMERAS[-1][1])
    rec.write_binary(str(src))
    formats.convert(src, tmp_path / "block.xml")
    formats.convert(tmp_path / "block.xml", tmp_path / "back")
    back = pycolmap.Reconstruction(str(tmp_path / "back"))
    ref = pycolmap.Reconstruction(str(src))
    d = np.abs(_projections(ref) - _projections(back)).max()
    assert d < 1e-6, d


def test_bad_input_is_a_clear_error(tmp_path):
    bad = tmp_path / "bad"
    shutil.copytree(SAMPLES / "kapture_maupertuis_colmap4_bin", bad)
    data = (bad / "images.bin").read_bytes()
    (bad / "images.bin").write_bytes(data[:500])
    with pytest.raises(CloudControlError, match=r"images\.bin.*truncated"):
        formats.convert(bad, tmp_path / "x.xml")
    assert not (tmp_path / "x.xml").exists()
    (tmp_path / "broken.xml").write_text("<BlocksExchange><Block>")
    with pytest.raises(CloudControlError, match=r"broken\.xml"):
        formats.convert(tmp_path / "broken.xml", tmp_path / "m")


def _gdalinfo(path):
    return json.loads(subprocess.run(["gdalinfo", "-json", str(path)], check=True,
                                     capture_output=True, text=True).stdout)


E0, N0, H = 500000.0, 4000000.0, 300.0


def _nadir_block(tmp_path):
    """One nadir photo, 600x400 px, f = 600 px, 300 m over a 100 m plane: GSD 0.5 m."""
    w, h, f = 600, 400, 600.0
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    x = E0 + (u - w / 2) / f * (H - 100.0)
    y = N0 - (v - h / 2) / f * (H - 100.0)
    img = np.stack([100 + 50 * np.sin(x / 5), 120 + 40 * np.cos(y / 7), 90 + 30 * np.sin((x + y) / 9)], -1)
    marker = (x - (E0 + 30.0)) ** 2 + (y - (N0 - 20.0)) ** 2 <= 2.0 ** 2
    img[marker] = 5
    (tmp_path / "img").mkdir()
    cv2.imwrite(str(tmp_path / "img" / "p1.png"), img.astype(np.uint8)[:, :, ::-1])
    xml = f"""<?xml version="1.0" encoding="utf-8"?>
<BlocksExchange version="2.1">
  <SpatialReferenceSystems><SRS><Id>0</Id><Name>UTM 50N</Name><Definition>EPSG:32650</Definition></SRS></SpatialReferenceSystems>
  <Block><Name>t</Name><SRSId>0</SRSId><Photogroups><Photogroup>
    <ImageDimensions><Width>{w}</Width><Height>{h}</Height></ImageDimensions>
    <FocalLengthPixels>{f}</FocalLengthPixels><CameraOrientation>XRightYDown</CameraOrientation>
    <PrincipalPoint><x>{w / 2 - 0.5}</x><y>{h / 2 - 0.5}</y></PrincipalPoint>
    <Photo><Id>1</Id><ImagePath>p1.png</ImagePath><Pose>
      <Rotation><M_00>1</M_00><M_01>0</M_01><M_02>0</M_02><M_10>0</M_10><M_11>-1</M_11><M_12>0</M_12><M_20>0</M_20><M_21>0</M_21><M_22>-1</M_22></Rotation>
      <Center><x>{E0}</x><y>{N0}</y><z>{H}</z></Center></Pose></Photo>
  </Photogroup></Photogroups></Block></BlocksExchange>"""
    (tmp_path / "block.xml").write_text(xml)
    gt = [E0 - 200, 2.0, 0, N0 + 150, 0, -2.0]
    formats.write_dem(tmp_path / "dem.tif", np.full((150, 200), 100.0), gt, "EPSG:32650")
    return tmp_path / "block.xml", tmp_path / "dem.tif", tmp_path / "img"


@pytest.mark.parametrize("cog", [False, True])
def test_gdalinfo_reports_orthophoto_metadata(tmp_path, cog):
    block, dem, img = _nadir_block(tmp_path)
    out = tmp_path / "ortho.tif"
    w, h = formats.orthophoto(block, dem, img, out, gsd=0.5, cog=cog)
    info = _gdalinfo(out)
    assert info["size"] == [w, h]
    assert info["coordinateSystem"]["wkt"].rstrip().endswith('ID["EPSG",32650]]')
    assert info["geoTransform"] == [E0 - 200, 0.5, 0.0, N0 + 150, 0.0, -0.5]
    bands = info["bands"]
    assert [b["colorInterpretation"] for b in bands] == ["Red", "Green", "Blue", "Alpha"]
    # The alpha band is the mask: no nodata value, which a GeoTIFF would give every band.
    assert all("noDataValue" not in b for b in bands)
    assert len(bands[0]["overviews"]) >= 2
    assert bands[0]["block"] == [256, 256]
    if cog:
        assert info["metadata"]["IMAGE_STRUCTURE"]["LAYOUT"] == "COG"
    # The marker lands where it is on the ground (within one ground pixel).
    rgba = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
    assert rgba.shape == (h, w, 4)
    rows, cols = np.nonzero((rgba[:, :, 3] == 255) & (rgba[:, :, 2] < 40))
    x = E0 - 200 + (cols.mean() + 0.5) * 0.5
    y = N0 + 150 - (rows.mean() + 0.5) * 0.5
    assert np.hypot(x - (E0 + 30.0), y - (N0 - 20.0)) < 0.5
    assert abs(len(rows) - np.pi * 4.0 / 0.25) < 0.3 * np.pi * 4.0 / 0.25


def test_dem_round_trip_and_gdalinfo(tmp_path):
    z = np.arange(20 * 30, dtype=np.float32).reshape(20, 30)
    z[3, 4] = np.nan
    gt = [E0, 1.0, 0.0, N0, 0.0, -1.0]
    formats.write_dem(tmp_path / "d.tif", z, gt, "EPSG:32650")
    back, gt2 = formats.read_dem(tmp_path / "d.tif")
    np.testing.assert_array_equal(np.isnan(back), np.isnan(z))
    np.testing.assert_array_equal(back[~np.isnan(z)], z[~np.isnan(z)])
    assert list(gt2) == gt
    info = _gdalinfo(tmp_path / "d.tif")
    assert info["bands"][0]["noDataValue"] == -9999
    assert info["geoTransform"] == gt
    with pytest.raises(CloudControlError, match="EPSG:999999"):
        formats.write_dem(tmp_path / "e.tif", z, gt, "EPSG:999999")
    assert not (tmp_path / "e.tif").exists()
