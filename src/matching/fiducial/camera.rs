//! The camera definition of a metric film camera (its calibration certificate): fiducial
//! marks with their calibrated positions and shapes, the data strip, and the plausible
//! scan pixel sizes.

use super::shape::{FiducialShape, ShapeKind};
use crate::matching::{GreyImage, MatchingError, Result};
use serde::{Deserialize, Serialize};
use std::path::{Component, Path};
use std::sync::Arc;

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
    /// Where the camera images its data strip (clock, altimeter, frame counter) outside
    /// the format: the asymmetry of the frame that tells the scan orientation when the
    /// fiducial layout is symmetric.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub data_strip: Option<DataStrip>,
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

/// A rectangle of the fiducial system (mm) holding the data strip: textured in a scan,
/// while its images under the square's rotations and reflections lie on the uniform
/// opaque frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DataStrip {
    /// [min, max] along x (mm).
    pub x_mm: [f64; 2],
    /// [min, max] along y (mm).
    pub y_mm: [f64; 2],
}

impl CameraDefinition {
    /// Reads a camera definition; template marks' image files are read relative to the
    /// folder of `path`.
    pub fn load(path: &Path) -> Result<Self> {
        let in_file = |e: String| MatchingError::Camera(format!("{}: {e}", path.display()));
        let text = crate::formats::input::read_text(path, crate::formats::input::Cap::camera())
            .map_err(|e| in_file(e.detail()))?;
        let json = serde_json::from_str(&text).map_err(|e| in_file(e.to_string()))?;
        Self::from_json(json, crate::formats::paths::folder_of(path)).map_err(in_file)
    }

    /// A camera definition from its JSON, validated, with template marks' image files read
    /// from `dir`; the error does not name the file (the caller does).
    pub fn from_json(json: serde_json::Value, dir: &Path) -> std::result::Result<Self, String> {
        let mut def: Self = serde_json::from_value(json).map_err(|e| e.to_string())?;
        def.validate()?;
        def.load_templates(dir)?;
        Ok(def)
    }

    /// Reads the image file of every template mark, relative to `dir` (the camera JSON's
    /// folder). A path that is absolute or leaves `dir` (`..`, a symbolic link out) is
    /// refused: a camera file must not make the program read elsewhere.
    pub fn load_templates(&mut self, dir: &Path) -> std::result::Result<(), String> {
        // The folder of a bare file name (`camera.json`) is the working folder.
        let dir = if dir.as_os_str().is_empty() {
            Path::new(".")
        } else {
            dir
        };
        let root = dir
            .canonicalize()
            .map_err(|e| format!("camera folder {}: {e}", dir.display()))?;
        for f in &mut self.fiducials {
            if f.shape.kind != ShapeKind::Template {
                continue;
            }
            let file = f.shape.file.as_deref().unwrap_or_default();
            let rel = Path::new(file);
            if rel.is_absolute()
                || rel
                    .components()
                    .any(|c| !matches!(c, Component::Normal(_) | Component::CurDir))
            {
                return Err(format!(
                    "fiducial {}: template file {file:?} must be a path inside the camera \
                     file's folder (no absolute path, no ..)",
                    f.id
                ));
            }
            let full = root.join(rel);
            let real = full
                .canonicalize()
                .map_err(|e| format!("fiducial {}: template file {}: {e}", f.id, full.display()))?;
            if !real.starts_with(&root) {
                return Err(format!(
                    "fiducial {}: template file {file:?} leads out of the camera file's folder",
                    f.id
                ));
            }
            // The size from the header first: a template is a small crop, and a file that
            // claims more is refused before it is decoded.
            let (w, h) = crate::formats::image_open::image_size(&real)
                .map_err(|e| format!("fiducial {}: {e}", f.id))?;
            check_template_size(f, self.format_mm, &real, w.into(), h.into())?;
            let img = GreyImage::load(&real).map_err(|e| format!("fiducial {}: {e}", f.id))?;
            if let Some([cx, cy]) = f.shape.centre_px {
                if !(cx >= 0.0 && cy >= 0.0 && cx <= img.width as f64 && cy <= img.height as f64) {
                    return Err(format!(
                        "fiducial {}: centre_px [{cx}, {cy}] lies outside the {}×{} template",
                        f.id, img.width, img.height
                    ));
                }
            }
            f.shape.image = Some(Arc::new(img));
        }
        Ok(())
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
        if self.fiducials.len() < 3 {
            return Err(format!(
                "{} fiducials defined; interior orientation needs at least 3",
                self.fiducials.len()
            ));
        }
        if self.fiducials.len() > MAX_FIDUCIALS {
            return Err(format!(
                "fiducials: {} marks listed; a camera has at most {MAX_FIDUCIALS} \
                 (fiducial::MAX_FIDUCIALS: 4 corner and 4 midside marks, 8 on a few)",
                self.fiducials.len()
            ));
        }
        for f in &self.fiducials {
            if !(f.x_mm.is_finite() && f.y_mm.is_finite()) {
                return Err(format!("fiducial {}: position is not finite", f.id));
            }
            f.shape
                .validate()
                .map_err(|e| format!("fiducial {}: {e}", f.id))?;
            // A mark is a small part of the frame; templates and searches are sized from
            // it, so a unit mistake (µm as mm) must not render a template of 10¹⁰ pixels.
            let max_mark = MAX_MARK_FRACTION * fw.min(fh);
            let sh = &f.shape;
            let sizes = [
                ("size_mm", Some(sh.size_mm)),
                ("line_mm", Some(sh.line_mm)),
                ("dot_mm", sh.dot_mm),
                ("ring_mm", sh.ring_mm),
                ("ring_line_mm", sh.ring_line_mm),
                ("gap_mm", sh.gap_mm),
            ];
            for (name, v) in sizes {
                if let Some(v) = v.filter(|v| !(v.is_finite() && *v <= max_mark)) {
                    return Err(format!(
                        "fiducial {}: {name} {v} is not a mark size: at most {max_mark} mm \
                         ({MAX_MARK_FRACTION} of the {} mm film side)",
                        f.id,
                        fw.min(fh)
                    ));
                }
            }
        }
        if let Some(s) = &self.data_strip {
            let ok = |r: [f64; 2]| r[0].is_finite() && r[1].is_finite() && r[0] < r[1];
            if !(ok(s.x_mm) && ok(s.y_mm)) {
                return Err(format!(
                    "data_strip x_mm {:?}, y_mm {:?}: each must be [min, max] with min < max",
                    s.x_mm, s.y_mm
                ));
            }
        }
        Ok(())
    }
}

