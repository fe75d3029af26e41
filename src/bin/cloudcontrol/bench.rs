//! `cloudcontrol bench accuracy`: generates synthetic blocks over a range of seeds, runs the
//! whole workflow on each in a child process (so that its peak memory is its own), and
//! prints one row per epoch and seed against the targets, plus the worst case. The scoring
//! is the library's (`pipeline::bench`).

use crate::synth::{PosArg, PresetArg};
use clap::{Args, Subcommand};
use cloudcontrol::pipeline::bench::{self, EpochScore, Targets};
use cloudcontrol::pipeline::project::Project;
use cloudcontrol::pipeline::report::Report;
use cloudcontrol::synth::{self, SynthConfig};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

#[derive(Subcommand)]
pub enum BenchCommand {
    /// Accuracy of the workflow over seeds: photos oriented and checkpoint RMSE in ground
    /// pixels per epoch and seed, beside what the true orientation scores; time and peak
    /// memory per run.
    ///
    /// Each seed is a synthetic block and a whole `cloudcontrol run` of it (about a minute
    /// per seed of the small preset on 2 cores).
    ///
    /// Example: cloudcontrol bench accuracy --preset small --seeds 1..3
    Accuracy(AccuracyArgs),
    /// Control patch success by the quality of the approximate orientation: the archive
    /// epochs of a synthetic block oriented from their DCPs with POS errors of increasing
    /// size, each with and without the iterative refinement (predict, match, resect,
    /// predict again); per group the share of photos oriented, the share of searched
    /// patches matched in the first and the last round, checkpoint errors and time.
    /// Writes OUT/patches.txt and OUT/patches.json.
    ///
    /// Example: cloudcontrol bench patches --out bench_patches
    Patches(crate::orient::BenchArgs),
}

