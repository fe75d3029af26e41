//! One template match as seed 001 does it: coarse-to-fine NCC over the pyramid, LSM at
//! full resolution from the NCC position, and acceptance only when NCC reaches its
//! threshold, LSM converged and the two positions agree (a cross-check between two
//! independent estimators of the same position).

use super::lsm::{lsm, LsmOptions, LsmResult};
use super::ncc::{ncc_search_pyramid, NccPeak, Window};
use super::pyramid::Levels;
use super::{holds_template, GreyImage, Result};
use serde::Serialize;

#[derive(Debug, Clone)]
pub struct MatchOptions {
    pub ncc_threshold: f64,
    /// Reject when the second-best peak reaches this fraction of the best.
    pub max_ambiguity: f64,
    /// NCC and LSM positions must agree within this (px).
    pub agreement_px: f64,
    /// Smallest template size used on a coarse pyramid level.
    pub min_template_px: usize,
    /// Match either polarity (negative and positive film, dark or bright marks).
    pub absolute: bool,
    /// Run LSM (false: NCC only, position and quality from the correlation peak).
    pub use_lsm: bool,
    pub lsm: LsmOptions,
}

impl Default for MatchOptions {
    fn default() -> Self {
        Self {
            ncc_threshold: 0.7,
            max_ambiguity: 0.95,
            agreement_px: 1.0,
            min_template_px: 11,
            absolute: false,
            use_lsm: true,
            lsm: LsmOptions::default(),
        }
    }
}

/// A match and its quality. `x, y` is the template centre in the image: the LSM position
/// when LSM ran and converged, else the NCC peak.
#[derive(Debug, Clone, Serialize)]
pub struct MatchResult {
    pub accepted: bool,
    /// Why the match was rejected (None when accepted).
    pub reason: Option<String>,
    pub x: f64,
    pub y: f64,
    pub ncc: f64,
    pub ncc_x: f64,
    pub ncc_y: f64,
    pub ambiguity: f64,
    pub lsm_converged: bool,
    pub lsm_iterations: usize,
    pub sigma_x: f64,
    pub sigma_y: f64,
    pub sigma0: f64,
    pub affine: [f64; 4],
}

/// Matches `tpl` inside `window` of the image pyramid `pyr`.
pub fn match_template<P: Levels + ?Sized>(
    pyr: &P,
    tpl: &GreyImage,
    window: Window,
    initial_affine: Option<[f64; 4]>,
    opts: &MatchOptions,
) -> Result<MatchResult> {
    let img = pyr.level(0);
    holds_template("image", img.width, img.height, tpl)?;
    let peak: NccPeak = ncc_search_pyramid(pyr, tpl, window, opts.min_template_px, opts.absolute)?;
    let mut out = MatchResult {
        accepted: false,
        reason: None,
        x: peak.x,
        y: peak.y,
        ncc: peak.ncc,
        ncc_x: peak.x,
        ncc_y: peak.y,
        ambiguity: peak.ratio,
        lsm_converged: false,
        lsm_iterations: 0,
        sigma_x: f64::NAN,
        sigma_y: f64::NAN,
        sigma0: f64::NAN,
        affine: initial_affine.unwrap_or([1.0, 0.0, 0.0, 1.0]),
    };
    let mut reasons = Vec::new();
    if peak.ncc < opts.ncc_threshold {
        reasons.push(format!(
            "NCC {:.3} below the threshold {:.2}",
            peak.ncc, opts.ncc_threshold
        ));
    }
    if peak.ratio >= opts.max_ambiguity {
        reasons.push(format!(
            "ambiguous: second peak {:.2} of the best",
            peak.ratio
        ));
    }
    if opts.use_lsm && reasons.is_empty() {
        let l: LsmResult = lsm(img, tpl, peak.x, peak.y, initial_affine, &opts.lsm);
        out.lsm_converged = l.converged;
        out.lsm_iterations = l.iterations;
        if l.converged {
            out.x = l.x;
            out.y = l.y;
            out.sigma_x = l.sigma_x;
            out.sigma_y = l.sigma_y;
            out.sigma0 = l.sigma0;
            out.affine = l.affine;
            let d = ((l.x - peak.x).powi(2) + (l.y - peak.y).powi(2)).sqrt();
            if d > opts.agreement_px {
                reasons.push(format!(
                    "NCC and LSM positions differ by {d:.2} px (tolerance {})",
                    opts.agreement_px
                ));
            }
        } else {
            reasons.push(format!(
                "LSM: {}",
                l.reason.unwrap_or_else(|| "not converged".into())
            ));
        }
    }
    out.accepted = reasons.is_empty();
    out.reason = (!reasons.is_empty()).then(|| reasons.join("; "));
    Ok(out)
}
