//! `cloudcontrol orient` (an archive epoch from DCP packages) and `cloudcontrol bench
//! patches` (control patch success by EO group, after seed 001's table 1.3, on a
//! synthetic block; `bench-table13` is its old, hidden name): argument handling and
//! output; the work is `control::archive::orient_epoch`.

use clap::Args;
use cloudcontrol::control::archive::{self, EpochResult};
use cloudcontrol::control::checkpoints;
use cloudcontrol::control::cloud::CloudOptions;
use cloudcontrol::control::dcp::{DcpPackage, EpochInfo};
use cloudcontrol::control::epoch::{block_origin, EpochCamera, EpochInput, EpochSpec, Navigation};
use cloudcontrol::control::export::{self, DcpExportOptions};
use cloudcontrol::formats::{self, control_points, write_bytes_atomically};
use cloudcontrol::matching::ScanOrientation;
use cloudcontrol::pipeline::film_frames;
use cloudcontrol::pipeline::partial::PartialEpoch;
use cloudcontrol::pipeline::project::Thresholds;
use cloudcontrol::synth::reading::{perturbed_navigation, synth_truth_block};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The arguments of `cloudcontrol orient` (its help and examples: `Command::Orient` in
/// main.rs). Writes OUT/block.json (the oriented block, world = local + origin),
/// OUT/colmap/ and OUT/blocks_exchange.xml (film: of the scans resampled into
/// OUT/resampled/), and OUT/report.json (per photo: oriented or why not, per-iteration
/// success ratios; the adjustment report).
#[derive(Args)]
pub struct OrientArgs {
    /// DCP package folder(s); all are verified and used together (e.g. several epochs).
    #[arg(long, required = true, num_args = 1..)]
    dcp: Vec<PathBuf>,
    /// A synthetic block folder (`cloudcontrol synth`); use with --epoch.
    #[arg(long, requires = "epoch", conflicts_with_all = ["camera", "images", "pos", "strips"])]
    synth: Option<PathBuf>,
    /// Epoch name inside the synthetic block, e.g. film_1978.
    #[arg(long)]
    epoch: Option<String>,
    /// Camera: a frame camera JSON (`{"kind": "frame", …}`) or a film camera certificate
    /// with fiducials (formats/cameras/).
    #[arg(long, requires = "images")]
    camera: Option<PathBuf>,
    /// Folder of the photos (PNG/TIFF/JPEG); photo names are the file stems.
    #[arg(long)]
    images: Option<PathBuf>,
    /// Epoch name (default: the photo folder's name).
    #[arg(long)]
    name: Option<String>,
    /// Film scans: scan pixel size (µm); estimated from the format and the scan size if
    /// not given.
    #[arg(long)]
    scan_pixel_um: Option<f64>,
    /// POS CSV: name,x,y,z,omega,phi,kappa[,sigma_xyz,sigma_angle] (degrees, world).
    #[arg(long, conflicts_with = "strips")]
    pos: Option<PathBuf>,
    /// Strips CSV: strip,photo,x,y,z[,flight_axis] with the centres of each strip's first
    /// and last photo (formats/pos/; flight axis +x when absent).
    #[arg(long)]
    strips: Option<PathBuf>,
    /// CRS of the navigation (default: the DEM's).
    #[arg(long)]
    crs: Option<String>,
    /// Ground DEM GeoTIFF (world coordinates, the packages' CRS).
    #[arg(long)]
    dem: PathBuf,
    /// Output folder: block.json, colmap/, blocks_exchange.xml, report.json (and
    /// resampled/ for film scans).
    #[arg(long)]
    out: PathBuf,
    /// Rejection threshold of the block adjustment in σ0.
    #[arg(long, default_value_t = 2.5)]
    reject_k: f64,
    /// Film scans: the scan orientation of every scan, e.g. "90" or "180m" (m = mirrored),
    /// for a camera whose fiducial layout cannot tell; default: found per scan.
    #[arg(long, value_parser = str::parse::<ScanOrientation>)]
    scan_orientation: Option<ScanOrientation>,
}

/// The epoch of the explicit options, through the one epoch builder; its origin is the
/// one origin rule over the navigation's centres.
fn explicit_input(a: &OrientArgs, dem_crs: Option<String>) -> Result<EpochInput, String> {
    let (Some(camera), Some(images)) = (&a.camera, &a.images) else {
        return Err("give either --synth DIR --epoch NAME, or --camera and --images".into());
    };
    let crs = a
        .crs
        .clone()
        .or(dem_crs)
        .ok_or("the CRS is unknown: give --crs (the DEM has none)")?;
    let spec = EpochSpec {
        name: a.name.clone().unwrap_or_else(|| {
            images
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_else(|| "epoch".into())
        }),
        date: None,
        photos: images.clone(),
        camera: camera.clone(),
        pos: a.pos.clone(),
        strips: a.strips.clone(),
        scan_pixel_um: a.scan_pixel_um,
    };
    let nav =
        Navigation::load(spec.pos.as_deref(), spec.strips.as_deref()).map_err(|e| e.to_string())?;
    let origin = block_origin(nav.centres().iter().map(|c| [c[0], c[1]]));
    EpochInput::build(&spec, &crs, origin).map_err(|e| e.to_string())
}

fn write_outputs(
    out: &Path,
    r: &mut EpochResult,
    camera: &EpochCamera,
) -> Result<serde_json::Value, String> {
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))?;
    // The photos named relative to the folder, as the workflow's block.json names them.
    cloudcontrol::pipeline::epoch_files::write_block_json(&out.join("block.json"), &mut r.block)
        .map_err(|e| e.to_string())?;
    let mut exports = serde_json::Map::new();
    let mut oriented = r.block.oriented_only();
    // An epoch that oriented no photo has no model to give: none is written (the command
    // ends partial, exit status 3).
    if oriented.photos.is_empty() {
        let reason = "no photo of the epoch was oriented";
        exports.insert("colmap".into(), json!({ "skipped": reason }));
        exports.insert("blocks_exchange".into(), json!({ "skipped": reason }));
        return finish_report(out, r, exports);
    }
    let mut pixel_mm = Default::default();
    // Film: COLMAP and BlocksExchange of the scans resampled into their fiducial frames,
    // as `cloudcontrol run` writes them (formats/workflow, "Resampled film scans").
    // A scan that cannot be resampled leaves the models unwritten, with the reason.
    let mut unwritable = None;
    if let (EpochCamera::Film(def), false) = (camera, oriented.photos.is_empty()) {
        let dir = out.join("resampled");
        let name = format!("{} ({})", def.name, r.epoch);
        match film_frames::to_frame_images(&oriented, def.format_mm, None, &name, &dir) {
            Ok(frames) => {
                let report =
                    serde_json::to_vec_pretty(&frames.report).map_err(|e| e.to_string())?;
                write_bytes_atomically(&dir.join("frames.json"), &report)
                    .map_err(|e| e.to_string())?;
                exports.insert("resampled".into(), json!("resampled/"));
                (oriented, pixel_mm) = (frames.block, frames.pixel_mm);
            }
            Err(e) => unwritable = Some(format!("film scans not resampled: {e}")),
        }
    }
    if let Some(reason) = unwritable {
        exports.insert("colmap".into(), json!({ "skipped": reason }));
        exports.insert("blocks_exchange".into(), json!({ "skipped": reason }));
        return finish_report(out, r, exports);
    }
    let colmap = formats::colmap::write(
        &out.join("colmap"),
        &oriented,
        &formats::colmap::WriteOptions {
            encoding: formats::colmap::Encoding::Text,
            layout: formats::colmap::Layout::Rigs,
        },
    );
    exports.insert(
        "colmap".into(),
        match colmap {
            Ok(()) => json!("colmap/"),
            Err(e) => json!({"skipped": e.to_string()}),
        },
    );
    let bx_opts = formats::blocks_exchange::WriteOptions {
        pixel_mm,
        ..Default::default()
    };
    let bx = formats::blocks_exchange::to_string(&oriented, &bx_opts).and_then(|s| {
        write_bytes_atomically(&out.join("blocks_exchange.xml"), s.as_bytes())
            .map_err(|e| e.to_string())
    });
    exports.insert(
        "blocks_exchange".into(),
        match bx {
            Ok(()) => json!("blocks_exchange.xml"),
            Err(e) => json!({"skipped": e}),
        },
    );
    finish_report(out, r, exports)
}