#[derive(Args)]
pub struct AccuracyArgs {
    /// Block size.
    #[arg(long, value_enum, default_value = "small")]
    preset: PresetArg,
    /// Seeds: `A..B` (inclusive) or a comma-separated list.
    #[arg(long, default_value = "1..3")]
    seeds: String,
    /// Fraction of the scene changed in the archive epochs (0–1).
    #[arg(long, default_value_t = 0.5)]
    change: f64,
    /// Approximate EO of the archive epochs.
    #[arg(long, value_enum, default_value = "rough")]
    pos: PosArg,
    /// Work folder: one `<preset>-<seed>/` per seed (block and run), and `bench.json`.
    #[arg(long, default_value = "cloudcontrol_bench")]
    out: PathBuf,
    /// Keep a block already generated in the work folder with the same configuration
    /// (only the run is repeated).
    #[arg(long)]
    reuse_blocks: bool,
    /// The control of the run: the block's LiDAR and reference flight (`project.toml`),
    /// or its orthophoto and DEM alone (`project_orthophoto.toml`).
    #[arg(long, value_enum, default_value = "lidar")]
    control: ControlArg,
    /// Run without the epochs' surfaces and their changes (`outputs.dsm` and
    /// `outputs.change` off, in a copy of the project beside it): the bench scores the
    /// orientation, and on the small preset dense matching and the change analysis are
    /// half of a run's time.
    #[arg(long)]
    no_surfaces: bool,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum ControlArg {
    Lidar,
    Orthophoto,
}

/// `A..B` or `a,b,c`.
fn parse_seeds(s: &str) -> Result<Vec<u64>, String> {
    let bad = |e: std::num::ParseIntError| format!("--seeds {s:?}: {e}");
    if let Some((a, b)) = s.split_once("..") {
        let (a, b) = (
            a.trim().parse::<u64>().map_err(bad)?,
            b.trim().parse::<u64>().map_err(bad)?,
        );
        if b < a || b - a >= 1000 {
            return Err(format!(
                "--seeds {s:?}: want A..B with A ≤ B, at most 1000 seeds"
            ));
        }
        return Ok((a..=b).collect());
    }
    s.split(',')
        .map(|t| t.trim().parse::<u64>().map_err(bad))
        .collect()
}

/// What one child run took: exit status, wall time, peak resident memory (MiB).
struct ChildRun {
    success: bool,
    seconds: f64,
    peak_mib: f64,
}

/// One seed's scored epochs, its run, and the LiDAR's own height error at the
/// checkpoints (mean, RMSE; m).
struct SeedResult {
    rows: Vec<EpochScore>,
    child: ChildRun,
    lidar: Option<(f64, f64)>,
}

/// Runs `cloudcontrol run <project>` as a child and measures its own peak RSS (wait4's
/// rusage of that child alone, not the maximum over every child so far).
fn run_child(project: &Path, log: &Path) -> Result<ChildRun, String> {
    let exe = std::env::current_exe().map_err(|e| format!("own executable: {e}"))?;
    let log_file = std::fs::File::create(log).map_err(|e| format!("{}: {e}", log.display()))?;
    let t = Instant::now();
    let child = Command::new(exe)
        .arg("--quiet")
        .arg("run")
        .arg(project)
        .stdout(Stdio::null())
        .stderr(log_file)
        .spawn()
        .map_err(|e| format!("starting the run: {e}"))?;
    let pid = child.id() as libc::pid_t;
    let mut status: libc::c_int = 0;
    // SAFETY: rusage is plain data that wait4 fills; `pid` is our own unwaited child.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let r = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
    if r != pid {
        return Err(format!(
            "waiting for the run: {}",
            std::io::Error::last_os_error()
        ));
    }
    Ok(ChildRun {
        success: libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0,
        seconds: t.elapsed().as_secs_f64(),
        // Linux reports ru_maxrss in KiB.
        peak_mib: usage.ru_maxrss as f64 / 1024.0,
    })
}

/// Writes the project `from` to `to` without the epochs' surfaces
/// ([`Project::without_surfaces`]).
fn without_surfaces(from: &Path, to: &Path) -> Result<(), String> {
    let text = format!(
        "# {} without the epochs' surfaces (cloudcontrol bench accuracy --no-surfaces).\n{}",
        from.file_name().unwrap_or_default().to_string_lossy(),
        Project::without_surfaces(from).map_err(|e| e.to_string())?
    );
    std::fs::write(to, text).map_err(|e| format!("{}: {e}", to.display()))
}

/// The last lines of a run's log: why it stopped.
fn tail(log: &Path) -> String {
    let text = std::fs::read_to_string(log).unwrap_or_default();
    let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
    lines[lines.len().saturating_sub(2)..].join(" | ")
}

fn one_seed(args: &AccuracyArgs, seed: u64, targets: &Targets) -> Result<SeedResult, String> {
    let config = SynthConfig {
        preset: args.preset.into(),
        seed,
        change: args.change,
        pos: args.pos.into(),
        laz: false,
    };
    let preset = serde_json::to_value(config.preset)
        .ok()
        .and_then(|v| v.as_str().map(str::to_string))
        .unwrap_or_default();
    let dir = args.out.join(format!("{preset}-{seed}"));
    let block = dir.join("block");
    let written = block.join(match args.control {
        ControlArg::Lidar => "project.toml",
        ControlArg::Orthophoto => "project_orthophoto.toml",
    });
    let project_path = if args.no_surfaces {
        written.with_file_name(format!(
            "{}_no_surfaces.toml",
            written.file_stem().unwrap_or_default().to_string_lossy()
        ))
    } else {
        written.clone()
    };
    if args.reuse_blocks && synth::holds_block(&block, &config) {
        // A fresh run over the kept block. The project as synth wrote it names the output
        // (its copy without surfaces may not exist yet, and names the same one).
        if let Ok(p) = Project::load(&written) {
            let _ = std::fs::remove_dir_all(p.output);
        }
    } else {
        let _ = std::fs::remove_dir_all(&dir);
        synth::generate(&config, &block).map_err(|e| format!("synthetic block: {e}"))?;
    }
    if args.no_surfaces {
        without_surfaces(&written, &project_path)?;
    }
    let child = run_child(&project_path, &dir.join("run.log"))?;
    if !child.success {
        return Err(format!(
            "run failed after {:.0} s: {}",
            child.seconds,
            tail(&dir.join("run.log"))
        ));
    }
    let project = Project::load(&project_path).map_err(|e| e.to_string())?;
    let report_path = project.output.join("report/report.json");
    let report: Report = std::fs::read(&report_path)
        .map_err(|e| e.to_string())
        .and_then(|b| serde_json::from_slice(&b).map_err(|e| e.to_string()))
        .map_err(|e| format!("{}: {e}", report_path.display()))?;
    let rows = bench::score_run(seed, &block, &project, &report, targets)
        .map_err(|e| format!("scoring: {e}"))?;
    Ok(SeedResult {
        rows,
        child,
        lidar: bench::lidar_height_error(&project.output),
    })
}

pub fn run(cmd: BenchCommand, json: bool) -> Result<(), String> {
    let args = match cmd {
        BenchCommand::Accuracy(a) => a,
        BenchCommand::Patches(a) => return crate::orient::run_bench(&a, json),
    };
    let seeds = parse_seeds(&args.seeds)?;
    std::fs::create_dir_all(&args.out).map_err(|e| format!("{}: {e}", args.out.display()))?;
    let targets = Targets::default();
    let mut rows: Vec<EpochScore> = Vec::new();
    let mut runs = Vec::new();
    if !json {
        outln!("{}", bench::TABLE_HEADER);
    }
    for &seed in &seeds {
        match one_seed(&args, seed, &targets) {
            Ok(SeedResult {
                rows: r,
                child,
                lidar,
            }) => {
                if !json {
                    for row in &r {
                        outln!("{}", bench::row_line(row));
                    }
                    let lidar = lidar
                        .map(|(m, r)| {
                            format!("; LiDAR at the checkpoints: mean dz {m:+.3} m, RMSE {r:.3} m")
                        })
                        .unwrap_or_default();
                    outln!(
                        "{seed:>4}  run: {:.1} s, peak RSS {:.0} MiB{lidar}",
                        child.seconds,
                        child.peak_mib
                    );
                }
                runs.push(serde_json::json!({
                    "seed": seed, "completed": true, "seconds": child.seconds,
                    "peak_rss_mib": child.peak_mib,
                    "lidar_checkpoint_dz_mean_m": lidar.map(|l| l.0),
                    "lidar_checkpoint_dz_rmse_m": lidar.map(|l| l.1),
                }));
                rows.extend(r);
            }
            Err(e) => {
                if !json {
                    outln!("{seed:>4}  MISS: {e}");
                }
                runs.push(serde_json::json!({"seed": seed, "completed": false, "error": e}));
            }
        }
    }
    let completed = runs.iter().filter(|r| r["completed"] == true).count();
    let all_met = completed == seeds.len() && rows.iter().all(|r| r.misses.is_empty());
    let peak = runs
        .iter()
        .filter_map(|r| r["peak_rss_mib"].as_f64())
        .fold(0.0, f64::max);
    let summary = format!(
        "{completed} of {} runs completed, peak RSS {peak:.0} MiB; {}",
        seeds.len(),
        bench::summary_line(&rows)
    );
    let out = serde_json::json!({
        "preset": serde_json::to_value(synth::Preset::from(args.preset)).unwrap_or_default(),
        "seeds": seeds,
        "change": args.change,
        "pos": serde_json::to_value(synth::PosQuality::from(args.pos)).unwrap_or_default(),
        "control": match args.control {
            ControlArg::Lidar => "lidar",
            ControlArg::Orthophoto => "orthophoto",
        },
        "surfaces": !args.no_surfaces,
        "targets": targets,
        "runs": runs,
        "rows": rows,
        "all_met": all_met,
        "summary": summary,
    });
    let text = serde_json::to_string_pretty(&out).map_err(|e| e.to_string())?;
    std::fs::write(args.out.join("bench.json"), &text)
        .map_err(|e| format!("{}: {e}", args.out.join("bench.json").display()))?;
    if json {
        outln!("{text}");
    } else {
        outln!("{summary}");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::parse_seeds;

    #[test]
    fn seeds() {
        assert_eq!(parse_seeds("1..3").unwrap(), vec![1, 2, 3]);
        assert_eq!(parse_seeds("4, 9").unwrap(), vec![4, 9]);
        assert!(parse_seeds("3..1").is_err());
        assert!(parse_seeds("x").is_err());
    }
}
