//! Fiducial interior orientation of film scans (seed 003): templates built from the
//! mark shapes of a camera definition (primitives, composites or image templates), a wide
//! search for two opposite marks, the remaining marks predicted through the similarity the
//! two define, each mark refined by NCC + LSM, and the affine (or projective) transform
//! pixel → fiducial mm estimated with residuals in µm. The scan orientation (rotated by
//! 90°/180°/270° or mirrored) is found, not guessed: all eight orientations of the
//! square's symmetry group are measured and compared ([`orientation`]), and a decision
//! below the confidence margin is an error naming the scan. Only windows around the
//! predicted marks (and the data strip) are read, each with its own pyramid ([`patches`]):
//! a scan file is never held whole. An oriented scan is resampled into a fiducial-frame
//! image with a plain frame camera ([`frame_image`]).

mod camera;
pub mod frame_image;
mod marks;
mod orientation;
mod patches;
mod shape;
mod solve;
mod wide;

pub use camera::{
    check_scan_pixel_um, scan_pixel_um_from_dpi, CameraDefinition, DataStrip, DistortionDef,
    FiducialDef, MAX_FIDUCIALS, MAX_FORMAT_MM, MAX_MARK_FRACTION, MAX_TEMPLATE_PIXELS,
    SCAN_PIXEL_UM,
};
pub use frame_image::{
    mean_scan_pixel_mm, resample_scan, write_frame_image, FiducialFrame, FrameImageReport,
};
pub use orientation::{
    interior_orientation_epoch, majority_of_votes, majority_orientation, OrientationScore,
    ScanOrientation, ORIENTATION_MARGIN_CAP, ORIENTATION_MIN_MARGIN,
};
pub use shape::{render_template, FiducialShape, ShapeKind};

use super::matcher::MatchOptions;
use super::scan_windows::ScanWindows;
use super::{GreyImage, MatchingError, Result};
use crate::geometry::{InteriorOrientation, InteriorTransformKind};
use nalgebra::{Matrix2, Vector2};
use orientation::Hypothesis;
use patches::Patches;
use rayon::prelude::*;
use serde::Serialize;
use std::path::Path;

#[derive(Debug, Clone)]
pub struct IoOptions {
    /// Scan pixel size (mm), when the scan's is known (e.g. an epoch's `scan_pixel_um` or
    /// `scan_dpi`); None estimates it from the fiducial marks, starting the search from
    /// the film format over the scan size.
    pub pixel_mm: Option<f64>,
    /// The scan orientation, when known (e.g. fixed for an epoch): used whatever the
    /// marks say (the others are still measured, for the reported margin). None: the
    /// marks decide, or the result is [`MatchingError::OrientationUndecided`].
    pub orientation: Option<ScanOrientation>,
    /// The orientation taken when the marks cannot decide (e.g. the majority of an
    /// epoch's decided scans, [`majority_orientation`]), instead of the
    /// [`MatchingError::OrientationUndecided`] error; a decided scan keeps its own.
    pub fallback_orientation: Option<ScanOrientation>,
    pub kind: InteriorTransformKind,
    /// Half-size of the wide search for the first two marks (mm).
    pub search_mm: f64,
    /// Marks with a residual above this are rejected and the transform re-estimated.
    pub max_residual_um: f64,
    /// Margin (cost of the second-best orientation over the best) below which the scan
    /// orientation is undecided; [`ORIENTATION_MIN_MARGIN`] by default.
    pub min_orientation_margin: f64,
    pub matching: MatchOptions,
}

impl Default for IoOptions {
    fn default() -> Self {
        // Shift-only LSM: the template is rendered in the scan's predicted geometry, and
        // the rotation of a circular mark is not observable (singular normal equations).
        let matching = MatchOptions {
            lsm: super::LsmOptions {
                affine: false,
                ..super::LsmOptions::default()
            },
            ncc_threshold: 0.6,
            absolute: true,
            agreement_px: 1.0,
            ..MatchOptions::default()
        };
        Self {
            pixel_mm: None,
            orientation: None,
            fallback_orientation: None,
            kind: InteriorTransformKind::Affine,
            search_mm: 10.0,
            max_residual_um: 0.0,
            min_orientation_margin: ORIENTATION_MIN_MARGIN,
            matching,
        }
    }
}

