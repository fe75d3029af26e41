//! Fiducial interior orientation of film scans (seed 003): templates built from the
//! mark primitives of a camera definition, a wide search for two opposite marks, the
//! remaining marks predicted through the similarity the two define, each mark refined
//! by NCC + LSM, and the affine (or projective) transform pixel → fiducial mm estimated
//! with residuals in µm. Scans rotated by 90°/180°/270° or mirrored are handled by
//! testing the eight orientations of the square's symmetry group.

use super::matcher::{match_template, MatchOptions};
use super::ncc::Window;
use super::{GreyImage, MatchingError, Pyramid, Result};
use crate::geometry::{InteriorOrientation, InteriorTransformKind};
use nalgebra::{Matrix2, Vector2};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::Path;

/// Camera definition (formats/cameras/*.json, schema in formats/cameras/README.md).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CameraDefinition {
    pub name: String,
    pub source: String,
    pub focal_mm: f64,
    pub principal_point_mm: [f64; 2],
    pub format_mm: [f64; 2],
    #[serde(default)]
    pub distortion: DistortionDef,
    pub fiducials: Vec<FiducialDef>,
}

#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct DistortionDef {
    #[serde(default)]
    pub k1: f64,
    #[serde(default)]
    pub k2: f64,
    #[serde(default)]
    pub k3: f64,
    #[serde(default)]
    pub p1: f64,
    #[serde(default)]
    pub p2: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FiducialDef {
    pub id: String,
    /// Calibrated position in the fiducial system (x right, y up, mm).
    pub x_mm: f64,
    pub y_mm: f64,
    pub shape: FiducialShape,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ShapeKind {
    /// Two bars of length `size_mm` and width `line_mm`.
    Cross,
    /// Filled disc of diameter `size_mm`.
    Circle,
    /// Annulus of outer diameter `size_mm` and width `line_mm`.
    Ring,
    /// Small filled disc of diameter `size_mm`.
    Dot,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FiducialShape {
    #[serde(rename = "type")]
    pub kind: ShapeKind,
    pub size_mm: f64,
    #[serde(default)]
    pub line_mm: f64,
    /// Optional central dot (diameter, mm) inside a cross, ring or circle outline.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dot_mm: Option<f64>,
}

impl FiducialShape {
    /// Whether a point (mm, relative to the mark centre) is on the mark.
    pub fn covers(&self, x: f64, y: f64) -> bool {
        let r = (x * x + y * y).sqrt();
        if let Some(d) = self.dot_mm {
            if r <= d / 2.0 {
                return true;
            }
        }
        let (s, l) = (self.size_mm / 2.0, self.line_mm.max(0.0) / 2.0);
        match self.kind {
            ShapeKind::Cross => (x.abs() <= s && y.abs() <= l) || (y.abs() <= s && x.abs() <= l),
            ShapeKind::Circle | ShapeKind::Dot => r <= s,
            ShapeKind::Ring => r <= s && r >= s - self.line_mm,
        }
    }

    /// Radius (mm) of the circle that contains the mark.
    pub fn extent_mm(&self) -> f64 {
        match self.kind {
            ShapeKind::Cross => (self.size_mm / 2.0).hypot(self.line_mm / 2.0),
            _ => self.size_mm / 2.0,
        }
    }

    fn key(&self) -> String {
        format!(
            "{:?}/{}/{}/{:?}",
            self.kind, self.size_mm, self.line_mm, self.dot_mm
        )
    }
}

impl CameraDefinition {
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| MatchingError::Camera(format!("{}: {e}", path.display())))?;
        let def: Self = serde_json::from_str(&text)
            .map_err(|e| MatchingError::Camera(format!("{}: {e}", path.display())))?;
        def.validate()
            .map_err(|e| MatchingError::Camera(format!("{}: {e}", path.display())))?;
        Ok(def)
    }

    pub fn validate(&self) -> std::result::Result<(), String> {
        if !(self.focal_mm > 0.0 && self.focal_mm.is_finite()) {
            return Err(format!(
                "focal_mm {} is not a positive length",
                self.focal_mm
            ));
        }
        let [fw, fh] = self.format_mm;
        if !(fw.is_finite() && fh.is_finite() && fw > 0.0 && fh > 0.0) || fw.max(fh) > MAX_FORMAT_MM
        {
            return Err(format!(
                "format_mm [{fw}, {fh}] is not a film format (positive, at most \
                 {MAX_FORMAT_MM} mm a side)"
            ));
        }
        // A mark is a small part of the frame; templates and searches are sized from it.
        let max_mark = MAX_MARK_FRACTION * fw.min(fh);
        if self.fiducials.len() < 3 {
            return Err(format!(
                "{} fiducials defined; interior orientation needs at least 3",
                self.fiducials.len()
            ));
        }
        for f in &self.fiducials {
            if !(f.x_mm.is_finite() && f.y_mm.is_finite()) {
                return Err(format!("fiducial {}: position is not finite", f.id));
            }
            if f.shape.size_mm.is_nan() || f.shape.size_mm <= 0.0 {
                return Err(format!("fiducial {}: size_mm must be positive", f.id));
            }
            let sizes = [
                ("size_mm", f.shape.size_mm),
                ("line_mm", f.shape.line_mm),
                ("dot_mm", f.shape.dot_mm.unwrap_or(0.0)),
            ];
            for (name, v) in sizes {
                if !(v.is_finite() && v >= 0.0 && v <= max_mark) {
                    return Err(format!(
                        "fiducial {}: {name} {v} is not a mark size: at most {max_mark} mm \
                         ({} of the {} mm film side)",
                        f.id,
                        MAX_MARK_FRACTION,
                        fw.min(fh)
                    ));
                }
            }
            if matches!(f.shape.kind, ShapeKind::Cross | ShapeKind::Ring)
                && (f.shape.line_mm.is_nan() || f.shape.line_mm <= 0.0)
            {
                return Err(format!(
                    "fiducial {}: {:?} needs line_mm > 0",
                    f.id, f.shape.kind
                ));
            }
        }
        Ok(())
    }
}

