//! `cloudcontrol dsm`: the surface of an oriented block by dense matching of its photos.

use cloudcontrol::dense::epoch::DsmOptions;
use cloudcontrol::dense::products::dsm_from_files;
use std::path::PathBuf;
use std::process::ExitCode;

/// Dense matching of an oriented block's stereo pairs into a DSM (dsm.tif, dsm_count.tif,
/// dsm_spread.tif, dsm.json in OUT; dsm_points.laz with --points).
///
/// Pairs are chosen from the orientations (overlap ≥ 25 %, base-to-height 0.05–1),
/// rectified, matched by semi-global matching within a band around the prior surface (a
/// DEM ± --margin, or without one a plane at the block's tie points ± their relief), and
/// every pair's points fused per cell (median). Cells without a match stay nodata.
///
/// Example: cloudcontrol dsm --block sparse/0 --images photos/ --dem dem.tif --out dsm/
#[derive(clap::Args)]
pub struct Args {
    /// Block: COLMAP model folder or BlocksExchange .xml (oriented photos).
    #[arg(long)]
    block: PathBuf,
    /// Folder the photos' image names are relative to (default: the block's folder).
    #[arg(long)]
    images: Option<PathBuf>,
    /// Prior surface bounding the search (GeoTIFF, the block's CRS); the DSM is made
    /// within its extent.
    #[arg(long)]
    dem: Option<PathBuf>,
    /// Output folder.
    #[arg(long)]
    out: PathBuf,
    /// DSM cell in metres (default: the finest power of two of a metre not finer than the
    /// photos' median ground pixel, e.g. 0.25 for 0.21).
    #[arg(long)]
    cell: Option<f64>,
    /// Vertical margin of the search around the prior (m): its errors and what was built
    /// or removed since it was measured.
    #[arg(long, default_value_t = DsmOptions::default().prior_margin_m)]
    margin: f64,
    /// Also write the surface as points (dsm_points.laz: a point a cell with a height,
    /// its intensity the number of points fused there).
    #[arg(long)]
    points: bool,
}

pub fn run(a: Args, json: bool, quiet: bool) -> ExitCode {
    let images = a
        .images
        .clone()
        .unwrap_or_else(|| cloudcontrol::formats::convert::default_images_dir(&a.block));
    if let Some(c) = a.cell {
        if !(c.is_finite() && c > 0.0) {
            return crate::console::fail(
                "dsm",
                format!("--cell {c}: needs a positive cell size in metres"),
                crate::EXIT_USAGE,
            );
        }
    }
    if !(a.margin.is_finite() && a.margin >= 0.0) {
        return crate::console::fail(
            "dsm",
            format!("--margin {}: needs a margin ≥ 0 m", a.margin),
            crate::EXIT_USAGE,
        );
    }
    let options = DsmOptions {
        cell: a.cell,
        prior_margin_m: a.margin,
        ..DsmOptions::default()
    };
    let bar = (!quiet && !json).then(|| {
        let b = indicatif::ProgressBar::new(0);
        b.set_style(
            indicatif::ProgressStyle::with_template("dsm {bar:30} {pos}/{len} pairs {msg}")
                .expect("template"),
        );
        b
    });
    let result = dsm_from_files(
        &a.block,
        &images,
        a.dem.as_deref(),
        (&a.out, a.points),
        &options,
        |k, n, r| {
            tracing::info!(
                left = r.pair.left,
                right = r.pair.right,
                matched = r.matched,
                seconds = r.seconds,
                "pair matched"
            );
            if let Some(b) = &bar {
                b.set_length(n as u64);
                b.set_position(k as u64);
                b.set_message(format!("{:.0} % matched", 100.0 * r.matched));
            }
        },
    );
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    match result {
        Ok(r) => {
            crate::console::report(json, quiet, &r, || {
                format!(
                    "{}: {}×{} cells of {:.3} m, {} with a height, from {} pairs in {:.1} s",
                    a.out
                        .join(cloudcontrol::dense::products::DSM_FILE)
                        .display(),
                    r.width,
                    r.height,
                    r.cell_m,
                    r.cells_with_height,
                    r.pairs.len(),
                    r.seconds
                )
            });
            ExitCode::SUCCESS
        }
        Err(e) => crate::console::fail("dsm", e, crate::EXIT_FAILED),
    }
}
