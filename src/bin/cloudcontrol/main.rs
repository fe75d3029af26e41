//! The `cloudcontrol` command line: argument parsing, progress and output only; the work
//! is done by the library.

mod adjust;
mod bench;
mod convert;
mod dcp;
mod lidar;
mod matching;
mod orient;
mod ortho;
mod run;
mod synth;

use clap::{Parser, Subcommand};
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
    /// Machine-readable JSON on stdout.
    #[arg(long, global = true)]
    json: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the built-in demonstration and print what it measured.
    ///
    /// Example: cloudcontrol demo --out demo_out
    ///
    /// Generates the small synthetic block (LiDAR, checkpoints, a reference epoch and two
    /// archive epochs: digital 2012 and film 1978), writes a project file for it and runs
    /// the whole workflow; prints per epoch the photos oriented and the checkpoint RMSE.
    /// A second run reuses the block and skips finished stages.
    Demo {
        /// Output folder (block/ and run/ inside).
        #[arg(long, default_value = "cloudcontrol_demo")]
        out: PathBuf,
        /// Size of the synthetic block.
        #[arg(long, value_enum, default_value = "small")]
        preset: run::DemoPreset,
    },
    /// Run a project: LiDAR sources, reference AT against the LiDAR, DCPs, archive epochs
    /// in time order, products and the accuracy report. Restartable: finished stages
    /// whose inputs did not change are skipped.
    ///
    /// Example: cloudcontrol run project.toml
    ///
    /// Exit codes: 0 done, 2 project file invalid (nothing was run), 1 a stage failed.
    Run(run::RunArgs),
    /// Digital Control Photo packages: generate from an oriented block, export, import into
    /// a store, verify, summarise, merge.
    ///
    /// Example: cloudcontrol dcp info run/dcp-reference_2024/package
    #[command(subcommand)]
    Dcp(dcp::DcpCommand),
    /// Write a synthetic aerial block with ground truth.
    ///
    /// Example: cloudcontrol synth --out block --preset small --seed 7
    Synth(synth::SynthArgs),
    /// LiDAR sources: info, catalogue, checkpoint evaluation, cleaning, DEM.
    ///
    /// Example: cloudcontrol lidar catalogue tiles/ --out tiles/catalogue.json
    Lidar {
        #[command(subcommand)]
        command: lidar::LidarCommand,
    },
    Icp(lidar::IcpArgs),
    /// Print the library version.
    ///
    /// Example: cloudcontrol version
    Version,
    Convert(convert::Args),
    Ortho(ortho::Args),
    /// Robust bundle adjustment of a COLMAP model with control, check points and LiDAR planes.
    ///
    /// Example: cloudcontrol adjust --model sparse/0 --control gcp.csv --measurements gcp_img.csv --self-calibrate fx,k1,k2 --out adjusted
    Adjust(adjust::AdjustArgs),
    /// Single-photo resection from control points.
    ///
    /// Example: cloudcontrol resect --camera 1800,1800,750,500 --width 1500 --height 1000 --points control.csv --out pose.json
    Resect(adjust::ResectArgs),
    /// Fiducial interior orientation of a film scan → io.json.
    ///
    /// Example: cloudcontrol io --camera formats/cameras/wild_rc10.json scan_0042.tif --out io.json
    Io(matching::IoArgs),
    /// Match a template in an image (NCC + LSM), for debugging.
    ///
    /// Example: cloudcontrol match photo.png chip.png --window 400,300,200,200 --json
    Match(matching::MatchArgs),
    /// Tie points between overlapping photos of a strip.
    ///
    /// Example: cloudcontrol ties s01_001.png s01_002.png s01_003.png --out ties.json
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
    /// Example (a synthetic block):
    ///   cloudcontrol orient --dcp ref.dcp --synth block --epoch film_1978 --dem dem.tif --out film
    ///
    /// Example (own scans):
    ///   cloudcontrol orient --dcp ref.dcp --camera rc10.json --images scans --strips strips.csv --crs EPSG:4547 --dem dem.tif --out film
    Orient(orient::OrientArgs),
    /// Seed 001 table 1.3 on a synthetic block: patch success per EO group, with and
    /// without iterative refinement, and the relative time.
    ///
    /// Example: cloudcontrol bench-table13 --out bench13
    /// Benchmarks of the workflow (accuracy over seeds).
    #[command(subcommand)]
    Bench(bench::BenchCommand),
    #[command(name = "bench-table13")]
    BenchTable13(orient::BenchArgs),
}

fn init_logging(quiet: bool, verbose: u8) {
    let level = if quiet {
        "error"
    } else {
        match verbose {
            0 => "warn",
            1 => "info",
            2 => "debug",
            _ => "trace",
        }
    };
    let filter = tracing_subscriber::EnvFilter::try_from_env("CLOUDCONTROL_LOG")
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(level));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .try_init();
}

/// Maps a subcommand's outcome to the exit code, printing the error (which names the input).
fn finish(name: &str, r: Result<(), String>) -> ExitCode {
    match r {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("cloudcontrol {name}: {e}");
            ExitCode::from(1)
        }
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    init_logging(cli.quiet, cli.verbose);
    match cli.command {
        Command::Convert(a) => convert::run(a, cli.json, cli.quiet),
        Command::Ortho(a) => ortho::run(a, cli.json, cli.quiet),
        Command::Io(a) => matching::io(a, cli.quiet),
        Command::Match(a) => matching::matching(a),
        Command::Ties(a) => matching::ties(a, cli.quiet),
        Command::Orient(a) => finish("orient", orient::run_orient(&a, cli.json, cli.quiet)),
        Command::Bench(c) => finish("bench", bench::run(c, cli.json)),
        Command::BenchTable13(a) => finish("bench-table13", orient::run_bench(&a, cli.json)),
        Command::Version => {
            println!("cloudcontrol {}", cloudcontrol::VERSION);
            ExitCode::SUCCESS
        }
        Command::Dcp(cmd) => match dcp::run(cmd, cli.json) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("cloudcontrol dcp: {e}");
                ExitCode::from(2)
            }
        },
        Command::Synth(args) => synth::run(args, cli.json, cli.quiet),
        Command::Adjust(a) => adjust::print_result("adjust", adjust::run_adjust(&a), cli.quiet),
        Command::Resect(a) => adjust::print_result("resect", adjust::run_resect(&a), cli.quiet),
        Command::Lidar { command } => {
            finish("lidar", lidar::run_lidar(command, cli.json, cli.quiet))
        }
        Command::Icp(args) => finish("icp", lidar::run_icp(args, cli.json, cli.quiet)),
        Command::Demo { out, preset } => {
            finish("demo", run::demo(&out, preset.into(), cli.json, cli.quiet))
        }
        Command::Run(a) => match run::run(&a, cli.json, cli.quiet) {
            Ok(()) => ExitCode::SUCCESS,
            Err((code, e)) => {
                eprintln!("cloudcontrol run: {e}");
                ExitCode::from(code)
            }
        },
    }
}