/// Largest film format side accepted (mm): aerial film is at most 9 × 18 in (229 × 457 mm).
pub const MAX_FORMAT_MM: f64 = 500.0;

/// Largest fiducial mark dimension (`size_mm`, `line_mm`, `dot_mm`) as a fraction of the
/// shorter film side (23 mm on 230 mm film; real marks are 1–20 mm).
pub const MAX_MARK_FRACTION: f64 = 0.1;

/// How the scan lies relative to the fiducial system: the ideal map pixel → mm
/// (x = col·s, y = −row·s about the centre) is rotated counter-clockwise by
/// `rotation_deg` and, when `mirrored`, reflected in the y axis first.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ScanOrientation {
    pub rotation_deg: u16,
    pub mirrored: bool,
}

impl ScanOrientation {
    pub fn all() -> Vec<Self> {
        let mut v = Vec::new();
        for mirrored in [false, true] {
            for rotation_deg in [0, 90, 180, 270] {
                v.push(Self {
                    rotation_deg,
                    mirrored,
                });
            }
        }
        v
    }

    /// Linear map from a pixel offset (col, row) to an mm offset, for pixel size `s`.
    pub fn linear(&self, s: f64) -> Matrix2<f64> {
        let base = Matrix2::new(s, 0.0, 0.0, -s);
        let m = if self.mirrored {
            Matrix2::new(-1.0, 0.0, 0.0, 1.0)
        } else {
            Matrix2::identity()
        };
        let (c, si) = match self.rotation_deg % 360 {
            90 => (0.0, 1.0),
            180 => (-1.0, 0.0),
            270 => (0.0, -1.0),
            _ => (1.0, 0.0),
        };
        Matrix2::new(c, -si, si, c) * m * base
    }
}

/// Scan pixel sizes (µm) taken as physically plausible for a film scan: photogrammetric
/// scanners work at 4–25 µm, office scanners down to 127 dpi (200 µm). A value outside is
/// a unit mistake (mm or dpi given as µm).
pub const SCAN_PIXEL_UM: std::ops::RangeInclusive<f64> = 3.0..=200.0;

