//! The precision of tie points as a scale mixture, and the gross-error test it gives:
//! each tie point's rays share one unknown variance factor λ, which varies from point to
//! point around the image group's; a gross error is a ray that disagrees with its own
//! point's other rays, not a ray far from the block's σ.
//!
//! Why: on the real kite block (COLMAP's own solution of 12 photos, 35,172 observations)
//! a ray's squared residual correlates at 0.49 with the mean of its point's other rays
//! (0.003 shuffled), and of the rays beyond 1.645 px (3.29 × 0.5 px) nearly all belong
//! to the quarter of points whose other rays are the least precise. Neither the SIFT
//! detection scale (re-detected with OpenCV on the same images: 0.61 % of the rays of
//! the finest quarter of scales beyond 1.645 px, 2.3 % of the coarsest tenth) nor the
//! local structure tensor (log-correlation with the squared residual 0.02–0.13 over
//! three scales) accounts for it: the precision belongs to the point. Data snooping
//! against one σ for every point rejected 3.0 % of that block's tie observations.
//!
//! The model, per tie point with n rays re-intersected with the orientations held
//! (sums of squares in units of the tested image σ²):
//! - λ has a scaled inverse-χ² prior: d0 degrees of freedom around s0² (d0 infinite: one
//!   variance for every point);
//! - a ray is a gross error with probability π, uniform over a disc of
//!   [`OUTLIER_RADIUS`] σ; its point then shows only its other rays' spread.
//!
//! (d0, s0², π) are the maximum-likelihood fit over all tie points. The outlier component
//! is what keeps the fit from reading gross errors as spread: without it, the kite
//! block with 2 % of its rays displaced 3–30 px fitted d0 = 1.5 and hid them. The test of
//! a ray is its leave-one-out prediction: the others' re-intersection predicts where the
//! ray should be, and its deviation q, with λ integrated over its posterior from the
//! prior and the others' own sum of squares S₋ on d₋ degrees of freedom, is F-distributed
//! with no gross error: q / (2 s²) ~ F(2, d0 + d₋), s² = (d0 s0² + S₋)/(d0 + d₋). A ray's
//! own gross error cannot inflate the factor it is tested with.
//!
//! Two-ray points are not tested this way (see the rejection test): they have no ray to
//! leave out.
//!
//! Measured on the kite block (α0 = 0.1 %, the adjustment's rounds): 0.37 % of the
//! clean block's tie observations are rejected, and of 703 displacements of 3–30 px
//! injected into 2 % of its rays 94.5 % are found with 0.53 % of the others rejected;
//! most misses are displacements below 8 px in points of three rays, where the prior's
//! spread makes an imprecise point as likely. On normal data the fit gives no
//! significant spread and the block keeps data snooping against one σ.

use serde::{Deserialize, Serialize};
use statrs::function::gamma::ln_gamma;
use std::f64::consts::PI;

/// Radius, in tested σ, of the disc over which a gross error's displacement is taken as
/// uniform (50 px at the kite block's 0.5 px). The fit of d0 and s0² barely depends on
/// it; it sets how far out a ray must lie to count as an outlier in the fit.
pub const OUTLIER_RADIUS: f64 = 100.0;

/// Fewer tie points give no distribution to fit: the block keeps one σ.
const MIN_POINTS: usize = 50;

/// Posterior probability the worst ray of a three-ray point must have of being the
/// point's gross error (against either other ray) to be rejected alone; below it the
/// point goes. Its other two rays have one redundancy between them, which with a
/// heavy-tailed prior often cannot tell the three apart.
pub const LOCALISE: f64 = 0.9;

/// One tie point's re-intersections: from all its rays and leaving each out.
#[derive(Debug, Clone)]
pub struct PointLoo {
    /// Residual indices of the rays.
    pub rays: Vec<usize>,
    /// Sum of squared residuals of all rays (tested σ²) and its degrees of freedom 2n − 3.
    pub ss: f64,
    pub dof: f64,
    /// Per ray (same order): the others' sum of squares and degrees of freedom 2n − 5;
    /// empty for two rays.
    pub loo: Vec<f64>,
}

