//! `cloudcontrol adjust` and `cloudcontrol resect`: argument parsing, CSV/COLMAP I/O and
//! reporting around `cloudcontrol::adjust`.

use clap::Args;
use cloudcontrol::adjust::georef::{georeference, GeorefOptions, SurveyedInput};
use cloudcontrol::adjust::{
    adjust_with_rejected, resect, AdjustOptions, Loss, PlaneConstraint, Rejection, ResectionOptions,
};
use cloudcontrol::block::{Block, ObjectPoint, PointId, PointKind};
use cloudcontrol::formats::control_points::{self, Measurement, SurveyedPoint};
use cloudcontrol::formats::csv::{read_records, read_records_renamed, Extra, Layout};
use cloudcontrol::formats::odm_gcp::{read_odm_gcp, GcpOptions};
use cloudcontrol::formats::{adjust_report, write_bytes_atomically};
use cloudcontrol::geometry::{Brown, Camera, FrameCamera};
use nalgebra::Vector3;
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
pub struct AdjustArgs {
    /// COLMAP text model folder (cameras.txt, images.txt, points3D.txt).
    #[arg(long)]
    pub model: PathBuf,
    /// Output folder for the adjusted COLMAP text model.
    #[arg(long)]
    pub out: PathBuf,
    /// Control points CSV: id,x,y,z[,sigma_xy,sigma_z] (id = POINT3D_ID or a name).
    #[arg(long)]
    pub control: Option<PathBuf>,
    /// Check points CSV, same columns (sigmas ignored).
    #[arg(long)]
    pub check: Option<PathBuf>,
    /// Ground control as OpenDroneMap's gcp_list.txt (CRS header, one line per image
    /// measurement; see formats/control-points/odm.md).
    #[arg(long)]
    pub gcp: Option<PathBuf>,
    /// σ of the --gcp coordinates: σ_xy,σ_z in metres (default 0.05,0.05; heights all 0.0
    /// are taken as unknown, σ_z 100 m, unless this is given).
    #[arg(long, value_delimiter = ',')]
    pub gcp_sigma: Vec<f64>,
    /// Image measurements of named control/check points: id,image_name,x,y (pixels).
    #[arg(long)]
    pub measurements: Option<PathBuf>,
    /// LiDAR planes CSV: point_id,nx,ny,nz,d,weight (world coordinates, weight in 1/m²).
    #[arg(long, num_args = 1..)]
    pub lidar_planes: Vec<PathBuf>,
    /// σ of the LiDAR's datum per axis (m): the planes' common shift is adjusted with this
    /// prior (report: `lidar_datum`). Without it the planes are the datum as they stand.
    #[arg(long)]
    pub lidar_datum_sigma: Option<f64>,
    /// Interior parameters to self-calibrate: any of f,pp,k1,k2,k3,p1,p2.
    #[arg(long, value_delimiter = ',')]
    pub self_calibrate: Vec<String>,
    /// Robust loss.
    #[arg(long, default_value = "huber")]
    pub robust: String,
    /// Gross-error elimination: `snooping` (Baarda data snooping against the a-priori σ,
    /// each observation tested with its own dimension at level --alpha), `threshold`
    /// (standardised residuals above --reject k·σ0, σ0 re-estimated each round) or `none`.
    #[arg(long, default_value = "snooping")]
    pub rejection: String,
    /// Significance level α0 of each data-snooping test.
    #[arg(long, default_value_t = 0.001)]
    pub alpha: f64,
    /// k of the `threshold` rule (in σ0); 0 disables elimination whatever the rule.
    #[arg(long, default_value_t = 3.0)]
    pub reject: f64,
    /// A-priori σ of image measurements (px).
    #[arg(long, default_value_t = 1.0)]
    pub sigma_px: f64,
    /// Most Levenberg–Marquardt iterations per adjustment round.
    #[arg(long, default_value_t = 50)]
    pub max_iterations: usize,
    /// JSON report: a summary of bounded size whatever the block's (formats/adjust/): σ0,
    /// variance components, self-calibration, check points, the rejections and the weakest
    /// photos up to 100 of each; the full listings go to --observations and --photos.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Every observation as CSV (kept: residuals, standardised residual, redundancy
    /// number; rejected: round, statistic, reason).
    #[arg(long)]
    pub observations: Option<PathBuf>,
    /// Every photo's exterior-orientation σ as CSV.
    #[arg(long)]
    pub photos: Option<PathBuf>,
    /// Skip the per-photo EO standard deviations (saves the multi-right-hand-side solve).
    #[arg(long)]
    pub no_covariance: bool,
}

