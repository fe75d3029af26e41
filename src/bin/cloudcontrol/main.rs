//! The `cloudcontrol` command line: argument parsing, progress and output only; the work
//! is done by the library.

#[macro_use]
mod console;

mod adjust;
mod bench;
mod change;
mod convert;
mod dcp;
mod dsm;
mod lidar;
mod matching;
mod orient;
mod ortho;
mod run;
mod synth;

use clap::{Parser, Subcommand};
use cloudcontrol::pipeline::partial::{self, PartialEpoch};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "cloudcontrol",
    version,
    about = "Orient archived aerial photos from LiDAR and previously oriented photos"
)]
struct Cli {
    /// Print only errors.
    #[arg(long, short, global = true)]
    quiet: bool,
    /// More log output (repeat for more).
    #[arg(long, short, global = true, action = clap::ArgAction::Count)]
    verbose: u8,
    /// Machine-readable JSON on stdout: results, and errors as
    /// {"error": {"command", "message", "input", "exit_status"}}.
    #[arg(long, global = true)]
    json: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the built-in demonstration and print what it measured.
    ///
    /// Example: cloudcontrol demo
    ///
    /// Generates the small synthetic block (LiDAR, checkpoints, a reference epoch and two
    /// archive epochs: digital 2012 and film 1978) in OUT/block with its project file
    /// (OUT/block/project.toml) and runs the whole workflow into OUT/run; prints per epoch
    /// the photos oriented and the checkpoint RMSE. About a minute on 2 cores; a second
    /// run reuses the block and skips finished stages.
    Demo {
        /// Output folder (block/ and run/ inside).
        #[arg(long, default_value = "cloudcontrol_demo")]
        out: PathBuf,
        /// Size of the synthetic block: small, the only block the demo runs on (the tiny
        /// preset of `cloudcontrol synth` is for unit tests and is refused).
        #[arg(long, default_value = "small", value_parser = run::demo_preset)]
        preset: cloudcontrol::synth::Preset,
    },
    /// Run a project: LiDAR sources, reference AT against the LiDAR, DCPs, archive epochs
    /// in time order, products and the accuracy report. Restartable: finished stages
    /// whose inputs did not change are skipped.
    ///
    /// Example: cloudcontrol run block/project.toml
    ///
    /// Exit statuses: 0 done, every photo of every epoch oriented; 1 a stage failed or an
    /// input was refused; 2 project file invalid (nothing was run); 3 partial: an epoch
    /// oriented fewer photos than it has (stderr says which, how many and why).
    Run(run::RunArgs),
    /// Digital Control Photo (DCP) packages: the control an epoch hands to older ones.
    /// Generate from an oriented block, export, import into a store, verify, summarise,
    /// merge, or make from an orthophoto and a DEM.
    ///
    /// Example: cloudcontrol dcp info run/dcp-reference_2024/package
    #[command(subcommand)]
    Dcp(dcp::DcpCommand),
    /// Write a synthetic aerial block with ground truth and its project file.
    ///
    /// Example: cloudcontrol synth --out synthetic --preset small --seed 3
    Synth(synth::SynthArgs),
    /// LiDAR sources: info, catalogue, checkpoint evaluation, cleaning, DEM.
    ///
    /// Example: cloudcontrol lidar catalogue tiles/ --out catalogue.json
    Lidar {
        #[command(subcommand)]
        command: lidar::LidarCommand,
    },
    Icp(lidar::IcpArgs),
    /// Print the library version (with --json: {"name", "version"}).
    ///
    /// Example: cloudcontrol version
    Version,
    Convert(convert::Args),
    Ortho(ortho::Args),
    Dsm(dsm::Args),
    Change(change::Args),
    /// Robust bundle adjustment of a COLMAP model with control, check points and LiDAR planes.
    ///
    /// Example: cloudcontrol adjust --model sparse/0 --control gcp.csv --measurements gcp_img.csv --self-calibrate f,k1,k2 --out adjusted
    Adjust(adjust::AdjustArgs),
    /// Single-photo resection from control points.
    ///
    /// Example: cloudcontrol resect --camera 1800,1800,750,500,-0.03,0.01,0,0.0002,-0.0001 --width 1500 --height 1000 --points control.csv --out pose.json
    Resect(adjust::ResectArgs),
    /// Fiducial interior orientation of a film scan → io.json.
    ///
    /// Example: cloudcontrol io --camera rc10.json scans/film_s01_001.png --out io.json
    Io(matching::IoArgs),
    /// Match a template in an image (NCC + LSM), for debugging: prints the match as JSON.
    ///
    /// Exit status 4 when the template was searched but no position was accepted.
    ///
    /// Example: cloudcontrol match photo.png chip.png --window 400,300,200,200
    Match(matching::MatchArgs),
    /// Tie points between overlapping photos of a strip.
    ///
    /// Example: cloudcontrol ties photos/reference_s01_001.png photos/reference_s01_002.png photos/reference_s01_003.png --out ties.json
    Ties(matching::TiesArgs),
    /// Orient an archive epoch (film scans or digital photos) from DCP packages.
    ///
    /// Film scans get their fiducial interior orientation; approximate orientations come
    /// from a POS or from strip end points; every photo is oriented from the control
    /// patches (predict, align, NCC + LSM, resect, repeat), then all together in a robust
    /// block adjustment. Writes OUT/block.json, OUT/colmap/, OUT/blocks_exchange.xml and
    /// OUT/report.json; for film, the models are of the scans resampled into fiducial-frame
    /// images in OUT/resampled/.
    ///
    /// Example (an epoch of a synthetic block):
    ///   cloudcontrol orient --dcp reference.dcp --synth block --epoch digital_2012 --dem dem.tif --out digital
    ///
    /// Example (own film scans with strip end points):
    ///   cloudcontrol orient --dcp reference.dcp --camera rc10.json --images scans --strips strips.csv --crs EPSG:4547 --dem dem.tif --out film
    ///
    /// Exit statuses: 0 every photo oriented; 3 partial: fewer photos oriented than given
    /// (stderr says how many and why; an epoch that oriented none writes no model); 1 an
    /// input was refused (e.g. a camera outside the plausible ranges of formats/cameras/).
    Orient(orient::OrientArgs),
    /// Benchmarks on synthetic blocks: accuracy of the workflow over seeds; control patch
    /// success with and without iterative refinement.
    ///
    /// Example: cloudcontrol bench accuracy --preset small --seeds 1..3
    #[command(subcommand)]
    Bench(bench::BenchCommand),
    /// The old name of `cloudcontrol bench patches`.
    #[command(name = "bench-table13", hide = true)]
    BenchTable13(orient::BenchArgs),
}

