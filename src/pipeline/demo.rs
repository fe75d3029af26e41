//! `cloudcontrol demo`: the whole workflow on the built-in small synthetic block — the
//! block is generated (LiDAR, checkpoints, a reference epoch with POS, a digital archive
//! epoch and a 1978 film epoch, both with a rough POS of 10 m / 3°), a project file
//! is written for it, and [`super::run::run_project`] runs. The film epoch of the demo has
//! a rough POS; `cloudcontrol synth --pos none` makes blocks with strip end points only. Checkpoint image measurements
//! stand for an operator's; they are the only file read from the block's `truth/`.

use super::project::Project;
use super::run::{run_project, Event, RunError, RunSummary};
use crate::synth::{self, PosQuality, Preset, SynthConfig};
use std::path::{Path, PathBuf};

/// Seed of the demo block (any seed works; this one is what the README shows).
pub const DEMO_SEED: u64 = 7;

#[derive(Debug, thiserror::Error)]
pub enum DemoError {
    #[error("synthetic block: {0}")]
    Synth(String),
    #[error("{path}: {message}")]
    Io { path: PathBuf, message: String },
    #[error(transparent)]
    Run(#[from] RunError),
}

/// The project file of the demo block (paths relative to the block folder).
pub fn project_toml(preset: Preset) -> String {
    let interval = match preset {
        Preset::Tiny => 60,
        _ => 120,
    };
    format!(
        r#"# cloudcontrol demo project: the built-in synthetic block.
name = "cloudcontrol-demo"
crs = "EPSG:4547"
output = "../run"

[control]
lidar = ["lidar"]
checkpoints = "checkpoints.csv"
# Checkpoint targets as measured in the photos (here: the synthetic truth stands for the
# operator's measurements); used only to evaluate each epoch.
checkpoint_images = "truth/checkpoint_images.csv"

[reference]
name = "reference_2024"
date = "2024-05-29"
photos = "epochs/reference_2024/images"
camera = "epochs/reference_2024/camera.json"
pos = "epochs/reference_2024/pos.csv"

[[archive]]
name = "digital_2012"
date = "2012-08-14"
photos = "epochs/digital_2012/images"
camera = "epochs/digital_2012/camera.json"
pos = "epochs/digital_2012/pos.csv"

[[archive]]
name = "film_1978"
date = "1978-06-06"
photos = "epochs/film_1978/images"
camera = "epochs/film_1978/camera.json"
pos = "epochs/film_1978/pos.csv"

[thresholds]
control_interval_px = {interval}
chip_size_px = 193
"#
    )
}

/// Generates the demo block under `out/block` (kept when it is already there with the
/// same configuration) and runs the workflow into `out/run`.
pub fn run(
    out: &Path,
    preset: Preset,
    on_event: &mut dyn FnMut(&Event),
) -> Result<RunSummary, DemoError> {
    let block = out.join("block");
    let cfg = SynthConfig {
        preset,
        seed: DEMO_SEED,
        change: 0.5,
        // Archive epochs with a rough POS (10 m / 3°), as from a flight plan.
        pos: PosQuality::Rough,
        laz: false,
    };
    if !same_block(&block, &cfg) {
        on_event(&Event::Start {
            stage: "synthetic block".into(),
            index: 0,
            total: 0,
        });
        let t = std::time::Instant::now();
        let _ = std::fs::remove_dir_all(&block);
        synth::generate(&cfg, &block).map_err(|e| DemoError::Synth(e.to_string()))?;
        on_event(&Event::Done {
            stage: "synthetic block".into(),
            skipped: false,
            seconds: t.elapsed().as_secs_f64(),
        });
    }
    let project_path = block.join("project.toml");
    std::fs::write(&project_path, project_toml(preset)).map_err(|e| DemoError::Io {
        path: project_path.clone(),
        message: e.to_string(),
    })?;
    let project = Project::load(&project_path).map_err(RunError::from)?;
    Ok(run_project(&project, on_event, None)?)
}

/// True when `dir` holds a finished synthetic block of this configuration.
fn same_block(dir: &Path, cfg: &SynthConfig) -> bool {
    let Ok(text) = std::fs::read_to_string(dir.join("manifest.json")) else {
        return false;
    };
    let Ok(m) = serde_json::from_str::<serde_json::Value>(&text) else {
        return false;
    };
    dir.join("epochs/film_1978/pos.csv").is_file()
        && m["seed"].as_u64() == Some(cfg.seed)
        && serde_json::to_value(cfg.preset).ok().as_ref() == Some(&m["preset"])
}