/// Checks a given scan pixel size (µm): finite, positive and within [`SCAN_PIXEL_UM`].
pub fn check_scan_pixel_um(um: f64) -> std::result::Result<(), String> {
    if um.is_finite() && SCAN_PIXEL_UM.contains(&um) {
        Ok(())
    } else {
        Err(format!(
            "scan pixel size {um} µm is not a plausible film scan pixel ({}–{} µm, i.e. \
             {:.0}–{:.0} dpi)",
            SCAN_PIXEL_UM.start(),
            SCAN_PIXEL_UM.end(),
            scan_pixel_um_from_dpi(*SCAN_PIXEL_UM.end()),
            scan_pixel_um_from_dpi(*SCAN_PIXEL_UM.start()),
        ))
    }
}

/// Pixel size (µm) of a scan at `dpi` dots per inch (25 400 µm to the inch); the same
/// formula turns a pixel size in µm back into dpi.
pub fn scan_pixel_um_from_dpi(dpi: f64) -> f64 {
    25_400.0 / dpi
}

#[derive(Debug, Clone)]
pub struct IoOptions {
    /// Scan pixel size (mm), when the scan's is known (e.g. an epoch's `scan_pixel_um` or
    /// `scan_dpi`); None estimates it from the fiducial marks, starting the search from
    /// the film format over the scan size.
    pub pixel_mm: Option<f64>,
    /// None: try all eight orientations and keep the best fitting one.
    pub orientation: Option<ScanOrientation>,
    pub kind: InteriorTransformKind,
    /// Half-size of the wide search for the first two marks (mm).
    pub search_mm: f64,
    /// Marks with a residual above this are rejected and the transform re-estimated.
    pub max_residual_um: f64,
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
            kind: InteriorTransformKind::Affine,
            search_mm: 10.0,
            max_residual_um: 0.0,
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
    /// Another orientation fitted equally well (a symmetric fiducial layout without an
    /// orientation hint); the transform is then right up to that symmetry.
    pub orientation_ambiguous: bool,
    /// Mean pixel size of the fitted pixel → mm transform (what the fiducials measure).
    pub pixel_mm: f64,
    /// Scan pixel size (µm): the given one, else the estimate from the fiducial marks.
    pub pixel_um: f64,
    /// `"given"`, or `"estimated from …"` saying how.
    pub pixel_source: String,
    pub transform: InteriorOrientation,
    pub marks: Vec<MarkResult>,
    pub rmse_um: f64,
}

/// Renders a mark as a template (mark 1, background 0), anti-aliased by 4×4
/// supersampling; `lin` maps a pixel offset to an mm offset.
pub fn render_template(shape: &FiducialShape, lin: &Matrix2<f64>, margin_mm: f64) -> GreyImage {
    let s = (lin.determinant().abs()).sqrt();
    let half = ((shape.extent_mm() + margin_mm) / s).ceil() as usize;
    let n = 2 * half + 1;
    let c = n as f64 / 2.0;
    GreyImage::from_fn(n, n, |x, y| {
        let mut hit = 0;
        for sy in 0..4 {
            for sx in 0..4 {
                let dx = x - 0.5 + (sx as f64 + 0.5) / 4.0 - c;
                let dy = y - 0.5 + (sy as f64 + 0.5) / 4.0 - c;
                let mm = lin * Vector2::new(dx, dy);
                if shape.covers(mm.x, mm.y) {
                    hit += 1;
                }
            }
        }
        hit as f64 / 16.0
    })
}

/// Fiducial interior orientation of a scan file.
pub fn interior_orientation_file(
    cam: &CameraDefinition,
    scan: &Path,
    opts: &IoOptions,
) -> Result<IoResult> {
    let img = GreyImage::load(scan)?;
    interior_orientation(cam, &img, &scan.display().to_string(), opts)
}

/// Wide-search cache key: rounded predicted pixel, mark shape, scan orientation.
type WideKey = (i64, i64, String, u16, bool);

struct Candidate {
    orientation: ScanOrientation,
    marks: Vec<MarkResult>,
    score: f64,
}

