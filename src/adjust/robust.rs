//! Gross-error elimination between solves. Baarda's data snooping (the default) tests
//! each observation with its own dimension against the a-priori σ, and a tie point's rays
//! against their own point's spread where the tie points differ in precision beyond
//! chance ([`tie_prior`](super::tie_prior)); the threshold rule
//! tests standardised residual components against k × the robust σ0 of the round. Both
//! remove one observation per object point and round, localise a point's gross error
//! among its rays by leaving one out, test control priors against their own rays'
//! intersection and re-admit against the final solution.

use super::chi2;
use super::evaluated::Evaluated;
use super::precision::{self, intersect, Snoop};
use super::problem::Problem;
use super::residual::{Kind, Loss, ResidualBlock};
use super::solver::{self, Structure};
use super::tie_prior::{self, PointLoo, TiePrior};
use super::{Rejected, Rejection};
use nalgebra::{DMatrix, DVector, Matrix3, Vector3};
use std::collections::{BTreeMap, BTreeSet};

/// The data-snooping guard takes the first solution's image σ0 instead of the a-priori σ
/// when it is at least this much larger (and significantly so). A test against a σ that
/// is too small by a factor f has the false-alarm rate of critical value 13.82/f² in
/// χ²(2): 0.1 % at f = 1, 0.33 % at 1.1, 0.8 % at 1.2 and 4.6 % at 1.5 — at 1.5 a block
/// would already lose one good observation in twenty, so the guard steps in at 1.1.
const GUARD_RATIO: f64 = 1.1;

/// The rejection test of one adjustment: rule, critical values and the image σ it uses.
pub(super) struct RejectionTest {
    rule: Rejection,
    /// Critical values of χ²(d), d = 0..3, at α0 (data snooping).
    crit: [f64; 4],
    /// σ of the image group in units of its a-priori σ that the test assumes.
    image_sigma: f64,
    /// Robust σ0 of the image group on the first solution (data snooping).
    first_round: Option<f64>,
    /// Observations rejected by the final sweep(s).
    pub(super) swept: usize,
    /// Factor the control points' σ were scaled by on the first solution (data snooping).
    pub(super) control_scale: Option<f64>,
    /// The tie points' precision prior fitted on the first solution (data snooping), when
    /// they differ in precision beyond chance: their rays are then tested against their
    /// own point's other rays.
    pub(super) tie_prior: Option<TiePrior>,
    /// Rounds whose tie rays were tested against their own points (the prior is fitted
    /// again every round and gives way to one σ once no spread is left).
    tie_rounds: usize,
    /// The first solution's statistics and tie point re-intersections, made for the
    /// calibration and kept for the same round's test when nothing changed in between
    /// ([`forget`](Self::forget)): at 200 photos the re-intersections alone take 44 ms.
    first: Option<(Stats, BTreeMap<usize, PointLoo>)>,
}

/// The test statistics of one solution.
struct Stats {
    snoop: Vec<Option<Snoop>>,
}

fn stats(st: &Structure, pb: &Problem) -> Stats {
    let ev = Evaluated::new(&pb.res, &pb.state, Loss::None);
    let pts = solver::point_inverses(&ev, st, 0.0);
    let snoop = precision::snooping(&ev, &pts);
    Stats { snoop }
}

impl RejectionTest {
    pub(super) fn new(rule: Rejection) -> Self {
        let mut crit = [f64::INFINITY; 4];
        if let Some(a) = rule.alpha() {
            for (d, c) in crit.iter_mut().enumerate().skip(1) {
                *c = chi2::critical(d, a);
            }
        }
        Self {
            rule,
            crit,
            image_sigma: 1.0,
            first_round: None,
            swept: 0,
            control_scale: None,
            tie_prior: None,
            tie_rounds: 0,
            first: None,
        }
    }

    /// Which test ran (the report's `rejection_test`).
    pub(super) fn describe(&self) -> String {
        let mut s = match self.rule {
            Rejection::None => "none".to_string(),
            Rejection::Threshold(k) => {
                format!("threshold k={k} sigma=max(robust_sigma0, 1)")
            }
            Rejection::DataSnooping(k) => {
                let a = chi2::alpha_of_k(k);
                // Four significant digits: 3.29 gives 0.001002, α0 = 0.001 gives 0.001.
                let e = 10f64.powi(3 - a.log10().floor() as i32);
                let a = (a * e).round() / e;
                match self.first_round {
                    Some(s) if self.image_sigma != 1.0 => {
                        format!("baarda_data_snooping alpha={a} sigma=first_round {s:.2}")
                    }
                    _ => format!("baarda_data_snooping alpha={a} sigma=a_priori"),
                }
            }
        };
        match &self.tie_prior {
            Some(p) => s.push_str(&format!(
                ", tie points leave_one_out prior d0={:.1} s0^2={:.2}",
                p.dof, p.factor
            )),
            None if self.tie_rounds > 0 => s.push_str(&format!(
                ", tie points leave_one_out for {} round(s), then one sigma",
                self.tie_rounds
            )),
            None => {}
        }
        if let Some(f) = self.control_scale {
            s.push_str(&format!(", control sigma x{f:.2}"));
        }
        if self.swept > 0 {
            s.push_str(&format!(", final sweep {}", self.swept));
        }
        s
    }

