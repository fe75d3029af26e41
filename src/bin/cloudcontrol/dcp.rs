//! `cloudcontrol dcp`: generate, export, import, inspect and merge Digital Control Photo
//! packages. The work is `control::archive` (selection, export) and `control::dcp`
//! (verification, import, merge).

use clap::{Args, Subcommand};
use cloudcontrol::control::cloud::CloudOptions;
use cloudcontrol::control::dcp::{Accuracy, DcpPackage, EpochInfo};
use cloudcontrol::control::export::{self, ControlPointSet, DcpExportOptions, OrientedBlock};
use cloudcontrol::control::ortho_source::{orthophoto_dcp, OrthoControlOptions, OrthoSource};
use cloudcontrol::formats::write_bytes_atomically;
use cloudcontrol::lidar::LIDAR_CELL_M;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};

#[derive(Subcommand)]
pub enum DcpCommand {
    /// List the cloud control points of an oriented block, without cutting chips.
    ///
    /// Picks Förstner-textured points on planar, stable LiDAR ground, one per interval
    /// cell of each photo, and writes them as JSON: world coordinates, σ, quality, and
    /// the pixel in every photo that sees them. These are exactly the points `dcp export`
    /// writes with the same options. The block is the one the workflow writes per epoch
    /// (block.json and images.json).
    ///
    /// Example:
    ///   cloudcontrol dcp generate --block run/epoch-reference_2024/block.json --images run/epoch-reference_2024/images.json --lidar tiles/ --interval-px 250 --out points.json
    Generate {
        #[command(flatten)]
        select: SelectArgs,
        /// Write the points here (JSON) instead of printing them.
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Write a DCP package from an oriented block: its cloud control points with chips.
    ///
    /// Example:
    ///   cloudcontrol dcp export --block run/epoch-reference_2024/block.json --images run/epoch-reference_2024/images.json --lidar tiles/ --out reference.dcp --name reference_2024 --date 2024-05-29
    Export {
        #[command(flatten)]
        select: SelectArgs,
        /// Package folder to write (replaced atomically when it exists).
        #[arg(long)]
        out: PathBuf,
        /// Epoch name (default: the package folder's name without extension).
        #[arg(long)]
        name: Option<String>,
        /// Acquisition date of the photos (ISO 8601).
        #[arg(long)]
        date: Option<String>,
        /// How the control was derived, recorded in the manifest.
        #[arg(long)]
        source: Option<String>,
    },
    /// Verify packages and copy them into a store folder (STORE/<package folder name>).
    ///
    /// Every package is verified in full first (manifest, version, CRS, every chip's
    /// checksum) and must have the CRS of the packages already in the store; a refused
    /// package leaves the store untouched.
    ///
    /// Example:
    ///   cloudcontrol dcp import reference.dcp ortho.dcp --into dcp_store
    Import {
        /// Package folders to import.
        #[arg(required = true)]
        packages: Vec<PathBuf>,
        /// The store folder (created when missing).
        #[arg(long)]
        into: PathBuf,
    },
    /// Verify a package (manifest, CRS, every chip's checksum) and summarise it.
    ///
    /// Example: cloudcontrol dcp info reference.dcp
    Info {
        /// Package folder (manifest.json, chips/).
        package: PathBuf,
    },
    /// Merge packages of one CRS into a new package.
    ///
    /// Example: cloudcontrol dcp merge reference.dcp ortho.dcp --out merged.dcp
    Merge {
        /// Package folders to merge (one CRS).
        packages: Vec<PathBuf>,
        /// Package folder to write (replaced atomically when it exists).
        #[arg(long)]
        out: PathBuf,
    },
    /// Write a DCP package from a georeferenced orthophoto and a DEM: control points
    /// where the orthophoto is textured and the DEM planar, chips from the orthophoto
    /// (formats/dcp/, "Orthophoto and DEM").
    ///
    /// The orthophoto is a GeoTIFF or an image with a world file (then give its CRS); a
    /// raster in another CRS than the package's is reprojected (GDAL's warper).
    ///
    /// Example:
    ///   cloudcontrol dcp from-orthophoto --orthophoto block/orthophoto/orthophoto.tif --dem block/orthophoto/dem.tif --crs EPSG:4547 --out ortho.dcp
    FromOrthophoto {
        /// Orthophoto: a GeoTIFF, or an image with a world file (.jgw, .tfw, .wld; then
        /// give --orthophoto-crs or --orthophoto-crs-file).
        #[arg(long)]
        orthophoto: PathBuf,
        /// CRS of the orthophoto when its file has none (EPSG:n or WKT).
        #[arg(long, conflicts_with = "orthophoto_crs_file")]
        orthophoto_crs: Option<String>,
        /// The same, read from a file (e.g. a .prj or .wkt beside a world file).
        #[arg(long)]
        orthophoto_crs_file: Option<PathBuf>,
        /// DEM GeoTIFF of the orthophoto's area (heights in metres): the control points'
        /// heights.
        #[arg(long)]
        dem: PathBuf,
        /// CRS of the DEM when its file has none.
        #[arg(long)]
        dem_crs: Option<String>,
        /// CRS of the package (projected, metres).
        #[arg(long)]
        crs: String,
        /// Package folder to write (replaced atomically when it exists).
        #[arg(long)]
        out: PathBuf,
        /// Epoch name (default: the package folder's name without extension).
        #[arg(long)]
        name: Option<String>,
        /// Acquisition date of the orthophoto's photos (ISO 8601: YYYY, YYYY-MM or
        /// YYYY-MM-DD).
        #[arg(long)]
        date: Option<String>,
        /// One control point per cell of this many orthophoto pixels at most.
        #[arg(long, default_value_t = OrthoControlOptions::default().interval_px)]
        interval_px: f64,
        /// Pyramid level of the interest operator (the archive photos' scale).
        #[arg(long, default_value_t = OrthoControlOptions::default().interest_level)]
        interest_level: usize,
        /// Chip side (px, odd).
        #[arg(long, default_value_t = OrthoControlOptions::default().chip_size)]
        chip_size: u32,
        /// 1σ plan accuracy of the orthophoto (m; default one pixel).
        #[arg(long)]
        plan_sigma_m: Option<f64>,
        /// 1σ height accuracy of the DEM (m).
        #[arg(long, default_value_t = OrthoControlOptions::default().dem_sigma_m)]
        dem_sigma_m: f64,
    },
}

/// The oriented block, its LiDAR and the selection of control points.
#[derive(Args)]
pub struct SelectArgs {
    /// block.json of an oriented epoch (as `cloudcontrol run` writes it).
    #[arg(long)]
    block: PathBuf,
    /// images.json of the epoch: photo id → image path (a relative path is taken from the
    /// folder of images.json, else from the working directory).
    #[arg(long)]
    images: PathBuf,
    /// LAS/LAZ tiles or folders of them (classified: ground is class 2).
    #[arg(long, required = true, num_args = 1..)]
    lidar: Vec<PathBuf>,
    /// Spacing of control points in each photo (px, ≤ 1000).
    #[arg(long, default_value_t = CloudOptions::default().interval_px)]
    interval_px: f64,
    /// Pyramid level the interest operator runs on (2 = 4× coarser than the photos).
    #[arg(long, default_value_t = DcpExportOptions::default().interest_level)]
    interest_level: usize,
    /// Chip side (px, odd); points keep half a chip away from the photo borders.
    #[arg(long, default_value_t = DcpExportOptions::default().chip_size)]
    chip_size: u32,
    /// Largest coplanarity (λmin/Σλ) of the LiDAR ground under a point.
    #[arg(long, default_value_t = CloudOptions::default().max_coplanarity)]
    max_coplanarity: f64,
    /// 1σ plan accuracy of the points' object coordinates (m).
    #[arg(long, default_value_t = DcpExportOptions::default().accuracy.plan_m)]
    accuracy_plan_m: f64,
    /// 1σ height accuracy of the points' object coordinates (m).
    #[arg(long, default_value_t = DcpExportOptions::default().accuracy.height_m)]
    accuracy_height_m: f64,
    /// Grid cell of the LiDAR ground model (m).
    #[arg(long, default_value_t = LIDAR_CELL_M)]
    lidar_cell_m: f64,
}

impl SelectArgs {
    fn options(&self) -> DcpExportOptions {
        let d = DcpExportOptions::default();
        DcpExportOptions {
            cloud: CloudOptions {
                interval_px: self.interval_px,
                max_coplanarity: self.max_coplanarity,
                ..d.cloud.clone()
            },
            chip_size: self.chip_size,
            accuracy: Accuracy {
                plan_m: self.accuracy_plan_m,
                height_m: self.accuracy_height_m,
            },
            interest_level: self.interest_level,
            ..d
        }
    }

