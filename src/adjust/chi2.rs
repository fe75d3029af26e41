//! The χ² distribution as data snooping needs it: the significance level α0 of a
//! one-dimensional test with critical value k (two-sided normal), and the critical value
//! of a d-dimensional test at the same α0. Through statrs (its regularised incomplete
//! gamma and safeguarded Newton quantile); critical values are memoised per thread, as
//! the rejection tests ask for the same few (d, α) once per point.

use statrs::distribution::{ChiSquared, ContinuousCDF, Normal};
use std::cell::RefCell;
use std::collections::HashMap;

/// Complementary error function.
pub fn erfc(x: f64) -> f64 {
    statrs::function::erf::erfc(x)
}

/// Upper tail P(χ²(d) > x).
pub fn upper_tail(d: usize, x: f64) -> f64 {
    if x <= 0.0 {
        return 1.0;
    }
    ChiSquared::new(d.max(1) as f64).map_or(f64::NAN, |c| c.sf(x))
}

thread_local! {
    static CRITICAL: RefCell<HashMap<(usize, u64), f64>> = RefCell::new(HashMap::new());
}

/// Critical value c with P(χ²(d) > c) = α.
pub fn critical(d: usize, alpha: f64) -> f64 {
    let d = d.max(1);
    if d == 2 {
        return -2.0 * alpha.ln();
    }
    CRITICAL.with(|m| {
        *m.borrow_mut()
            .entry((d, alpha.to_bits()))
            .or_insert_with(|| {
                ChiSquared::new(d as f64).map_or(f64::NAN, |c| c.inverse_cdf(1.0 - alpha))
            })
    })
}

/// α0 of the two-sided one-dimensional test with critical value `k` (k = 3.29: 0.1 %).
pub fn alpha_of_k(k: f64) -> f64 {
    erfc(k / std::f64::consts::SQRT_2)
}

/// The one-dimensional critical value of significance level `alpha`.
pub fn k_of_alpha(alpha: f64) -> f64 {
    Normal::standard().inverse_cdf(1.0 - 0.5 * alpha)
}
