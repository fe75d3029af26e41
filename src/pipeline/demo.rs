//! `cloudcontrol demo`: the whole workflow on the built-in small synthetic block — the
//! block is generated (LiDAR, checkpoints, a reference epoch with POS, a digital archive
//! epoch and a 1978 film epoch, both with a rough POS of 10 m / 3°) with its project file
//! (`synth::project`), and [`super::run::run_project`] runs it. `cloudcontrol synth --pos
//! none` makes blocks with strip end points only. Checkpoint image measurements stand for
//! an operator's; they are the only file read from the block's `truth/`.

use super::project::Project;
use super::run::{run_project, Event, RunError, RunSummary};
use crate::synth::{self, PosQuality, Preset, SynthConfig};
use std::path::Path;

/// Seed of the demo block (any seed works; this one is what the README shows).
pub const DEMO_SEED: u64 = 7;

#[derive(Debug, thiserror::Error)]
pub enum DemoError {
    #[error("synthetic block: {0}")]
    Synth(String),
    #[error(
        "the {0:?} preset cannot run the demo: the demo runs on the small preset (the tiny \
         one's 400 × 266 px digital photos have no room for the 193 px control chips, and \
         its film scans at 200 µm are too coarse for the fiducial marks)"
    )]
    Preset(Preset),
    #[error(transparent)]
    Run(#[from] RunError),
}

/// Generates the demo block under `out/block` (kept when it is already there with the
/// same configuration) and runs the workflow into `out/run`. Only the small preset: the
/// demo's epochs need what it has (see [`DemoError::Preset`]; larger presets are blocks
/// for `cloudcontrol synth` and `run`, not a demonstration).
pub fn run(
    out: &Path,
    preset: Preset,
    on_event: &mut dyn FnMut(&Event),
) -> Result<RunSummary, DemoError> {
    if preset != Preset::Small {
        return Err(DemoError::Preset(preset));
    }
    let block = out.join("block");
    let cfg = SynthConfig {
        preset,
        seed: DEMO_SEED,
        change: 0.5,
        // Archive epochs with a rough POS (10 m / 3°), as from a flight plan.
        pos: PosQuality::Rough,
        laz: false,
    };
    if !synth::holds_block(&block, &cfg) {
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
    // The project file the generator wrote for the block.
    let project_path = block.join("project.toml");
    let project = Project::load(&project_path).map_err(RunError::from)?;
    Ok(run_project(&project, on_event, None)?)
}