    fn load(&self) -> Result<(OrientedBlock, DcpExportOptions), String> {
        let opts = self.options();
        // Bad options are reported before the LiDAR is read.
        opts.validate()?;
        let b = OrientedBlock::load(&self.block, &self.images, &self.lidar, self.lidar_cell_m)
            .map_err(|e| e.to_string())?;
        Ok((b, opts))
    }
}

fn summary(package: &Path, p: &DcpPackage) -> Value {
    let m = &p.manifest;
    json!({
        "package": package,
        "version": m.version,
        "crs": m.crs,
        "epoch": m.epoch,
        "gsd_m": m.gsd_m,
        "accuracy": m.accuracy,
        "photos": m.photos.len(),
        "points": m.points.len(),
        "measurements": m.points.iter().map(|p| p.measurements.len()).sum::<usize>(),
        "files_verified": m.files.len(),
    })
}

fn print_json(v: &Value) {
    outln!("{}", serde_json::to_string_pretty(v).expect("json"));
}

fn points_summary(set: &ControlPointSet) -> (usize, usize) {
    let photos: std::collections::BTreeSet<u32> = set
        .points
        .iter()
        .flat_map(|p| p.measurements.iter().map(|m| m.photo))
        .collect();
    (set.points.len(), photos.len())
}

pub fn run(cmd: DcpCommand, json_out: bool) -> Result<(), String> {
    match cmd {
        DcpCommand::Generate { select, out } => {
            let (b, opts) = select.load()?;
            let set = b.select(&opts).map_err(|e| e.to_string())?;
            let text = serde_json::to_string_pretty(&set).map_err(|e| e.to_string())?;
            let Some(out) = out else {
                outln!("{text}");
                return Ok(());
            };
            write_bytes_atomically(&out, text.as_bytes()).map_err(|e| e.to_string())?;
            let (points, photos) = points_summary(&set);
            if json_out {
                print_json(
                    &json!({"out": out, "crs": set.crs, "points": points, "photos": photos}),
                );
            } else {
                outln!(
                    "{}: {points} control points in {photos} photos",
                    out.display()
                );
            }
            Ok(())
        }
        DcpCommand::Export {
            select,
            out,
            name,
            date,
            source,
        } => {
            let (b, mut opts) = select.load()?;
            if let Some(s) = source {
                opts.source = s;
            }
            let epoch = EpochInfo {
                name: name.unwrap_or_else(|| export::package_epoch_name(&out)),
                date,
            };
            let p = b.export(epoch, &out, &opts).map_err(|e| e.to_string())?;
            let s = summary(&out, &p);
            if json_out {
                print_json(&s);
            } else {
                outln!(
                    "{}: {} control points, {} photos, {} chips",
                    out.display(),
                    s["points"],
                    s["photos"],
                    s["measurements"]
                );
            }
            Ok(())
        }
        DcpCommand::FromOrthophoto {
            orthophoto,
            orthophoto_crs,
            orthophoto_crs_file,
            dem,
            dem_crs,
            crs,
            out,
            name,
            date,
            interval_px,
            interest_level,
            chip_size,
            plan_sigma_m,
            dem_sigma_m,
        } => {
            let ortho_crs = match (orthophoto_crs, orthophoto_crs_file) {
                (Some(c), _) => Some(c),
                (None, Some(f)) => Some(
                    // A CRS definition is at most 64 KiB (formats/README.md).
                    cloudcontrol::formats::input::read_text(
                        &f,
                        cloudcontrol::formats::input::Cap::fixed(64 << 10, "CRS definition"),
                    )
                    .map_err(|e| e.to_string())?
                    .trim()
                    .to_string(),
                ),
                (None, None) => None,
            };
            let src = OrthoSource {
                orthophoto: &orthophoto,
                orthophoto_crs: ortho_crs.as_deref(),
                dem: &dem,
                dem_crs: dem_crs.as_deref(),
                epoch: EpochInfo {
                    name: name.unwrap_or_else(|| export::package_epoch_name(&out)),
                    date,
                },
            };
            let opts = OrthoControlOptions {
                interval_px,
                interest_level,
                chip_size,
                plan_sigma_m,
                dem_sigma_m,
                ..OrthoControlOptions::default()
            };
            let (p, rep) = orthophoto_dcp(&src, &crs, &out, &opts).map_err(|e| e.to_string())?;
            if json_out {
                print_json(&serde_json::json!({
                    "package": summary(&out, &p),
                    "selection": rep,
                }));
            } else {
                outln!(
                    "{}: {} control points from {} candidates ({} without DEM, {} not planar), ground pixel {:.3} m",
                    out.display(),
                    rep.points,
                    rep.candidates,
                    rep.outside_dem,
                    rep.not_planar,
                    rep.gsd_m
                );
            }
            Ok(())
        }
        DcpCommand::Import { packages, into } => {
            let imported = DcpPackage::import(&packages, &into).map_err(|e| e.to_string())?;
            if json_out {
                let v: Vec<Value> = imported.iter().map(|p| summary(&p.dir, p)).collect();
                print_json(&Value::from(v));
            } else {
                for (src, p) in packages.iter().zip(&imported) {
                    outln!(
                        "{} → {}: {} control points, verified",
                        src.display(),
                        p.dir.display(),
                        p.manifest.points.len()
                    );
                }
            }
            Ok(())
        }
        DcpCommand::Info { package } => {
            let p = DcpPackage::open(&package).map_err(|e| e.to_string())?;
            let m = &p.manifest;
            if json_out {
                print_json(&summary(&package, &p));
            } else {
                let measurements: usize = m.points.iter().map(|p| p.measurements.len()).sum();
                outln!("{}: verified ({} files)", package.display(), m.files.len());
                outln!(
                    "  epoch {} ({}), CRS {}, GSD {} m",
                    m.epoch.name,
                    m.epoch.date.as_deref().unwrap_or("undated"),
                    m.crs,
                    m.gsd_m
                );
                outln!(
                    "  {} photos, {} control points, {} chips",
                    m.photos.len(),
                    m.points.len(),
                    measurements
                );
                outln!(
                    "  accuracy ±{} m plan, ±{} m height",
                    m.accuracy.plan_m,
                    m.accuracy.height_m
                );
            }
            Ok(())
        }
        DcpCommand::Merge { packages, out } => {
            if packages.is_empty() {
                return Err("dcp merge: give at least one package".into());
            }
            let opened = packages
                .iter()
                .map(|p| DcpPackage::open(p).map_err(|e| e.to_string()))
                .collect::<Result<Vec<_>, _>>()?;
            let merged = DcpPackage::merge(&opened, &out).map_err(|e| e.to_string())?;
            if json_out {
                outln!(
                    "{}",
                    json!({"package": out, "points": merged.manifest.points.len(), "photos": merged.manifest.photos.len()})
                );
            } else {
                outln!(
                    "{}: {} points from {} packages",
                    out.display(),
                    merged.manifest.points.len(),
                    packages.len()
                );
            }
            Ok(())
        }
    }
}
