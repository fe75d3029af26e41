//! The measurement of a hypothesis' marks, in two steps: planned (templates drawn, windows
//! placed around the predictions and read) one hypothesis after the other, then measured
//! (NCC + LSM) in parallel in the windows read, so that the results do not depend on the
//! threads.

use super::super::matcher::MatchOptions;
use super::super::ncc::Window;
use super::super::{GreyImage, Result};
use super::patches::{smoothed, Patches, Ready};
use super::shape::render_template;
use super::{CameraDefinition, FiducialDef, IoOptions, MarkResult, MAX_TEMPLATE_PIXELS};
use nalgebra::{Matrix2, Vector2};
use rayon::prelude::*;
use std::collections::HashMap;

/// A mark's template: its shape and the bits of the map it is drawn through.
type TemplateKey = (String, [u64; 4]);

/// Each mark's search, its windows read.
pub(super) struct MarkPlan {
    /// Every mark's result before its search (with the reason when it cannot be searched).
    marks: Vec<MarkResult>,
    /// Each mark's template (an index into `templates`) and window.
    searches: Vec<Option<(usize, Window)>>,
    /// Templates, and whether each is smoothed ([`smoothed`]; else too small for it).
    templates: Vec<(GreyImage, bool)>,
}

/// Plans the measurement of every mark around its predicted position: a ±1 mm window, of
/// the scan smoothed as its template is ([`super::patches::SMOOTH_PX`]), the template
/// drawn through `lin` (pixel → mm at the mark). Err: the scan could not be read.
pub(super) fn plan(
    cam: &CameraDefinition,
    scan: &mut Patches,
    lin: &dyn Fn(&FiducialDef) -> Matrix2<f64>,
    predict: &dyn Fn(&FiducialDef) -> Vector2<f64>,
    s: f64,
    margin_mm: f64,
    opts: &IoOptions,
) -> Result<MarkPlan> {
    let mut out = MarkPlan {
        marks: Vec::new(),
        searches: Vec::new(),
        templates: Vec::new(),
    };
    // Marks of one shape drawn through the same map share their template (an affine's
    // map is the same at every mark).
    let mut drawn: HashMap<TemplateKey, Option<usize>> = HashMap::new();
    for f in &cam.fiducials {
        let pred = predict(f);
        let lin = lin(f);
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
        let key = (
            f.shape.key(),
            [lin.m11, lin.m12, lin.m21, lin.m22].map(f64::to_bits),
        );
        let templates = &mut out.templates;
        let k = *drawn.entry(key).or_insert_with(|| {
            let t = render_template(&f.shape, &lin, margin_mm)?;
            templates.push(smoothed(&t).map_or((t, false), |s| (s, true)));
            Some(templates.len() - 1)
        });
        let search = match k {
            None => {
                mr.reason = Some(format!(
                    "no template at this scale (smaller than 5 scan pixels, or more than \
                     {MAX_TEMPLATE_PIXELS} pixels)"
                ));
                None
            }
            Some(k) => {
                let (tpl, smooth) = &out.templates[k];
                // Local search: ±1 mm around the prediction covers scan shear and scale.
                let half = (1.0 / s).max(8.0);
                let (hw, hh) = (
                    half + tpl.width as f64 / 2.0,
                    half + tpl.height as f64 / 2.0,
                );
                match scan.around(pred.x, pred.y, hw, hh) {
                    None => {
                        mr.reason = Some("predicted position outside the scan".into());
                        None
                    }
                    Some(w) => {
                        scan.prepare(tpl, w, &opts.matching, *smooth)?;
                        Some((k, w))
                    }
                }
            }
        };
        out.marks.push(mr);
        out.searches.push(search);
    }
    Ok(out)
}

impl MarkPlan {
    /// The marks measured (NCC + LSM) in the windows read, in parallel.
    pub(super) fn measure(self, ready: &Ready, opts: &MatchOptions) -> Vec<MarkResult> {
        let MarkPlan {
            marks,
            searches,
            templates,
        } = self;
        marks
            .into_par_iter()
            .zip(searches)
            .map(|(mut mr, search)| {
                let Some((k, w)) = search else {
                    return mr;
                };
                let (tpl, smooth) = &templates[k];
                match ready.search(tpl, w, opts, *smooth) {
                    Err(e) => mr.reason = Some(e.to_string()),
                    Ok(m) => {
                        mr.ncc = m.ncc;
                        if m.accepted {
                            mr.x = m.x;
                            mr.y = m.y;
                            mr.sigma_px = m.sigma_x.hypot(m.sigma_y);
                            mr.used = true;
                        } else {
                            mr.reason = m.reason;
                        }
                    }
                }
                mr
            })
            .collect()
    }
}
