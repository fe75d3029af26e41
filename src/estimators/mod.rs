//! Robust estimation of small models from samples with gross errors: one interface for
//! every minimal solver (relative orientation, resection, homographies, planes…), driven
//! by RANSAC or by least median of squares (LMedS, breakdown point 50 %, seed 003).
//!
//! The drivers are deterministic: the random stream comes from the caller's seed.

pub mod similarity2;
pub mod similarity3;

use rand::seq::index::sample;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

/// A model family with a minimal solver.
pub trait Estimator {
    type Sample;
    type Model: Clone;
    /// Samples the minimal solver needs.
    const MIN_SAMPLES: usize;
    /// All models consistent with a minimal sample (P3P gives up to four); empty when the
    /// sample is degenerate.
    fn fit_minimal(&self, samples: &[&Self::Sample]) -> Vec<Self::Model>;
    /// Squared residual of a sample under a model, in the units the threshold uses.
    fn residual_sq(&self, model: &Self::Model, sample: &Self::Sample) -> f64;
    /// Optional least-squares refinement on the inliers (local optimisation).
    fn refine(&self, model: &Self::Model, _inliers: &[&Self::Sample]) -> Option<Self::Model> {
        Some(model.clone())
    }
}

/// Which robust driver estimates the model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum RobustMethod {
    /// Least median of squares: 50 % breakdown, no threshold to choose.
    Lmeds,
    /// RANSAC with the inlier threshold of [`RobustOptions`].
    Ransac,
}

impl RobustMethod {
    /// Estimates a model of `est` from `samples` with this driver.
    pub fn estimate<E: Estimator>(
        self,
        est: &E,
        samples: &[E::Sample],
        opts: &RobustOptions,
    ) -> Result<RobustResult<E::Model>, RobustError> {
        let draws = MinimalSamples::new(samples, E::MIN_SAMPLES, opts.seed)?;
        match self {
            RobustMethod::Lmeds => lmeds(est, draws, opts),
            RobustMethod::Ransac => ransac(est, draws, opts),
        }
    }
}

#[derive(Debug, Clone)]
pub struct RobustOptions {
    /// Inlier threshold on the residual (not squared), in the estimator's units.
    pub threshold: f64,
    /// Probability of having drawn at least one all-inlier sample when stopping.
    pub confidence: f64,
    pub max_iterations: usize,
    pub min_iterations: usize,
    pub seed: u64,
}

impl Default for RobustOptions {
    fn default() -> Self {
        Self {
            threshold: 1.0,
            confidence: 0.999,
            max_iterations: 10_000,
            min_iterations: 50,
            seed: 42,
        }
    }
}

/// Result of a robust estimation.
#[derive(Debug, Clone)]
pub struct RobustResult<M> {
    pub model: M,
    pub inliers: Vec<bool>,
    pub num_inliers: usize,
    pub iterations: usize,
    /// LMedS: the median squared residual of the best model; RANSAC: mean inlier residual².
    pub score: f64,
    /// Robust standard deviation of the residuals (LMedS: 1.4826·(1+5/(n−p))·√median).
    pub sigma: f64,
}

#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum RobustError {
    #[error("{needed} samples are needed, only {got} given")]
    TooFewSamples { needed: usize, got: usize },
    #[error("no model could be fitted: every minimal sample was degenerate")]
    NoModel,
}

fn iterations_needed(inlier_ratio: f64, m: usize, confidence: f64) -> usize {
    let p_good = inlier_ratio.powi(m as i32);
    if p_good <= f64::EPSILON {
        return usize::MAX;
    }
    if p_good >= 1.0 {
        return 1;
    }
    ((1.0 - confidence).ln() / (1.0 - p_good).ln())
        .ceil()
        .max(1.0) as usize
}

fn classify<E: Estimator>(
    est: &E,
    model: &E::Model,
    samples: &[E::Sample],
    t2: f64,
) -> (Vec<bool>, usize, f64) {
    let mut inl = vec![false; samples.len()];
    let (mut n, mut sum) = (0, 0.0);
    for (i, s) in samples.iter().enumerate() {
        let r = est.residual_sq(model, s);
        if r <= t2 {
            inl[i] = true;
            n += 1;
            sum += r;
        }
    }
    (inl, n, if n > 0 { sum / n as f64 } else { f64::INFINITY })
}

/// The items whose flag is set (the inliers of a consensus, in order).
pub fn selected<'a, T>(items: &'a [T], keep: &[bool]) -> Vec<&'a T> {
    items
        .iter()
        .zip(keep)
        .filter(|(_, &b)| b)
        .map(|(s, _)| s)
        .collect()
}

/// Random minimal samples (without repetition) from a seeded stream, so that both drivers
/// are deterministic and refuse a set smaller than one minimal sample alike.
struct MinimalSamples<'a, S> {
    samples: &'a [S],
    m: usize,
    rng: ChaCha8Rng,
}

