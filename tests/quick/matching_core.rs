//! Pyramids, resampling, Förstner, NCC and LSM against known truth on synthetic
//! textured patches, and the bad-input contract.

use cloudcontrol::matching::lsm::{lsm, LsmOptions};
use cloudcontrol::matching::ncc::{ncc_search, ncc_search_pyramid, Window};
use cloudcontrol::matching::pyramid::downsample;
use cloudcontrol::matching::resample::{warp_patch, Interpolation, PatchWarp};
use cloudcontrol::matching::{
    forstner, match_template, ForstnerOptions, GreyImage, MatchOptions, MatchingError, Pyramid,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Band-limited texture: random plane waves of 7–30 px wavelength, mean 100.
fn texture(seed: u64) -> impl Fn(f64, f64) -> f64 {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let waves: Vec<(f64, f64, f64, f64)> = (0..24)
        .map(|_| {
            let lambda = rng.gen_range(7.0..30.0);
            let th: f64 = rng.gen_range(0.0..std::f64::consts::PI);
            let k = 2.0 * std::f64::consts::PI / lambda;
            (
                k * th.cos(),
                k * th.sin(),
                rng.gen_range(0.0..6.3),
                rng.gen_range(4.0..12.0),
            )
        })
        .collect();
    move |x, y| {
        100.0
            + waves
                .iter()
                .map(|w| w.3 * (w.0 * x + w.1 * y + w.2).sin())
                .sum::<f64>()
    }
}

/// Template around world point c0 and an image where template offset u appears at
/// P + A·u with radiometry 20 + 0.8·g and Gaussian noise.
fn pair(
    seed: u64,
    tsize: usize,
    isize: usize,
    p: [f64; 2],
    a: [f64; 4],
    noise: f64,
) -> (GreyImage, GreyImage) {
    let f = texture(seed);
    let c0 = [300.0, 200.0];
    let h = tsize as f64 / 2.0;
    let tpl = GreyImage::from_fn(tsize, tsize, |x, y| f(c0[0] + x - h, c0[1] + y - h));
    let det = a[0] * a[3] - a[1] * a[2];
    let ai = [a[3] / det, -a[1] / det, -a[2] / det, a[0] / det];
    let mut rng = ChaCha8Rng::seed_from_u64(seed + 1000);
    let nd = Normal::new(0.0, noise.max(1e-12)).unwrap();
    let img = GreyImage::from_fn(isize, isize, |x, y| {
        let (dx, dy) = (x - p[0], y - p[1]);
        let u = ai[0] * dx + ai[1] * dy;
        let v = ai[2] * dx + ai[3] * dy;
        20.0 + 0.8 * f(c0[0] + u, c0[1] + v)
    });
    let img = GreyImage {
        data: img
            .data
            .iter()
            .map(|&v| v + nd.sample(&mut rng) as f32)
            .collect(),
        ..img
    };
    (tpl, img)
}

#[test]
fn lsm_recovers_subpixel_shift_and_affine_and_ncc_alone_is_within_02px() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let (mut e_lsm, mut e_ncc, mut e_ncc_shift) = (0.0, 0.0, 0.0);
    let mut e_aff: f64 = 0.0;
    let trials = 30;
    for t in 0..trials {
        let p = [
            48.0 + rng.gen_range(0.0..1.0),
            47.0 + rng.gen_range(0.0..1.0),
        ];
        let (s, rot, sh) = (
            rng.gen_range(0.92..1.08),
            rng.gen_range(-0.08..0.08f64),
            rng.gen_range(-0.05..0.05),
        );
        let a = [
            s * rot.cos(),
            -s * rot.sin() + sh,
            s * rot.sin(),
            s * rot.cos(),
        ];
        let (tpl, img) = pair(100 + t, 31, 96, p, a, 1.0);
        let pk = ncc_search(&img, &tpl, Window::whole(&img), false).unwrap();
        e_ncc += (pk.x - p[0]).powi(2) + (pk.y - p[1]).powi(2);
        let l = lsm(&img, &tpl, pk.x, pk.y, None, &LsmOptions::default());
        assert!(l.converged, "trial {t}: {:?}", l.reason);
        e_lsm += (l.x - p[0]).powi(2) + (l.y - p[1]).powi(2);
        for (lk, ak) in l.affine.iter().zip(&a) {
            e_aff = e_aff.max((lk - ak).abs());
        }
        assert!(l.sigma_x > 0.0 && l.sigma_x < 0.05, "σx {}", l.sigma_x);
        assert!((l.r1 - 1.25).abs() < 0.02, "radiometric scale {}", l.r1);
        // Pure shift: NCC alone.
        let (tpl, img) = pair(200 + t, 31, 96, p, [1.0, 0.0, 0.0, 1.0], 1.0);
        let pk = ncc_search(&img, &tpl, Window::whole(&img), false).unwrap();
        e_ncc_shift += (pk.x - p[0]).powi(2) + (pk.y - p[1]).powi(2);
    }
    let rms = |e: f64| (e / trials as f64).sqrt();
    eprintln!(
        "LSM shift RMS {:.4} px, max affine error {:.4}, NCC RMS (affine) {:.3} px, NCC RMS (shift) {:.3} px",
        rms(e_lsm),
        e_aff,
        rms(e_ncc),
        rms(e_ncc_shift)
    );
    assert!(rms(e_lsm) <= 0.05, "LSM RMS {}", rms(e_lsm));
    assert!(e_aff < 0.01, "affine parameter error {e_aff}");
    assert!(rms(e_ncc_shift) <= 0.2, "NCC RMS {}", rms(e_ncc_shift));
}

