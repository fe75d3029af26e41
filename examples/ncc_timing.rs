//! Pure-Rust timing of the NCC correlation methods (no Python call overhead), to see
//! which part of `ncc_surface` costs what: `cargo run --release --example ncc_timing`.
use cloudcontrol::matching::ncc::{ncc_surface_with, CorrelationMethod};
use cloudcontrol::matching::{GreyImage, Window};
use std::time::Instant;

fn texture(n: usize, seed: u64) -> GreyImage {
    // Cheap deterministic texture: sum of hashed sinusoids is enough for timing.
    let mut s = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    let mut data = Vec::with_capacity(n * n);
    for _ in 0..n * n {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        data.push(((s >> 40) & 0xff) as f32);
    }
    GreyImage::new(n, n, data).expect("texture")
}

fn time(f: impl Fn(), repeat: usize) -> f64 {
    let mut best = f64::INFINITY;
    for _ in 0..3 {
        let t0 = Instant::now();
        for _ in 0..repeat {
            f();
        }
        best = best.min(t0.elapsed().as_secs_f64() / repeat as f64);
    }
    best
}

fn main() {
    // `ncc_timing fft 64 21 2000`: loop one case (for a profiler).
    let args: Vec<String> = std::env::args().collect();
    // `ncc_timing lsm 2000`: loop least-squares matching of a 31×31 patch.
    if args.len() == 3 && args[1] == "lsm" {
        let n: usize = args[2].parse().unwrap();
        let img = texture(128, 7);
        let smooth = cloudcontrol::matching::pyramid::downsample(&img);
        let tpl = smooth.crop(16, 16, 31, 31).expect("tpl");
        let opts = cloudcontrol::matching::LsmOptions::default();
        let t0 = Instant::now();
        for _ in 0..n {
            std::hint::black_box(cloudcontrol::matching::lsm(
                &smooth, &tpl, 31.8, 31.3, None, &opts,
            ));
        }
        let r = cloudcontrol::matching::lsm(&smooth, &tpl, 31.8, 31.3, None, &opts);
        println!(
            "LSM {:.3} ms per patch, {} iterations",
            t0.elapsed().as_secs_f64() * 1e3 / n as f64,
            r.iterations
        );
        let t0 = Instant::now();
        let mut acc = 0.0;
        for _ in 0..n {
            for r in 0..31 {
                for c in 0..31 {
                    let (x, y) = (17.3 + c as f64 * 0.98, 16.9 + r as f64 * 1.01);
                    let (g, gx, gy) =
                        cloudcontrol::matching::resample::bicubic_with_gradient(&smooth, x, y)
                            .unwrap();
                    acc += g + gx + gy;
                }
            }
        }
        std::hint::black_box(acc);
        println!(
            "961 samples with gradient: {:.3} ms",
            t0.elapsed().as_secs_f64() * 1e3 / n as f64
        );
        return;
    }
    if args.len() == 5 {
        let (win, t, n): (usize, usize, usize) = (
            args[2].parse().unwrap(),
            args[3].parse().unwrap(),
            args[4].parse().unwrap(),
        );
        let m = if args[1] == "fft" {
            CorrelationMethod::Fft
        } else {
            CorrelationMethod::Direct
        };
        let img = texture(win, 1);
        let tpl = img.crop(win / 4, win / 3, t, t).expect("tpl");
        for _ in 0..n {
            std::hint::black_box(
                ncc_surface_with(&img, &tpl, Window::whole(&img), m).expect("ncc"),
            );
        }
        return;
    }
    println!(
        "{:>8} {:>6} {:>10} {:>10} {:>10}",
        "template", "window", "auto ms", "direct ms", "fft ms"
    );
    for win in [64usize, 128, 256] {
        for t in [21usize, 31, 41] {
            let img = texture(win, (win * 100 + t) as u64);
            let tpl = img.crop(win / 4, win / 3, t, t).expect("tpl");
            let w = Window::whole(&img);
            let repeat = (2e7 / (((win - t + 1) * (win - t + 1) * t * t) as f64)).max(5.0) as usize;
            let (img, tpl) = (&img, &tpl);
            let run = |m| {
                move || {
                    std::hint::black_box(ncc_surface_with(img, tpl, w, m).expect("ncc"));
                }
            };
            let ta = time(run(CorrelationMethod::Auto), repeat);
            let td = time(run(CorrelationMethod::Direct), repeat);
            let tf = time(run(CorrelationMethod::Fft), repeat);
            println!(
                "{t:>8} {win:>6} {:>10.3} {:>10.3} {:>10.3}",
                ta * 1e3,
                td * 1e3,
                tf * 1e3
            );
        }
    }
}
