//! Gross-error elimination between solves: standardised residuals against the robust
//! σ0 (or the a-priori σ for Baarda's data snooping), one observation per object point
//! and round, leave-one-out localisation among a point's rays, the test of control
//! priors against their own rays' intersection, and re-admission against the final
//! solution.

use super::precision::{self, intersect};
use super::problem::Problem;
use super::residual::Kind;
use super::solver::{self, Structure};
use super::{AdjustOptions, Rejected, Rejection};
use nalgebra::{Vector2, Vector3};
use std::collections::BTreeMap;

fn rejection_k(r: Rejection) -> Option<f64> {
    match r {
        Rejection::None => None,
        Rejection::Threshold(k) | Rejection::DataSnooping(k) => Some(k),
    }
}

pub(super) fn select_rejections(
    st: &Structure,
    pb: &Problem,
    opts: &AdjustOptions,
    round: usize,
    n_points: usize,
) -> Vec<(usize, Rejected)> {
    let Some(k) = rejection_k(opts.rejection) else {
        return Vec::new();
    };
    let ev = solver::evaluate(&pb.res, &pb.state, opts.loss);
    let _ = n_points;
    let pts = solver::point_systems(st, &pb.res, &ev, 0.0);
    let unit = precision::standardized(&pb.res, &ev, &pts, 1.0);
    // Baarda's data snooping tests against the a-priori σ (variance factor 1); the
    // threshold test against the robust a-posteriori σ0.
    let s0 = match opts.rejection {
        Rejection::DataSnooping(_) => 1.0,
        _ => precision::robust_sigma0(&ev, &unit),
    };
    if !s0.is_finite() || s0 <= 0.0 {
        return Vec::new();
    }
    let std: Vec<Option<(f64, f64)>> = unit.iter().map(|u| u.map(|(r, w)| (r, w / s0))).collect();
    let reason =
        |w: f64, kind: &str| format!("{kind}: standardised residual {w:.2} > {k} (σ0 = {s0:.3})");
    let mut out = Vec::new();
    // A control point's surveyed position is tested against its intersection from its
    // own rays (with the current orientations): a strong prior absorbs its gross error
    // into the image residuals, which would otherwise be rejected instead of the prior.
    let mut tested_points = std::collections::BTreeSet::new();
    for (i, r) in pb.res.iter().enumerate() {
        let (Kind::PointPrior { value, sigma }, Some(p), true) = (&r.kind, r.point, r.active)
        else {
            continue;
        };
        let mut v = nalgebra::Matrix3::zeros();
        let mut g = Vector3::zeros();
        let mut rays = 0;
        for &j in &st.point_res[p] {
            if let (Kind::Image { .. }, Some(e)) = (&pb.res[j].kind, &ev.evals[j]) {
                let w = ev.weights[j];
                v += w * e.j_point.transpose() * e.j_point;
                g += w * e.j_point.transpose() * e.r;
                rays += 1;
            }
        }
        if rays < 2 {
            continue;
        }
        let Some(q) = v.try_inverse() else { continue };
        let x_rays = pb.state.points[p] - q * g;
        let d = x_rays - value;
        let w = (0..3)
            .map(|c| d[c].abs() / (s0 * (q[(c, c)] + sigma[c] * sigma[c]).sqrt()))
            .fold(0.0, f64::max);
        if w > k {
            out.push((i, w));
            tested_points.insert(p);
        }
    }
    // Per object point only its worst observation goes in one round: a gross error smears
    // into the other rays of its point, which recover once it is removed.
    let mut best: BTreeMap<(u8, usize), (usize, f64)> = BTreeMap::new();
    for (i, s) in std.iter().enumerate() {
        let Some((_, w)) = s else { continue };
        if *w <= k {
            continue;
        }
        let r = &pb.res[i];
        // POS priors are not rejected: a photo without its prior may lose the datum, and
        // a POS gross error shows in the image residuals of the photo all the same.
        if matches!(
            r.kind,
            Kind::PointPrior { .. } | Kind::PosCenter { .. } | Kind::PosAttitude { .. }
        ) || r.point.is_some_and(|p| tested_points.contains(&p))
        {
            continue;
        }
        let key = match r.point {
            Some(p) => (0, p),
            None => (1, r.photo.unwrap_or(0)),
        };
        let e = best.entry(key).or_insert((i, *w));
        if *w > e.1 {
            *e = (i, *w);
        }
    }
    for (key, (i, w)) in best {
        let i = match key {
            (0, p) => localize(pb, st, p).unwrap_or(i),
            _ => i,
        };
        out.push((i, w));
    }
    out.sort_by_key(|(i, _)| *i);
    out.into_iter()
        .map(|(i, w)| {
            (
                i,
                Rejected {
                    observation: pb.refs[i].clone(),
                    round,
                    standardized_residual: w,
                    reason: reason(w, pb.res[i].kind.label()),
                },
            )
        })
        .collect()
}