/// One fiducial mark's measurement.
#[derive(Debug, Clone, Serialize)]
pub struct MarkResult {
    pub id: String,
    pub x: f64,
    pub y: f64,
    pub x_mm: f64,
    pub y_mm: f64,
    /// Used in the transform.
    pub used: bool,
    pub ncc: f64,
    pub sigma_px: f64,
    /// Calibrated minus transformed, µm (NaN when not used).
    pub residual_um: [f64; 2],
    pub residual_norm_um: f64,
    pub reason: Option<String>,
}

#[derive(Debug, Clone, Serialize)]
pub struct IoResult {
    pub camera: String,
    pub orientation: ScanOrientation,
    /// The marks alone do not decide the orientation (margin below
    /// [`IoOptions::min_orientation_margin`]); only with a given or fallback orientation,
    /// since an undecided search is otherwise an error.
    pub orientation_ambiguous: bool,
    /// Cost of the best other orientation over the chosen one's
    /// ([`OrientationScore::cost`]); below 1 when a given orientation fits worse than
    /// another. [`ORIENTATION_MARGIN_CAP`] when no other orientation measured enough marks.
    pub orientation_margin: f64,
    /// `"given"`, `"decided by the marks"`, `"fallback …"` ([`IoOptions::fallback_orientation`])
    /// or `"epoch majority (…)"`.
    pub orientation_source: String,
    /// Every measured orientation hypothesis, best first.
    pub orientation_hypotheses: Vec<OrientationScore>,
    /// Mean pixel size of the fitted pixel → mm transform (what the fiducials measure).
    pub pixel_mm: f64,
    /// Scan pixel size (µm): the given one, else the estimate from the fiducial marks.
    pub pixel_um: f64,
    /// `"given"`, or `"estimated from …"` saying how.
    pub pixel_source: String,
    pub transform: InteriorOrientation,
    pub marks: Vec<MarkResult>,
    pub rmse_um: f64,
    /// What a user should know (a given orientation that fits worse than another, a given
    /// pixel size the marks contradict), in words; also logged.
    pub warnings: Vec<String>,
    /// Pixels of the scan read: the windows around the marks and the data strip, a few
    /// per cent of a scan. Not serialised, so that io.json depends on the scan only.
    #[serde(skip)]
    pub scan_pixels_read: u64,
}

/// Fiducial interior orientation of a scan file, read by windows around the marks
/// ([`ScanWindows`]).
pub fn interior_orientation_file(
    cam: &CameraDefinition,
    scan: &Path,
    opts: &IoOptions,
) -> Result<IoResult> {
    let windows = ScanWindows::open(scan)?;
    orient(cam, windows, &scan.display().to_string(), opts)
}

/// Fiducial interior orientation of a scan in memory; `name` labels errors.
pub fn interior_orientation(
    cam: &CameraDefinition,
    img: &GreyImage,
    name: &str,
    opts: &IoOptions,
) -> Result<IoResult> {
    orient(cam, ScanWindows::held(img), name, opts)
}