impl PointLoo {
    pub fn new(rays: Vec<usize>, ss: f64, loo: Vec<f64>) -> Self {
        let dof = (2 * rays.len()) as f64 - 3.0;
        Self { rays, ss, dof, loo }
    }

    pub fn loo_dof(&self) -> f64 {
        self.dof - 2.0
    }

    /// The deviation of ray k from the others' prediction: the growth of the sum of
    /// squares when it joins them (exact for the linearised intersection).
    pub fn q(&self, k: usize) -> f64 {
        (self.ss - self.loo[k]).max(0.0)
    }
}

/// The tie points' precision prior (the report's `tie_point_prior`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TiePrior {
    /// Degrees of freedom d0 of the variance factors' prior (finite: the points differ
    /// in precision beyond chance).
    pub dof: f64,
    /// The typical variance factor s0², in units of the tested image σ².
    pub factor: f64,
    /// Share π of rays the fit takes as gross errors.
    pub outlier_share: f64,
    /// Tie points the fit used.
    pub points: usize,
}

/// The log marginal density of a residual vector of d dimensions (d a small integer) and
/// sum of squares S (unit σ), its variance factor integrated over the prior: a
/// multivariate t. The Γ terms depend on d alone and are tabled once per (d0, s0²): the
/// fit evaluates the density about 10⁸ times on a block of 10⁴ points.
struct Marginal {
    d0: f64,
    s02: f64,
    /// ln Γ((d0+d)/2) − ln Γ(d0/2) + ½ d0 ln(d0 s0²) − ½ d ln π, by d.
    constant: Vec<f64>,
}

impl Marginal {
    fn new(d0: f64, s02: f64, max_dof: usize) -> Self {
        let constant = (0..=max_dof)
            .map(|d| {
                let d = d as f64;
                if !d0.is_finite() {
                    -0.5 * d * (2.0 * PI * s02).ln()
                } else {
                    ln_gamma(0.5 * (d0 + d)) - ln_gamma(0.5 * d0) + 0.5 * d0 * (d0 * s02).ln()
                        - 0.5 * d * PI.ln()
                }
            })
            .collect();
        Self { d0, s02, constant }
    }

    fn ln(&self, ss: f64, d: f64) -> f64 {
        if d <= 0.0 {
            return 0.0;
        }
        if ss.is_infinite() {
            return f64::NEG_INFINITY;
        }
        let c = match self.constant.get(d as usize) {
            Some(&c) => c,
            None => Marginal::new(self.d0, self.s02, d as usize).constant[d as usize],
        };
        if !self.d0.is_finite() {
            return c - ss / (2.0 * self.s02);
        }
        c - 0.5 * (self.d0 + d) * (self.d0 * self.s02 + ss).ln()
    }
}

/// Per point, the likelihood's parts that do not depend on π: ln A (every ray clean) and
/// ln Σ_k B_k (ray k, one of them, a gross error).
fn parts(p: &PointLoo, m: &Marginal) -> (f64, f64) {
    let a = m.ln(p.ss, p.dof);
    let b = if p.loo.is_empty() {
        // Two rays: either one displaced leaves one residual dimension, uniform along
        // the epipolar line.
        2f64.ln() - (2.0 * OUTLIER_RADIUS).ln()
    } else {
        let disc = -(PI * OUTLIER_RADIUS * OUTLIER_RADIUS).ln();
        log_sum_exp(p.loo.iter().map(|&s| m.ln(s, p.loo_dof()))) + disc
    };
    (a, b)
}

/// ln Σ exp(x), in one pass (a running maximum).
fn log_sum_exp(v: impl Iterator<Item = f64>) -> f64 {
    let (mut m, mut sum) = (f64::NEG_INFINITY, 0.0);
    for x in v {
        if x > m {
            sum = sum * (m - x).exp() + 1.0;
            m = x;
        } else if x > f64::NEG_INFINITY {
            sum += (x - m).exp();
        }
    }
    if m.is_finite() {
        m + sum.ln()
    } else {
        m
    }
}

const SHARES: [f64; 7] = [1e-4, 3e-4, 1e-3, 3e-3, 0.01, 0.03, 0.1];
const DOFS: [f64; 16] = [
    0.5,
    1.0,
    1.5,
    2.0,
    2.5,
    3.0,
    4.0,
    5.0,
    6.0,
    8.0,
    12.0,
    20.0,
    35.0,
    60.0,
    120.0,
    f64::INFINITY,
];