    /// Guard against a wrong a-priori image σ, on the first solution: the robust σ0 of
    /// the image group replaces the a-priori σ, fixed for all later rounds, when it
    /// exceeds it by `GUARD_RATIO` and by three of its standard errors (√(1.36/n) for the
    /// median estimator). A σ0 below 1 keeps the a-priori σ: the test is then
    /// conservative. The σ0 is 1.4826 × the median |z| of the decorrelated standardised
    /// components, over the object points none of whose observations fails the test at
    /// that σ0 (iterated): a gross error smears into its point's other rays, and with 5 %
    /// of the observations displaced the median over all points came out 1.24 for a
    /// right a-priori σ.
    pub(super) fn calibrate(&mut self, st: &Structure, pb: &mut Problem) -> bool {
        if !matches!(self.rule, Rejection::DataSnooping(_)) {
            return false;
        }
        // One evaluation of the first solution serves both groups and the round's test.
        let s = stats(st, pb);
        self.calibrate_image(pb, &s);
        let ties = self.fit_tie_prior(st, pb);
        let rescaled = self.scale_control(st, pb);
        self.first = (!rescaled).then_some((s, ties));
        rescaled
    }

    /// The problem changed (planes re-fitted): the kept first-solution statistics no
    /// longer describe it.
    pub(super) fn forget(&mut self) {
        self.first = None;
    }

    /// The tie points' precision prior on the first solution, from every tie point's
    /// re-intersections with the orientations held ([`tie_prior::fit`]), in units of the
    /// tested image σ. The first solution is used, with its gross errors still in: the
    /// fit's outlier component takes them, and the prior stays fixed for later rounds.
    fn fit_tie_prior(&mut self, st: &Structure, pb: &Problem) -> BTreeMap<usize, PointLoo> {
        let Some(alpha) = self.rule.alpha() else {
            return BTreeMap::new();
        };
        let t = std::time::Instant::now();
        let ties = self.tie_points(st, pb);
        let t_loo = t.elapsed().as_secs_f64();
        self.tie_prior = tie_prior::fit(ties.values(), alpha, None);
        tracing::debug!(
            t_loo,
            t_fit = t.elapsed().as_secs_f64() - t_loo,
            "tie point re-intersections and prior"
        );
        if let Some(p) = &self.tie_prior {
            tracing::info!(
                d0 = p.dof,
                s02 = p.factor,
                outlier_share = p.outlier_share,
                points = p.points,
                "the tie points differ in precision: their rays are tested against their own point's"
            );
        }
        ties
    }

    /// Re-intersections of every tie point (no control, no plane) with two active rays
    /// or more, by object point; a point whose rays do not intersect all together is left
    /// to data snooping.
    fn tie_points(&self, st: &Structure, pb: &Problem) -> BTreeMap<usize, PointLoo> {
        use rayon::prelude::*;
        let f2 = self.image_sigma * self.image_sigma;
        (0..st.point_res.len())
            .into_par_iter()
            .filter(|&p| !is_held(pb, st, p))
            .filter_map(|p| {
                Some((
                    p,
                    point_loo(
                        pb,
                        active_rays(pb, st, p),
                        f2,
                        Some((&pb.state.points[p], self.crit[3])),
                    )?,
                ))
            })
            .collect::<Vec<_>>()
            .into_iter()
            .collect()
    }

    /// The tie prior's test of a point of three rays or more: its worst ray, or the whole
    /// point when its three rays cannot be told apart ([`tie_prior::LOCALISE`]).
    fn tie_candidate(&self, prior: &TiePrior, p: &PointLoo) -> Option<Candidate> {
        let alpha = self.rule.alpha()?;
        let (k, tail) = prior.worst(p)?;
        let dof = p.loo_dof();
        let blame = if p.rays.len() == 3 && prior.blame(p, k) < tie_prior::LOCALISE {
            Blame::Point
        } else {
            Blame::Ray(p.rays[k])
        };
        let (i, w) = (p.rays[k], prior.studentized(p.q(k), p.loo[k], dof));
        let test = format!("F(2, {:.1}) of the other rays", prior.dof + dof);
        (tail < alpha).then(|| Candidate {
            i,
            w,
            rank: (alpha / tail.max(f64::MIN_POSITIVE)).ln() + 1.0,
            reason: format!(
                "image: tie ray {w:.2} σ from its point's other rays, p = {tail:.1e} < α0 = \
                 {:.3} % ({test}, tie point prior d0 = {:.1}, s0² = {:.2})",
                100.0 * alpha,
                prior.dof,
                prior.factor
            ),
            blame: Some(blame),
        })
    }

    fn calibrate_image(&mut self, pb: &Problem, s: &Stats) {
        let img: Vec<(usize, &Snoop)> = pb
            .res
            .iter()
            .zip(&s.snoop)
            .filter(|(r, _)| matches!(r.kind, Kind::Image { .. }))
            .filter_map(|(r, t)| Some((r.point()?, t.as_ref()?)))
            .collect();
        let scale = |flagged: &BTreeSet<usize>| {
            let z: Vec<f64> = img
                .iter()
                .filter(|(p, _)| !flagged.contains(p))
                .flat_map(|(_, t)| t.z[..t.dof].iter().map(|v| v.abs()))
                .collect();
            (precision::robust_scale(z.clone()), z.len())
        };
        let (mut s0, mut n) = scale(&BTreeSet::new());
        for _ in 0..10 {
            if !s0.is_finite() {
                return;
            }
            let flagged: BTreeSet<usize> = img
                .iter()
                .filter(|(_, t)| t.dof > 0 && t.t / (s0 * s0) > self.crit[t.dof])
                .map(|(p, _)| *p)
                .collect();
            let (s1, n1) = scale(&flagged);
            let done = (s1 - s0).abs() <= 1e-3 * s0;
            (s0, n) = (s1, n1);
            if done {
                break;
            }
        }
        if !s0.is_finite() {
            return;
        }
        self.first_round = Some(s0);
        let se = (1.36 / n as f64).sqrt();
        tracing::debug!(
            sigma0 = s0,
            components = n,
            "robust image σ0 of the first solution"
        );
        if s0 > GUARD_RATIO && s0 > 1.0 + 3.0 * se {
            self.image_sigma = s0;
            tracing::warn!(
                sigma0 = s0,
                "the a-priori image σ is too optimistic: data snooping tests against the first solution's σ0"
            );
        }
    }

