//! `cloudcontrol io`, `cloudcontrol match` and `cloudcontrol ties`: argument handling,
//! progress and output for the matching module.

use clap::Args;
use cloudcontrol::block::Block;
use cloudcontrol::formats::raster::read_dem;
use cloudcontrol::formats::write_bytes_atomically;
use cloudcontrol::geometry::InteriorTransformKind;
use cloudcontrol::matching::fiducial::{
    check_scan_pixel_um, interior_orientation_file, CameraDefinition, IoOptions,
};
use cloudcontrol::matching::ncc::Window;
use cloudcontrol::matching::ties::{coverage, link_tracks, match_pair, predict_shift, TieOptions};
use cloudcontrol::matching::{block_tie_points, BlockTieOptions, Pixels, Surface};
use cloudcontrol::matching::{match_template, GreyImage, MatchOptions, Pyramid, RobustMethod};
use indicatif::{ProgressBar, ProgressStyle};
use nalgebra::Vector3;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::process::ExitCode;

/// Fiducial interior orientation of a film scan.
#[derive(Args)]
pub struct IoArgs {
    /// Camera definition (formats/cameras/*.json).
    #[arg(long)]
    camera: PathBuf,
    /// Scanned photo (TIFF, PNG, JPEG; 8/16-bit grey or RGB).
    scan: PathBuf,
    /// Write io.json here (atomically); otherwise print it.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Scan pixel size in µm (default: estimated from the film format).
    #[arg(long)]
    pixel_um: Option<f64>,
    /// Projective instead of affine pixel → mm transform.
    #[arg(long)]
    projective: bool,
    /// Known scan orientation, e.g. "90" or "180m" (m = mirrored); default: search all.
    #[arg(long)]
    orientation: Option<String>,
}

/// Match a template image in an image (NCC over the pyramid, then LSM), for debugging.
#[derive(Args)]
pub struct MatchArgs {
    /// Image to search in (PNG, TIFF, JPEG; grey or RGB).
    image: PathBuf,
    /// Template to find in it (smaller than the window).
    template: PathBuf,
    /// Search window: col,row,width,height (default: the whole image).
    #[arg(long, value_delimiter = ',')]
    window: Option<Vec<usize>>,
    /// Least normalised cross-correlation (NCC) of an accepted position.
    #[arg(long, default_value_t = 0.7)]
    ncc_threshold: f64,
}

/// Tie points between overlapping photos: guided by the approximate orientations of a
/// block (--block, from POS/EO), else blind along a strip of photos in flight order.
#[derive(Args)]
pub struct TiesArgs {
    /// Photos in flight order along the strip (without --block).
    #[arg(num_args = 0.., required_unless_present = "block")]
    photos: Vec<PathBuf>,
    /// Block JSON (cameras, photos with approximate EO and POS priors): each photo's
    /// points are predicted into the overlapping photos and searched around there.
    #[arg(long, conflicts_with = "photos")]
    block: Option<PathBuf>,
    /// Folder of the block's images (photo names are relative to it); default: the
    /// block file's folder.
    #[arg(long, requires = "block")]
    image_dir: Option<PathBuf>,
    /// DEM GeoTIFF (world coordinates of the block's CRS) for the predictions.
    #[arg(long, requires = "block", conflicts_with = "height")]
    dem: Option<PathBuf>,
    /// σ of the DEM heights (m).
    #[arg(long, default_value_t = 2.0)]
    dem_sigma: f64,
    /// Mean terrain height (block-local) for the predictions, without a DEM.
    #[arg(long, requires = "block")]
    height: Option<f64>,
    /// σ of the relief about the mean height (m).
    #[arg(long, default_value_t = 30.0)]
    height_sigma: f64,
    /// Write the block with the new tie points here (atomically).
    #[arg(long, requires = "block")]
    out_block: Option<PathBuf>,
    /// Points required near each standard position that lies in an overlap.
    #[arg(long, default_value_t = 3)]
    min_per_position: usize,
    /// Output JSON (tracks, pair statistics, coverage of the standard positions).
    #[arg(long)]
    out: PathBuf,
    /// Robust relative orientation: lmeds or ransac.
    #[arg(long, default_value = "lmeds")]
    robust: String,
}

fn fail(cmd: &str, e: impl std::fmt::Display) -> ExitCode {
    crate::console::fail(cmd, e, crate::EXIT_FAILED)
}

