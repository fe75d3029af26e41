//! `cloudcontrol adjust` and `cloudcontrol resect`: argument parsing, CSV/COLMAP I/O and
//! reporting around `cloudcontrol::adjust`.

use clap::Args;
use cloudcontrol::adjust::{
    adjust, resect, AdjustOptions, Loss, PlaneConstraint, Rejection, ResectionOptions,
};
use cloudcontrol::block::{ObjectPoint, Observation, PointKind};
use cloudcontrol::formats::write_bytes_atomically;
use cloudcontrol::geometry::{Brown, Camera, FrameCamera, Similarity};
use nalgebra::Vector3;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
pub struct AdjustArgs {
    /// COLMAP text model folder (cameras.txt, images.txt, points3D.txt).
    #[arg(long)]
    pub model: PathBuf,
    /// Output folder for the adjusted COLMAP text model.
    #[arg(long)]
    pub out: PathBuf,
    /// Control points CSV: id,x,y,z,sigma_xy,sigma_z (id = POINT3D_ID or a name).
    #[arg(long)]
    pub control: Option<PathBuf>,
    /// Check points CSV, same columns (sigmas ignored).
    #[arg(long)]
    pub check: Option<PathBuf>,
    /// Image measurements of named control/check points: id,image_name,x,y (pixels).
    #[arg(long)]
    pub measurements: Option<PathBuf>,
    /// LiDAR planes CSV: point_id,nx,ny,nz,d,weight (world coordinates, weight in 1/m²).
    #[arg(long, num_args = 1..)]
    pub lidar_planes: Vec<PathBuf>,
    /// Interior parameters to self-calibrate: any of f,pp,k1,k2,k3,p1,p2.
    #[arg(long, value_delimiter = ',')]
    pub self_calibrate: Vec<String>,
    /// Robust loss.
    #[arg(long, default_value = "huber")]
    pub robust: String,
    /// Gross-error elimination threshold k (in σ0); 0 disables it.
    #[arg(long, default_value_t = 3.0)]
    pub reject: f64,
    /// Baarda data snooping (a-priori σ) instead of the k·σ0 threshold.
    #[arg(long)]
    pub snooping: bool,
    /// A-priori σ of image measurements (px).
    #[arg(long, default_value_t = 1.0)]
    pub sigma_px: f64,
    #[arg(long, default_value_t = 50)]
    pub max_iterations: usize,
    /// JSON report path.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Leave per-observation residuals out of the report.
    #[arg(long)]
    pub no_residuals: bool,
    /// Skip the per-photo EO standard deviations (saves the multi-right-hand-side solve).
    #[arg(long)]
    pub no_covariance: bool,
}

#[derive(Args, Debug)]
pub struct ResectArgs {
    /// Camera: fx,fy,cx,cy[,k1,k2,k3,p1,p2] in pixels.
    #[arg(long, value_delimiter = ',')]
    pub camera: Vec<f64>,
    #[arg(long)]
    pub width: u32,
    #[arg(long)]
    pub height: u32,
    /// Control CSV: x,y,X,Y,Z (pixel, world), header line required.
    #[arg(long)]
    pub points: PathBuf,
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

fn read_csv(path: &Path) -> Result<Vec<Vec<String>>, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut rows = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let l = line.trim();
        if i == 0 || l.is_empty() || l.starts_with('#') {
            continue;
        }
        rows.push(l.split(',').map(|s| s.trim().to_string()).collect());
    }
    Ok(rows)
}

fn num(s: &str, path: &Path, line: usize, what: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|_| {
        format!(
            "{}: row {line}: {what} '{s}' is not a number",
            path.display()
        )
    })?;
    if !v.is_finite() {
        return err(format!(
            "{}: row {line}: {what} is not finite",
            path.display()
        ));
    }
    Ok(v)
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

/// A control/check row: id, world position, σ (x, y, z).
type PointRow = (String, Vector3<f64>, [f64; 3]);

fn read_points(path: &Path) -> Result<Vec<PointRow>, String> {
    let mut out = Vec::new();
    for (i, r) in read_csv(path)?.iter().enumerate() {
        if r.len() < 4 {
            return err(format!(
                "{}: row {}: expected id,x,y,z,sigma_xy,sigma_z",
                path.display(),
                i + 1
            ));
        }
        let x = Vector3::new(
            num(&r[1], path, i + 1, "x")?,
            num(&r[2], path, i + 1, "y")?,
            num(&r[3], path, i + 1, "z")?,
        );
        let sxy = r
            .get(4)
            .map(|s| num(s, path, i + 1, "sigma_xy"))
            .transpose()?
            .unwrap_or(0.05);
        let sz = r
            .get(5)
            .map(|s| num(s, path, i + 1, "sigma_z"))
            .transpose()?
            .unwrap_or(0.05);
        out.push((r[0].clone(), x, [sxy, sxy, sz]));
    }
    Ok(out)
}

