"""LiDAR over the Python binding, cross-checked with laspy (an independent LAS
implementation): laspy writes a tile that our library catalogues and evaluates, and
laspy reads the tiles our `cloudcontrol lidar clean` writes."""
import json
import pathlib
import subprocess

import laspy
import numpy as np
import pytest

import cloudcontrol
from cloudcontrol import lidar

ROOT = pathlib.Path(__file__).resolve().parents[3]
BIN = ROOT / "target" / "release" / "cloudcontrol"
E0, N0 = 500_000.0, 4_400_000.0


def ground(x, y):
    return 50.0 + 0.02 * (x - E0) + 0.01 * (y - N0)


def geokeys_vlr(epsg):
    keys = np.array([1, 1, 0, 2, 1024, 0, 1, 1, 3072, 0, 1, epsg], dtype="<u2")
    return laspy.VLR(user_id="LASF_Projection", record_id=34735, description="GeoKeyDirectoryTag",
                     record_data=keys.tobytes())


def write_tile(path, offset2=0.25, seed=1, epsg=32650, noise=0):
    rng = np.random.default_rng(seed)
    xs, ys, src = [], [], []
    for sid, x0, x1 in [(1, 0.0, 120.0), (2, 80.0, 200.0)]:
        n = int(3 * (x1 - x0) * 100)
        xs.append(E0 + rng.uniform(x0, x1, n))
        ys.append(N0 + rng.uniform(0, 100, n))
        src.append(np.full(n, sid))
    x, y, s = np.concatenate(xs), np.concatenate(ys), np.concatenate(src)
    z = ground(x, y) + rng.normal(0, 0.05, x.size) + np.where(s == 2, offset2, 0.0)
    if noise:
        i = rng.choice(x.size, noise, replace=False)
        z[i] -= rng.uniform(3, 15, noise)
    hdr = laspy.LasHeader(point_format=1, version="1.2")
    hdr.scales = np.array([0.001, 0.001, 0.001])
    hdr.offsets = np.array([E0, N0, 0.0])
    hdr.vlrs.append(geokeys_vlr(epsg))
    las = laspy.LasData(hdr)
    las.x, las.y, las.z = x, y, z
    las.classification = np.full(x.size, 2, dtype=np.uint8)
    las.point_source_id = s.astype(np.uint16)
    las.gps_time = np.linspace(3e8, 3e8 + 600, x.size)
    las.write(str(path))
    return x, y, z, s


def checkpoints(seed=2):
    rng = np.random.default_rng(seed)
    x = E0 + np.concatenate([rng.uniform(5, 75, 10), rng.uniform(125, 195, 10)])
    y = N0 + rng.uniform(5, 95, 20)
    return np.column_stack([x, y, ground(x, y)])


def test_catalogue_of_a_laspy_file(tmp_path):
    f = tmp_path / "tile.las"
    x, y, z, s = write_tile(f)
    cat = lidar.catalogue(f)
    assert cat["crs"] == "EPSG:32650"
    assert cat["point_count"] == x.size
    t = cat["tiles"][0]
    assert t["version"] == "1.2" and t["point_format"] == 1
    assert t["classes"] == {"2": x.size}
    assert t["point_sources"] == {"1": int((s == 1).sum()), "2": int((s == 2).sum())}
    assert t["bounds"][0] == pytest.approx(x.min(), abs=1e-3)
    assert t["bounds"][5] == pytest.approx(z.max(), abs=1e-3)
    assert t["density_pts_m2"] == pytest.approx(x.size / ((x.max() - x.min()) * (y.max() - y.min())), rel=1e-3)
    assert t["gps_time_range"] == pytest.approx([3e8, 3e8 + 600])


def test_checkpoint_evaluation_sees_the_strip_offset(tmp_path):
    f = tmp_path / "tile.las"
    write_tile(f, offset2=0.25)
    cps = checkpoints()
    dz, stats = lidar.evaluate_checkpoints([f], cps)
    assert stats["count"] == 20 and stats["skipped"] == 0
    assert np.abs(dz[:10]).max() < 0.05
    assert dz[10:].mean() == pytest.approx(0.25, abs=0.02)
    assert stats["rmse_m"] == pytest.approx(np.sqrt(np.mean(dz ** 2)))
    # A checkpoint far away is skipped (NaN), not an error.
    far = np.vstack([cps, [E0 + 9000, N0, 50]])
    dz2, st2 = lidar.evaluate_checkpoints(f, far)
    assert np.isnan(dz2[-1]) and st2["skipped"] == 1