/// Points per parallel task of the likelihood: fixed chunks summed in order, so the
/// thread count never changes a bit of the fit. Small enough that the screen's 2,000
/// points are several tasks (at 2,048 they were one, on one core).
const CHUNK: usize = 256;

/// ln(1 + eˣ) without overflow.
fn softplus(x: f64) -> f64 {
    if x > 0.0 {
        x + (-x).exp().ln_1p()
    } else {
        x.exp().ln_1p()
    }
}

/// ln(1 + y) for y ≥ 0, by its series where the next term is below the rounding: on a
/// clean block nearly every point's gross-error odds are that small, and `ln_1p` was
/// the fit's largest cost.
fn ln_1p_small(y: f64) -> f64 {
    if y < 1e-8 {
        y - 0.5 * y * y
    } else {
        y.ln_1p()
    }
}

/// The log-likelihood at (d0, s0²), maximised over π on `shares` (a run of [`SHARES`]):
/// (value, π). A point's two hypotheses, every ray clean (n ln(1−π) + ln A) or one ray a
/// gross error (ln π + (n−1) ln(1−π) + ln Σ B), are summed as
/// n ln(1−π) + ln A + ln(1 + π/(1−π) · Σ B / A): one exponential per point for all the
/// shares, and a logarithm per share only where the odds are not negligible.
fn likelihood(points: &[&PointLoo], d0: f64, s02: f64, shares: &[f64]) -> (f64, f64) {
    use rayon::prelude::*;
    let max_dof = points.iter().map(|p| p.dof as usize).max().unwrap_or(0);
    let m = Marginal::new(d0, s02, max_dof);
    // Per share: ln(π/(1−π)), π/(1−π), ln(1−π).
    let logs: Vec<(f64, f64, f64)> = shares
        .iter()
        .map(|&pi| ((pi / (1.0 - pi)).ln(), pi / (1.0 - pi), (1.0 - pi).ln()))
        .collect();
    // Per chunk, the log-likelihood at every share.
    let chunks: Vec<[f64; SHARES.len()]> = points
        .par_chunks(CHUNK)
        .map(|c| {
            let mut ll = [0.0; SHARES.len()];
            for p in c {
                let (a, b) = parts(p, &m);
                let n = p.rays.len() as f64;
                let lls = ll.iter_mut().zip(&logs);
                if !a.is_finite() {
                    // Every ray clean is impossible: one is a gross error.
                    lls.for_each(|(l, &(odds, _, l0))| *l += n * l0 + odds + b);
                } else if b > a {
                    lls.for_each(|(l, &(odds, _, l0))| *l += n * l0 + a + softplus(odds + b - a));
                } else {
                    let e = (b - a).exp();
                    lls.for_each(|(l, &(_, ratio, l0))| *l += n * l0 + a + ln_1p_small(ratio * e));
                }
            }
            ll
        })
        .collect();
    shares
        .iter()
        .enumerate()
        .map(|(k, &pi)| (chunks.iter().map(|c| c[k]).sum::<f64>(), pi))
        .fold(
            (f64::NEG_INFINITY, f64::NAN),
            |m, x| if x.0 > m.0 { x } else { m },
        )
}

/// Half-width in ln s0² of the first bracket around a guess of s0² (the screen's, or the
/// last round's): on the kite block the screen's s0² was within 5 % of all points' at
/// every d0 (ln s0² within 0.05).
const BRACKET: f64 = 0.25;