/// Leave-one-out localisation of a gross error among the rays of an object point:
/// the ray whose removal leaves the others most consistent (smallest sum of squared
/// residuals of a re-intersection with the current orientations). With three rays or
/// more this tells a wrong ray from the good ones its error smeared into.
fn localize(pb: &Problem, st: &Structure, p: usize) -> Option<usize> {
    let rays: Vec<usize> = st.point_res[p]
        .iter()
        .copied()
        .filter(|&j| pb.res[j].active && matches!(pb.res[j].kind, Kind::Image { .. }))
        .collect();
    if rays.len() < 3 {
        return None;
    }
    let ray = |j: usize| {
        let r = &pb.res[j];
        let Kind::Image { pixel, sigma } = r.kind else {
            unreachable!()
        };
        (
            &pb.state.cameras[r.camera.expect("camera")],
            &pb.state.poses[r.photo.expect("photo")],
            [pixel.x, pixel.y],
            sigma,
        )
    };
    let mut best: Option<(usize, f64)> = None;
    for &skip in &rays {
        let others: Vec<_> = rays
            .iter()
            .filter(|&&j| j != skip)
            .map(|&j| ray(j))
            .collect();
        let Some(x) = intersect(&others) else {
            continue;
        };
        let ssr: f64 = others
            .iter()
            .map(|(c, pose, px, s)| {
                crate::geometry::project(c, pose, &x)
                    .map(|q| ((q.pixel - Vector2::new(px[0], px[1])) / *s).norm_squared())
                    .unwrap_or(f64::INFINITY)
            })
            .sum();
        if best.is_none_or(|(_, b)| ssr < b) {
            best = Some((skip, ssr));
        }
    }
    best.map(|(j, _)| j)
}

/// Re-admits rejected observations whose residual against the current solution is
/// within k·σ0 (r = 1: a rejected observation does not take part in the solution).
pub(super) fn readmit(
    pb: &mut Problem,
    rejected: &mut Vec<Rejected>,
    opts: &AdjustOptions,
) -> bool {
    let Some(k) = rejection_k(opts.rejection) else {
        return false;
    };
    let st = pb.structure();
    let ev = solver::evaluate(&pb.res, &pb.state, opts.loss);
    let pts = solver::point_systems(&st, &pb.res, &ev, 0.0);
    let s0 = precision::robust_sigma0(&ev, &precision::standardized(&pb.res, &ev, &pts, 1.0));
    if !s0.is_finite() {
        return false;
    }
    let index: BTreeMap<String, usize> = pb
        .refs
        .iter()
        .enumerate()
        .filter(|(i, _)| !pb.res[*i].active)
        .map(|(i, r)| (format!("{r:?}"), i))
        .collect();
    let mut any = false;
    rejected.retain(|rj| {
        let Some(&i) = index.get(&format!("{:?}", rj.observation)) else {
            return true;
        };
        let mut blk = pb.res[i].clone();
        blk.active = true;
        let ok = blk
            .evaluate(&pb.state)
            .map(|e| (0..e.dim).all(|c| e.r[c].abs() < k * s0))
            .unwrap_or(false);
        // Only when the point is still in the solution.
        let alive = blk
            .point
            .is_none_or(|p| pb.res.iter().any(|r| r.active && r.point == Some(p)));
        if ok && alive {
            pb.res[i].active = true;
            any = true;
            false
        } else {
            true
        }
    });
    any
}
