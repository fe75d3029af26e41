//! Single-photo resection and bad input of the adjustment.

use cloudcontrol::adjust::synthetic::{generate, SyntheticOptions};
use cloudcontrol::adjust::{
    adjust, resect, AdjustError, AdjustOptions, PlaneConstraint, ResectionOptions,
};
use cloudcontrol::block::{Block, PointKind};
use cloudcontrol::geometry::{project, Brown, Camera, FrameCamera, Pose};
use nalgebra::Vector3;
use rand::{Rng, SeedableRng};

fn small_block() -> Block {
    let o = SyntheticOptions {
        strips: 2,
        photos_per_strip: 4,
        tie_points: 800,
        check_points: 0,
        control_grid: (2, 2),
        ..Default::default()
    };
    generate(&o).start
}

fn camera() -> Camera {
    Camera::Frame(FrameCamera {
        distortion: Brown {
            k1: -0.03,
            p1: 1e-4,
            ..Default::default()
        },
        ..FrameCamera::pinhole(6000, 4000, 5000.0)
    })
}

/// `n` control points on hilly ground seen by a photo, `outliers` of them with 20–200 px errors.
fn resection_case(n: usize, outliers: usize, seed: u64) -> (Pose, Vec<[f64; 2]>, Vec<[f64; 3]>) {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let truth = Pose::from_opk(0.02, -0.015, 1.2, Vector3::new(500.0, 300.0, 1200.0));
    let cam = camera();
    let (mut px, mut xs) = (Vec::new(), Vec::new());
    while px.len() < n {
        let x = Vector3::new(
            rng.gen_range(0.0..1000.0),
            rng.gen_range(-200.0..800.0),
            rng.gen_range(-50.0..80.0),
        );
        let Ok(p) = project(&cam, &truth, &x) else {
            continue;
        };
        if p.pixel.x < 0.0 || p.pixel.y < 0.0 || p.pixel.x > 6000.0 || p.pixel.y > 4000.0 {
            continue;
        }
        let mut q = [
            p.pixel.x + rng.gen_range(-0.5..0.5),
            p.pixel.y + rng.gen_range(-0.5..0.5),
        ];
        if px.len() < outliers {
            let a: f64 = rng.gen_range(0.0..std::f64::consts::TAU);
            let m: f64 = rng.gen_range(20.0..200.0);
            q[0] += m * a.cos();
            q[1] += m * a.sin();
        }
        px.push(q);
        xs.push([x.x, x.y, x.z]);
    }
    (truth, px, xs)
}

fn pose_error(a: &Pose, b: &Pose) -> (f64, f64) {
    let m = a.rotation * b.rotation.transpose();
    (
        (a.center - b.center).norm(),
        ((m.trace() - 1.0) / 2.0).clamp(-1.0, 1.0).acos(),
    )
}

#[test]
fn resection_recovers_the_pose_from_3_to_50_points_with_up_to_half_outliers() {
    let cam = camera();
    for (n, out, lmeds) in [
        (3, 0, false),
        (4, 0, false),
        (8, 3, false),
        (20, 10, false),
        (50, 25, false),
        (50, 20, true),
        (12, 5, true),
        (12, 6, false),
    ] {
        let (truth, px, xs) = resection_case(n, out, n as u64 * 7 + out as u64);
        let opts = ResectionOptions {
            lmeds,
            ..Default::default()
        };
        let r = resect(&cam, &px, &xs, 0.3, &opts).unwrap();
        let (ce, re) = pose_error(&r.pose, &truth);
        eprintln!("n {n} outliers {out} lmeds {lmeds}: centre {ce:.3} m, rotation {re:.2e} rad, inliers {}", r.num_inliers);
        // Three points fit exactly: the noise maps straight into the pose (the wrong P3P
        // branches are tens of metres and degrees away).
        let (cmax, rmax) = if n == 3 { (8.0, 8e-3) } else { (2.0, 2e-3) };
        assert!(ce < cmax && re < rmax, "n {n}: centre {ce} rotation {re}");
        // Every planted outlier is found, no good point lost.
        for (i, &ok) in r.inliers.iter().enumerate() {
            assert_eq!(ok, i >= out, "n {n}, point {i}");
        }
        if n - out > 3 {
            let s = (r.covariance[3][3] + r.covariance[4][4] + r.covariance[5][5]).sqrt();
            assert!(
                s > 0.0 && ce < 6.0 * s.max(0.05),
                "centre error {ce} vs σ {s}"
            );
        }
    }
}

