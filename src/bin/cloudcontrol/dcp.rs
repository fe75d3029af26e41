//! `cloudcontrol dcp`: inspect, verify and merge Digital Control Photo packages.

use clap::Subcommand;
use cloudcontrol::control::dcp::DcpPackage;
use serde_json::json;
use std::path::PathBuf;

#[derive(Subcommand)]
pub enum DcpCommand {
    /// Verify a package (manifest, CRS, every chip's checksum) and summarise it.
    ///
    /// Example: cloudcontrol dcp info out/reference.dcp
    Info { package: PathBuf },
    /// Merge packages of one CRS into a new package.
    ///
    /// Example: cloudcontrol dcp merge a.dcp b.dcp --out ab.dcp
    Merge {
        packages: Vec<PathBuf>,
        #[arg(long)]
        out: PathBuf,
    },
}

pub fn run(cmd: DcpCommand, json_out: bool) -> Result<(), String> {
    match cmd {
        DcpCommand::Info { package } => {
            let p = DcpPackage::open(&package).map_err(|e| e.to_string())?;
            let m = &p.manifest;
            let measurements: usize = m.points.iter().map(|p| p.measurements.len()).sum();
            let summary = json!({
                "package": package,
                "version": m.version,
                "crs": m.crs,
                "epoch": m.epoch,
                "gsd_m": m.gsd_m,
                "accuracy": m.accuracy,
                "photos": m.photos.len(),
                "points": m.points.len(),
                "measurements": measurements,
                "files_verified": m.files.len(),
            });
            if json_out {
                println!("{}", serde_json::to_string_pretty(&summary).expect("json"));
            } else {
                println!("{}: verified ({} files)", package.display(), m.files.len());
                println!(
                    "  epoch {} ({}), CRS {}, GSD {} m",
                    m.epoch.name,
                    m.epoch.date.as_deref().unwrap_or("undated"),
                    m.crs,
                    m.gsd_m
                );
                println!(
                    "  {} photos, {} control points, {} chips",
                    m.photos.len(),
                    m.points.len(),
                    measurements
                );
                println!(
                    "  accuracy ±{} m plan, ±{} m height",
                    m.accuracy.plan_m, m.accuracy.height_m
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
                println!(
                    "{}",
                    json!({"package": out, "points": merged.manifest.points.len(), "photos": merged.manifest.photos.len()})
                );
            } else {
                println!(
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