/// `report.json`: the epoch's result with what was exported.
fn finish_report(
    out: &Path,
    r: &EpochResult,
    exports: serde_json::Map<String, serde_json::Value>,
) -> Result<serde_json::Value, String> {
    let mut report = serde_json::to_value(r).map_err(|e| e.to_string())?;
    if let Some(a) = report.get_mut("adjustment").and_then(|a| a.as_object_mut()) {
        a.remove("residuals");
    }
    report["origin"] = json!(r.block.origin);
    report["exports"] = serde_json::Value::Object(exports);
    let text = serde_json::to_vec_pretty(&report).map_err(|e| e.to_string())?;
    write_bytes_atomically(&out.join("report.json"), &text).map_err(|e| e.to_string())?;
    Ok(report)
}

/// Orients the epoch and writes its outputs; Ok: the epoch's shortfall when it oriented
/// fewer photos than it has (the command then exits 3, saying why).
pub fn run_orient(
    a: &OrientArgs,
    json_out: bool,
    quiet: bool,
) -> Result<Option<PartialEpoch>, String> {
    let t0 = Instant::now();
    // The epoch's own inputs first (camera, navigation, photos: cheap, and the usual
    // mistakes), then every package is verified (manifest, CRS, chip checksums), all
    // before anything is done.
    let (dem, dem_crs) = formats::raster::read_dem(&a.dem).map_err(|e| e.to_string())?;
    let input = match (&a.synth, &a.epoch) {
        (Some(dir), Some(epoch)) => {
            EpochInput::from_synth_epoch(dir, epoch).map_err(|e| e.to_string())?
        }
        _ => explicit_input(a, dem_crs.map(|c| c.label()))?,
    };
    let packages: Vec<DcpPackage> = a
        .dcp
        .iter()
        .map(|p| DcpPackage::open(p).map_err(|e| e.to_string()))
        .collect::<Result<_, _>>()?;
    let dem = dem
        .shifted(input.origin)
        .map_err(|e| format!("{}: {e}", a.dem.display()))?;
    // The same options as `cloudcontrol run` with default thresholds.
    let mut opts = Thresholds {
        reject_k: a.reject_k,
        ..Thresholds::default()
    }
    .archive_options();
    opts.photo.io.orientation = a.scan_orientation;
    // Progress per photo on stderr (a spinner on a terminal, lines in a log).
    let shown =
        crate::console::ProgressGuard::start(quiet || json_out, &format!("orient {}", input.name));
    let mut r = archive::orient_epoch(&input, &packages, &dem, &opts).map_err(|e| e.to_string())?;
    let report = write_outputs(&a.out, &mut r, &input.camera)?;
    drop(shown);
    if json_out {
        outln!(
            "{}",
            serde_json::to_string_pretty(&report).map_err(|e| e.to_string())?
        );
    } else if !quiet {
        outln!(
            "cloudcontrol orient — epoch {}: {} of {} photos oriented ({:.1} s)",
            r.epoch,
            r.photos.iter().filter(|p| p.oriented).count(),
            r.photos.len(),
            t0.elapsed().as_secs_f64()
        );
        for p in &r.photos {
            let ratios: Vec<String> = p
                .iterations
                .iter()
                .map(|i| format!("{:.2}", i.success_ratio))
                .collect();
            outln!(
                "  {:<24} {:<3} matches {:>3}  σ {:>5.2} px  success per round [{}]{}",
                p.name,
                if p.oriented { "ok" } else { "NO" },
                p.control_matches,
                p.sigma_px,
                ratios.join(", "),
                p.reason
                    .as_ref()
                    .map(|r| format!("  ({r})"))
                    .unwrap_or_default()
            );
        }
        if let Some(adj) = &r.adjustment {
            outln!(
                "  block adjustment: σ0 {:.2}, RMSE {:.2} px, {} rejected, {} control points",
                adj.sigma0,
                adj.rmse_px,
                adj.rejected.count,
                adj.points
            );
        }
        outln!("  written to {}", a.out.display());
    }
    Ok(PartialEpoch::of_result(&r, Some(a.out.join("report.json"))))
}