/// Fiducial interior orientation of a scan in memory; `name` labels errors.
pub fn interior_orientation(
    cam: &CameraDefinition,
    img: &GreyImage,
    name: &str,
    opts: &IoOptions,
) -> Result<IoResult> {
    cam.validate().map_err(MatchingError::Camera)?;
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
        None => cam.format_mm[0].max(cam.format_mm[1]) / img.width.min(img.height) as f64,
    };
    let pyr = Pyramid::new(img, 8, 16);
    let centre = Vector2::new(img.width as f64 / 2.0, img.height as f64 / 2.0);
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
    let orientations = match opts.orientation {
        Some(o) => vec![o],
        None => ScanOrientation::all(),
    };
    let margin_mm = 0.5
        * cam
            .fiducials
            .iter()
            .map(|f| f.shape.extent_mm())
            .fold(0.0, f64::max);
    let mut wide_cache: HashMap<WideKey, Option<(f64, f64, f64)>> = HashMap::new();
    let mut wide = |f: &FiducialDef, o: ScanOrientation| -> Option<(f64, f64, f64)> {
        let lin = o.linear(s);
        let inv = lin.try_inverse()?;
        let p = centre + inv * Vector2::new(f.x_mm, f.y_mm);
        let key = (
            p.x.round() as i64,
            p.y.round() as i64,
            f.shape.key(),
            o.rotation_deg,
            o.mirrored,
        );
        if let Some(v) = wide_cache.get(&key) {
            return *v;
        }
        let tpl = render_template(&f.shape, &lin, margin_mm);
        let half = opts.search_mm / s + tpl.width as f64 / 2.0;
        let res = Window::around(img, p.x, p.y, half, half).and_then(|w| {
            let mut mo = opts.matching.clone();
            mo.use_lsm = false;
            match_template(&pyr, &tpl, w, None, &mo).ok()
        });
        let v = res
            .filter(|m| m.ncc >= opts.matching.ncc_threshold)
            .map(|m| (m.x, m.y, m.ncc));
        wide_cache.insert(key, v);
        v
    };
    let mut candidates = Vec::new();
    for o in orientations {
        let Some((fa, fb, pa, pb)) = pairs.iter().find_map(|&(i, j, _)| {
            let (fa, fb) = (&cam.fiducials[i], &cam.fiducials[j]);
            Some((fa, fb, wide(fa, o)?, wide(fb, o)?))
        }) else {
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
        let mut marks = Vec::new();
        let mut score = 0.0;
        for f in &cam.fiducials {
            let pred = origin_px + inv * Vector2::new(f.x_mm, f.y_mm);
            let tpl = render_template(&f.shape, &lin, margin_mm);
            // Local search: ±1 mm around the prediction covers scan shear and scale.
            let half = (1.0 / s).max(8.0) + tpl.width as f64 / 2.0;
            let mut mr = MarkResult {
                id: f.id.clone(),
                x: pred.x,
                y: pred.y,
                x_mm: f.x_mm,
                y_mm: f.y_mm,
                used: false,
                ncc: 0.0,
                sigma_px: f64::NAN,
                residual_um: [f64::NAN; 2],
                residual_norm_um: f64::NAN,
                reason: None,
            };
            match Window::around(img, pred.x, pred.y, half, half) {
                None => mr.reason = Some("predicted position outside the scan".into()),
                Some(w) => match match_template(&pyr, &tpl, w, None, &opts.matching) {
                    Err(e) => mr.reason = Some(e.to_string()),
                    Ok(m) => {
                        mr.ncc = m.ncc;
                        if m.accepted {
                            mr.x = m.x;
                            mr.y = m.y;
                            mr.sigma_px = m.sigma_x.hypot(m.sigma_y);
                            mr.used = true;
                            score += m.ncc;
                        } else {
                            mr.reason = m.reason;
                        }
                    }
                },
            }
            marks.push(mr);
        }
        candidates.push(Candidate {
            orientation: o,
            marks,
            score,
        });
    }
    candidates.sort_by(|a, b| b.score.total_cmp(&a.score));
    let Some(best) = candidates.first() else {
        return Err(orr(format!(
            "no two opposite fiducial marks (first tried: {} and {}) found in a ±{} mm \
             search in any scan orientation (pixel size {:.4} mm; wrong camera definition \
             or pixel size?)",
            cam.fiducials[ia].id, cam.fiducials[ib].id, opts.search_mm, s
        )));
    };
    let ambiguous = candidates
        .get(1)
        .is_some_and(|c| c.score > 0.0 && (best.score - c.score).abs() < 0.02 * best.score);
    let orientation = best.orientation;
    let mut marks = best.marks.clone();
    let need = match opts.kind {
        InteriorTransformKind::Affine => 3,
        InteriorTransformKind::Projective => 4,
    };
    let max_res = if opts.max_residual_um > 0.0 {
        opts.max_residual_um
    } else {
        // Three times a good measurement (0.2 px), at least 10 µm.
        (3.0 * 0.2 * s * 1000.0).max(10.0) * 1.5
    };
    loop {
        let used: Vec<usize> = (0..marks.len()).filter(|&i| marks[i].used).collect();
        if used.len() < need {
            let why: Vec<String> = marks
                .iter()
                .filter(|m| !m.used)
                .map(|m| format!("{}: {}", m.id, m.reason.clone().unwrap_or_default()))
                .collect();
            return Err(orr(format!(
                "only {} of {} fiducial marks measured, {:?} needs {need} ({})",
                used.len(),
                marks.len(),
                opts.kind,
                why.join("; ")
            )));
        }
        let px: Vec<[f64; 2]> = used.iter().map(|&i| [marks[i].x, marks[i].y]).collect();
        let mm: Vec<[f64; 2]> = used
            .iter()
            .map(|&i| [marks[i].x_mm, marks[i].y_mm])
            .collect();
        let (io, res) = InteriorOrientation::estimate(opts.kind, &px, &mm)?;
        for m in marks.iter_mut() {
            m.residual_um = [f64::NAN; 2];
            m.residual_norm_um = f64::NAN;
        }
        let mut worst = (0usize, -1.0);
        for (k, &i) in used.iter().enumerate() {
            marks[i].residual_um = res[k];
            marks[i].residual_norm_um = res[k][0].hypot(res[k][1]);
            if marks[i].residual_norm_um > worst.1 {
                worst = (i, marks[i].residual_norm_um);
            }
        }
        // Redundancy is needed to see a gross error; with exactly `need` marks the
        // residuals are zero by construction.
        if worst.1 > max_res && used.len() > need {
            let m = &mut marks[worst.0];
            m.used = false;
            m.reason = Some(format!(
                "residual {:.1} µm above {:.1} µm (damaged or misidentified mark)",
                worst.1, max_res
            ));
            tracing::info!(scan = name, mark = %m.id, "fiducial rejected: {}", m.reason.as_deref().unwrap_or(""));
            continue;
        }
        let dof = match opts.kind {
            InteriorTransformKind::Affine => 6,
            InteriorTransformKind::Projective => 8,
        };
        let ss: f64 = res.iter().map(|r| r[0] * r[0] + r[1] * r[1]).sum();
        let rmse = if res.len() * 2 > dof {
            (ss / (2 * res.len() - dof) as f64).sqrt()
        } else {
            (ss / (2 * res.len()) as f64).sqrt()
        };
        // RMSE of the residuals themselves (what operators compare with the 0.2 px goal).
        let rmse_plain = (ss / (2 * res.len()) as f64).sqrt();
        tracing::debug!(scan = name, rmse_um = rmse, "interior orientation");
        let measured_um = io.mean_pixel_size_mm() * 1000.0;
        let (pixel_um, pixel_source) = match opts.pixel_mm {
            Some(given) => {
                let given_um = given * 1000.0;
                // Film and scanner scale stay well within 1 %; more is a wrong value.
                if (measured_um / given_um - 1.0).abs() > 0.02 {
                    tracing::warn!(
                        scan = name,
                        "given scan pixel size {given_um:.3} µm, but the fiducial marks measure \
                         {measured_um:.3} µm"
                    );
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
        return Ok(IoResult {
            camera: cam.name.clone(),
            orientation,
            orientation_ambiguous: ambiguous,
            pixel_mm: io.mean_pixel_size_mm(),
            pixel_um,
            pixel_source,
            transform: io,
            marks,
            rmse_um: rmse_plain,
        });
    }
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
            "pixel_mm": self.pixel_mm,
            "pixel_um": self.pixel_um,
            "pixel_source": self.pixel_source,
            "rmse_um": self.rmse_um,
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