#[test]
fn coarse_to_fine_search_finds_the_patch_in_a_wide_window() {
    let p = [171.3, 64.7];
    let (tpl, img) = pair(7, 33, 256, p, [1.0, 0.0, 0.0, 1.0], 1.0);
    let pyr = Pyramid::new(&img, 6, 16);
    assert!(pyr.levels.len() >= 3);
    let pk = ncc_search_pyramid(&pyr, &tpl, Window::whole(&img), 9, false).unwrap();
    assert!(
        (pk.x - p[0]).abs() < 0.3 && (pk.y - p[1]).abs() < 0.3,
        "{pk:?}"
    );
    let m = match_template(
        &pyr,
        &tpl,
        Window::whole(&img),
        None,
        &MatchOptions::default(),
    )
    .unwrap();
    assert!(m.accepted, "{:?}", m.reason);
    assert!(
        (m.x - p[0]).abs() < 0.05 && (m.y - p[1]).abs() < 0.05,
        "{m:?}"
    );
    assert!(m.ambiguity < 0.9, "ambiguity {}", m.ambiguity);
}

#[test]
fn pyramid_keeps_corner_origin_coordinates() {
    // A linear ramp sampled at pixel centres must stay the same function of (x, y) on
    // every level once coordinates are halved.
    let img = GreyImage::from_fn(64, 48, |x, y| 3.0 * x + 5.0 * y);
    let l1 = downsample(&img);
    assert_eq!((l1.width, l1.height), (32, 24));
    for r in 3..20 {
        for c in 3..28 {
            let (x, y) = (2.0 * (c as f64 + 0.5), 2.0 * (r as f64 + 0.5));
            assert!((l1.at(c, r) as f64 - (3.0 * x + 5.0 * y)).abs() < 1e-3);
        }
    }
    let flat = downsample(&GreyImage::filled(20, 20, 7.0));
    assert!(flat.data.iter().all(|&v| (v - 7.0).abs() < 1e-5));
}