def test_errors_name_the_file(tmp_path):
    bad = tmp_path / "short.las"
    write_tile(tmp_path / "ok.las")
    bad.write_bytes((tmp_path / "ok.las").read_bytes()[:-500])
    with pytest.raises(cloudcontrol.CloudControlError) as e:
        lidar.catalogue(bad)
    assert "short.las" in str(e.value) and "truncated" in str(e.value)
    other = tmp_path / "utm51.las"
    write_tile(other, epsg=32651)
    with pytest.raises(cloudcontrol.CloudControlError) as e:
        lidar.catalogue([tmp_path / "ok.las", other])
    assert "utm51.las" in str(e.value) and "EPSG:32651" in str(e.value)
    with pytest.raises(cloudcontrol.CloudControlError):
        lidar.evaluate_checkpoints(tmp_path / "ok.las", [[np.nan, 0, 0]])


@pytest.mark.skipif(not BIN.exists(), reason="cloudcontrol binary not built")
def test_laspy_reads_the_tiles_we_write(tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    x, y, z, s = write_tile(src / "tile.las", offset2=0.25, noise=200)
    out = tmp_path / "clean"
    r = subprocess.run([str(BIN), "--json", "lidar", "clean", "--lidar", str(src), "--out-dir", str(out),
                        "--reference", "1"], capture_output=True, text=True, check=True)
    rep = json.loads(r.stdout)
    off = {st["source_id"]: st["offset_m"][2] for st in rep["strip_offsets"]["strips"]}
    assert off[2] == pytest.approx(0.25, abs=0.01)
    cleaned = laspy.read(str(out / "tile.las"))
    assert len(cleaned.points) == x.size
    assert np.array_equal(np.asarray(cleaned.point_source_id), s)
    dz = np.asarray(cleaned.z) - z
    assert np.allclose(dz[s == 1], 0, atol=1.5e-3)
    assert np.allclose(dz[s == 2], -off[2], atol=1.5e-3)
    noise = np.asarray(cleaned.classification) == 7
    assert 190 <= noise.sum() <= 210
    cps = checkpoints()
    _, after = lidar.evaluate_checkpoints(out / "tile.las", cps)
    assert after["rmse_m"] < 0.05


def test_source_planes_and_icp(tmp_path):
    f = tmp_path / "tile.las"
    write_tile(f, offset2=0.0)
    src = lidar.LidarSource(f, bbox=(E0, N0, E0 + 120, N0 + 100))
    assert 30_000 < len(src) < 60_000
    q = np.array([[E0 + 50.0, N0 + 50.0, ground(E0 + 50.0, N0 + 50.0) + 1.0]])
    pl = src.planes(q)
    n_true = np.array([-0.02, -0.01, 1.0]) / np.linalg.norm([-0.02, -0.01, 1.0])
    # 12 neighbours within ~1 m at σ 5 cm: the normal is good to ~1–2°.
    assert np.degrees(np.arccos(pl["normal"][0] @ n_true)) < 3.0
    assert pl["distance"][0] == pytest.approx(1.0, abs=0.05)
    assert 0 < pl["weight"][0] <= 1
    # Far from the data: no plane (NaN row), not an error.
    assert np.isnan(src.planes([[E0 - 500, N0, 50]])["distance"]).all()
    rng = np.random.default_rng(3)
    x = E0 + rng.uniform(10, 110, 3000)
    y = N0 + rng.uniform(10, 90, 3000)
    pts = np.column_stack([x, y, ground(x, y) + 0.8])
    m, st = src.icp(pts, rigid=True, initial_gate=3.0)
    moved = pts @ m[:3, :3].T + m[:3, 3]
    assert np.abs(moved[:, 2] - ground(moved[:, 0], moved[:, 1])).max() < 0.05
    assert st["rmse_m"] < 0.05 and st["scale"] == 1.0 and st["inliers"] > 2000
    with pytest.raises(cloudcontrol.CloudControlError) as e:
        lidar.LidarSource(f, bbox=(E0 - 1000, N0 - 1000, E0 - 900, N0 - 900))
    assert "no LiDAR point" in str(e.value)
