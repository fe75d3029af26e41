//! Whether control points alone fix the datum of a block: the seven parameters of a
//! spatial similarity (three translations, three rotations, scale). A 3-D control point
//! fixes three coordinates, a 2-D one (σ_z = ∞) only plan, a height point only height.

use super::AdjustError;
use nalgebra::{DMatrix, Vector3};

/// Singular values below this fraction of the largest count as a datum defect.
const RANK_TOL: f64 = 1e-3;

/// Checks that the control points (position, known axes) fix all seven datum parameters.
pub fn check_control_geometry(c: &[(Vector3<f64>, [bool; 3])]) -> Result<(), AdjustError> {
    if c.iter().all(|(_, k)| k.iter().all(|&a| a)) {
        return check_full(&c.iter().map(|(p, _)| *p).collect::<Vec<_>>());
    }
    let plan = c.iter().filter(|(_, k)| k[0] && k[1]).count();
    let height = c.iter().filter(|(_, k)| k[2]).count();
    if height == 0 {
        return Err(AdjustError::Degenerate(format!(
            "the {} control point(s) are 2-D (σ_z = ∞): they fix the plan position but nothing fixes the block's heights and tilt; add control with known heights, POS priors or LiDAR planes",
            c.len()
        )));
    }
    if plan == 0 {
        return Err(AdjustError::Degenerate(format!(
            "the {} control point(s) are height-only: nothing fixes the block's plan position, azimuth and scale; add control with known plan coordinates, POS priors or LiDAR planes",
            c.len()
        )));
    }
    // Linearised similarity: each known coordinate a of a point X (centred, scaled) is
    // moved by δt_a + (δω × X)_a + δs·X_a.
    let mean = c.iter().fold(Vector3::zeros(), |a, (p, _)| a + p) / c.len() as f64;
    let spread = (c
        .iter()
        .map(|(p, _)| (p - mean).norm_squared())
        .sum::<f64>()
        / c.len() as f64)
        .sqrt()
        .max(1e-9);
    let rows: Vec<[f64; 7]> = c
        .iter()
        .flat_map(|(p, k)| {
            let x = (p - mean) / spread;
            (0..3).filter(|&a| k[a]).map(move |a| {
                let mut r = [0.0; 7];
                r[a] = 1.0;
                let e = Vector3::ith(a, 1.0);
                // (δω × X)_a = δω · (X × e_a)
                let w = x.cross(&e);
                r[3..6].copy_from_slice(w.as_slice());
                r[6] = x[a];
                r
            })
        })
        .collect();
    let m = DMatrix::from_fn(rows.len(), 7, |i, j| rows[i][j]);
    let s = m.singular_values();
    let (lo, hi) = s
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(l, h), &v| (l.min(v), h.max(v)));
    if rows.len() < 7 || lo < RANK_TOL * hi {
        return Err(AdjustError::Degenerate(format!(
            "the control points' known coordinates ({plan} with plan, {height} with height) cannot fix the datum: plan needs two points apart, height three not on a line (or POS / LiDAR planes)"
        )));
    }
    Ok(())
}

/// 3-D control fixes the datum only when at least three points span a plane.
fn check_full(c: &[Vector3<f64>]) -> Result<(), AdjustError> {
    if c.len() < 3 {
        return Err(AdjustError::Degenerate(format!(
            "{} control point(s) cannot fix the datum; at least 3 not on a line are needed (or POS / LiDAR planes)",
            c.len()
        )));
    }
    let mean = c.iter().fold(Vector3::zeros(), |a, b| a + b) / c.len() as f64;
    let mut m = DMatrix::zeros(c.len(), 3);
    for (i, p) in c.iter().enumerate() {
        for k in 0..3 {
            m[(i, k)] = p[k] - mean[k];
        }
    }
    let s = m.singular_values();
    let mut s: Vec<f64> = s.iter().copied().collect();
    s.sort_by(|a, b| b.total_cmp(a));
    if s[0] <= 0.0 || s[1] < RANK_TOL * s[0] {
        return Err(AdjustError::Degenerate(format!(
            "the {} control points are collinear (spread {:.3} m across their line); they cannot fix the rotation about it",
            c.len(),
            s[1] / (c.len() as f64).sqrt()
        )));
    }
    Ok(())
}