#[test]
fn resampling_is_exact_on_linear_and_quadratic_grey_values() {
    let img = GreyImage::from_fn(40, 40, |x, y| 2.0 * x - y + 0.01 * x * x);
    let warp = PatchWarp::Affine([0.9, 0.2, 10.3, -0.1, 1.1, 12.7]);
    for interp in [Interpolation::Bilinear, Interpolation::Bicubic] {
        let (p, outside) = warp_patch(&img, &warp, 11, 11, interp);
        assert_eq!(outside, 0);
        for r in 0..11 {
            for c in 0..11 {
                let (x, y) = warp.apply(c as f64 + 0.5, r as f64 + 0.5);
                let truth = 2.0 * x - y + 0.01 * x * x;
                let tol = if interp == Interpolation::Bicubic {
                    1e-3
                } else {
                    0.01
                };
                assert!((p.at(c, r) as f64 - truth).abs() < tol, "{interp:?}");
            }
        }
    }
    let h = nalgebra::Matrix3::new(1.0, 0.0, 5.0, 0.0, 1.0, 5.0, 0.001, 0.0, 1.0);
    let (p, _) = warp_patch(
        &img,
        &PatchWarp::Homography(h),
        9,
        9,
        Interpolation::Bicubic,
    );
    let (x, y) = PatchWarp::Homography(h).apply(4.5, 4.5);
    assert!((p.at(4, 4) as f64 - (2.0 * x - y + 0.01 * x * x)).abs() < 1e-3);
}

#[test]
fn forstner_finds_corners_evenly() {
    // Checkerboard of 16-px squares, slightly blurred: interest points are the corners.
    let img = GreyImage::from_fn(128, 128, |x, y| {
        let s = |t: f64| (std::f64::consts::PI * t / 16.0).sin();
        100.0 + 80.0 * (s(x) * s(y)).signum() * (s(x) * s(y)).abs().powf(0.3)
    });
    let pts = forstner(
        &img,
        &ForstnerOptions {
            border: 8,
            grid: (4, 4),
            per_cell: 2,
            ..ForstnerOptions::default()
        },
    );
    assert!(pts.len() >= 16, "{} points", pts.len());
    for p in &pts {
        let dx = (p.x / 16.0 - (p.x / 16.0).round()).abs() * 16.0;
        let dy = (p.y / 16.0 - (p.y / 16.0).round()).abs() * 16.0;
        assert!(dx <= 0.3 && dy <= 0.3, "point {p:?} not at a corner");
        assert!(p.q >= 0.5);
    }
    // Every grid cell contributes.
    let mut cells = [0; 16];
    for p in &pts {
        cells[(p.y / 32.0) as usize * 4 + (p.x / 32.0) as usize] += 1;
    }
    assert!(cells.iter().all(|&c| c >= 1), "{cells:?}");
}

#[test]
fn bad_input_gives_clear_errors_or_no_match() {
    let img = GreyImage::from_fn(64, 64, texture(3));
    let pyr = Pyramid::new(&img, 4, 16);
    let opts = MatchOptions::default();
    // Constant template.
    let flat = GreyImage::filled(21, 21, 50.0);
    let e = match_template(&pyr, &flat, Window::whole(&img), None, &opts).unwrap_err();
    assert!(matches!(e, MatchingError::Textureless { .. }), "{e}");
    assert!(e.to_string().contains("no texture"));
    // Image smaller than the template.
    let small = Pyramid::new(&GreyImage::from_fn(15, 15, texture(3)), 1, 4);
    let tpl = img.crop(10, 10, 21, 21).unwrap();
    let e = match_template(&small, &tpl, Window::whole(&small.levels[0]), None, &opts).unwrap_err();
    assert!(matches!(e, MatchingError::TooSmall { .. }), "{e}");
    assert!(e.to_string().contains("smaller than the template"), "{e}");
    // Textureless search area: a result without a match, with its reason.
    let blank = Pyramid::new(&GreyImage::filled(64, 64, 10.0), 4, 16);
    let m = match_template(&blank, &tpl, Window::whole(&blank.levels[0]), None, &opts).unwrap();
    assert!(
        !m.accepted && m.reason.as_deref().unwrap().contains("NCC"),
        "{m:?}"
    );
    // Unrelated texture: rejected with its reason.
    let other = Pyramid::new(&GreyImage::from_fn(64, 64, texture(99)), 4, 16);
    let m = match_template(&other, &tpl, Window::whole(&other.levels[0]), None, &opts).unwrap();
    assert!(!m.accepted, "{m:?}");
    // Unreadable image file.
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("broken.tif");
    std::fs::write(&bad, b"not a tiff").unwrap();
    let e = GreyImage::load(&bad).unwrap_err();
    assert!(e.to_string().contains("broken.tif"), "{e}");
    let e = GreyImage::load(&dir.path().join("missing.png")).unwrap_err();
    assert!(e.to_string().contains("missing.png"), "{e}");
}

