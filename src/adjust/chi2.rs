//! Critical values of the χ² tests of gross errors: an image measurement is a 2-D
//! observation, a control point or a POS centre 3-D, a plane distance 1-D, and each is
//! tested at the same level α0 with its own number of degrees of freedom.
//!
//! Hand-written rather than `statrs`: we need three degrees of freedom, whose upper
//! tails have closed forms in erfc, and statrs would pull a second nalgebra version into
//! the build (+40 s of compile time on the 2-core CI machine for three formulas).

/// Upper tail Q(x) = P(χ²_k > x) for k = 1, 2, 3.
fn upper_tail(dof: u32, x: f64) -> f64 {
    if x <= 0.0 {
        return 1.0;
    }
    let h = x / 2.0;
    match dof {
        1 => erfc(h.sqrt()),
        2 => (-h).exp(),
        _ => erfc(h.sqrt()) + (2.0 * x / std::f64::consts::PI).sqrt() * (-h).exp(),
    }
}

/// Complementary error function (Numerical Recipes' Chebyshev fit, relative error
/// below 1.2·10⁻⁷ everywhere: far below what a test level needs).
fn erfc(x: f64) -> f64 {
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

/// The χ² quantile x with P(χ²_dof > x) = alpha, for dof 1–3 (higher dof are tested
/// as 3-D: the adjustment has no larger observation).
pub fn quantile(dof: u32, alpha: f64) -> f64 {
    let alpha = alpha.clamp(1e-12, 0.5);
    let (mut lo, mut hi) = (0.0, 200.0);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if upper_tail(dof.clamp(1, 3), mid) > alpha {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Critical value of the normalised residual w (w² ~ χ²_dof): √quantile.
pub fn critical(dof: u32, alpha: f64) -> f64 {
    quantile(dof, alpha).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_quantiles() {
        // Tables: χ²(1) 0.999 = 10.828, χ²(2) = 13.816, χ²(3) = 16.266; χ²(3) 0.95 = 7.815.
        for (dof, alpha, q) in [
            (1, 0.001, 10.828),
            (2, 0.001, 13.816),
            (3, 0.001, 16.266),
            (3, 0.05, 7.815),
        ] {
            assert!((quantile(dof, alpha) - q).abs() < 2e-3, "{dof} {alpha}");
        }
        assert!((critical(1, 0.001) - 3.2905).abs() < 1e-3);
    }
}
