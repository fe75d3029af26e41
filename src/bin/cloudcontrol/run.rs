//! `cloudcontrol run` and `cloudcontrol demo`: progress while the stages run, then the
//! per-epoch summary table (or JSON).

use cloudcontrol::pipeline::project::Project;
use cloudcontrol::pipeline::run::{check_output, run_project, Event, RunError, RunSummary};
use cloudcontrol::pipeline::stages::{OutputFolder, StageError};
use cloudcontrol::pipeline::{demo, report::EpochReport};
use cloudcontrol::synth::Preset;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::time::Duration;

#[derive(clap::Args)]
pub struct RunArgs {
    /// Project file (TOML, see formats/project/).
    project: PathBuf,
    /// Check the project file and list the stages without running them.
    #[arg(long)]
    check: bool,
}

#[derive(Clone, Copy, clap::ValueEnum)]
pub enum DemoPreset {
    Tiny,
    Small,
}

impl From<DemoPreset> for Preset {
    fn from(p: DemoPreset) -> Self {
        match p {
            DemoPreset::Tiny => Preset::Tiny,
            DemoPreset::Small => Preset::Small,
        }
    }
}

/// A spinner per stage on stderr (hidden with --quiet or --json).
fn progress(hidden: bool) -> impl FnMut(&Event) {
    let bar = if hidden {
        ProgressBar::hidden()
    } else {
        let b = ProgressBar::new_spinner();
        b.set_style(
            ProgressStyle::with_template("{spinner} [{elapsed_precise}] {msg}")
                .unwrap_or_else(|_| ProgressStyle::default_spinner()),
        );
        b.enable_steady_tick(Duration::from_millis(120));
        b
    };
    move |e: &Event| match e {
        Event::Start {
            stage,
            index,
            total,
        } => {
            if *total > 0 {
                bar.set_message(format!("[{index}/{total}] {stage}"));
            } else {
                bar.set_message(stage.clone());
            }
        }
        Event::Done {
            stage,
            skipped,
            seconds,
        } => {
            let what = if *skipped {
                "unchanged, skipped".to_string()
            } else {
                format!("{seconds:.1} s")
            };
            bar.println(format!("  {stage:<28} {what}"));
        }
    }
}

fn px(m: f64, gsd: f64) -> String {
    if m.is_finite() {
        format!("{m:.3} m {:>5.2} px", m / gsd)
    } else {
        "   —".into()
    }
}

fn print_summary(s: &RunSummary, json: bool) {
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&s.to_json()).expect("summary serialises")
        );
        return;
    }
    println!();
    println!(
        "{:<16} {:>6} {:>9} {:>7}  {:<18} {:<18} {:>7}",
        "epoch", "GSD m", "oriented", "checks", "plan RMSE", "height RMSE", "time s"
    );
    for e in &s.report.epochs {
        row(e);
    }
    println!();
    println!("outputs under {}", s.output.display());
    for (epoch, files) in &s.products {
        for f in files {
            println!("  {epoch:<16} {}", f.display());
        }
    }
    println!(
        "  report           {}",
        s.output.join("report/report.html").display()
    );
}

fn row(e: &EpochReport) {
    println!(
        "{:<16} {:>6.3} {:>4}/{:<4} {:>7}  {:<18} {:<18} {:>7.1}",
        e.name,
        e.gsd_m,
        e.photos_oriented,
        e.photos_total,
        e.checkpoints.len(),
        px(e.check_rmse_plan_m, e.gsd_m),
        px(e.check_rmse_height_m, e.gsd_m),
        e.time_s
    );
}

/// Exit code 2: the project file is invalid, or its output folder is not a run's to write,
/// and nothing ran; 1: a stage failed, or another run is writing the output folder.
pub fn run(a: &RunArgs, json: bool, quiet: bool) -> Result<(), (u8, String)> {
    let project = Project::load(&a.project).map_err(|e| (2, e.to_string()))?;
    let refused = |e: RunError| {
        let code = match &e {
            RunError::Stage(StageError::Output { .. }) => 2,
            _ => 1,
        };
        (code, e.to_string())
    };
    if a.check {
        let state = check_output(&project).map_err(refused)?;
        if !quiet {
            let what = match state {
                OutputFolder::Missing => "made by the run",
                OutputFolder::Empty => "empty, taken by the run",
                OutputFolder::Owned => "made by an earlier run",
            };
            println!(
                "{}: valid; {} archive epoch(s), output {} ({what})",
                a.project.display(),
                project.archive.len(),
                project.output.display()
            );
        }
        return Ok(());
    }
    let mut on_event = progress(quiet || json);
    let s = run_project(&project, &mut on_event, None).map_err(refused)?;
    if !quiet || json {
        print_summary(&s, json);
    }
    Ok(())
}

pub fn demo(out: &Path, preset: Preset, json: bool, quiet: bool) -> Result<(), String> {
    let t = std::time::Instant::now();
    if !quiet && !json {
        println!(
            "cloudcontrol demo: {} synthetic block (LiDAR, checkpoints, reference 2024, digital 2012, film 1978) under {}",
            match preset {
                Preset::Tiny => "tiny",
                _ => "small",
            },
            out.display()
        );
    }
    let mut on_event = progress(quiet || json);
    let s = demo::run(out, preset, &mut on_event).map_err(|e| e.to_string())?;
    if !quiet || json {
        print_summary(&s, json);
    }
    if !quiet && !json {
        println!("demo finished in {:.1} s", t.elapsed().as_secs_f64());
    }
    Ok(())
}