    /// Variance component of the control group on the first solution: each control
    /// point's surveyed position against the intersection of its own rays, dᵀ(Q + Σ)⁻¹d ~
    /// χ²(d) with d its known axes. A control σ stated too small for the whole group (a
    /// GCP file of digitised or handheld-GNSS points given σ 5 cm, fitting at decimetres)
    /// would make every test fail, and the adjustment would reject good control and bend
    /// the block onto it, pushing good tie observations over the image test. When the
    /// median p-value of the points' tests is significantly small at α0 (the k-th smallest
    /// of n uniforms, k the median's rank), every control σ is scaled by the factor that
    /// brings the median p-value to ½, re-weighting the group (one robust variance
    /// component step, fixed for later rounds). A median does not move for a minority of
    /// wrong points: those are left for the test. Returns whether weights changed.
    fn scale_control(&mut self, st: &Structure, pb: &mut Problem) -> bool {
        let alpha = self.rule.alpha().unwrap_or(f64::NAN);
        let f2 = self.image_sigma * self.image_sigma;
        let tests: Vec<(Vector3<f64>, Matrix3<f64>, Vector3<f64>)> = pb
            .res
            .iter()
            .enumerate()
            .filter(|(_, r)| r.active && matches!(r.kind, Kind::PointPrior { .. }))
            .filter_map(|(i, r)| prior_vs_rays(st, pb, Loss::None, r.point()?, i))
            .filter(|(_, _, sigma)| sigma.iter().any(|v| v.is_finite()))
            .collect();
        let n = tests.len();
        if n < 3 || !alpha.is_finite() {
            return false;
        }
        let k = n.div_ceil(2);
        let median_p = |f: f64| {
            let mut p: Vec<f64> = tests
                .iter()
                .map(|(d, q, sigma)| {
                    let (t, dof) = prior_test(d, q, &(sigma * f.sqrt()), f2);
                    chi2::upper_tail(dof, t)
                })
                .collect();
            p.sort_by(f64::total_cmp);
            p[k - 1]
        };
        let m = median_p(1.0);
        // P(k-th smallest of n uniforms ≤ m) = P(at least k of n below m).
        let significance: f64 = (k..=n)
            .map(|j| binomial(n, j) * m.powi(j as i32) * (1.0 - m).powi((n - j) as i32))
            .sum();
        if significance >= alpha {
            return false;
        }
        let (mut lo, mut hi) = (1.0f64, 1.0f64);
        while median_p(hi) < 0.5 && hi < 1e8 {
            hi *= 4.0;
        }
        for _ in 0..60 {
            let mid = (lo * hi).sqrt();
            if median_p(mid) < 0.5 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let scale = hi.sqrt();
        if scale < GUARD_RATIO {
            return false;
        }
        for r in pb.res.iter_mut() {
            if let Kind::PointPrior { sigma, .. } = &mut r.kind {
                *sigma *= scale;
            }
        }
        self.control_scale = Some(scale);
        tracing::warn!(
            scale,
            points = n,
            "the control σ is too optimistic for the control as a whole: every control σ is scaled"
        );
        true
    }

    /// Observations to reject after a solution. Per object point only the worst goes
    /// (a gross error smears into the other rays of its point, which recover once it is
    /// removed). `sweep` (the rounds ran out) takes every exceedance: data snooping per
    /// failing point by `sweep_point`, the threshold rule all at once.
    pub(super) fn select(
        &mut self,
        st: &Structure,
        pb: &Problem,
        loss: Loss,
        round: usize,
        sweep: bool,
    ) -> Vec<(usize, Rejected)> {
        let cand = match self.rule {
            Rejection::None => return Vec::new(),
            Rejection::Threshold(k) => {
                let (cand, tested) = threshold_candidates(st, pb, loss, k);
                if sweep {
                    cand
                } else {
                    beyond_chance(cand, tested, k)
                }
            }
            Rejection::DataSnooping(_) => self.snooping_candidates(st, pb),
        };
        let mut out: Vec<(usize, f64, String)> = Vec::new();
        let mut blamed = BTreeSet::new();
        for c in &cand {
            if matches!(pb.res[c.i].kind, Kind::PointPrior { .. }) {
                blamed.extend(pb.res[c.i].point());
                out.push((c.i, c.w, c.reason.clone()));
            }
        }
        let mut best: BTreeMap<usize, &Candidate> = BTreeMap::new();
        let mut swept = BTreeSet::new();
        for c in &cand {
            let r = &pb.res[c.i];
            // POS priors are not rejected: a photo without its prior may lose the datum, and
            // a POS gross error shows in the image residuals of the photo all the same.
            let Some(p) = r.point() else { continue };
            if matches!(r.kind, Kind::PointPrior { .. }) || blamed.contains(&p) {
                continue;
            }
            if sweep {
                swept.insert(p);
                if !matches!(self.rule, Rejection::DataSnooping(_)) {
                    out.push((c.i, c.w, c.reason.clone()));
                }
                continue;
            }
            let e = best.entry(p).or_insert(c);
            if c.rank > e.rank {
                *e = c;
            }
        }
        let mut with_point = BTreeSet::new();
        if matches!(self.rule, Rejection::DataSnooping(_)) {
            for p in swept {
                for (i, w, reason, whole) in self.sweep_point(st, pb, p) {
                    if whole {
                        with_point.insert(i);
                    }
                    out.push((i, w, reason));
                }
            }
        }
        let (f2, crit1) = self.localisation_test();
        for (p, c) in best {
            let blame = match (c.blame, &pb.res[c.i].kind) {
                (Some(b), _) => Some((b, active_rays(pb, st, p))),
                (None, Kind::Image { .. }) => {
                    let rays = active_rays(pb, st, p);
                    localize(pb, &rays, is_held(pb, st, p), f2, crit1).map(|b| (b, rays))
                }
                _ => None,
            };
            match blame {
                None => out.push((c.i, c.w, c.reason.clone())),
                Some((Blame::Ray(i), _)) if i == c.i => out.push((i, c.w, c.reason.clone())),
                Some((Blame::Ray(i), _)) => out.push((
                    i,
                    c.w,
                    format!(
                        "{}; left out as the ray that leaves the others most consistent",
                        c.reason
                    ),
                )),
                Some((Blame::Point, rays)) => {
                    for &j in &rays {
                        with_point.insert(j);
                        out.push((j, c.w, point_reason(&c.reason, rays.len())));
                    }
                }
            }
        }
        out.sort_by_key(|(i, _, _)| *i);
        out.into_iter()
            .map(|(i, w, reason)| {
                (
                    i,
                    Rejected {
                        observation: pb.refs[i].clone(),
                        round,
                        standardized_residual: w,
                        reason: if sweep {
                            format!("{reason} (final sweep)")
                        } else {
                            reason
                        },
                        with_point: with_point.contains(&i),
                    },
                )
            })
            .collect()
    }

    /// The variance factor of the image σ the tests assume, and the χ²(1) critical value
    /// a leave-one-out pair is tested with (the threshold rule at α0 = 0.1 %).
    fn localisation_test(&self) -> (f64, f64) {
        let crit1 = if self.crit[1].is_finite() {
            self.crit[1]
        } else {
            chi2::critical(1, 0.001)
        };
        (self.image_sigma * self.image_sigma, crit1)
    }

    /// Final sweep of one object point: data snooping within the point with the
    /// orientations held — reject the worst (localised) observation, re-intersect, test
    /// the rest again — until all pass or too few rays remain. Rejecting every exceedance
    /// at once would also take the good rays a gross error smeared into.
    fn sweep_point(
        &self,
        st: &Structure,
        pb: &Problem,
        p: usize,
    ) -> Vec<(usize, f64, String, bool)> {
        let (f2, crit1) = self.localisation_test();
        if let Some(prior) = self.tie_prior.as_ref().filter(|_| !is_held(pb, st, p)) {
            let rays = active_rays(pb, st, p);
            if rays.len() >= 3
                && point_loo(
                    pb,
                    rays.clone(),
                    f2,
                    Some((&pb.state.points[p], self.crit[3])),
                )
                .is_some()
            {
                return self.sweep_tie_point(prior, pb, rays);
            }
        }
        let mut idx: Vec<usize> = st
            .point_res
            .of(p)
            .filter(|&j| pb.res[j].active && pb.res[j].point() == Some(p))
            .collect();
        let mut out = Vec::new();
        loop {
            let rays: Vec<usize> = idx
                .iter()
                .copied()
                .filter(|&j| matches!(pb.res[j].kind, Kind::Image { .. }))
                .collect();
            let held = idx.iter().any(|&j| match pb.res[j].kind {
                Kind::PointPrior { .. } => pb.res[j].kind.dof() == 3,
                Kind::Plane { .. } => true,
                _ => false,
            });
            if rays.len() < 2 && !held {
                break;
            }
            let tests = precision::point_snooping(&pb.res, &pb.state, &idx);
            let mut worst: Option<(usize, f64, f64, usize)> = None;
            for (&j, t) in idx.iter().zip(&tests) {
                let Some(t) = t else { continue };
                let tt = match pb.res[j].kind {
                    Kind::Image { .. } => t.t / f2,
                    Kind::Plane { .. } => t.t,
                    _ => continue,
                };
                let rank = if t.dof > 0 {
                    tt / self.crit[t.dof]
                } else {
                    0.0
                };
                if worst.is_none_or(|w| rank > w.2) {
                    worst = Some((j, tt, rank, t.dof));
                }
            }
            let Some((j, t, _, dof)) = worst.filter(|w| w.2 > 1.0) else {
                break;
            };
            let reason = self.reason(&pb.res[j], t, dof);
            let blame = match pb.res[j].kind {
                Kind::Image { .. } => localize(pb, &rays, held, f2, crit1),
                _ => None,
            };
            let i = match blame {
                None => j,
                Some(Blame::Ray(i)) => i,
                Some(Blame::Point) => {
                    out.extend(
                        rays.iter()
                            .map(|&k| (k, t.sqrt(), point_reason(&reason, rays.len()), true)),
                    );
                    break;
                }
            };
            out.push((i, t.sqrt(), reason, false));
            idx.retain(|&k| k != i);
        }
        out
    }

    /// [`sweep_point`](Self::sweep_point) of a tie point tested by the tie prior.
    fn sweep_tie_point(
        &self,
        prior: &TiePrior,
        pb: &Problem,
        mut rays: Vec<usize>,
    ) -> Vec<(usize, f64, String, bool)> {
        let f2 = self.image_sigma * self.image_sigma;
        let mut out = Vec::new();
        // Down to two rays, the point is left to the next sweep's data snooping.
        while let Some(c) = (rays.len() >= 3)
            .then(|| point_loo(pb, rays.clone(), f2, None))
            .flatten()
            .and_then(|l| self.tie_candidate(prior, &l))
        {
            match c.blame {
                Some(Blame::Point) => {
                    let reason = point_reason(&c.reason, rays.len());
                    out.extend(rays.iter().map(|&k| (k, c.w, reason.clone(), true)));
                    break;
                }
                _ => {
                    rays.retain(|&k| k != c.i);
                    out.push((c.i, c.w, c.reason, false));
                }
            }
        }
        out
    }

    fn reason(&self, r: &ResidualBlock, t: f64, dof: usize) -> String {
        let sigma = if self.image_sigma == 1.0 {
            "a-priori σ".to_string()
        } else {
            format!("σ0 {:.2} of the first solution", self.image_sigma)
        };
        format!(
            "{}: w² = {t:.2} > {:.2} (χ²({dof}) at α0 = {:.3} %, {sigma})",
            r.kind.label(),
            self.crit[dof],
            100.0 * self.rule.alpha().unwrap_or(f64::NAN)
        )
    }

    fn snooping_candidates(&mut self, st: &Structure, pb: &Problem) -> Vec<Candidate> {
        let (s, first_ties) = match self.first.take() {
            Some((s, ties)) => (s, Some(ties)),
            None => (stats(st, pb), None),
        };
        let f2 = self.image_sigma * self.image_sigma;
        let mut out = Vec::new();
        // The prior is fitted again on every round's solution of the observations kept:
        // the first solution's gross errors, several in one point among them, read as
        // spread there (a block of normal noise with 5 % of its rays displaced fitted d0 = 5
        // and kept 8 % of them), and are gone once their rounds have removed them.
        let mut ties = BTreeMap::new();
        if self.tie_prior.is_some() {
            ties = first_ties.unwrap_or_else(|| self.tie_points(st, pb));
            self.tie_prior = self
                .rule
                .alpha()
                .and_then(|a| tie_prior::fit(ties.values(), a, self.tie_prior.as_ref()));
        }
        // A two-ray point has no ray to leave out: its one redundant component cannot
        // tell an imprecise point from a gross error, and the prior alone would decide
        // (with d0 = 2, F(1, 2) at 0.1 % passes a pair 30 σ apart). Its rays keep one σ
        // in the adjustment, so keeping an imprecise pair at full weight costs more than
        // losing the weakest kind of tie point: two-ray points stay with data snooping.
        // (Tested by the prior too, the small bench's digital epochs' heights went
        // 0.79 -> 0.97, 0.70 -> 0.89 and 0.47 -> 0.89 GSD on seeds 1, 2 and 9, their
        // reference epochs' tie sets being mostly pairs.)
        ties.retain(|_, p| p.rays.len() >= 3);
        match &self.tie_prior {
            Some(prior) => {
                self.tie_rounds += 1;
                out.extend(ties.values().filter_map(|p| self.tie_candidate(prior, p)));
            }
            None => ties.clear(),
        }
        for (i, r) in pb.res.iter().enumerate() {
            if matches!(r.kind, Kind::Image { .. })
                && r.point().is_some_and(|p| ties.contains_key(&p))
            {
                continue;
            }
            let (t, dof) = match (&r.kind, r.point(), r.active) {
                (Kind::PointPrior { .. }, Some(p), true) => {
                    match prior_vs_rays(st, pb, Loss::None, p, i) {
                        Some((d, q, sigma)) => prior_test(&d, &q, &sigma, f2),
                        None => continue,
                    }
                }
                (Kind::Image { .. }, _, _) => match &s.snoop[i] {
                    Some(t) => (t.t / f2, t.dof),
                    None => continue,
                },
                (Kind::Plane { .. }, _, _) => match &s.snoop[i] {
                    Some(t) => (t.t, t.dof),
                    None => continue,
                },
                _ => continue,
            };
            if dof == 0 || t <= self.crit[dof] {
                continue;
            }
            out.push(Candidate {
                i,
                w: t.sqrt(),
                rank: t / self.crit[dof],
                reason: self.reason(r, t, dof),
                blame: None,
            });
        }
        out
    }

    /// Re-admits rejected observations that pass the test against the current solution
    /// (they do not take part in it: their residual's cofactor is their own plus their
    /// point's).
    pub(super) fn readmit(
        &self,
        pb: &mut Problem,
        rejected: &mut Vec<Rejected>,
        loss: Loss,
    ) -> bool {
        let st = pb.structure();
        let index: BTreeMap<String, usize> = pb
            .refs
            .iter()
            .enumerate()
            .filter(|(i, _)| !pb.res[*i].active)
            .map(|(i, r)| (format!("{r:?}"), i))
            .collect();
        // The threshold rule re-admits within k × the robust σ0 of the current solution;
        // data snooping tests against the same σ as the rounds did.
        let (pts, s0) = match self.rule {
            Rejection::None => return false,
            Rejection::Threshold(_) => {
                let ev = Evaluated::new(&pb.res, &pb.state, loss);
                let pts = solver::point_inverses(&ev, &st, 0.0);
                let u = precision::standardized(&ev, &pts, 1.0);
                (pts, threshold_sigma0(&ev, &u))
            }
            Rejection::DataSnooping(_) => {
                let ev = Evaluated::new(&pb.res, &pb.state, Loss::None);
                (solver::point_inverses(&ev, &st, 0.0), 1.0)
            }
        };
        if !s0.is_finite() {
            return false;
        }
        let f2 = self.image_sigma * self.image_sigma;
        let alive: BTreeSet<usize> = pb
            .res
            .iter()
            .filter(|r| r.active)
            .filter_map(|r| r.point())
            .collect();
        let mut readmit = Vec::new();
        rejected.retain(|rj| {
            let Some(&i) = index.get(&format!("{:?}", rj.observation)) else {
                return true;
            };
            let mut blk = pb.res[i].clone();
            blk.active = true;
            let Some(e) = blk.evaluate(&pb.state) else {
                return true;
            };
            // Only when the point is still in the solution.
            if blk.point().is_some_and(|p| !alive.contains(&p)) {
                return true;
            }
            let known = blk.kind.known();
            // A tie ray against its point's other rays, as the rounds tested it.
            if let (Some(prior), Kind::Image { .. }, Some(p)) =
                (&self.tie_prior, &blk.kind, blk.point())
            {
                let others = active_rays(pb, &st, p);
                if !is_held(pb, &st, p) && others.len() >= 2 {
                    let mut all = others.clone();
                    all.push(i);
                    let ok = match (
                        intersection_ssr(pb, &all, f2),
                        intersection_ssr(pb, &others, f2),
                    ) {
                        (Some(a), Some(o)) => {
                            let dof = (2 * others.len()) as f64 - 3.0;
                            prior.tail(a - o, o, dof) >= self.rule.alpha().unwrap_or(0.0)
                        }
                        _ => false,
                    };
                    if ok {
                        readmit.push(i);
                    }
                    return !ok;
                }
            }
            let ok = match self.rule {
                Rejection::Threshold(k) => (0..e.dim)
                    .filter(|&c| known[c])
                    .all(|c| e.r[c].abs() < k * s0),
                _ => {
                    let (t, dof) = precision::predicted(&blk, &e, &pts, f2);
                    t <= self.crit[dof]
                }
            };
            if ok {
                readmit.push(i);
            }
            !ok
        });
        for &i in &readmit {
            tracing::debug!(observation = ?pb.refs[i], "re-admitted");
            pb.res[i].active = true;
        }
        !readmit.is_empty()
    }
}

/// Binomial coefficient C(n, k) as a float (n is a number of control points).
fn binomial(n: usize, k: usize) -> f64 {
    (0..k).fold(1.0, |c, j| c * (n - j) as f64 / (j + 1) as f64)
}

/// The reason of a ray that went with its point.
fn point_reason(test: &str, rays: usize) -> String {
    format!(
        "{test}; the point's {rays} rays cannot tell which one is wrong (leaving out any one \
         fits): the tie point is removed"
    )
}

/// An observation above the critical value: its index, test statistic (w), rank among
/// its point's observations and the reason for the report.
struct Candidate {
    i: usize,
    w: f64,
    rank: f64,
    reason: String,
    /// Where the test itself put the gross error (the tie prior's leave-one-out test);
    /// None: to be localised.
    blame: Option<Blame>,
}

/// The significance level, for the whole block, of a rejection once the exceedances of
/// a round are no more than clean data gives by chance (see [`beyond_chance`]).
const BLOCK_ALPHA: f64 = 0.05;

/// The exceedances of a round that chance does not explain. Clean data exceeds k·σ0 in a
/// fraction α(k) of its components (1.2 % at k = 2.5, and an image observation has two):
/// a rule that rejects every exceedance and solves again finds that fraction anew in
/// every round, and 20 rounds took 40 % of the observations of a small block's film
/// epoch (1,800 of 3,000 tie points, and 33 of 64 control points in the first round).
/// While the exceedances are more than chance gives (the expected count plus three of
/// its standard deviations), there are gross errors among them and the round takes
/// them as before; once they are not, only those beyond the block-wide critical value
/// (level [`BLOCK_ALPHA`] over all `tested` components, Bonferroni) go, and the rounds
/// stop.
fn beyond_chance(cand: Vec<Candidate>, tested: usize, k: f64) -> Vec<Candidate> {
    let expected = tested as f64 * chi2::alpha_of_k(k);
    if cand.len() as f64 > expected + 3.0 * expected.sqrt() + 1.0 {
        return cand;
    }
    let block_k = chi2::k_of_alpha(BLOCK_ALPHA / tested.max(1) as f64).max(k);
    cand.into_iter().filter(|c| c.w > block_k).collect()
}

/// The σ0 of the k·σ0 rule: the round's robust σ0, but never below the a-priori σ. An
/// observation within k of its own stated σ is not a gross error because the others
/// fit better than stated: on the small block's film epoch, LSM tie points of one film
/// fit to 0.03 px where their σ says 0.1 px, and a robust σ0 of 0.23 put the threshold at
/// 0.6 σ, so a quarter of the image observations went (bench accuracy, seed 3).
fn threshold_sigma0(ev: &Evaluated, unit: &[Option<(f64, f64)>]) -> f64 {
    precision::robust_sigma0(ev, unit).max(1.0)
}

/// The k·σ0 rule: standardised residual components against the round's σ0. With
/// the candidates, the number of components tested.
fn threshold_candidates(
    st: &Structure,
    pb: &Problem,
    loss: Loss,
    k: f64,
) -> (Vec<Candidate>, usize) {
    let ev = Evaluated::new(&pb.res, &pb.state, loss);
    let pts = solver::point_inverses(&ev, st, 0.0);
    let unit = precision::standardized(&ev, &pts, 1.0);
    let s0 = threshold_sigma0(&ev, &unit);
    if !s0.is_finite() || s0 <= 0.0 {
        return (Vec::new(), 0);
    }
    let reason =
        |w: f64, kind: &str| format!("{kind}: standardised residual {w:.2} > {k} (σ0 = {s0:.3})");
    let mut out = Vec::new();
    let mut tested = 0;
    for (i, r) in pb.res.iter().enumerate() {
        let w = match (&r.kind, r.point(), r.active) {
            (Kind::PointPrior { .. }, Some(p), true) => {
                let Some((d, q, sigma)) = prior_vs_rays(st, pb, loss, p, i) else {
                    continue;
                };
                let known = (0..3).filter(|&c| sigma[c].is_finite());
                tested += known.clone().count();
                known
                    .map(|c| d[c].abs() / (s0 * (q[(c, c)] + sigma[c] * sigma[c]).sqrt()))
                    .fold(0.0, f64::max)
            }
            (
                Kind::PointPrior { .. }
                | Kind::PosCenter { .. }
                | Kind::PosAttitude { .. }
                | Kind::LidarDatum { .. },
                ..,
            ) => continue,
            _ => match unit[i] {
                Some((_, w)) => {
                    tested += r.kind.known().iter().filter(|&&b| b).count();
                    w / s0
                }
                None => continue,
            },
        };
        if w > k {
            out.push(Candidate {
                i,
                w,
                rank: w,
                reason: reason(w, r.kind.label()),
                blame: None,
            });
        }
    }
    (out, tested)
}

/// A control point's surveyed position against its intersection from its own rays (with
/// the current orientations): a strong prior absorbs its gross error into the image
/// residuals, which would otherwise be rejected instead of the prior. Returns the
/// difference (m), the rays' object-space cofactor (m², a-priori image σ) and the prior's
/// σ; `None` with fewer than two rays.
fn prior_vs_rays(
    st: &Structure,
    pb: &Problem,
    loss: Loss,
    p: usize,
    i: usize,
) -> Option<(Vector3<f64>, Matrix3<f64>, Vector3<f64>)> {
    let ev = Evaluated::new(&pb.res, &pb.state, loss);
    let Kind::PointPrior { value, sigma } = &pb.res[i].kind else {
        return None;
    };
    let mut v = Matrix3::zeros();
    let mut g = Vector3::zeros();
    let mut rays = 0;
    for j in st.point_res.of(p) {
        if !matches!(pb.res[j].kind, Kind::Image { .. }) {
            continue;
        }
        if let Some((e, w)) = ev.at(j) {
            v += w * e.j_point.transpose() * e.j_point;
            g += w * e.j_point.transpose() * e.r;
            rays += 1;
        }
    }
    if rays < 2 {
        return None;
    }
    let q = v.try_inverse()?;
    let x_rays = pb.state.points[p] - q * g;
    Some((x_rays - value, q, *sigma))
}

/// dᵀ(f²Q + Σ)⁻¹d over the prior's known axes, and their number.
fn prior_test(d: &Vector3<f64>, q: &Matrix3<f64>, sigma: &Vector3<f64>, f2: f64) -> (f64, usize) {
    let idx: Vec<usize> = (0..3).filter(|&c| sigma[c].is_finite()).collect();
    let n = idx.len();
    let m = DMatrix::from_fn(n, n, |a, b| {
        f2 * q[(idx[a], idx[b])] + if a == b { sigma[idx[a]].powi(2) } else { 0.0 }
    });
    let v = DVector::from_fn(n, |a, _| d[idx[a]]);
    match m.cholesky() {
        Some(c) => (v.dot(&c.solve(&v)), n),
        None => (0.0, 0),
    }
}

/// The active image observations of object point `p`.
fn active_rays(pb: &Problem, st: &Structure, p: usize) -> Vec<usize> {
    st.point_res
        .of(p)
        .filter(|&j| pb.res[j].active && matches!(pb.res[j].kind, Kind::Image { .. }))
        .collect()
}

/// Where the gross error of an object point that failed its test lies.
#[derive(Debug, Clone, Copy)]
enum Blame {
    /// This ray: leaving it out leaves the others consistent.
    Ray(usize),
    /// No single ray: the disagreement has no redundancy that tells the rays apart. Two
    /// rays share one residual; three rays along one base line have one redundant
    /// component along it (x-parallax), in which each ray's test statistic is the same.
    /// The point leaves the block, else a ray chosen at random goes and the gross error
    /// stays in the remaining two, where no test can see it.
    Point,
}

/// Leave-one-out localisation of a gross error among the rays of an object point: the ray
/// whose removal leaves the others most consistent (smallest sum of squared residuals of
/// a re-intersection with the current orientations, in units of the tested σ, `f2` its
/// variance factor). A point of three rays is localised only when leaving out any other
/// ray leaves an inconsistent pair (its SSR, χ²(1) under H0, above `crit1`). `held`: the
/// point also has a control prior or a LiDAR plane, whose redundancy tells the rays apart
/// (`None` for the caller's own choice when it has fewer than three rays).
fn localize(pb: &Problem, rays: &[usize], held: bool, f2: f64, crit1: f64) -> Option<Blame> {
    if rays.len() < 3 {
        return (!held && rays.len() == 2).then_some(Blame::Point);
    }
    let mut ssr: Vec<(f64, usize)> = Vec::new();
    for &skip in rays {
        let others: Vec<usize> = rays.iter().copied().filter(|&j| j != skip).collect();
        if let Some(s) = intersection_ssr(pb, &others, f2) {
            ssr.push((s, skip));
        }
    }
    ssr.sort_by(|a, b| a.0.total_cmp(&b.0));
    let &(_, best) = ssr.first()?;
    if rays.len() == 3 && !held && ssr.get(1).is_none_or(|s| s.0 <= crit1) {
        return Some(Blame::Point);
    }
    Some(Blame::Ray(best))
}

/// The sum of squared residuals of image observations `rays` at object point `x` with
/// the current orientations, in units of each ray's σ and the variance factor `f2`.
fn ssr_at(pb: &Problem, rays: &[usize], x: &Vector3<f64>, f2: f64) -> f64 {
    let s: f64 = rays
        .iter()
        .map(|&j| {
            let r: &ResidualBlock = &pb.res[j];
            let Kind::Image { pixel, sigma } = r.kind else {
                unreachable!("an image observation")
            };
            let (c, pose) = (
                &pb.state.cameras[r.camera().expect("camera")],
                &pb.state.poses[r.photo().expect("photo")],
            );
            crate::geometry::project(c, pose, x)
                .map(|q| ((q.pixel - pixel) / sigma).norm_squared())
                .unwrap_or(f64::INFINITY)
        })
        .sum();
    s / f2
}

/// [`ssr_at`] the re-intersection of `rays`; None when they do not intersect.
fn intersection_ssr(pb: &Problem, rays: &[usize], f2: f64) -> Option<f64> {
    reintersect(pb, rays, f2, None).map(|(s, _)| s)
}

/// The re-intersection of `rays` (from `start` when given, else from their midpoint) and
/// its [`ssr_at`].
fn reintersect(
    pb: &Problem,
    rays: &[usize],
    f2: f64,
    start: Option<&Vector3<f64>>,
) -> Option<(f64, Vector3<f64>)> {
    let ray = |j: usize| {
        let r: &ResidualBlock = &pb.res[j];
        let Kind::Image { pixel, sigma } = r.kind else {
            unreachable!("an image observation")
        };
        (
            &pb.state.cameras[r.camera().expect("camera")],
            &pb.state.poses[r.photo().expect("photo")],
            [pixel.x, pixel.y],
            sigma,
        )
    };
    let rays_of: Vec<_> = rays.iter().map(|&j| ray(j)).collect();
    let x = match start {
        Some(x0) => precision::refine_intersection(&rays_of, *x0)?,
        None => intersect(&rays_of)?,
    };
    Some((ssr_at(pb, rays, &x, f2), x))
}

/// A tie point's re-intersections from all its `rays` and leaving each out (three rays
/// or more); None with fewer than two rays or when all of them do not intersect. Rays
/// left after one is left out that do not intersect count as inconsistent (an infinite
/// sum): leaving that one out explains nothing.
///
/// `held_at`: the point's position in the adjustment, with the critical value of χ²(3).
/// A point the adjustment holds that much farther from its rays than their own
/// intersection (a redescending robust loss gives a point far from its rays no gradient
/// back) is None too: it is left to data snooping, whose test of its rays it fails.
fn point_loo(
    pb: &Problem,
    rays: Vec<usize>,
    f2: f64,
    held_at: Option<(&Vector3<f64>, f64)>,
) -> Option<PointLoo> {
    if rays.len() < 2 {
        return None;
    }
    let (ss, all) = reintersect(pb, &rays, f2, None).filter(|(s, _)| s.is_finite())?;
    if let Some((x, crit)) = held_at {
        if ssr_at(pb, &rays, x, f2) - ss > crit {
            return None;
        }
    }
    let mut loo = Vec::new();
    if rays.len() >= 3 {
        for &skip in &rays {
            let others: Vec<usize> = rays.iter().copied().filter(|&j| j != skip).collect();
            loo.push(reintersect(pb, &others, f2, Some(&all)).map_or(f64::INFINITY, |(s, _)| s));
        }
    }
    Some(PointLoo::new(rays, ss, loo))
}

/// Whether object point `p` has an active control prior (with a known axis) or a LiDAR
/// plane besides its rays.
fn is_held(pb: &Problem, st: &Structure, p: usize) -> bool {
    st.point_res.of(p).any(|j| {
        let r = &pb.res[j];
        r.active
            && r.point() == Some(p)
            && match r.kind {
                Kind::PointPrior { .. } => r.kind.dof() > 0,
                Kind::Plane { .. } => true,
                _ => false,
            }
    })
}
