//! `cloudcontrol synth`: writes a synthetic aerial block with ground truth.

use clap::{Args, ValueEnum};
use cloudcontrol::synth::{self, PosQuality, Preset, SynthConfig};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Clone, Copy, ValueEnum)]
pub enum PresetArg {
    Tiny,
    Small,
    Medium,
    Large,
}

#[derive(Clone, Copy, ValueEnum)]
pub enum PosArg {
    Good,
    Rough,
    None,
}

impl From<PresetArg> for Preset {
    fn from(p: PresetArg) -> Self {
        match p {
            PresetArg::Tiny => Preset::Tiny,
            PresetArg::Small => Preset::Small,
            PresetArg::Medium => Preset::Medium,
            PresetArg::Large => Preset::Large,
        }
    }
}

impl From<PosArg> for PosQuality {
    fn from(p: PosArg) -> Self {
        match p {
            PosArg::Good => PosQuality::Good,
            PosArg::Rough => PosQuality::Rough,
            PosArg::None => PosQuality::None,
        }
    }
}

#[derive(Args)]
pub struct SynthArgs {
    /// Output folder (created; existing files are overwritten).
    #[arg(long)]
    out: PathBuf,
    /// Block size: tiny (tests), small (demo, < 75 s), medium (≈100 photos), large (≈400 photos).
    #[arg(long, value_enum, default_value = "small")]
    preset: PresetArg,
    /// Random seed; the same seed gives byte-identical output.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Fraction of the scene changed in the archive epochs (0–1).
    #[arg(long, default_value_t = 0.5)]
    change: f64,
    /// Approximate EO of the archive epochs: good (1 m / 0.5°), rough (10 m / 3°), none (strip ends).
    #[arg(long, value_enum, default_value = "rough")]
    pos: PosArg,
    /// Write LiDAR tiles as LAZ.
    #[arg(long)]
    laz: bool,
}

pub fn run(args: SynthArgs, json: bool, quiet: bool) -> ExitCode {
    let config = SynthConfig {
        preset: args.preset.into(),
        seed: args.seed,
        change: args.change,
        pos: args.pos.into(),
        laz: args.laz,
    };
    let spinner = if quiet || json {
        indicatif::ProgressBar::hidden()
    } else {
        let s = indicatif::ProgressBar::new_spinner();
        s.set_message(format!(
            "rendering synthetic block into {}",
            args.out.display()
        ));
        s.enable_steady_tick(std::time::Duration::from_millis(200));
        s
    };
    let result = synth::generate(&config, &args.out);
    spinner.finish_and_clear();
    match result {
        Ok(m) => {
            if json {
                let v = serde_json::json!({
                    "out": args.out.display().to_string(),
                    "photos": m.epochs.iter().map(|e| (e.name.clone(), e.photos.len())).collect::<Vec<_>>(),
                    "lidar_points": m.lidar.points,
                    "checkpoints": m.checkpoint_count,
                    "files": m.files.len(),
                    "total_s": m.run.total_s,
                    "peak_memory_mib": m.run.peak_memory_mib,
                });
                outln!("{}", serde_json::to_string_pretty(&v).expect("json"));
            } else if !quiet {
                outln!(
                    "cloudcontrol synth — {} ({:?}, seed {})",
                    args.out.display(),
                    m.preset,
                    m.seed
                );
                outln!(
                    "  lidar        {} points in {} tiles, {:.1} pts/m², {} strips",
                    m.lidar.points,
                    m.lidar.tiles.len(),
                    m.lidar.density_per_m2,
                    m.lidar.strips
                );
                outln!("  checkpoints  {}", m.checkpoint_count);
                for e in &m.epochs {
                    outln!(
                        "  {:<15} {} {} photos {}×{} at {:.2} m",
                        e.name,
                        e.kind,
                        e.photos.len(),
                        e.image_size[0],
                        e.image_size[1],
                        e.gsd_m
                    );
                }
                for (stage, s) in &m.run.stages {
                    outln!("  time {stage:<14} {s:.2} s");
                }
                outln!(
                    "  total        {:.2} s on {} threads, peak memory {:.0} MiB",
                    m.run.total_s,
                    m.run.threads,
                    m.run.peak_memory_mib
                );
            }
            ExitCode::SUCCESS
        }
        Err(e) => crate::console::fail("synth", e, crate::EXIT_FAILED),
    }
}