/// Checks a template mark's image of `w`×`h` pixels (read from the header of `file`)
/// against [`MAX_TEMPLATE_PIXELS`] and its extent on the film against the mark bound
/// ([`MAX_MARK_FRACTION`] of the shorter film side, from the mark's point to the crop's
/// farthest corner).
fn check_template_size(
    f: &FiducialDef,
    format_mm: [f64; 2],
    file: &Path,
    w: u64,
    h: u64,
) -> std::result::Result<(), String> {
    if w.saturating_mul(h) > MAX_TEMPLATE_PIXELS {
        return Err(format!(
            "fiducial {}: template {} of {w}×{h} pixels: at most {MAX_TEMPLATE_PIXELS} pixels \
             (fiducial::MAX_TEMPLATE_PIXELS; a mark's crop is a few hundred pixels a side)",
            f.id,
            file.display()
        ));
    }
    let tp = f.shape.pixel_mm.unwrap_or(0.0);
    let [cx, cy] = f
        .shape
        .centre_px
        .unwrap_or([w as f64 / 2.0, h as f64 / 2.0]);
    let reach = cx.max(w as f64 - cx).hypot(cy.max(h as f64 - cy)) * tp;
    let side = format_mm[0].min(format_mm[1]);
    let max_mark = MAX_MARK_FRACTION * side;
    if reach.is_nan() || reach > max_mark {
        return Err(format!(
            "fiducial {}: template {} of {w}×{h} pixels at pixel_mm {tp} reaches {reach:.1} mm \
             from the mark's point: not a mark: at most {max_mark} mm ({MAX_MARK_FRACTION} of \
             the {side} mm film side; is pixel_mm the template's pixel on the film?)",
            f.id,
            file.display()
        ));
    }
    Ok(())
}

/// Most fiducial marks a camera definition may list: metric cameras have 4 (corners or
/// midsides) or 8; every step that pairs marks is bounded by it.
pub const MAX_FIDUCIALS: usize = 16;

/// Most pixels of a template mark's image, and of any template rendered into a scan's
/// geometry (4 Mi pixels, 16 MiB as f32): a real mark's crop is a few hundred pixels a
/// side (the largest NAGAP crop with its data strip text, 1790 × 440); the correlation of
/// a larger one would outgrow the search's buffers ([`crate::matching::ncc::NCC_SCRATCH_BYTES`]).
pub const MAX_TEMPLATE_PIXELS: u64 = 1 << 22;

/// Largest film format side accepted (mm): aerial film is at most 9 × 18 in (229 × 457 mm).
pub const MAX_FORMAT_MM: f64 = 500.0;

/// Largest fiducial mark dimension (`size_mm`, `line_mm`, `dot_mm`, ring and gap sizes) as
/// a fraction of the shorter film side (23 mm on 230 mm film; real marks are 1–20 mm).
pub const MAX_MARK_FRACTION: f64 = 0.1;

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