#[derive(Args, Debug)]
pub struct ResectArgs {
    /// Camera: fx,fy,cx,cy[,k1,k2,k3,p1,p2] in pixels.
    #[arg(long, value_delimiter = ',')]
    pub camera: Vec<f64>,
    /// Photo width (px).
    #[arg(long)]
    pub width: u32,
    /// Photo height (px).
    #[arg(long)]
    pub height: u32,
    /// Control CSV: col,row,X,Y,Z (pixel column and row, world), header line required;
    /// the older header x,y,X,Y,Z is read too (formats/adjust/README.md).
    #[arg(long)]
    pub points: PathBuf,
    /// A-priori σ of the image measurements (px).
    #[arg(long, default_value_t = 1.0)]
    pub sigma_px: f64,
    /// RANSAC inlier threshold (px).
    #[arg(long, default_value_t = 4.0)]
    pub threshold: f64,
    /// Least median of squares instead of RANSAC.
    #[arg(long)]
    pub lmeds: bool,
    /// JSON result path (stdout when absent).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

fn err<T>(m: impl Into<String>) -> Result<T, String> {
    Err(m.into())
}

fn text<E: std::fmt::Display>(e: E) -> String {
    e.to_string()
}

/// A row of `resect --points` (formats/adjust/README.md): pixel column and row, world
/// X, Y, Z.
#[derive(serde::Deserialize)]
struct ResectRow {
    col: f64,
    row: f64,
    x: f64,
    y: f64,
    z: f64,
}

/// `resect --points`, through the one CSV reader: columns `col,row,X,Y,Z`; the older
/// header `x,y,X,Y,Z` (pixel, then world: names that differ only in case) is read as it.
fn read_resect_points(path: &Path) -> Result<Vec<ResectRow>, String> {
    const COLUMNS: [&str; 5] = ["col", "row", "x", "y", "z"];
    let old_header = |header: &[&str]| {
        (header == ["x", "y", "X", "Y", "Z"]).then(|| COLUMNS.map(String::from).to_vec())
    };
    let layout = Layout {
        required: &COLUMNS,
        optional: &[],
        extra: Extra::Refuse,
    };
    let table = read_records_renamed::<ResectRow>(path, &layout, &old_header).map_err(text)?;
    Ok(table.rows.into_iter().map(|(_, r)| r).collect())
}

const F_NAMES: [(&str, &[&str]); 7] = [
    ("f", &["fx", "fy"]),
    ("pp", &["cx", "cy"]),
    ("k1", &["k1"]),
    ("k2", &["k2"]),
    ("k3", &["k3"]),
    ("p1", &["p1"]),
    ("p2", &["p2"]),
];

#[derive(serde::Deserialize)]
struct PlaneRow {
    point_id: u64,
    nx: f64,
    ny: f64,
    nz: f64,
    d: f64,
    weight: f64,
}

/// σ_z of a GCP whose height is unknown (m).
const UNKNOWN_HEIGHT_SIGMA_M: f64 = 100.0;

type Surveyed = (Vec<SurveyedPoint>, Vec<Measurement>, Vec<String>);

/// The surveyed points and their measurements from the command line's files, with notes
/// on what was assumed.
fn read_surveyed(a: &AdjustArgs) -> Result<Surveyed, String> {
    let mut points = Vec::new();
    let mut measurements = Vec::new();
    let mut notes = Vec::new();
    if let Some(p) = &a.control {
        points.extend(control_points::read_points(p).map_err(text)?);
    }
    if let Some(p) = &a.check {
        points.extend(
            control_points::read_points(p)
                .map_err(text)?
                .into_iter()
                .map(|q| SurveyedPoint {
                    kind: PointKind::Check,
                    ..q
                }),
        );
    }
    if let Some(p) = &a.measurements {
        measurements.extend(control_points::read_measurements(p).map_err(text)?);
    }
    if let Some(p) = &a.gcp {
        let mut o = GcpOptions {
            sigma_px: a.sigma_px,
            ..GcpOptions::default()
        };
        match a.gcp_sigma[..] {
            [] => {}
            [xy, z] if xy > 0.0 && z > 0.0 => (o.sigma_xy, o.sigma_z) = (xy, z),
            [xy, z] => {
                return err(format!(
                    "--gcp-sigma: σ must be positive (inf for an unknown axis), got {xy},{z}"
                ))
            }
            _ => return err("--gcp-sigma: expected two values, σ_xy,σ_z (m)"),
        }
        let f = read_odm_gcp(p, &o).map_err(text)?;
        // The adjustment needs metric, conformal coordinates (the model has no CRS to
        // convert into): a geographic file is refused with its UTM zone as a suggestion.
        let lon_lat = f.points.first().map(|g| (g.xyz[0], g.xyz[1]));
        f.crs
            .require_projected(lon_lat.filter(|_| f.crs.is_geographic()))
            .map_err(|e| format!("{}: {e}", p.display()))?;
        let mut gcps = f.points;
        if f.heights_all_zero && a.gcp_sigma.is_empty() {
            // ODM users write 0 where the height is unknown: such heights can only level
            // the block, so they enter with a σ that leaves everything else to the images.
            for g in &mut gcps {
                g.sigma_z = UNKNOWN_HEIGHT_SIGMA_M;
            }
            notes.push(format!(
                "{}: every GCP height is 0.0, taken as unknown (σ_z {UNKNOWN_HEIGHT_SIGMA_M} m: the heights only level the block); give --gcp-sigma to override",
                p.display()
            ));
        }
        points.extend(gcps);
        measurements.extend(f.measurements);
    }
    Ok((points, measurements, notes))
}

/// The block point of each surveyed row: a POINT3D_ID of the model (its track supplies
/// the measurements) or a point measured by name.
fn surveyed_points(
    block: &mut Block,
    rows: &[SurveyedPoint],
    measurements: &[Measurement],
) -> Result<Vec<PointId>, String> {
    let measured: std::collections::BTreeSet<&str> =
        measurements.iter().map(|m| m.id.as_str()).collect();
    let mut ids = Vec::with_capacity(rows.len());
    for r in rows {
        let by_id =
            r.id.parse::<u64>()
                .ok()
                .filter(|k| block.points.contains_key(k) && !measured.contains(r.id.as_str()));
        let id = match by_id {
            Some(k) => k,
            None if measured.contains(r.id.as_str()) => {
                match block.points.values().find(|p| p.name == r.id) {
                    Some(p) => p.id,
                    None => {
                        let k = block.next_point_id();
                        block.points.insert(
                            k,
                            ObjectPoint {
                                id: k,
                                name: r.id.clone(),
                                kind: PointKind::Tie,
                                position: Vector3::zeros(),
                                sigma: None,
                                color: [255, 0, 0],
                                observations: Vec::new(),
                            },
                        );
                        k
                    }
                }
            }
            None => {
                return err(format!(
                    "point '{}' is neither a POINT3D_ID of the model nor measured in --measurements/--gcp",
                    r.id
                ))
            }
        };
        let p = block.points.get_mut(&id).expect("found or inserted");
        if p.name.is_empty() {
            p.name = r.id.clone();
        }
        ids.push(id);
    }
    Ok(ids)
}

pub fn run_adjust(a: &AdjustArgs) -> Result<serde_json::Value, String> {
    let t0 = std::time::Instant::now();
    keep_freed_memory();
    let mut block = cloudcontrol::formats::colmap::read(&a.model).map_err(text)?;
    // COLMAP measurements carry no precision: the command line gives it.
    for p in block.points.values_mut() {
        for o in &mut p.observations {
            o.sigma_px = a.sigma_px;
        }
    }
    let (rows, measurements, notes) = read_surveyed(a)?;
    let ids = surveyed_points(&mut block, &rows, &measurements)?;
    let measurements_path = a
        .measurements
        .as_deref()
        .or(a.gcp.as_deref())
        .unwrap_or(Path::new("measurements"));
    control_points::add_measurements(&mut block, &measurements, measurements_path).map_err(text)?;
    let loss = match a.robust.as_str() {
        "huber" => Loss::Huber(2.0),
        "cauchy" => Loss::Cauchy(2.0),
        "none" => Loss::None,
        o => return err(format!("--robust: '{o}' is not one of huber, cauchy, none")),
    };
    let rejection = match a.rejection.as_str() {
        _ if a.reject <= 0.0 => Rejection::None,
        "none" => Rejection::None,
        "threshold" => Rejection::Threshold(a.reject),
        "snooping" if a.alpha > 0.0 && a.alpha < 0.5 => Rejection::data_snooping(a.alpha),
        "snooping" => return err(format!("--alpha: {} is not a level in (0, 0.5)", a.alpha)),
        o => {
            return err(format!(
                "--rejection: '{o}' is not one of snooping, threshold, none"
            ))
        }
    };
    let opts = AdjustOptions {
        loss,
        rejection,
        max_iterations: a.max_iterations,
        covariance: !a.no_covariance,
        lidar_datum_sigma_m: a.lidar_datum_sigma.map(|v| [v; 3]),
        ..Default::default()
    };
    // The model is in its own frame: the adjustment runs in a local frame at the
    // control's mean, where the georeferencing brings the model.
    let control: Vec<&SurveyedPoint> = rows
        .iter()
        .filter(|r| r.kind == PointKind::Control)
        .collect();
    let origin = if control.is_empty() {
        Vector3::from(block.origin)
    } else {
        control
            .iter()
            .map(|r| Vector3::from(r.xyz))
            .sum::<Vector3<f64>>()
            / control.len() as f64
    };
    let surveyed: Vec<SurveyedInput> = rows
        .iter()
        .zip(&ids)
        .map(|(r, &point)| SurveyedInput {
            point,
            position: Vector3::from(r.xyz) - origin,
            sigma: [r.sigma_xy, r.sigma_xy, r.sigma_z],
            kind: r.kind,
        })
        .collect();
    let georef = if control.is_empty() {
        for s in &surveyed {
            let p = block.points.get_mut(&s.point).expect("listed");
            (p.kind, p.position, p.sigma) = (s.kind, s.position, None);
        }
        None
    } else {
        let g = georeference(
            &mut block,
            &surveyed,
            &GeorefOptions {
                adjust: AdjustOptions {
                    covariance: false,
                    ..opts.clone()
                },
                alpha: a.alpha,
                ..GeorefOptions::default()
            },
        )
        .map_err(|e| format!("georeferencing the model onto the control: {e}"))?;
        block.origin = [origin.x, origin.y, origin.z];
        Some(g)
    };
    for cam in block.cameras.values_mut() {
        for n in &a.self_calibrate {
            let names = F_NAMES.iter().find(|(k, _)| k == n).ok_or_else(|| {
                format!("--self-calibrate: unknown parameter '{n}' (use f,pp,k1,k2,k3,p1,p2)")
            })?;
            cam.free_params
                .extend(names.1.iter().map(|s| s.to_string()));
        }
    }
    let mut planes = Vec::new();
    for path in &a.lidar_planes {
        let t = read_records::<PlaneRow>(
            path,
            &Layout {
                required: &["point_id", "nx", "ny", "nz", "d", "weight"],
                optional: &[],
                extra: Extra::Refuse,
            },
        )
        .map_err(text)?;
        for (_, r) in t.rows {
            let n = [r.nx, r.ny, r.nz];
            // d refers to world coordinates; shift it to the block-local frame.
            planes.push(PlaneConstraint {
                point: r.point_id,
                normal: n,
                d: r.d - Vector3::from(n).dot(&Vector3::from(block.origin)),
                weight: r.weight,
            });
        }
    }
    // The free network's rejections are the block's gross errors found already: the
    // adjustment starts without them and tests them again on its final solution.
    let earlier = georef
        .as_ref()
        .map_or(&[][..], |g| &g.free_network_rejected[..]);
    let rep = adjust_with_rejected(&mut block, &planes, None, &opts, earlier).map_err(text)?;
    let colmap_text = cloudcontrol::formats::colmap::WriteOptions {
        encoding: cloudcontrol::formats::colmap::Encoding::Text,
        layout: cloudcontrol::formats::colmap::Layout::Rigs,
    };
    cloudcontrol::formats::colmap::write(&a.out, &block, &colmap_text).map_err(text)?;
    let mut extra = serde_json::Map::new();
    extra.insert(
        "time_s".into(),
        serde_json::json!(t0.elapsed().as_secs_f64()),
    );
    extra.insert("adjust_time_s".into(), serde_json::json!(rep.time_s));
    extra.insert("origin".into(), serde_json::json!(block.origin));
    if let Some(g) = georef {
        extra.insert(
            "georeference".into(),
            serde_json::to_value(&g).map_err(text)?,
        );
    }
    if !notes.is_empty() {
        extra.insert("notes".into(), serde_json::json!(notes));
    }
    if let Some(path) = &a.observations {
        adjust_report::write_observations_csv(path, &rep, &block).map_err(text)?;
    }
    if let Some(path) = &a.photos {
        adjust_report::write_photos_csv(path, &rep).map_err(text)?;
    }
    let v = match &a.report {
        Some(path) => adjust_report::write_summary(path, &rep, extra).map_err(text)?,
        None => {
            let mut v = serde_json::to_value(adjust_report::summary(&rep)).map_err(text)?;
            if let Some(o) = v.as_object_mut() {
                o.extend(extra);
            }
            v
        }
    };
    Ok(v)
}

pub fn run_resect(a: &ResectArgs) -> Result<serde_json::Value, String> {
    let p = &a.camera;
    let d = match p.len() {
        4 => [0.0; 5],
        9 => [p[4], p[5], p[6], p[7], p[8]],
        n => return err(format!("--camera: expected 4 or 9 values, got {n}")),
    };
    let cam = Camera::Frame(FrameCamera {
        width: a.width,
        height: a.height,
        fx: p[0],
        fy: p[1],
        cx: p[2],
        cy: p[3],
        distortion: Brown::from_array(d),
    });
    let mut px = Vec::new();
    let mut xs = Vec::new();
    for r in read_resect_points(&a.points)? {
        px.push([r.col, r.row]);
        xs.push([r.x, r.y, r.z]);
    }
    // Resect in a local frame: projected coordinates of 10⁶ m would cost precision.
    let origin = xs
        .iter()
        .fold([0.0; 3], |s, x| [s[0] + x[0], s[1] + x[1], s[2] + x[2]])
        .map(|v| v / xs.len().max(1) as f64);
    let local: Vec<[f64; 3]> = xs
        .iter()
        .map(|x| [x[0] - origin[0], x[1] - origin[1], x[2] - origin[2]])
        .collect();
    let opts = ResectionOptions {
        threshold_px: a.threshold,
        lmeds: a.lmeds,
        ..Default::default()
    };
    let mut r = resect(&cam, &px, &local, a.sigma_px, &opts).map_err(|e| e.to_string())?;
    r.pose.center += Vector3::from(origin);
    let v = serde_json::to_value(&r).map_err(|e| e.to_string())?;
    if let Some(o) = &a.out {
        write_bytes_atomically(
            o,
            &serde_json::to_vec_pretty(&v).map_err(|e| e.to_string())?,
        )
        .map_err(|e| e.to_string())?;
    }
    Ok(v)
}

/// Prints the result JSON (the adjustment's without its list of weakest photos) or the error.
pub fn print_result(
    what: &str,
    r: Result<serde_json::Value, String>,
    quiet: bool,
) -> std::process::ExitCode {
    match r {
        Ok(v) => {
            if !quiet {
                let mut v = v;
                // The report's lists of names (up to 100 photos) are for the file.
                if let Some(p) = v.get_mut("photo_precision").and_then(|p| p.as_object_mut()) {
                    p.remove("weakest");
                }
                outln!("{}", serde_json::to_string_pretty(&v).expect("json"));
            }
            std::process::ExitCode::SUCCESS
        }
        Err(e) => crate::console::fail(what, e, crate::EXIT_FAILED),
    }
}

/// This process only adjusts: its working set is the solver's per-iteration systems and
/// residual records (12 MB at 50 photos, allocated afresh each iteration), which glibc
/// serves with mmap and hands back at once, so every iteration faulted its pages in again
/// (14 % of a 50-photo adjustment's samples in the kernel's page-fault path). Up to
/// glibc's largest mmap threshold (32 MiB) blocks come from the heap, and the heap is not
/// trimmed below 512 MiB free: 0.14 → 0.12 s at 50 photos. Not for the pipeline, whose
/// peak memory is bounded.
fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes glibc's allocation thresholds; called before any large
    // allocation of this command.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 512 << 20);
    }
}