#[test]
fn images_load_8_and_16_bit_grey_and_rgb() {
    let dir = tempfile::tempdir().unwrap();
    let img = GreyImage::from_fn(40, 30, |x, y| 2.0 * x + y);
    let p8 = dir.path().join("a.png");
    img.save(&p8, false).unwrap();
    let back = GreyImage::load(&p8).unwrap();
    assert_eq!((back.width, back.height), (40, 30));
    assert!(back
        .data
        .iter()
        .zip(&img.data)
        .all(|(a, b)| (a - b.round()).abs() < 1e-6));
    let p16 = dir.path().join("a16.tif");
    let img16 = GreyImage::from_fn(40, 30, |x, y| 1000.0 * x + y);
    img16.save(&p16, true).unwrap();
    let back = GreyImage::load(&p16).unwrap();
    assert!((back.at(39, 29) - img16.at(39, 29).round()).abs() < 1e-3);
    // GDAL window read of the same file.
    let w = GreyImage::load_window(&p16, Some((10, 5, 8, 6))).unwrap();
    assert_eq!(w.at(0, 0), back.at(10, 5));
    let rgb = image::RgbImage::from_fn(8, 8, |x, _| image::Rgb([x as u8 * 10, 100, 0]));
    let prgb = dir.path().join("c.png");
    rgb.save(&prgb).unwrap();
    let g = GreyImage::load(&prgb).unwrap();
    assert!((g.at(2, 0) - (0.299 * 20.0 + 0.587 * 100.0)).abs() < 1e-3);
}

#[test]
fn fft_and_direct_correlation_agree() {
    use cloudcontrol::matching::ncc::{ncc_surface_with, CorrelationMethod};
    // Non-power-of-two window sizes exercise the mixed-radix FFT path too.
    for (w, h, t) in [(64, 64, 21), (97, 75, 31), (130, 128, 41)] {
        let img = GreyImage::from_fn(w, h, texture(w as u64));
        let tpl = img.crop(w / 4, h / 3, t, t).unwrap();
        let d =
            ncc_surface_with(&img, &tpl, Window::whole(&img), CorrelationMethod::Direct).unwrap();
        let f = ncc_surface_with(&img, &tpl, Window::whole(&img), CorrelationMethod::Fft).unwrap();
        let worst = d
            .values
            .iter()
            .zip(&f.values)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(
            worst < 1e-4,
            "{w}×{h}, template {t}: max difference {worst}"
        );
        let i = d
            .values
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .unwrap()
            .0;
        assert_eq!((i % d.width, i / d.width), (w / 4, h / 3));
    }
}

/// Naive NCC in f64 for one position (template top-left at window (i, j)).
fn ncc_reference(img: &GreyImage, tpl: &GreyImage, c0: usize, r0: usize) -> f64 {
    let n = (tpl.width * tpl.height) as f64;
    let tm = tpl.data.iter().map(|&v| v as f64).sum::<f64>() / n;
    let mut im = 0.0;
    for r in 0..tpl.height {
        for c in 0..tpl.width {
            im += img.at(c0 + c, r0 + r) as f64;
        }
    }
    im /= n;
    let (mut num, mut st, mut si) = (0.0, 0.0, 0.0);
    for r in 0..tpl.height {
        for c in 0..tpl.width {
            let a = tpl.at(c, r) as f64 - tm;
            let b = img.at(c0 + c, r0 + r) as f64 - im;
            num += a * b;
            st += a * a;
            si += b * b;
        }
    }
    num / (st * si).sqrt()
}