#[test]
fn resection_rejects_bad_input() {
    let cam = camera();
    let (_, px, xs) = resection_case(6, 0, 3);
    let o = ResectionOptions::default();
    assert!(matches!(
        resect(&cam, &px[..2], &xs[..2], 0.3, &o),
        Err(AdjustError::TooFewObservations(_))
    ));
    let line: Vec<[f64; 3]> = (0..5)
        .map(|i| [i as f64 * 10.0, i as f64 * 5.0, 0.0])
        .collect();
    let e = resect(&cam, &px[..5], &line, 0.3, &o).unwrap_err();
    assert!(e.to_string().contains("collinear"), "{e}");
    let mut bad = px.clone();
    bad[2][1] = f64::NAN;
    let e = resect(&cam, &bad, &xs, 0.3, &o).unwrap_err();
    assert!(e.to_string().contains("control point 2"), "{e}");
    assert!(resect(&cam, &px, &xs[..5], 0.3, &o).is_err());
}

#[test]
fn adjustment_rejects_bad_input_with_named_items() {
    let opts = AdjustOptions::default();
    // One photo.
    let mut b = small_block();
    let keep = *b.photos.keys().next().unwrap();
    b.photos.retain(|k, _| *k == keep);
    for p in b.points.values_mut() {
        p.observations.retain(|o| o.photo == keep);
    }
    let e = adjust(&mut b, &[], None, &opts).unwrap_err();
    assert!(
        matches!(e, AdjustError::Degenerate(_)) && e.to_string().contains("resection"),
        "{e}"
    );
    // NaN pixel.
    let mut b = small_block();
    let id = *b.points.keys().next().unwrap();
    b.points.get_mut(&id).unwrap().observations[0].pixel[0] = f64::NAN;
    let e = adjust(&mut b, &[], None, &opts).unwrap_err();
    assert!(e.to_string().contains(&format!("point {id}")), "{e}");
    // Unknown point of a plane.
    let mut b = small_block();
    let pl = PlaneConstraint {
        point: 9_999_999,
        normal: [0.0, 0.0, 1.0],
        d: 0.0,
        weight: 1.0,
    };
    let e = adjust(&mut b, &[pl], None, &opts).unwrap_err();
    assert!(
        matches!(e, AdjustError::UnknownId { .. }) && e.to_string().contains("9999999"),
        "{e}"
    );
    // Unknown self-calibration parameter.
    let mut b = small_block();
    b.cameras.get_mut(&1).unwrap().free_params = vec!["focal".into()];
    let e = adjust(&mut b, &[], None, &opts).unwrap_err();
    assert!(e.to_string().contains("focal"), "{e}");
    // Collinear control as the only datum.
    let mut b = small_block();
    for (k, p) in b
        .points
        .values_mut()
        .filter(|p| p.kind == PointKind::Control)
        .enumerate()
    {
        p.position = Vector3::new(k as f64 * 100.0, 50.0, 10.0);
    }
    let e = adjust(&mut b, &[], None, &opts).unwrap_err();
    assert!(e.to_string().contains("collinear"), "{e}");
    // A photo with too few observations.
    let mut b = small_block();
    let last = *b.photos.keys().next_back().unwrap();
    for p in b.points.values_mut() {
        let mut seen = 0;
        p.observations.retain(|o| {
            if o.photo == last {
                seen += 1;
                false
            } else {
                true
            }
        });
        let _ = seen;
    }
    let e = adjust(&mut b, &[], None, &opts).unwrap_err();
    assert!(
        matches!(e, AdjustError::TooFewObservations(_))
            && e.to_string().contains(&format!("photo {last}")),
        "{e}"
    );
    // Bad option.
    let mut b = small_block();
    let o = AdjustOptions {
        rejection: cloudcontrol::adjust::Rejection::Threshold(f64::NAN),
        ..Default::default()
    };
    assert!(matches!(
        adjust(&mut b, &[], None, &o),
        Err(AdjustError::InvalidOption { .. })
    ));
}

