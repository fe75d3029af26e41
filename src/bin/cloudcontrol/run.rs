//! `cloudcontrol run` and `cloudcontrol demo`: progress while the stages run, then the
//! per-epoch summary table (or JSON).

use crate::console::{self, ProgressGuard};
use cloudcontrol::formats::paths::normalise;
use cloudcontrol::pipeline::partial::PartialEpoch;
use cloudcontrol::pipeline::project::Project;
use cloudcontrol::pipeline::run::{check_output, run_project, Event, RunError, RunSummary};
use cloudcontrol::pipeline::stages::{OutputFolder, StageError};
use cloudcontrol::pipeline::validate::{check_inputs, InputProblems};
use cloudcontrol::pipeline::{demo, report::EpochReport};
use cloudcontrol::synth::Preset;
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
pub struct RunArgs {
    /// Project file (TOML, see formats/project/).
    project: PathBuf,
    /// Check the project file, its output folder and every input of every epoch (cameras,
    /// POS, photo names and image sizes, checkpoints), listing every problem, without
    /// running anything.
    #[arg(long)]
    check: bool,
}

/// `demo --preset`: the small block. The tiny preset (for unit tests of other modules)
/// cannot carry the demo: its 400 × 266 px digital photos leave no room for the 193 px
/// control chips of the next epoch's DCPs, and its film scans at 200 µm are too coarse
/// for the fiducial marks to decide each scan's orientation.
pub fn demo_preset(s: &str) -> Result<Preset, String> {
    match s {
        "small" => Ok(Preset::Small),
        "tiny" => Err(
            "the tiny preset cannot run the demo (its 400 × 266 px digital photos \
             have no room for the 193 px control chips, its film scans at 200 µm are too \
             coarse for the fiducial marks): use small, or `cloudcontrol synth --preset tiny` \
             for a tiny block"
                .into(),
        ),
        _ => Err(format!(
            "{s:?}: the demo runs on the small preset (--preset small)"
        )),
    }
}

