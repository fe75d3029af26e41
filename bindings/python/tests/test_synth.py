"""Independent readers on the synthetic block: laspy reads our LAS and LAZ tiles (the
same points as the las crate wrote, checked against the generator's manifest and truth),
GDAL reads the WKT CRS of the tiles."""

import csv
import json
import os
import pathlib
import subprocess
import tempfile

import laspy
import numpy as np
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[3]
CLI = pathlib.Path(os.environ.get("CLOUDCONTROL_CLI", ROOT / "target" / "release" / "cloudcontrol"))


@pytest.fixture(scope="module")
def blocks():
    if not CLI.exists():
        pytest.skip(f"{CLI} not built")
    tmp = tempfile.TemporaryDirectory()
    out = {}
    for fmt in ("las", "laz"):
        d = pathlib.Path(tmp.name) / fmt
        args = [str(CLI), "synth", "--out", str(d), "--preset", "tiny", "--seed", "5", "-q"]
        if fmt == "laz":
            args.append("--laz")
        subprocess.run(args, check=True)
        out[fmt] = (d, json.loads((d / "manifest.json").read_text()))
    yield out
    tmp.cleanup()


def read_all(d, manifest):
    return [(t, laspy.read(d / t["path"])) for t in manifest["lidar"]["tiles"]]


def test_laspy_reads_the_tiles_as_generated(blocks):
    d, m = blocks["las"]
    tiles = read_all(d, m)
    assert sum(len(las.points) for _, las in tiles) == m["lidar"]["points"]
    per_source = {}
    classes = set()
    for t, las in tiles:
        h = las.header
        assert (h.version.major, h.version.minor) == (1, 4)
        assert h.point_format.id == 6
        assert np.allclose(h.scales, 0.001)
        assert h.offsets[0] == t["cell"][0] and h.offsets[1] == t["cell"][1]
        assert len(las.points) == t["points"] == h.point_count
        x, y = np.asarray(las.x), np.asarray(las.y)
        # Points lie in their tile cell (up to the strip offsets, a few cm).
        assert x.min() >= t["cell"][0] - 0.5 and x.max() <= t["cell"][2] + 0.5
        assert y.min() >= t["cell"][1] - 0.5 and y.max() <= t["cell"][3] + 0.5
        for sid, n in zip(*np.unique(np.asarray(las.point_source_id), return_counts=True)):
            per_source[int(sid)] = per_source.get(int(sid), 0) + int(n)
        classes |= set(np.unique(np.asarray(las.classification)).tolist())
        # Header bounds enclose the stored coordinates to within one scale unit.
        for lo, hi, v in ((h.mins[0], h.maxs[0], x), (h.mins[1], h.maxs[1], y), (h.mins[2], h.maxs[2], np.asarray(las.z))):
            assert lo <= v.min() + 1e-9 and v.min() - lo <= 0.0011
            assert hi >= v.max() - 1e-9 and hi - v.max() <= 0.0011
    truth = {int(r["point_source_id"]): int(r["points"]) for r in csv.DictReader(open(d / "truth/lidar_strips.csv"))}
    assert per_source == truth
    assert {2, 5, 6, 7, 18} <= classes


def test_laz_and_las_hold_identical_points(blocks):
    (dl, ml), (dz, mz) = blocks["las"], blocks["laz"]
    assert [t["points"] for t in ml["lidar"]["tiles"]] == [t["points"] for t in mz["lidar"]["tiles"]]
    for (_, a), (_, b) in zip(read_all(dl, ml), read_all(dz, mz)):
        for dim in ("X", "Y", "Z", "intensity", "classification", "point_source_id", "gps_time", "return_number"):
            assert np.array_equal(np.asarray(a[dim]), np.asarray(b[dim])), dim


def test_crs_is_read_by_gdal(blocks, tmp_path):
    d, m = blocks["las"]
    las = laspy.read(d / m["lidar"]["tiles"][0]["path"])
    vlrs = [v for v in las.header.vlrs if v.record_id == 2112]
    assert len(vlrs) == 1
    wkt = vlrs[0].string if hasattr(vlrs[0], "string") else bytes(vlrs[0].record_data).decode()
    wkt = wkt.rstrip("\0")
    f = tmp_path / "tile.wkt"
    f.write_text(wkt)
    out = subprocess.run(["gdalsrsinfo", "-e", str(f)], check=True, capture_output=True, text=True).stdout
    assert "EPSG:4547" in out, out
    # laspy also flags the WKT bit in the global encoding.
    assert las.header.global_encoding.wkt


def test_binding_writes_the_same_block_as_the_cli(blocks, tmp_path):
    from cloudcontrol import synth
    from cloudcontrol._ffi import CloudControlError

    d, m = blocks["las"]
    m2 = synth.generate(tmp_path / "ffi", preset="tiny", seed=5)
    assert m2["files"] == m["files"]
    with pytest.raises(CloudControlError, match="change"):
        synth.generate(tmp_path / "bad", preset="tiny", change=float("nan"))
    with pytest.raises(CloudControlError, match="change"):
        synth.generate(tmp_path / "bad", preset="tiny", change=1.5)
