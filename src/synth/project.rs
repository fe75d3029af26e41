//! `project.toml` of a synthetic block (formats/project/): the file a user would write for
//! it, so that any preset, seed and POS quality runs with `cloudcontrol run` (the demo and
//! the accuracy bench read the same file). Paths are relative to the block folder.

use super::{EpochInfo, Preset};
use std::fmt::Write;

/// The project of a block whose epochs are `epochs` (the first is the reference). An epoch
/// navigated by strip end points gets `strips`, one with a POS gets `pos`. The checkpoint
/// image measurements are the synthetic truth standing for an operator's.
pub fn project_toml(preset: Preset, crs: &str, epochs: &[EpochInfo]) -> String {
    // Cloud control points every ~half a chip in the reference photos; the tiny preset's
    // photos are 600 px wide, so its control is denser to give the archive epochs enough.
    let interval = match preset {
        Preset::Tiny => 60,
        _ => 120,
    };
    let mut s = format!(
        r#"# cloudcontrol project of a synthetic block (cloudcontrol synth).
name = "cloudcontrol-synth"
crs = "{crs}"
output = "../run"

[control]
lidar = ["lidar"]
checkpoints = "checkpoints.csv"
# Checkpoint targets as measured in the photos (here: the synthetic truth stands for the
# operator's measurements); used only to evaluate each epoch.
checkpoint_images = "truth/checkpoint_images.csv"
"#
    );
    for (k, e) in epochs.iter().enumerate() {
        let table = if k == 0 { "[reference]" } else { "[[archive]]" };
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