/// Progress on stderr (nothing with --quiet or --json): a spinner with the stage and the
/// photo being worked on when stderr is a terminal, else a line per stage and per photo;
/// a line per finished stage with its time.
fn progress(hidden: bool) -> (ProgressGuard, impl FnMut(&Event)) {
    let guard = ProgressGuard::start(hidden, "");
    let on_event = move |e: &Event| match e {
        Event::Start {
            stage,
            index,
            total,
        } => {
            if *total > 0 {
                console::stage(&format!("[{index}/{total}] {stage}"));
            } else {
                console::stage(stage);
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
            console::line(&format!("  {stage:<28} {what}"));
        }
    };
    (guard, on_event)
}

/// The summary's paths as the user reads them: `…/block/../run` (a project's output
/// given as `../run`) printed `…/run` (lexically: the paths the run used are unchanged).
fn normalise_paths(s: &mut RunSummary) {
    s.output = normalise(&s.output);
    for files in s.products.values_mut() {
        for f in files.iter_mut() {
            *f = normalise(f);
        }
    }
    for p in &mut s.partial {
        if let Some(r) = p.result.as_mut() {
            *r = normalise(r);
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

fn print_summary(s: &mut RunSummary, json: bool) {
    normalise_paths(s);
    if json {
        outln!(
            "{}",
            serde_json::to_string_pretty(&s.to_json()).expect("summary serialises")
        );
        return;
    }
    outln!();
    outln!(
        "{:<16} {:>6} {:>9} {:>7}  {:<18} {:<18} {:>7}",
        "epoch",
        "GSD m",
        "oriented",
        "checks",
        "plan RMSE",
        "height RMSE",
        "time s"
    );
    for e in &s.report.epochs {
        row(e);
    }
    outln!();
    outln!("outputs under {}", s.output.display());
    for (epoch, files) in &s.products {
        for f in files {
            outln!("  {epoch:<16} {}", f.display());
        }
    }
    outln!(
        "  report           {}",
        s.output.join("report/report.html").display()
    );
}

fn row(e: &EpochReport) {
    outln!(
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

/// With --json, the problems of the project's inputs as one document on stdout: the
/// error as every command gives it (`error`: command, message, input, exit status) and
/// `problems`, each with `file`, `line`, `key` and `message` (the error's `input`: the
/// first problem's file). The error is then not
/// printed a second time as JSON (stderr still says it).
fn print_problems(project: &Path, p: &InputProblems) {
    let message = format!("{p}");
    let doc = serde_json::json!({
        "project": normalise(project),
        "valid": false,
        "problems": p.problems,
        "error": {
            "command": "run",
            "message": message,
            "input": p.problems.first().map(|q| normalise(&q.file)),
            "exit_status": 2,
        },
    });
    outln!(
        "{}",
        serde_json::to_string_pretty(&doc).expect("problems serialise")
    );
    console::set_json(false);
}

/// Exit code 2: the project file or its inputs are invalid (every problem listed), or its
/// output folder is not a run's to write, and nothing ran; 1: a stage failed, or another
/// run is writing the output folder.
/// Ok: the epochs that oriented fewer photos than they have (exit code 3 when any).
pub fn run(a: &RunArgs, json: bool, quiet: bool) -> Result<Vec<PartialEpoch>, (u8, String)> {
    let project = Project::load(&a.project).map_err(|e| (2, e.to_string()))?;
    let refused = |e: RunError| {
        let code = match &e {
            RunError::Stage(StageError::Output { .. }) | RunError::Inputs(_) => 2,
            _ => 1,
        };
        if let (RunError::Inputs(p), true) = (&e, json) {
            print_problems(&a.project, p);
        }
        (code, e.to_string())
    };
    if a.check {
        let state = check_output(&project).map_err(refused)?;
        check_inputs(&project).map_err(|p| refused(p.into()))?;
        let (key, what) = match state {
            OutputFolder::Missing => ("missing", "made by the run"),
            OutputFolder::Empty => ("empty", "empty, taken by the run"),
            OutputFolder::Owned => ("owned", "made by an earlier run"),
        };
        if json {
            let doc = serde_json::json!({
                "project": normalise(&a.project),
                "valid": true,
                "reference": project.reference.as_ref().map(|e| &e.name),
                "archive": project.archive.iter().map(|e| &e.name).collect::<Vec<_>>(),
                "output": normalise(&project.output),
                "output_state": key,
            });
            outln!(
                "{}",
                serde_json::to_string_pretty(&doc).expect("check serialises")
            );
        } else if !quiet {
            outln!(
                "{}: valid; {} archive epoch(s), output {} ({what})",
                a.project.display(),
                project.archive.len(),
                normalise(&project.output).display()
            );
        }
        return Ok(Vec::new());
    }
    let (shown, mut on_event) = progress(quiet || json);
    let mut s = run_project(&project, &mut on_event, None).map_err(refused)?;
    drop(shown);
    if !quiet || json {
        print_summary(&mut s, json);
    }
    Ok(s.partial)
}

/// Ok: the epochs that oriented fewer photos than they have (exit code 3 when any).
pub fn demo(
    out: &Path,
    preset: Preset,
    json: bool,
    quiet: bool,
) -> Result<Vec<PartialEpoch>, String> {
    let t = std::time::Instant::now();
    if !quiet && !json {
        outln!(
            "cloudcontrol demo: {} synthetic block (LiDAR, checkpoints, reference 2024, digital 2012, film 1978) under {}",
            match preset {
                Preset::Tiny => "tiny",
                Preset::Small => "small",
                Preset::Medium => "medium",
                Preset::Large => "large",
            },
            normalise(out).display()
        );
    }
    let (shown, mut on_event) = progress(quiet || json);
    let mut s = demo::run(out, preset, &mut on_event).map_err(|e| e.to_string())?;
    drop(shown);
    if !quiet || json {
        print_summary(&mut s, json);
    }
    if !quiet && !json {
        outln!("demo finished in {:.1} s", t.elapsed().as_secs_f64());
    }
    Ok(s.partial)
}