pub fn io(a: IoArgs, quiet: bool) -> ExitCode {
    if let Some(um) = a.pixel_um {
        if let Err(m) = check_scan_pixel_um(um) {
            return fail("io", format!("--pixel-um: {m}"));
        }
    }
    let cam = match CameraDefinition::load(&a.camera) {
        Ok(c) => c,
        Err(e) => return fail("io", e),
    };
    let orientation = match a.orientation.as_deref().map(str::parse).transpose() {
        Ok(o) => o,
        Err(m) => return fail("io", format!("--orientation: {m}")),
    };
    let opts = IoOptions {
        pixel_mm: a.pixel_um.map(|u| u / 1000.0),
        orientation,
        kind: if a.projective {
            InteriorTransformKind::Projective
        } else {
            InteriorTransformKind::Affine
        },
        ..IoOptions::default()
    };
    let io = match interior_orientation_file(&cam, &a.scan, &opts) {
        Ok(io) => io,
        Err(e) => return fail("io", e),
    };
    let text = serde_json::to_string_pretty(&io.to_json()).expect("io.json serialises");
    match &a.out {
        Some(p) => {
            if let Err(e) = write_bytes_atomically(p, text.as_bytes()) {
                return fail("io", e);
            }
            if !quiet {
                let used = io.marks.iter().filter(|m| m.used).count();
                outln!(
                    "{}: {used}/{} marks, RMSE {:.1} µm, orientation {} ({}, margin {:.1}×{}) → {}",
                    a.scan.display(),
                    io.marks.len(),
                    io.rmse_um,
                    io.orientation,
                    io.orientation_source,
                    io.orientation_margin,
                    if io.orientation_ambiguous {
                        "; the marks alone do not decide it"
                    } else {
                        ""
                    },
                    p.display()
                );
            }
        }
        None => outln!("{text}"),
    }
    ExitCode::SUCCESS
}

pub fn matching(a: MatchArgs) -> ExitCode {
    let (img, tpl) = match (GreyImage::load(&a.image), GreyImage::load(&a.template)) {
        (Ok(i), Ok(t)) => (i, t),
        (Err(e), _) | (_, Err(e)) => return fail("match", e),
    };
    let window = match a.window.as_deref() {
        Some([c, r, w, h]) => {
            if c + w > img.width || r + h > img.height {
                return fail(
                    "match",
                    format!(
                        "--window {w}×{h} at ({c}, {r}) is outside the {}×{} image",
                        img.width, img.height
                    ),
                );
            }
            Window {
                col: *c,
                row: *r,
                width: *w,
                height: *h,
            }
        }
        Some(_) => return fail("match", "--window: expected col,row,width,height"),
        None => Window::whole(&img),
    };
    let opts = MatchOptions {
        ncc_threshold: a.ncc_threshold,
        ..MatchOptions::default()
    };
    // The image becomes level 0 of its pyramid: no second copy of it.
    let pyr = Pyramid::from_image(img, 8, 16);
    match match_template(&pyr, &tpl, window, None, &opts) {
        Ok(m) => {
            outln!(
                "{}",
                serde_json::to_string_pretty(&m).expect("match serialises")
            );
            if m.accepted {
                ExitCode::SUCCESS
            } else {
                // No position accepted: a result, with its own exit status (README.md).
                ExitCode::from(super::EXIT_NO_MATCH)
            }
        }
        Err(e) => fail("match", e),
    }
}