/// Maximises over ln s0² (Brent's method, to `tolerance` in ln s0²) for one d0: (ll, s0²,
/// π). Without a guess the whole range 10⁻³–10³ is searched; with one, a bracket of
/// ±[`BRACKET`] around it, widened about its best while that lands on an edge.
fn best_factor(
    points: &[&PointLoo],
    d0: f64,
    guess: Option<f64>,
    tolerance: f64,
    shares: &[f64],
) -> (f64, f64, f64) {
    let (min, max) = (1e-3f64.ln(), 1e3f64.ln());
    let f = |x: f64| likelihood(points, d0, x.exp(), shares);
    let (mut lo, mut hi) = match guess {
        Some(s) => ((s.ln() - BRACKET).max(min), (s.ln() + BRACKET).min(max)),
        None => (min, max),
    };
    loop {
        let (x, ll, pi) = brent_max(lo, hi, tolerance, f);
        let edge = (x - lo < 2.0 * tolerance && lo > min) || (hi - x < 2.0 * tolerance && hi < max);
        if !edge {
            return (ll, x.exp(), pi);
        }
        let w = 2.0 * (hi - lo);
        (lo, hi) = ((x - w).max(min), (x + w).min(max));
    }
}

/// Brent's maximisation of `f` (value, π) over [a, b] to about `tolerance` in x: golden
/// sections where a parabola through the last three points would not be trusted, the
/// parabola's vertex where it is: (x, value, π). On the kite block and the 50- and
/// 200-photo bench blocks it needed 5–8 likelihoods over a bracket of ±0.25 to 10⁻³ and
/// 11–13 over the whole range to 10⁻², where the golden section needs 15 and 17.
fn brent_max(
    mut a: f64,
    mut b: f64,
    tolerance: f64,
    f: impl Fn(f64) -> (f64, f64),
) -> (f64, f64, f64) {
    // (3 − √5)/2: the golden section's step.
    const C: f64 = 0.381_966_011_250_105_1;
    // The search minimises g = −value.
    let g = |x: f64| {
        let (v, pi) = f(x);
        (-v, pi)
    };
    let mut x = a + C * (b - a);
    let (mut w, mut v) = (x, x);
    let first = g(x);
    let (mut fx, mut fw, mut fv) = (first.0, first.0, first.0);
    let mut pi_x = first.1;
    let (mut d, mut e) = (0.0f64, 0.0f64);
    let tol1 = tolerance / 3.0;
    let tol2 = 2.0 * tol1;
    loop {
        let m = 0.5 * (a + b);
        if (x - m).abs() <= tol2 - 0.5 * (b - a) {
            break;
        }
        let mut parabolic = false;
        if e.abs() > tol1 {
            let r = (x - w) * (fx - fv);
            let mut q = (x - v) * (fx - fw);
            let mut p = (x - v) * q - (x - w) * r;
            q = 2.0 * (q - r);
            if q > 0.0 {
                p = -p;
            }
            q = q.abs();
            let last = e;
            e = d;
            if p.abs() < (0.5 * q * last).abs() && p > q * (a - x) && p < q * (b - x) {
                d = p / q;
                let u = x + d;
                if u - a < tol2 || b - u < tol2 {
                    d = tol1.copysign(m - x);
                }
                parabolic = true;
            }
        }
        if !parabolic {
            e = if x >= m { a - x } else { b - x };
            d = C * e;
        }
        let u = if d.abs() >= tol1 {
            x + d
        } else {
            x + tol1.copysign(d)
        };
        let (fu, pi_u) = g(u);
        if fu <= fx {
            if u >= x {
                a = x;
            } else {
                b = x;
            }
            (v, fv) = (w, fw);
            (w, fw) = (x, fx);
            (x, fx, pi_x) = (u, fu, pi_u);
        } else {
            if u < x {
                a = u;
            } else {
                b = u;
            }
            if fu <= fw || w == x {
                (v, fv) = (w, fw);
                (w, fw) = (u, fu);
            } else if fu <= fv || v == x || v == w {
                (v, fv) = (u, fu);
            }
        }
    }
    (x, -fx, pi_x)
}

/// Tie points the d0 grid is first searched on, an even stride through them: the grid's
/// best and its neighbours are then fitted on every point, beside one variance for the
/// likelihood-ratio test, with s0² bracketed around the screen's and π on the screen's
/// best and two grid steps each side. The whole grid on every point took 4.4 s of a
/// 10.6 s adjustment of 800 photos (66,666 tie points), twice pycolmap's share of its
/// call.
const SCREEN_POINTS: usize = 2000;

/// ln s0² tolerance of the fits the test is made from: a 10⁻² error in ln s0² would move
/// the log-likelihood of 10⁵ residual dimensions by about 1, the size of the test's own
/// critical difference (1.9 at 5 %).
const FINE: f64 = 1e-3;

