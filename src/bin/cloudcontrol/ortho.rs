//! `cloudcontrol ortho`: true orthophoto of an oriented block on a DEM.

use cloudcontrol::formats::convert::orthophoto_from_files;
use cloudcontrol::formats::ortho::OrthoOptions;
use std::path::PathBuf;
use std::process::ExitCode;

/// Orthorectify the oriented photos of a block onto a DEM (RGB + alpha GeoTIFF).
///
/// Example: cloudcontrol ortho --block block.xml --images photos/ --dem dem.tif --out ortho.tif --cog
#[derive(clap::Args)]
pub struct Args {
    /// Block: COLMAP model folder or BlocksExchange .xml.
    #[arg(long)]
    block: PathBuf,
    /// DEM GeoTIFF (world coordinates, the block's CRS).
    #[arg(long)]
    dem: PathBuf,
    /// Output GeoTIFF.
    #[arg(long)]
    out: PathBuf,
    /// Folder the photos' image names are relative to (default: the block's folder).
    #[arg(long)]
    images: Option<PathBuf>,
    /// Ground sampling distance in metres (default: the photos' median ground pixel).
    #[arg(long)]
    gsd: Option<f64>,
    /// Extent x_min,y_min,x_max,y_max in world coordinates (default: the DEM's).
    #[arg(long, value_delimiter = ',', num_args = 4)]
    extent: Option<Vec<f64>>,
    /// Write a cloud-optimised GeoTIFF.
    #[arg(long)]
    cog: bool,
    /// Skip the visibility test (plain rectification, faster, ghosts at occlusions).
    #[arg(long)]
    no_occlusion: bool,
    /// MiB of decoded photos kept between tiles (photos are decoded when a tile needs
    /// them; a tile's own photos are held even beyond this).
    #[arg(long, default_value_t = cloudcontrol::formats::ortho::DEFAULT_IMAGE_CACHE_BYTES >> 20)]
    image_cache_mib: u64,
}

pub fn run(a: Args, json: bool, quiet: bool) -> ExitCode {
    let images = a
        .images
        .clone()
        .unwrap_or_else(|| cloudcontrol::formats::convert::default_images_dir(&a.block));
    let opts = OrthoOptions {
        gsd: a.gsd,
        extent: a.extent.as_ref().map(|e| (e[0], e[1], e[2], e[3])),
        cog: a.cog,
        occlusion: !a.no_occlusion,
        image_cache_bytes: a.image_cache_mib.saturating_mul(1 << 20),
        ..Default::default()
    };
    let spinner = (!quiet && !json).then(|| {
        let s = indicatif::ProgressBar::new_spinner();
        s.set_message(format!("orthorectifying onto {}", a.dem.display()));
        s.enable_steady_tick(std::time::Duration::from_millis(120));
        s
    });
    let result = orthophoto_from_files(&a.block, &a.dem, &images, &a.out, &opts);
    if let Some(s) = spinner {
        s.finish_and_clear();
    }
    match result {
        Ok(r) => {
            crate::console::report(json, quiet, &r, || {
                format!(
                    "{}: {}×{} px at {:.3} m, {} cells filled, {} taken from a farther photo because of occlusion",
                    a.out.display(),
                    r.width,
                    r.height,
                    r.gsd,
                    r.filled,
                    r.occluded_fallbacks
                )
            });
            ExitCode::SUCCESS
        }
        Err(e) => crate::console::fail("ortho", e, crate::EXIT_FAILED),
    }
}