pub fn run_adjust(a: &AdjustArgs) -> Result<serde_json::Value, String> {
    let t0 = std::time::Instant::now();
    let mut block = cloudcontrol::formats::colmap::read(&a.model).map_err(|e| e.to_string())?;
    // COLMAP measurements carry no precision: the command line gives it.
    for p in block.points.values_mut() {
        for o in &mut p.observations {
            o.sigma_px = a.sigma_px;
        }
    }
    let by_name: BTreeMap<String, u32> = block
        .photos
        .values()
        .map(|p| (p.name.clone(), p.id))
        .collect();
    let mut meas: BTreeMap<String, Vec<Observation>> = BTreeMap::new();
    if let Some(mp) = &a.measurements {
        for (i, r) in read_csv(mp)?.iter().enumerate() {
            if r.len() < 4 {
                return err(format!(
                    "{}: row {}: expected id,image_name,x,y",
                    mp.display(),
                    i + 1
                ));
            }
            let photo = *by_name.get(&r[1]).ok_or_else(|| {
                format!("{}: row {}: unknown image '{}'", mp.display(), i + 1, r[1])
            })?;
            meas.entry(r[0].clone()).or_default().push(Observation {
                photo,
                pixel: [num(&r[2], mp, i + 1, "x")?, num(&r[3], mp, i + 1, "y")?],
                sigma_px: a.sigma_px,
                provenance: "measurements".into(),
            });
        }
    }
    let mut control = Vec::new();
    for (path, kind) in [
        (&a.control, PointKind::Control),
        (&a.check, PointKind::Check),
    ] {
        let Some(path) = path else { continue };
        for (id, x, s) in read_points(path)? {
            let pid = match id
                .parse::<u64>()
                .ok()
                .filter(|k| block.points.contains_key(k))
            {
                Some(k) => k,
                None => {
                    let obs = meas.remove(&id).ok_or_else(|| format!("{}: point '{id}' is neither a POINT3D_ID of the model nor measured in --measurements", path.display()))?;
                    let k = block.next_point_id();
                    block.points.insert(
                        k,
                        ObjectPoint {
                            id: k,
                            name: id.clone(),
                            kind: PointKind::Tie,
                            position: Vector3::zeros(),
                            sigma: None,
                            color: [255, 0, 0],
                            observations: obs,
                        },
                    );
                    k
                }
            };
            control.push((pid, id, kind, x, s));
        }
    }
    // The model is in its own frame: bring it onto the control with a similarity (the
    // adjustment then starts close to the solution), in a local frame at the control's mean.
    if control.iter().filter(|c| c.2 == PointKind::Control).count() >= 3 {
        let mut src = Vec::new();
        let mut dst = Vec::new();
        for (pid, name, kind, x, _) in &control {
            if *kind != PointKind::Control {
                continue;
            }
            let pt = &block.points[pid];
            let pos = if pt.position == Vector3::zeros() {
                let rays: Vec<_> = pt
                    .observations
                    .iter()
                    .map(|o| {
                        let ph = &block.photos[&o.photo];
                        (
                            ph.pose.center,
                            ph.pose.direction_to_world(
                                &block.cameras[&ph.camera]
                                    .model
                                    .unproject(o.pixel)
                                    .unwrap_or(Vector3::z()),
                            ),
                        )
                    })
                    .collect();
                intersect_rays(&rays).ok_or_else(|| {
                    format!("control point '{name}' has fewer than two usable rays")
                })?
            } else {
                pt.position
            };
            src.push(pos);
            dst.push(*x);
        }
        let origin = dst.iter().sum::<Vector3<f64>>() / dst.len() as f64;
        let dst_local: Vec<Vector3<f64>> = dst.iter().map(|x| x - origin).collect();
        let sim = Similarity::estimate(&src, &dst_local, None, true)
            .map_err(|e| format!("initial similarity onto the control: {e}"))?;
        for p in block.photos.values_mut() {
            p.pose = sim.apply_pose(&p.pose);
        }
        for p in block.points.values_mut() {
            p.position = sim.apply(&p.position);
        }
        block.origin = [origin.x, origin.y, origin.z];
    }
    let origin = Vector3::from(block.origin);
    for (pid, name, kind, x, s) in &control {
        let pt = block.points.get_mut(pid).expect("inserted");
        pt.kind = *kind;
        pt.position = x - origin;
        pt.sigma = (*kind == PointKind::Control).then_some(*s);
        if pt.name.is_empty() {
            pt.name = name.clone();
        }
    }
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
        for (i, r) in read_csv(path)?.iter().enumerate() {
            if r.len() < 6 {
                return err(format!(
                    "{}: row {}: expected point_id,nx,ny,nz,d,weight",
                    path.display(),
                    i + 1
                ));
            }
            let point: u64 = r[0].parse().map_err(|_| {
                format!("{}: row {}: bad point id '{}'", path.display(), i + 1, r[0])
            })?;
            let n = [
                num(&r[1], path, i + 1, "nx")?,
                num(&r[2], path, i + 1, "ny")?,
                num(&r[3], path, i + 1, "nz")?,
            ];
            // d refers to world coordinates; shift it to the block-local frame.
            let d = num(&r[4], path, i + 1, "d")? - Vector3::from(n).dot(&origin);
            planes.push(PlaneConstraint {
                point,
                normal: n,
                d,
                weight: num(&r[5], path, i + 1, "weight")?,
            });
        }
    }
    let loss = match a.robust.as_str() {
        "huber" => Loss::Huber(2.0),
        "cauchy" => Loss::Cauchy(2.0),
        "none" => Loss::None,
        o => return err(format!("--robust: '{o}' is not one of huber, cauchy, none")),
    };
    let rejection = if a.reject <= 0.0 {
        Rejection::None
    } else if a.snooping {
        Rejection::DataSnooping(a.reject)
    } else {
        Rejection::Threshold(a.reject)
    };
    let opts = AdjustOptions {
        loss,
        rejection,
        max_iterations: a.max_iterations,
        covariance: !a.no_covariance,
        ..Default::default()
    };
    let mut rep = adjust(&mut block, &planes, None, &opts).map_err(|e| e.to_string())?;
    let text = cloudcontrol::formats::colmap::WriteOptions {
        encoding: cloudcontrol::formats::colmap::Encoding::Text,
        layout: cloudcontrol::formats::colmap::Layout::Rigs,
    };
    cloudcontrol::formats::colmap::write(&a.out, &block, &text).map_err(|e| e.to_string())?;
    if a.no_residuals {
        rep.residuals.clear();
    }
    let mut v = serde_json::to_value(&rep).map_err(|e| e.to_string())?;
    v["time_s"] = serde_json::json!(t0.elapsed().as_secs_f64());
    v["adjust_time_s"] = serde_json::json!(rep.time_s);
    v["origin"] = serde_json::json!(block.origin);
    if let Some(r) = &a.report {
        let bytes = serde_json::to_vec_pretty(&v).map_err(|e| e.to_string())?;
        write_bytes_atomically(r, &bytes).map_err(|e| e.to_string())?;
    }
    Ok(v)
}