/// The arguments of `cloudcontrol bench patches` (seed 001's table 1.3 reproduced on a
/// synthetic block: per EO group, the share of predicted control patches matched per
/// photo, with and without iterative refinement, and the relative time).
#[derive(Args)]
pub struct BenchArgs {
    /// Work folder: the synthetic block, patches.txt (the table) and patches.json.
    #[arg(long)]
    out: PathBuf,
    /// Synthetic preset: tiny, small (film at 0.5 m ground pixel) or medium.
    #[arg(long, default_value = "small")]
    preset: String,
    /// Seed of the synthetic block.
    #[arg(long, default_value_t = 3)]
    seed: u64,
    /// Noise draws per EO group.
    #[arg(long, default_value_t = 3)]
    draws: u64,
}

#[derive(serde::Serialize)]
struct GroupRow {
    group: String,
    refinement: bool,
    photos: usize,
    oriented_pct: f64,
    /// Mean over photos of matched / searched patches in the first round.
    first_round_success: f64,
    /// Mean over photos of matched / searched patches in the last round.
    final_success: f64,
    mean_rounds: f64,
    checkpoint_plan_px: f64,
    checkpoint_height_px: f64,
    time_s: f64,
    relative_time: f64,
    /// Photos not oriented: "epoch/photo (draw d): reason".
    failures: Vec<String>,
}