pub fn ties(a: TiesArgs, quiet: bool) -> ExitCode {
    let robust = match a.robust.as_str() {
        "lmeds" | "lms" => RobustMethod::Lmeds,
        "ransac" => RobustMethod::Ransac,
        other => {
            return fail(
                "ties",
                format!("--robust {other}: expected lmeds or ransac"),
            )
        }
    };
    if a.block.is_some() {
        return ties_oriented(&a, robust, quiet);
    }
    if a.photos.len() < 2 {
        return fail("ties", "at least two photos are needed");
    }
    // Each photo becomes level 0 of its pyramid (held once, not copied into it).
    let mut pyrs = Vec::new();
    for p in &a.photos {
        match GreyImage::load(p) {
            Ok(i) => pyrs.push(Pyramid::from_image(i, 6, 32)),
            Err(e) => return fail("ties", e),
        }
    }
    let photos: Vec<&GreyImage> = pyrs.iter().map(|p| &p.levels[0]).collect();
    let opts = TieOptions {
        robust,
        ..TieOptions::default()
    };
    // Neighbours and second neighbours along the strip (triple overlap links tracks).
    let mut preds = Vec::new();
    for i in 0..photos.len() {
        for j in [i + 1, i + 2] {
            if j < photos.len() {
                if let Some(p) = predict_shift(&pyrs[i], &pyrs[j], i, j) {
                    preds.push(p);
                }
            }
        }
    }
    let bar = if quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(preds.len() as u64)
    };
    bar.set_style(
        ProgressStyle::with_template("{bar:30} {pos}/{len} pairs {msg}").expect("template"),
    );
    let mut pairs = Vec::new();
    for p in &preds {
        match match_pair(photos[p.a], &pyrs[p.b], p, &opts) {
            Ok(m) => pairs.push(m),
            Err(e) => tracing::warn!("pair {}–{} skipped: {e}", p.a, p.b),
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    let tracks = link_tracks(&pairs, opts.merge_px);
    let sizes: Vec<(usize, usize)> = photos.iter().map(|p| (p.width, p.height)).collect();
    let cov = coverage(&sizes, &preds, &tracks);
    let doc = serde_json::json!({
        "photos": a.photos.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
        "pairs": pairs.iter().map(|p| serde_json::json!({
            "a": p.a, "b": p.b,
            "candidates": p.candidates.len(),
            "accepted": p.inliers.iter().filter(|&&i| i).count(),
            "sigma_px": p.sigma_px,
            "fundamental": p.fundamental,
        })).collect::<Vec<_>>(),
        "tracks": tracks,
        "coverage": cov,
    });
    if let Err(e) = write_bytes_atomically(
        &a.out,
        serde_json::to_string_pretty(&doc).expect("json").as_bytes(),
    ) {
        return fail("ties", e);
    }
    if !quiet {
        let missing: usize = cov.iter().map(|c| c.missing(1).len()).sum();
        outln!(
            "{} pairs, {} tracks, {missing} standard positions without points → {}",
            pairs.len(),
            tracks.len(),
            a.out.display()
        );
    }
    ExitCode::SUCCESS
}

/// `ties --block`: the approximate-orientation path of the library, reading the block,
/// its images and the DEM (or mean height), writing the report and the extended block.
fn ties_oriented(a: &TiesArgs, robust: RobustMethod, quiet: bool) -> ExitCode {
    let path = a.block.as_ref().expect("checked by the caller");
    let mut block: Block = match cloudcontrol::formats::input::read_text(
        path,
        cloudcontrol::formats::input::Cap::document(),
    )
    .map_err(|e| e.detail())
    .and_then(|t| serde_json::from_str(&t).map_err(|e| e.to_string()))
    {
        Ok(b) => b,
        Err(e) => return fail("ties", format!("{}: {e}", path.display())),
    };
    if let Err(e) = block.validate() {
        return fail("ties", format!("{}: {e}", path.display()));
    }
    let dir = a.image_dir.clone().unwrap_or_else(|| {
        path.parent()
            .map(|p| p.to_path_buf())
            .unwrap_or_else(|| PathBuf::from("."))
    });
    // Photos are decoded when their pairs are matched; a missing file is named first.
    let files: BTreeMap<_, _> = block
        .photos
        .iter()
        .map(|(id, photo)| (*id, dir.join(&photo.name)))
        .collect();
    if let Some(p) = files.values().find(|p| !p.is_file()) {
        return fail("ties", format!("{}: photo image not found", p.display()));
    }
    let images: BTreeMap<_, _> = files.iter().map(|(id, p)| (*id, Pixels::File(p))).collect();
    let dem = match &a.dem {
        Some(p) => match read_dem(p) {
            Ok((d, _)) => Some(d),
            Err(e) => return fail("ties", format!("{}: {e}", p.display())),
        },
        None => None,
    };
    let surface = match (&dem, a.height) {
        (Some(dem), _) => Surface::Dem {
            dem,
            origin: Vector3::from(block.origin),
            sigma_m: a.dem_sigma,
        },
        (None, Some(height)) => Surface::Plane {
            height,
            sigma_m: a.height_sigma,
        },
        (None, None) => {
            return fail(
                "ties",
                "--block needs --dem or --height for the predictions",
            )
        }
    };
    let mut opts = BlockTieOptions::default();
    opts.ties.robust = robust;
    let report = match block_tie_points(&mut block, &images, &surface, a.min_per_position, &opts) {
        Ok(r) => r,
        Err(e) => return fail("ties", e),
    };
    let json = serde_json::to_string_pretty(&report).expect("json");
    if let Err(e) = write_bytes_atomically(&a.out, json.as_bytes()) {
        return fail("ties", e);
    }
    if let Some(out) = &a.out_block {
        let json = serde_json::to_string_pretty(&block).expect("json");
        if let Err(e) = write_bytes_atomically(out, json.as_bytes()) {
            return fail("ties", e);
        }
    }
    if !quiet {
        let missing: usize = report.coverage.iter().map(|c| c.missing.len()).sum();
        let skipped = report.pairs.iter().filter(|p| p.skipped.is_some()).count();
        outln!(
            "{} pairs ({skipped} skipped), {} tie points with {} observations, {missing} standard positions with fewer than {} points → {}",
            report.pairs.len(),
            report.points_added,
            report.observations_added,
            report.min_per_position,
            a.out.display()
        );
    }
    ExitCode::SUCCESS
}