fn intersect_rays(rays: &[(Vector3<f64>, Vector3<f64>)]) -> Option<Vector3<f64>> {
    if rays.len() < 2 {
        return None;
    }
    let mut a = nalgebra::Matrix3::zeros();
    let mut b = Vector3::zeros();
    for (c, d) in rays {
        let d = d.normalize();
        let p = nalgebra::Matrix3::identity() - d * d.transpose();
        a += p;
        b += p * c;
    }
    a.try_inverse().map(|m| m * b)
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
    for (i, r) in read_csv(&a.points)?.iter().enumerate() {
        if r.len() < 5 {
            return err(format!(
                "{}: row {}: expected x,y,X,Y,Z",
                a.points.display(),
                i + 1
            ));
        }
        let v: Vec<f64> = (0..5)
            .map(|k| num(&r[k], &a.points, i + 1, "value"))
            .collect::<Result<_, _>>()?;
        px.push([v[0], v[1]]);
        xs.push([v[2], v[3], v[4]]);
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

/// Prints the result JSON (without the bulky per-observation arrays) or the error.
pub fn print_result(
    what: &str,
    r: Result<serde_json::Value, String>,
    quiet: bool,
) -> std::process::ExitCode {
    match r {
        Ok(v) => {
            if !quiet {
                let mut v = v;
                if let Some(o) = v.as_object_mut() {
                    o.remove("residuals");
                    o.remove("photo_precision");
                }
                println!("{}", serde_json::to_string_pretty(&v).expect("json"));
            }
            std::process::ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("cloudcontrol {what}: {e}");
            std::process::ExitCode::from(1)
        }
    }
}