impl<'a, S> MinimalSamples<'a, S> {
    fn new(samples: &'a [S], m: usize, seed: u64) -> Result<Self, RobustError> {
        if samples.len() < m {
            return Err(RobustError::TooFewSamples {
                needed: m,
                got: samples.len(),
            });
        }
        Ok(Self {
            samples,
            m,
            rng: ChaCha8Rng::seed_from_u64(seed),
        })
    }

    fn draw(&mut self) -> Vec<&'a S> {
        sample(&mut self.rng, self.samples.len(), self.m)
            .iter()
            .map(|i| &self.samples[i])
            .collect()
    }
}

fn refine_on<E: Estimator>(
    est: &E,
    model: &E::Model,
    samples: &[E::Sample],
    inl: &[bool],
) -> Option<E::Model> {
    let chosen = selected(samples, inl);
    if chosen.len() < E::MIN_SAMPLES {
        return None;
    }
    est.refine(model, &chosen)
}

/// RANSAC with adaptive stopping and a final least-squares refinement on the inliers
/// (re-classified after refinement, LO-RANSAC style).
fn ransac<E: Estimator>(
    est: &E,
    mut draws: MinimalSamples<'_, E::Sample>,
    opts: &RobustOptions,
) -> Result<RobustResult<E::Model>, RobustError> {
    let (samples, n, m) = (draws.samples, draws.samples.len(), draws.m);
    let t2 = opts.threshold * opts.threshold;
    let mut best: Option<(E::Model, Vec<bool>, usize, f64)> = None;
    let mut needed = opts.max_iterations;
    let mut it = 0;
    while it < needed.max(opts.min_iterations).min(opts.max_iterations) {
        it += 1;
        for model in est.fit_minimal(&draws.draw()) {
            let (inl, k, mean) = classify(est, &model, samples, t2);
            let better = best
                .as_ref()
                .is_none_or(|b| k > b.2 || (k == b.2 && mean < b.3));
            if better {
                needed = iterations_needed(k as f64 / n as f64, m, opts.confidence);
                best = Some((model, inl, k, mean));
            }
        }
    }
    let (mut model, mut inl, mut k, mut mean) = best.ok_or(RobustError::NoModel)?;
    // Local optimisation: refine on the inliers while the consensus grows.
    for _ in 0..5 {
        let Some(r) = refine_on(est, &model, samples, &inl) else {
            break;
        };
        let (inl2, k2, mean2) = classify(est, &r, samples, t2);
        if k2 < k || (k2 == k && mean2 >= mean) {
            break;
        }
        (model, inl, k, mean) = (r, inl2, k2, mean2);
    }
    Ok(RobustResult {
        sigma: mean.sqrt(),
        model,
        inliers: inl,
        num_inliers: k,
        iterations: it,
        score: mean,
    })
}

/// Least median of squares (Rousseeuw): the model minimising the median squared residual
/// over random minimal samples; inliers are those within 2.5 robust σ. Tolerates up to
/// 50 % gross errors without a threshold chosen in advance.
fn lmeds<E: Estimator>(
    est: &E,
    mut draws: MinimalSamples<'_, E::Sample>,
    opts: &RobustOptions,
) -> Result<RobustResult<E::Model>, RobustError> {
    let (samples, n, m) = (draws.samples, draws.samples.len(), draws.m);
    // Enough draws to hit an outlier-free sample with 50 % contamination.
    let iterations =
        iterations_needed(0.5, m, opts.confidence).clamp(opts.min_iterations, opts.max_iterations);
    let mut best: Option<(E::Model, f64)> = None;
    let mut res = vec![0.0; n];
    for _ in 0..iterations {
        for model in est.fit_minimal(&draws.draw()) {
            for (r, s) in res.iter_mut().zip(samples) {
                *r = est.residual_sq(&model, s);
            }
            let mid = n / 2;
            let med = *res.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1;
            if best.as_ref().is_none_or(|b| med < b.1) {
                best = Some((model, med));
            }
        }
    }
    let (mut model, med) = best.ok_or(RobustError::NoModel)?;
    let sigma = 1.4826 * (1.0 + 5.0 / (n.saturating_sub(m).max(1)) as f64) * med.sqrt();
    let t2 = (2.5 * sigma.max(1e-12)).powi(2);
    let (mut inl, mut k, mut mean) = classify(est, &model, samples, t2);
    if let Some(r) = refine_on(est, &model, samples, &inl) {
        let (inl2, k2, mean2) = classify(est, &r, samples, t2);
        if k2 >= k {
            (model, inl, k, mean) = (r, inl2, k2, mean2);
        }
    }
    let _ = mean;
    Ok(RobustResult {
        model,
        inliers: inl,
        num_inliers: k,
        iterations,
        score: med,
        sigma,
    })
}