/// The interior orientation of a scan read by windows.
fn orient(
    cam: &CameraDefinition,
    scan: ScanWindows,
    name: &str,
    opts: &IoOptions,
) -> Result<IoResult> {
    cam.validate().map_err(MatchingError::Camera)?;
    let mut scan = Patches::new(scan);
    let (width, height) = scan.size();
    if let Some(f) = cam
        .fiducials
        .iter()
        .find(|f| f.shape.kind == ShapeKind::Template && f.shape.image.is_none())
    {
        return Err(MatchingError::Camera(format!(
            "{}: fiducial {}: template image {:?} not read (CameraDefinition::load reads it \
             relative to the camera file)",
            cam.name,
            f.id,
            f.shape.file.as_deref().unwrap_or_default()
        )));
    }
    let orr = |m: String| MatchingError::Orientation {
        scan: name.to_string(),
        message: m,
    };
    // The search needs a scale: the given pixel size, else the film format over the scan
    // size (a scan with margins is larger: the search tolerates 0.8–1.25 of it).
    let s = match opts.pixel_mm {
        Some(s) => {
            check_scan_pixel_um(s * 1000.0).map_err(orr)?;
            s
        }
        None => cam.format_mm[0].max(cam.format_mm[1]) / width.min(height) as f64,
    };
    let margin_mm = 0.5
        * cam
            .fiducials
            .iter()
            .map(|f| f.shape.extent_mm())
            .fold(0.0, f64::max);
    // Templates are drawn at the scan's pixel (within the 0.8–1.25 of it the search
    // accepts): a mark large for that pixel is refused here, not drawn.
    for f in &cam.fiducials {
        let px = f.shape.template_pixels_bound(0.8 * s, margin_mm);
        if px.is_nan() || px > MAX_TEMPLATE_PIXELS as f64 {
            return Err(orr(format!(
                "camera {:?}, fiducial {}: its template at {:.4} mm a scan pixel would have \
                 {px:.0} pixels (a mark reaching {:.2} mm, drawn with a {margin_mm:.2} mm \
                 border), over {MAX_TEMPLATE_PIXELS} (fiducial::MAX_TEMPLATE_PIXELS): a \
                 mark too large for this scan's pixel size",
                cam.name,
                f.id,
                s,
                f.shape.extent_mm()
            )));
        }
    }
    let centre = Vector2::new(width as f64 / 2.0, height as f64 / 2.0);
    // Two marks far apart carry the wide search; when one of them is missing or
    // damaged, the next pair (by decreasing distance) takes over.
    let n = cam.fiducials.len();
    let mut pairs = Vec::new();
    for i in 0..n {
        for j in i + 1..n {
            let f = (&cam.fiducials[i], &cam.fiducials[j]);
            pairs.push((i, j, (f.0.x_mm - f.1.x_mm).hypot(f.0.y_mm - f.1.y_mm)));
        }
    }
    pairs.sort_by(|a, b| b.2.total_cmp(&a.2).then(a.0.cmp(&b.0)).then(a.1.cmp(&b.1)));
    let dmax = pairs[0].2;
    pairs.retain(|p| p.2 >= 0.6 * dmax);
    let (ia, ib) = (pairs[0].0, pairs[0].1);
    let mut wide = wide::Wide::new(s, centre, margin_mm, opts);
    wide.prefetch(&mut scan, cam, (ia, ib))?;
    let (_, dof) = solve::need_and_dof(opts.kind);
    let max_res = if opts.max_residual_um > 0.0 {
        opts.max_residual_um
    } else {
        // Three times a good measurement (0.2 px), at least 10 µm.
        (3.0 * 0.2 * s * 1000.0).max(10.0) * 1.5
    };
    // Every orientation is measured, also with one given: the margin then says whether
    // the marks agree with it.
    let mut given_failed: Option<String> = None;
    // The two marks of every orientation first: their wide windows are then dropped
    // before the marks' windows are read.
    let mut found = Vec::new();
    for o in ScanOrientation::all() {
        let mut two = None;
        for &(i, j, _) in &pairs {
            let (fa, fb) = (&cam.fiducials[i], &cam.fiducials[j]);
            let Some(pa) = wide.find(&mut scan, fa, o)? else {
                continue;
            };
            if let Some(pb) = wide.find(&mut scan, fb, o)? {
                two = Some((fa, fb, pa, pb));
                break;
            }
        }
        found.push((o, two));
    }
    scan.drop_unsmoothed();
    let mut plans = Vec::new();
    for (o, two) in found {
        let is_given = opts.orientation == Some(o);
        let Some((fa, fb, pa, pb)) = two else {
            if is_given {
                given_failed = Some(format!(
                    "no two opposite fiducial marks (first tried: {} and {}) found in a ±{} mm \
                     search in the given orientation {o} (pixel size {s:.4} mm; wrong camera \
                     definition or pixel size?)",
                    cam.fiducials[ia].id, cam.fiducials[ib].id, opts.search_mm
                ));
            }
            continue;
        };
        // Similarity pixel → mm from the two marks; it fixes the orientation, scale and
        // shift, and predicts the others to well within their small search windows.
        let dp = Vector2::new(pb.0 - pa.0, pb.1 - pa.1);
        let dm = Vector2::new(fb.x_mm - fa.x_mm, fb.y_mm - fa.y_mm);
        let lin0 = o.linear(s);
        let scale = dm.norm() / dp.norm();
        if !(0.8..1.25).contains(&(scale / s)) {
            continue;
        }
        let ang_p = (lin0 * dp).y.atan2((lin0 * dp).x);
        let ang_m = dm.y.atan2(dm.x);
        let dang = ang_m - ang_p;
        let rot = Matrix2::new(dang.cos(), -dang.sin(), dang.sin(), dang.cos());
        let lin = rot * lin0 * (scale / s);
        let Some(inv) = lin.try_inverse() else {
            continue;
        };
        let origin_px = Vector2::new(pa.0, pa.1) - inv * Vector2::new(fa.x_mm, fa.y_mm);
        let predict = |f: &FiducialDef| origin_px + inv * Vector2::new(f.x_mm, f.y_mm);
        let plan = marks::plan(cam, &mut scan, &|_| lin, &predict, s, margin_mm, opts)?;
        plans.push((o, plan));
    }
    // Every window is read by now: the hypotheses are measured in parallel, each search
    // in a window read before (the results of one thread).
    let measured: Vec<(ScanOrientation, Vec<MarkResult>)> = {
        let ready = scan.ready();
        plans
            .into_par_iter()
            .map(|(o, plan)| (o, plan.measure(&ready, &opts.matching)))
            .collect()
    };
    let mut hyps: Vec<Hypothesis> = Vec::new();
    let mut fit_errors: Vec<(usize, String)> = Vec::new();
    for (o, mut marks) in measured {
        let is_given = opts.orientation == Some(o);
        match solve::fit(&mut marks, opts.kind, max_res, name) {
            Ok(fit) => {
                let score = orientation::score(
                    o,
                    &marks,
                    fit.ss,
                    fit.rmse_plain,
                    dof,
                    max_res,
                    0.02 * s * 1000.0,
                );
                hyps.push(Hypothesis {
                    orientation: o,
                    marks,
                    io: fit.io,
                    rmse_plain: fit.rmse_plain,
                    score,
                });
            }
            Err(e) => {
                let used = marks.iter().filter(|m| m.used).count();
                if is_given {
                    given_failed = Some(e.clone());
                }
                fit_errors.push((used, e));
            }
        }
    }
    if let Some(e) = given_failed {
        return Err(orr(e));
    }
    if hyps.is_empty() {
        fit_errors.sort_by_key(|e| std::cmp::Reverse(e.0));
        return Err(orr(match fit_errors.into_iter().next() {
            Some((_, e)) => e,
            None => format!(
                "no two opposite fiducial marks (first tried: {} and {}) found in a ±{} mm \
                 search in any scan orientation (pixel size {:.4} mm; wrong camera definition \
                 or pixel size?)",
                cam.fiducials[ia].id, cam.fiducials[ib].id, opts.search_mm, s
            ),
        }));
    }
    let strip_stds = match &cam.data_strip {
        Some(strip) => hyps
            .iter()
            .map(|h| scan.strip_std(&h.io, strip))
            .collect::<Result<Vec<_>>>()?,
        None => Vec::new(),
    };
    let best_margin = orientation::rank(&mut hyps, &strip_stds);
    let scores: Vec<OrientationScore> = hyps.iter().map(|h| h.score.clone()).collect();
    let describe = |k: usize| {
        let h = &scores[k];
        format!(
            "{}: {} marks, geometry {:.2} µm, unexplained {:.3}{}",
            h.orientation,
            h.marks_used,
            h.geometry_um,
            h.unexplained,
            h.strip_std
                .map(|v| format!(", data strip σ {v:.1}"))
                .unwrap_or_default()
        )
    };
    let position = |o: ScanOrientation| hyps.iter().position(|h| h.orientation == o);
    let (chosen, source) = if let Some(o) = opts.orientation {
        let k = position(o).expect("the given orientation was measured");
        (k, "given".to_string())
    } else if best_margin >= opts.min_orientation_margin {
        (0, "decided by the marks".to_string())
    } else if let Some((o, k)) = opts
        .fallback_orientation
        .and_then(|o| Some((o, position(o)?)))
    {
        (
            k,
            format!(
                "fallback {o}: the marks do not decide (margin {best_margin:.2} between {} and {})",
                hyps[0].orientation, hyps[1].orientation
            ),
        )
    } else {
        let detail = format!("{}; {}", describe(0), describe(1));
        return Err(MatchingError::OrientationUndecided {
            scan: name.to_string(),
            best: hyps[0].orientation,
            second: hyps[1].orientation,
            margin: best_margin,
            required: opts.min_orientation_margin,
            detail,
        });
    };
    let other = hyps
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != chosen)
        .map(|(_, h)| h.score.cost)
        .fold(f64::INFINITY, f64::min);
    let margin = (other / hyps[chosen].score.cost).min(ORIENTATION_MARGIN_CAP);
    // What a user should know about this scan's orientation, kept with the result (the
    // run's report lists it) as well as logged.
    let mut warnings = Vec::new();
    if margin < 1.0 {
        let w = format!(
            "scan orientation {} ({source}) fits the fiducial marks {:.2}× worse than {}",
            hyps[chosen].orientation,
            1.0 / margin,
            hyps[0].orientation
        );
        tracing::warn!(scan = name, "{w}");
        warnings.push(w);
    }
    let mut h = hyps.swap_remove(chosen);
    // The templates were drawn through the similarity of two marks; drawn again through
    // the fitted transform (scale difference and shear of the scanner included), an
    // asymmetric mark (a real crop) no longer pulls its match off by a fraction of the
    // geometric mismatch.
    let io0 = h.io.clone();
    let plan = marks::plan(
        cam,
        &mut scan,
        &|f| {
            let (_, jac) = io0.mm_to_pixel_with_jacobian(Vector2::new(f.x_mm, f.y_mm));
            jac.try_inverse().unwrap_or_else(|| o_lin(&io0))
        },
        &|f| io0.mm_to_pixel(Vector2::new(f.x_mm, f.y_mm)),
        s,
        margin_mm,
        opts,
    )?;
    let mut marks = plan.measure(&scan.ready(), &opts.matching);
    tracing::debug!(
        scan = name,
        pixels_read = scan.pixels_read(),
        pixels = width * height,
        "fiducial windows"
    );
    if let Ok(fit) = solve::fit(&mut marks, opts.kind, max_res, name) {
        if marks.iter().filter(|m| m.used).count() >= h.score.marks_used {
            h.marks = marks;
            h.io = fit.io;
            h.rmse_plain = fit.rmse_plain;
        }
    }
    tracing::debug!(scan = name, rmse_um = h.rmse_plain, orientation = %h.orientation, margin, "interior orientation");
    let io = h.io;
    let measured_um = io.mean_pixel_size_mm() * 1000.0;
    let (pixel_um, pixel_source) = match opts.pixel_mm {
        Some(given) => {
            let given_um = given * 1000.0;
            // Film and scanner scale stay well within 1 %; more is a wrong value.
            if (measured_um / given_um - 1.0).abs() > 0.02 {
                let w = format!(
                    "given scan pixel size {given_um:.3} µm, but the fiducial marks measure \
                     {measured_um:.3} µm"
                );
                tracing::warn!(scan = name, "{w}");
                warnings.push(w);
            }
            (given_um, "given".to_string())
        }
        None => (
            measured_um,
            format!(
                "estimated from the fiducial marks (mean scale of the {:?} pixel → mm \
                 transform; the search started from format / scan size = {:.2} µm)",
                opts.kind,
                s * 1000.0
            ),
        ),
    };
    Ok(IoResult {
        camera: cam.name.clone(),
        orientation: h.orientation,
        orientation_ambiguous: margin < opts.min_orientation_margin,
        orientation_margin: margin,
        orientation_source: source,
        orientation_hypotheses: scores,
        pixel_mm: io.mean_pixel_size_mm(),
        pixel_um,
        pixel_source,
        transform: io,
        marks: h.marks,
        rmse_um: h.rmse_plain,
        warnings,
        scan_pixels_read: scan.pixels_read(),
    })
}

