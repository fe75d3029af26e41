//! Unit tests of `synth::noise`.

mod tests {
    #[test]
    fn fast_sin_matches_libm() {
        let mut worst: f64 = 0.0;
        for k in -20000..20000 {
            let x = k as f64 * 0.0137;
            worst = worst.max((cloudcontrol::synth::noise::fast_sin(x) - x.sin()).abs());
        }
        assert!(worst < 4e-6, "worst {worst}");
    }
}