/// Exit statuses, the same for every command (README.md, "Exit statuses"): 0 done;
/// [`EXIT_FAILED`]; [`EXIT_USAGE`] (also clap's for a wrong command line); [`EXIT_PARTIAL`];
/// [`EXIT_NO_MATCH`].
/// An input was refused or a step failed; the message names the input.
pub const EXIT_FAILED: u8 = 1;
/// The command line or the project file is invalid: nothing was run.
pub const EXIT_USAGE: u8 = 2;
/// Finished, but an epoch oriented fewer photos than it has (`run`, `demo`, `orient`):
/// the products of what was oriented are written, and stderr says which epoch, how many
/// and why.
pub const EXIT_PARTIAL: u8 = 3;
/// `match`: the template was searched, but no position was accepted.
pub const EXIT_NO_MATCH: u8 = 4;

/// Maps a subcommand's outcome to the exit code, printing the error (which names the
/// input; with --json also as JSON on stdout).
fn finish(name: &str, r: Result<(), String>) -> ExitCode {
    match r {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => console::fail(name, e, EXIT_FAILED),
    }
}

/// The exit of a command that orients epochs: [`EXIT_PARTIAL`], saying on stderr which
/// epochs oriented fewer photos than they have, how many and why; else success.
fn partial_or_done(name: &str, partial: &[PartialEpoch]) -> ExitCode {
    if partial.is_empty() {
        return ExitCode::SUCCESS;
    }
    errln!(
        "cloudcontrol {name}: partial: {} epoch(s) oriented fewer photos than they have \
         (exit status {EXIT_PARTIAL})\n{}",
        partial.len(),
        partial::describe_all(partial)
    );
    ExitCode::from(EXIT_PARTIAL)
}