#[test]
fn correlation_matches_naive_reference_on_odd_shapes() {
    use cloudcontrol::matching::ncc::{ncc_surface_with, CorrelationMethod};
    // Windows inside a larger image (stride ≠ width), result widths below, at and above
    // the SIMD block widths (1, 7, 8, 9, 17, 70) and heights below the row blocking, and
    // non-square templates: every block shape and overlapping tail of the direct kernel
    // and the padded (fast-length) FFT sizes.
    let img = GreyImage::from_fn(160, 120, texture(11));
    for (ww, wh, tw, th) in [
        (21, 21, 21, 21),
        (27, 13, 21, 7),
        (28, 30, 21, 29),
        (29, 11, 21, 9),
        (37, 40, 21, 31),
        (90, 34, 21, 31),
        (101, 77, 13, 5),
    ] {
        let tpl = img.crop(50, 40, tw, th).unwrap();
        let window = Window {
            col: 31,
            row: 17,
            width: ww,
            height: wh,
        };
        for method in [CorrelationMethod::Direct, CorrelationMethod::Fft] {
            let s = ncc_surface_with(&img, &tpl, window, method).unwrap();
            assert_eq!((s.width, s.height), (ww + 1 - tw, wh + 1 - th));
            for j in 0..s.height {
                for i in 0..s.width {
                    let r = ncc_reference(&img, &tpl, window.col + i, window.row + j);
                    let v = s.values[j * s.width + i] as f64;
                    assert!(
                        (v - r).abs() < 2e-4,
                        "{method:?} {ww}×{wh} template {tw}×{th} at ({i}, {j}): {v} vs {r}"
                    );
                }
            }
        }
    }
}

#[test]
fn bicubic_gradient_is_the_derivative_of_the_interpolant() {
    use cloudcontrol::matching::resample::{bicubic, bicubic_with_gradient};
    let img = GreyImage::from_fn(40, 40, texture(5));
    for (x, y) in [(10.3, 12.7), (20.0, 20.5), (5.99, 30.01), (33.4, 6.6)] {
        let (g, gx, gy) = bicubic_with_gradient(&img, x, y).unwrap();
        let h = 1e-5;
        let dx = (bicubic(&img, x + h, y).unwrap() - bicubic(&img, x - h, y).unwrap()) / (2.0 * h);
        let dy = (bicubic(&img, x, y + h).unwrap() - bicubic(&img, x, y - h).unwrap()) / (2.0 * h);
        assert!((g - bicubic(&img, x, y).unwrap()).abs() < 1e-9);
        assert!(
            (gx - dx).abs() < 1e-4 && (gy - dy).abs() < 1e-4,
            "{gx} {dx} {gy} {dy}"
        );
    }
    // Outside the 4×4 support: no value (callers fall back to differences).
    assert!(bicubic_with_gradient(&img, 1.2, 20.0).is_none());
    assert!(bicubic_with_gradient(&img, f64::NAN, 20.0).is_none());
}

/// Large FFT correlations run their passes on the rayon pool; called from inside an outer
/// parallel loop (as tie matching does), a thread that steals a second correlation while
/// waiting must not trip over its own reusable buffers. (Stealing is timing-dependent:
/// this exercises the nesting, it cannot force it.)
#[test]
fn nested_parallel_fft_correlations() {
    use cloudcontrol::matching::ncc::{ncc_surface_with, CorrelationMethod};
    use rayon::prelude::*;
    let img = GreyImage::from_fn(300, 280, texture(21));
    let tpl = img.crop(120, 100, 41, 41).unwrap();
    let reference =
        ncc_surface_with(&img, &tpl, Window::whole(&img), CorrelationMethod::Fft).unwrap();
    let all: Vec<_> = (0..16)
        .into_par_iter()
        .map(|_| ncc_surface_with(&img, &tpl, Window::whole(&img), CorrelationMethod::Fft).unwrap())
        .collect();
    for s in all {
        assert_eq!(s.values, reference.values);
    }
}