pub fn run_bench(a: &BenchArgs, json_out: bool) -> Result<(), String> {
    use cloudcontrol::synth::{self, PosQuality, Preset, SynthConfig};
    let preset = match a.preset.as_str() {
        "tiny" => Preset::Tiny,
        "small" => Preset::Small,
        "medium" => Preset::Medium,
        p => return Err(format!("--preset {p}: tiny, small or medium")),
    };
    let dir = a.out.join("block");
    let t = Instant::now();
    synth::generate(
        &SynthConfig {
            preset,
            seed: a.seed,
            change: 0.5,
            pos: PosQuality::Rough,
            laz: false,
        },
        &dir,
    )
    .map_err(|e| e.to_string())?;
    let mut tiles: Vec<PathBuf> = std::fs::read_dir(dir.join("lidar"))
        .map_err(|e| e.to_string())?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "las" || e == "laz"))
        .collect();
    tiles.sort();
    let refb = synth_truth_block(&dir, "reference_2024").map_err(|e| e.to_string())?;
    let surface = cloudcontrol::lidar::lidar_surfaces(&tiles, refb.origin, 1.0, None)
        .map_err(|e| e.to_string())?;
    let pkg = export::export_dcp(
        &refb,
        &surface,
        EpochInfo {
            name: "reference_2024".into(),
            date: None,
        },
        &a.out.join("reference.dcp"),
        &DcpExportOptions {
            cloud: CloudOptions {
                interval_px: 120.0,
                max_coplanarity: 0.02,
                ..CloudOptions::default()
            },
            chip_size: 193,
            ..DcpExportOptions::default()
        },
    )
    .map_err(|e| e.to_string())?;
    errln!(
        "block and {} DCP points ready in {:.1} s",
        pkg.manifest.points.len(),
        t.elapsed().as_secs_f64()
    );
    let packages = [pkg];
    let groups: [(&str, f64, f64, bool); 4] = [
        ("10 m / 3°", 10.0, 3f64.to_radians(), false),
        ("10 m / 3°", 10.0, 3f64.to_radians(), true),
        ("5 m / 1°", 5.0, 1f64.to_radians(), true),
        ("1 m / 1′", 1.0, (1.0f64 / 60.0).to_radians(), true),
    ];
    let epochs = ["film_1978", "digital_2012"];
    let mut rows: Vec<GroupRow> = Vec::new();
    for (label, sc, sa, refine) in groups {
        let mut first = Vec::new();
        let mut last = Vec::new();
        let mut rounds = Vec::new();
        let (mut oriented, mut photos) = (0usize, 0usize);
        let mut failures = Vec::new();
        let (mut plan, mut height, mut n_eval) = (0.0, 0.0, 0usize);
        let t = Instant::now();
        for epoch in epochs {
            let truth = synth_truth_block(&dir, epoch).map_err(|e| e.to_string())?;
            let base = EpochInput::from_synth_epoch(&dir, epoch).map_err(|e| e.to_string())?;
            for d in 0..a.draws {
                let input = EpochInput {
                    navigation: perturbed_navigation(&truth, sc, sa, 1000 * a.seed + d),
                    ..base.clone()
                };
                let mut opts = Thresholds::default().archive_options();
                if !refine {
                    opts.photo.orient.max_iterations = 1;
                }
                let r = archive::orient_epoch(&input, &packages, &surface.ground, &opts)
                    .map_err(|e| e.to_string())?;
                for p in &r.photos {
                    photos += 1;
                    oriented += p.oriented as usize;
                    if !p.oriented {
                        failures.push(format!(
                            "{epoch}/{} (draw {d}): {}",
                            p.name,
                            p.reason.as_ref().map(|r| r.to_string()).unwrap_or_default()
                        ));
                    }
                    if let (Some(f), Some(l)) = (p.iterations.first(), p.iterations.last()) {
                        first.push(f.success_ratio);
                        last.push(l.success_ratio);
                        rounds.push(p.iterations.len() as f64);
                    }
                }
                let meas = control_points::read_checkpoint_measurements(
                    &dir.join("truth/checkpoint_images.csv"),
                    epoch,
                )
                .map_err(|e| e.to_string())?;
                let surveyed: Vec<(String, [f64; 3])> =
                    control_points::read_points(&dir.join("checkpoints.csv"))
                        .map_err(|e| e.to_string())?
                        .into_iter()
                        .map(|p| (p.id, p.xyz))
                        .collect();
                if let Ok(e) =
                    checkpoints::evaluate_checkpoints(&r.block, &meas, &surveyed, r.gsd_m)
                {
                    plan += e.rmse_plan_px.powi(2);
                    height += e.rmse_height_px.powi(2);
                    n_eval += 1;
                }
            }
        }
        let mean = |v: &[f64]| {
            if v.is_empty() {
                0.0
            } else {
                v.iter().sum::<f64>() / v.len() as f64
            }
        };
        rows.push(GroupRow {
            group: label.into(),
            refinement: refine,
            photos,
            oriented_pct: 100.0 * oriented as f64 / photos.max(1) as f64,
            first_round_success: mean(&first),
            final_success: mean(&last),
            mean_rounds: mean(&rounds),
            checkpoint_plan_px: (plan / n_eval.max(1) as f64).sqrt(),
            checkpoint_height_px: (height / n_eval.max(1) as f64).sqrt(),
            time_s: t.elapsed().as_secs_f64(),
            relative_time: 0.0,
            failures,
        });
    }
    let t0 = rows[0].time_s.max(1e-9);
    for r in &mut rows {
        r.relative_time = r.time_s / t0;
    }
    let mut table = String::new();
    table.push_str(&format!(
        "Control patch success by EO group, synthetic preset {} seed {}: {} draws × {:?}\n",
        a.preset, a.seed, a.draws, epochs
    ));
    table.push_str(
        "EO group    refinement  photos  oriented  success (1st round)  success (final)  rounds  CP plan px  CP height px  time s  rel. time\n",
    );
    for r in &rows {
        table.push_str(&format!(
            "{:<11} {:<11} {:>6}  {:>7.0}%  {:>19.2}  {:>15.2}  {:>6.1}  {:>10.2}  {:>12.2}  {:>6.1}  {:>9.2}\n",
            r.group,
            if r.refinement { "yes" } else { "no" },
            r.photos,
            r.oriented_pct,
            r.first_round_success,
            r.final_success,
            r.mean_rounds,
            r.checkpoint_plan_px,
            r.checkpoint_height_px,
            r.time_s,
            r.relative_time
        ));
    }
    for r in &rows {
        for f in &r.failures {
            table.push_str(&format!(
                "  not oriented in {} ({}): {f}\n",
                r.group,
                if r.refinement { "refined" } else { "one round" }
            ));
        }
    }
    write_bytes_atomically(&a.out.join("patches.txt"), table.as_bytes())
        .map_err(|e| e.to_string())?;
    let j = serde_json::to_vec_pretty(&rows).map_err(|e| e.to_string())?;
    write_bytes_atomically(&a.out.join("patches.json"), &j).map_err(|e| e.to_string())?;
    if json_out {
        outln!("{}", String::from_utf8_lossy(&j));
    } else {
        out!("{table}");
    }
    Ok(())
}
