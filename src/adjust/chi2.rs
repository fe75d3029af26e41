//! The χ² distribution with one to three degrees of freedom, as far as data snooping
//! needs it: the significance level α0 of a one-dimensional test with critical value k
//! (two-sided normal), and the critical value of a d-dimensional test at the same α0.
//! Closed forms (d = 1, 3 through erfc; d = 2 exponential), no statistics crate.

/// Complementary error function (Chebyshev fit, relative error below 1.2·10⁻⁷ for all x;
/// Press et al., Numerical Recipes, `erfcc`).
pub fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let poly = -z * z - 1.265_512_23
        + t * (1.000_023_68
            + t * (0.374_091_96
                + t * (0.096_784_18
                    + t * (-0.186_288_06
                        + t * (0.278_868_07
                            + t * (-1.135_203_98
                                + t * (1.488_515_87 + t * (-0.822_152_23 + t * 0.170_872_77))))))));
    let r = t * poly.exp();
    if x >= 0.0 {
        r
    } else {
        2.0 - r
    }
}

/// Upper tail P(χ²(d) > x) for d = 1, 2, 3.
pub fn upper_tail(d: usize, x: f64) -> f64 {
    if x <= 0.0 {
        return 1.0;
    }
    let h = (0.5 * x).sqrt();
    match d {
        1 => erfc(h),
        2 => (-0.5 * x).exp(),
        _ => erfc(h) + (2.0 * x / std::f64::consts::PI).sqrt() * (-0.5 * x).exp(),
    }
}

/// Critical value c with P(χ²(d) > c) = α (bisection on the monotone tail).
pub fn critical(d: usize, alpha: f64) -> f64 {
    if d == 2 {
        return -2.0 * alpha.ln();
    }
    let (mut lo, mut hi) = (0.0f64, 1.0f64);
    while upper_tail(d, hi) > alpha && hi < 1e4 {
        hi *= 2.0;
    }
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if upper_tail(d, mid) > alpha {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// α0 of the two-sided one-dimensional test with critical value `k` (k = 3.29: 0.1 %).
pub fn alpha_of_k(k: f64) -> f64 {
    erfc(k / std::f64::consts::SQRT_2)
}

/// The one-dimensional critical value of significance level `alpha`.
pub fn k_of_alpha(alpha: f64) -> f64 {
    critical(1, alpha).sqrt()
}
