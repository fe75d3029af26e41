//! `project.toml` of a synthetic block (formats/project/): the file a user would write for
//! it, so that any preset, seed and POS quality runs with `cloudcontrol run` (the demo and
//! the accuracy bench read the same file). Paths are relative to the block folder.

use super::{EpochInfo, Preset};
use std::fmt::Write;

/// The project of a block whose epochs are `epochs` (the first is the reference). An epoch
/// navigated by strip end points gets `strips`, one with a POS gets `pos`. The checkpoint
/// image measurements are the synthetic truth standing for an operator's.
pub fn project_toml(preset: Preset, crs: &str, epochs: &[EpochInfo]) -> String {
    let control = r#"lidar = ["lidar"]
"#;
    project(
        preset,
        crs,
        "cloudcontrol-synth",
        "../run",
        control,
        epochs,
        true,
    )
}

/// The project of the same block controlled by its orthophoto and DEM alone
/// (`orthophoto/`): no LiDAR, no reference epoch; the archive epochs are oriented from the
/// orthophoto's control points, each older one also from the DCPs of the newer.
pub fn orthophoto_project_toml(preset: Preset, crs: &str, epochs: &[EpochInfo]) -> String {
    // The synthetic surface model is exact but for its 1 m grid.
    let control = r#"orthophoto = "orthophoto/orthophoto.tif"
dem = "orthophoto/dem.tif"
dem_sigma_m = 0.1
"#;
    project(
        preset,
        crs,
        "cloudcontrol-synth-orthophoto",
        "../run_orthophoto",
        control,
        &epochs[1.min(epochs.len())..],
        false,
    )
}

fn project(
    preset: Preset,
    crs: &str,
    name: &str,
    output: &str,
    control: &str,
    epochs: &[EpochInfo],
    with_reference: bool,
) -> String {
    // Cloud control points every ~half a chip in the reference photos; the tiny preset's
    // photos are 600 px wide, so its control is denser to give the archive epochs enough.
    let interval = match preset {
        Preset::Tiny => 60,
        _ => 120,
    };
    let mut s = format!(
        r#"# cloudcontrol project of a synthetic block (cloudcontrol synth).
name = "{name}"
crs = "{crs}"
output = "{output}"

[control]
{control}checkpoints = "checkpoints.csv"
# Checkpoint targets as measured in the photos (here: the synthetic truth stands for the
# operator's measurements); used only to evaluate each epoch.
checkpoint_images = "truth/checkpoint_images.csv"
"#
    );
    for (k, e) in epochs.iter().enumerate() {
        let table = if k == 0 && with_reference {
            "[reference]"
        } else {
            "[[archive]]"
        };
        let nav_key = if e.navigation.ends_with("strips.csv") {
            "strips"
        } else {
            "pos"
        };
        // Writing to a String cannot fail.
        let _ = write!(
            s,
            "\n{table}\nname = \"{}\"\ndate = \"{}\"\nphotos = \"{}\"\ncamera = \"{}\"\n{nav_key} = \"{}\"\n",
            e.name, e.date, e.images_dir, e.camera, e.navigation
        );
    }
    let _ = write!(
        s,
        "\n[thresholds]\ncontrol_interval_px = {interval}\nchip_size_px = 193\n"
    );
    s
}
