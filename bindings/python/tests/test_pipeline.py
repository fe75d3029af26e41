"""The workflow from Python: a project on the small synthetic block is run through the C
ABI, its report meets the checkpoint targets, pycolmap reads the reference epoch's COLMAP
model with the orientations of our block, and a bad project file fails naming the key."""
import json
import pathlib

import numpy as np
import pycolmap
import pytest

import cloudcontrol
from cloudcontrol import synth

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
def block(tmp_path_factory):
    d = tmp_path_factory.mktemp("pipeline") / "block"
    synth.generate(d, preset="small", seed=7, pos="rough")
    (d / "project.toml").write_text(PROJECT)
    return d


def test_run_meets_the_checkpoint_targets_and_pycolmap_reads_the_model(block):
    res = cloudcontrol.run(block / "project.toml")
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

    # A second run skips every finished stage.
    again = cloudcontrol.run(block / "project.toml")
    assert again["ran"] == []


def test_a_bad_project_fails_naming_the_key(block):
    bad = block / "bad.toml"
    bad.write_text(PROJECT.replace('chip_size_px = 193', 'chip_size_px = 193\nnot_a_key = 1'))
    with pytest.raises(cloudcontrol.CloudControlError, match="not_a_key"):
        cloudcontrol.run(bad)