/// The command line, or clap's message and status for a wrong one (with --json also
/// as a JSON error); help and version are printed as asked.
fn parse() -> Result<Cli, ExitCode> {
    Cli::try_parse().map_err(|e| {
        use clap::error::ErrorKind;
        let asked = matches!(
            e.kind(),
            ErrorKind::DisplayHelp
                | ErrorKind::DisplayVersion
                | ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand
        );
        if asked || !std::env::args().any(|a| a == "--json") {
            let _ = e.print();
            return ExitCode::from(e.exit_code().clamp(0, 255) as u8);
        }
        console::set_json(true);
        let message = e.kind().to_string();
        let detail = e.render().to_string();
        let detail = detail
            .lines()
            .find_map(|l| l.strip_prefix("error: "))
            .unwrap_or(&message);
        console::fail("", detail, EXIT_USAGE)
    })
}

fn main() -> ExitCode {
    let cli = match parse() {
        Ok(c) => c,
        Err(code) => return code,
    };
    console::init_logging(cli.quiet, cli.verbose);
    console::set_json(cli.json);
    match cli.command {
        Command::Convert(a) => convert::run(a, cli.json, cli.quiet),
        Command::Ortho(a) => ortho::run(a, cli.json, cli.quiet),
        Command::Dsm(a) => dsm::run(a, cli.json, cli.quiet),
        Command::Change(a) => change::run(a, cli.json, cli.quiet),
        Command::Io(a) => matching::io(a, cli.quiet),
        Command::Match(a) => matching::matching(a),
        Command::Ties(a) => matching::ties(a, cli.quiet),
        Command::Orient(a) => match orient::run_orient(&a, cli.json, cli.quiet) {
            Ok(p) => partial_or_done("orient", p.as_slice()),
            Err(e) => finish("orient", Err(e)),
        },
        Command::Bench(c) => finish("bench", bench::run(c, cli.json)),
        Command::BenchTable13(a) => finish("bench patches", orient::run_bench(&a, cli.json)),
        Command::Version => {
            if cli.json {
                outln!(
                    "{}",
                    serde_json::json!({"name": "cloudcontrol", "version": cloudcontrol::VERSION})
                );
            } else {
                outln!("cloudcontrol {}", cloudcontrol::VERSION);
            }
            ExitCode::SUCCESS
        }
        Command::Dcp(cmd) => finish("dcp", dcp::run(cmd, cli.json).map_err(|e| e.to_string())),
        Command::Synth(args) => synth::run(args, cli.json, cli.quiet),
        Command::Adjust(a) => adjust::print_result("adjust", adjust::run_adjust(&a), cli.quiet),
        Command::Resect(a) => adjust::print_result("resect", adjust::run_resect(&a), cli.quiet),
        Command::Lidar { command } => {
            finish("lidar", lidar::run_lidar(command, cli.json, cli.quiet))
        }
        Command::Icp(args) => finish("icp", lidar::run_icp(args, cli.json, cli.quiet)),
        Command::Demo { out, preset } => match run::demo(&out, preset, cli.json, cli.quiet) {
            Ok(p) => partial_or_done("demo", &p),
            Err(e) => finish("demo", Err(e)),
        },
        Command::Run(a) => match run::run(&a, cli.json, cli.quiet) {
            Ok(p) => partial_or_done("run", &p),
            Err((code, e)) => console::fail("run", e, code),
        },
    }
}