/// The d0 grid's values next to `d0` (two each side) and one variance.
fn near(d0: f64) -> Vec<f64> {
    let at = DOFS.iter().position(|&d| d == d0).unwrap_or(0);
    let mut near: Vec<f64> = DOFS[at.saturating_sub(2)..(at + 3).min(DOFS.len())].to_vec();
    if near.last().is_some_and(|d| d.is_finite()) {
        near.push(f64::INFINITY);
    }
    near
}

/// The outlier shares next to `pi` on [`SHARES`] (two each side).
fn near_shares(pi: f64) -> &'static [f64] {
    let at = SHARES.iter().position(|&s| s == pi).unwrap_or(0);
    &SHARES[at.saturating_sub(2)..(at + 3).min(SHARES.len())]
}

/// (ll, d0, s0², π) at each of `dofs`, s0² searched about `guess(d0)` (each likelihood is
/// parallel over the points).
fn grid(
    points: &[&PointLoo],
    dofs: &[f64],
    guess: impl Fn(f64) -> Option<f64>,
    tolerance: f64,
    shares: &[f64],
) -> Vec<(f64, f64, f64, f64)> {
    dofs.iter()
        .map(|&d0| {
            let (ll, s02, pi) = best_factor(points, d0, guess(d0), tolerance, shares);
            (ll, d0, s02, pi)
        })
        .collect()
}

/// (ll, d0, s0², π) along the d0 grid from one variance down, each s0² searched about the
/// last d0's (s0² moves smoothly with d0). `climb`: stop once two d0 in a row fall below
/// the best so far (the profile likelihood of d0 has one maximum; a clean block stops
/// after four of the sixteen), else the whole grid.
fn chain(points: &[&PointLoo], tolerance: f64, climb: bool) -> Vec<(f64, f64, f64, f64)> {
    let mut fits: Vec<(f64, f64, f64, f64)> = Vec::with_capacity(DOFS.len());
    let (mut best, mut worse) = (f64::NEG_INFINITY, 0);
    for &d0 in DOFS.iter().rev() {
        let guess = fits.last().map(|f| f.2).or_else(|| median_factor(points));
        let (ll, s02, pi) = best_factor(points, d0, guess, tolerance, &SHARES);
        fits.push((ll, d0, s02, pi));
        if ll > best {
            (best, worse) = (ll, 0);
        } else {
            worse += 1;
            if climb && worse == 2 {
                break;
            }
        }
    }
    fits
}

/// A first s0² for one variance, robust to the gross errors: the median over points of
/// S/d scaled by the χ²_d median's approximation d(1 − 2/(9d))³ (Wilson–Hilferty), so
/// that it estimates the variance factor itself. The bracket about it is widened when the
/// maximum lies outside: a guess saves the search over the whole range 10⁻³–10³ (11–13
/// likelihoods against 5–8 on the 50- and 200-photo bench blocks).
fn median_factor(points: &[&PointLoo]) -> Option<f64> {
    let mut v: Vec<f64> = points
        .iter()
        .filter(|p| p.dof > 0.0)
        .map(|p| p.ss / (p.dof * (1.0 - 2.0 / (9.0 * p.dof)).powi(3)))
        .collect();
    if v.is_empty() {
        return None;
    }
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, f64::total_cmp);
    (*m > 0.0 && m.is_finite()).then_some(*m)
}

/// The fit of largest likelihood.
fn best_of(fits: &[(f64, f64, f64, f64)]) -> Option<(f64, f64, f64, f64)> {
    fits.iter().copied().filter(|f| f.0.is_finite()).fold(
        None,
        |m: Option<(f64, f64, f64, f64)>, f| match m {
            Some(m) if m.0 >= f.0 => Some(m),
            _ => Some(f),
        },
    )
}