/// Linear part (pixel → mm) of a transform.
fn o_lin(io: &InteriorOrientation) -> Matrix2<f64> {
    io.pixel_to_mm.fixed_view::<2, 2>(0, 0).into_owned()
}

impl IoResult {
    /// The io.json document: `marks` (id, pixel x/y, residual µm, …), `transform`
    /// (pixel → mm with its type, row-major 3×3 homogeneous matrices) and `rmse_um`.
    pub fn to_json(&self) -> serde_json::Value {
        let m = &self.transform.pixel_to_mm;
        let inv = m.try_inverse().unwrap_or_else(nalgebra::Matrix3::identity);
        let rows = |a: &nalgebra::Matrix3<f64>| -> Vec<f64> {
            (0..3)
                .flat_map(|r| (0..3).map(move |c| a[(r, c)]))
                .collect()
        };
        let num = |v: f64| {
            if v.is_finite() {
                serde_json::json!(v)
            } else {
                serde_json::Value::Null
            }
        };
        serde_json::json!({
            "camera": self.camera,
            "orientation": self.orientation,
            "orientation_ambiguous": self.orientation_ambiguous,
            "orientation_margin": self.orientation_margin,
            "orientation_source": self.orientation_source,
            "orientation_hypotheses": self.orientation_hypotheses.iter().map(|h| serde_json::json!({
                "orientation": h.orientation,
                "marks_used": h.marks_used,
                "rmse_um": num(h.rmse_um),
                "geometry_um": num(h.geometry_um),
                "unexplained": num(h.unexplained),
                "strip_std": h.strip_std.map(num),
                "cost": num(h.cost),
            })).collect::<Vec<_>>(),
            "pixel_mm": self.pixel_mm,
            "pixel_um": self.pixel_um,
            "pixel_source": self.pixel_source,
            "rmse_um": self.rmse_um,
            "warnings": self.warnings,
            "transform": {
                "type": self.transform.kind,
                "pixel_to_mm": rows(m),
                "mm_to_pixel": rows(&inv),
            },
            "marks": self.marks.iter().map(|k| serde_json::json!({
                "id": k.id,
                "x": k.x,
                "y": k.y,
                "x_mm": k.x_mm,
                "y_mm": k.y_mm,
                "used": k.used,
                "ncc": k.ncc,
                "sigma_px": num(k.sigma_px),
                "residual_um": [num(k.residual_um[0]), num(k.residual_um[1])],
                "residual_norm_um": num(k.residual_norm_um),
                "reason": k.reason,
            })).collect::<Vec<_>>(),
        })
    }
}