#[test]
fn free_network_and_determinism_across_thread_counts() {
    let mut b = small_block();
    for p in b.points.values_mut() {
        if p.kind != PointKind::Tie {
            p.kind = PointKind::Tie;
            p.sigma = None;
        }
    }
    let run = |threads: usize| {
        let mut bb = b.clone();
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let rep = pool.install(|| adjust(&mut bb, &[], None, &AdjustOptions::default()).unwrap());
        (bb, rep)
    };
    let (b1, r1) = run(1);
    let (b2, r2) = run(2);
    assert_eq!(r1.datum, "free_network");
    assert!(r1.sigma0 > 0.4 && r1.sigma0 < 0.6, "σ0 {}", r1.sigma0);
    assert_eq!(r1.sigma0.to_bits(), r2.sigma0.to_bits());
    for (id, p) in &b1.photos {
        assert_eq!(
            p.pose, b2.photos[id].pose,
            "photo {id} differs between 1 and 2 threads"
        );
    }
    let _ = b.points.len();
    b.photos.clear();
}

#[test]
fn pos_priors_alone_fix_the_datum_and_data_snooping_runs() {
    use cloudcontrol::block::PosPrior;
    let o = SyntheticOptions {
        strips: 2,
        photos_per_strip: 8,
        tie_points: 2000,
        check_points: 0,
        seed: 8,
        ..Default::default()
    };
    let syn = generate(&o);
    let mut b = syn.start.clone();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
    for p in b.points.values_mut() {
        p.kind = PointKind::Tie;
        p.sigma = None;
    }
    for (id, p) in b.photos.iter_mut() {
        let t = &syn.truth.photos[id].pose;
        let e = Vector3::new(
            rng.gen_range(-0.05..0.05),
            rng.gen_range(-0.05..0.05),
            rng.gen_range(-0.05..0.05),
        );
        p.prior = Some(PosPrior {
            center: t.center + e,
            center_sigma: [0.05; 3],
            rotation: Some(t.rotation),
            rotation_sigma_rad: 1e-3,
        });
    }
    let opts = AdjustOptions {
        rejection: cloudcontrol::adjust::Rejection::DataSnooping(4.0),
        ..Default::default()
    };
    let rep = adjust(&mut b, &[], None, &opts).unwrap();
    assert_eq!(rep.datum, "pos");
    let mut worst: f64 = 0.0;
    for (id, p) in &b.photos {
        worst = worst.max((p.pose.center - syn.truth.photos[id].pose.center).norm());
    }
    eprintln!(
        "POS datum: worst centre error {worst:.3} m, σ0 {:.3}, {} rejected",
        rep.sigma0, rep.rejected.count
    );
    assert!(worst < 0.15, "worst centre error {worst}");
    // A-priori σ = 1 px, noise 0.5 px: snooping against σ = 1 rejects next to nothing.
    assert!(rep.rejected.count < 5);
}

#[test]
fn sparse_path_is_deterministic_across_thread_counts() {
    let o = SyntheticOptions {
        strips: 3,
        photos_per_strip: 25,
        tie_points: 5000,
        check_points: 0,
        seed: 13,
        ..Default::default()
    };
    let b = generate(&o).start;
    let run = |threads: usize| {
        let mut bb = b.clone();
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let rep = pool.install(|| adjust(&mut bb, &[], None, &AdjustOptions::default()).unwrap());
        (bb, rep)
    };
    let (b1, r1) = run(1);
    let (b2, r2) = run(2);
    assert_eq!(r1.sigma0.to_bits(), r2.sigma0.to_bits());
    for (id, p) in &b1.photos {
        assert_eq!(p.pose, b2.photos[id].pose, "photo {id}");
    }
}