/// The prior fitted to the tie points, or None: fewer than [`MIN_POINTS`] points, or no
/// spread significant at `alpha` (the likelihood-ratio test of a finite d0 against one
/// variance, χ²(1)); the block is then tested against one σ as before.
///
/// The d0 grid is searched near `previous`, the last round's fit (a round removes few
/// observations, and the fit is repeated every round), or else first on a stride of
/// [`SCREEN_POINTS`] points, from one variance down while the likelihood grows
/// ([`chain`]). On the 200-photo bench block the fit took 0.20 s of a 1.3 s adjustment
/// with the golden section over the whole grid, 0.05 s so.
pub fn fit<'a>(
    points: impl IntoIterator<Item = &'a PointLoo>,
    alpha: f64,
    previous: Option<&TiePrior>,
) -> Option<TiePrior> {
    let points: Vec<&PointLoo> = points
        .into_iter()
        .filter(|p| p.ss.is_finite() && p.loo.iter().all(|s| s.is_finite()))
        .collect();
    if points.len() < MIN_POINTS {
        return None;
    }
    let fits = match previous {
        Some(p) => grid(&points, &near(p.dof), |_| Some(p.factor), FINE, &SHARES),
        None if points.len() > SCREEN_POINTS => {
            let stride = points.len().div_ceil(SCREEN_POINTS);
            let screen: Vec<&PointLoo> = points.iter().step_by(stride).copied().collect();
            let coarse = chain(&screen, 1e-2, true);
            let best = best_of(&coarse)?;
            let guess = |d0: f64| coarse.iter().find(|f| f.1 == d0).map(|f| f.2);
            grid(&points, &near(best.1), guess, FINE, near_shares(best.3))
        }
        None => chain(&points, FINE, false),
    };
    let one = fits.iter().find(|f| f.1.is_infinite())?.0;
    let best = best_of(&fits)?;
    let critical = super::chi2::critical(1, alpha);
    tracing::debug!(
        d0 = best.1,
        s02 = best.2,
        pi = best.3,
        gain = best.0 - one,
        "tie point prior"
    );
    if !best.1.is_finite() || 2.0 * (best.0 - one) <= critical {
        return None;
    }
    Some(TiePrior {
        dof: best.1,
        factor: best.2,
        outlier_share: best.3,
        points: points.len(),
    })
}

impl TiePrior {
    /// P-value of ray k of a point of three rays or more: P(F(2, d0 + d₋) > q/(2 s²)).
    pub fn ray_tail(&self, p: &PointLoo, k: usize) -> f64 {
        self.tail(p.q(k), p.loo[k], p.loo_dof())
    }

    /// The posterior variance factor s² of a ray's point from its other rays (sum of
    /// squares `others` on `dof` degrees of freedom) and the prior.
    fn posterior(&self, others: f64, dof: f64) -> f64 {
        (self.dof * self.factor + others) / (self.dof + dof)
    }

    /// P(F(2, d0 + d₋) > q/(2 s²)) for a ray whose deviation from the prediction of its
    /// point's other rays is `q`.
    pub fn tail(&self, q: f64, others: f64, dof: f64) -> f64 {
        let nu = self.dof + dof;
        // F(2, ν) has the closed tail (1 + 2x/ν)^(−ν/2).
        (1.0 + q.max(0.0) / (nu * self.posterior(others, dof))).powf(-0.5 * nu)
    }

    /// The deviation in units of its posterior σ, √(q/s²) (the report's standardised
    /// residual of a tie ray).
    pub fn studentized(&self, q: f64, others: f64, dof: f64) -> f64 {
        (q.max(0.0) / self.posterior(others, dof)).sqrt()
    }

    /// The worst ray (index into `p.rays`) and its p-value; None for two rays.
    pub fn worst(&self, p: &PointLoo) -> Option<(usize, f64)> {
        (0..p.loo.len())
            .map(|k| (k, self.ray_tail(p, k)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
    }

    /// Posterior probability that ray k, not another single ray, is the point's gross
    /// error: each hypothesis weighted by how well the remaining rays fit together.
    pub fn blame(&self, p: &PointLoo, k: usize) -> f64 {
        let m = Marginal::new(self.dof, self.factor, p.loo_dof() as usize);
        let l: Vec<f64> = p.loo.iter().map(|&s| m.ln(s, p.loo_dof())).collect();
        let all = log_sum_exp(l.iter().copied());
        if !all.is_finite() {
            return 0.0;
        }
        (l[k] - all).exp()
    }
}
