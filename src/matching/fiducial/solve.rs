//! The interior orientation solve: the pixel → fiducial mm transform from the measured
//! marks, with marks of gross residual (damaged, misidentified) rejected one by one.

use super::MarkResult;
use crate::geometry::{InteriorOrientation, InteriorTransformKind};

/// A fitted transform and its residual statistics (µm).
pub(super) struct Fit {
    pub io: InteriorOrientation,
    /// Sum of squared residuals over the used marks (µm², both coordinates).
    pub ss: f64,
    /// RMS of the residuals themselves (what operators compare with the 0.2 px goal).
    pub rmse_plain: f64,
}

/// Marks the transform needs, and the parameters it has.
pub(super) fn need_and_dof(kind: InteriorTransformKind) -> (usize, usize) {
    match kind {
        InteriorTransformKind::Affine => (3, 6),
        InteriorTransformKind::Projective => (4, 8),
    }
}

/// Fits `kind` to the used marks, rejecting the worst mark while it is above `max_res`
/// (µm) and redundancy remains; residuals are written into `marks`. Err says which marks
/// are missing and why.
pub(super) fn fit(
    marks: &mut [MarkResult],
    kind: InteriorTransformKind,
    max_res: f64,
    name: &str,
) -> Result<Fit, String> {
    let (need, _) = need_and_dof(kind);
    loop {
        let used: Vec<usize> = (0..marks.len()).filter(|&i| marks[i].used).collect();
        if used.len() < need {
            let why: Vec<String> = marks
                .iter()
                .filter(|m| !m.used)
                .map(|m| format!("{}: {}", m.id, m.reason.clone().unwrap_or_default()))
                .collect();
            return Err(format!(
                "only {} of {} fiducial marks measured, {kind:?} needs {need} ({})",
                used.len(),
                marks.len(),
                why.join("; ")
            ));
        }
        let px: Vec<[f64; 2]> = used.iter().map(|&i| [marks[i].x, marks[i].y]).collect();
        let mm: Vec<[f64; 2]> = used
            .iter()
            .map(|&i| [marks[i].x_mm, marks[i].y_mm])
            .collect();
        let (io, res) = InteriorOrientation::estimate(kind, &px, &mm).map_err(|e| e.to_string())?;
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
            tracing::debug!(scan = name, mark = %m.id, "fiducial rejected: {}", m.reason.as_deref().unwrap_or(""));
            continue;
        }
        let ss: f64 = res.iter().map(|r| r[0] * r[0] + r[1] * r[1]).sum();
        return Ok(Fit {
            io,
            ss,
            rmse_plain: (ss / (2 * res.len()) as f64).sqrt(),
        });
    }
}
