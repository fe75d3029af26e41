//! Bundle adjustment on synthetic aerial blocks with known truth.

use cloudcontrol::adjust::synthetic::{generate, SyntheticOptions};
use cloudcontrol::adjust::{adjust, AdjustOptions, Loss, ObservationRef, Rejection};
use cloudcontrol::block::{Block, PointId, PointKind};
use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
use std::collections::BTreeSet;

fn rotation_angle(a: &nalgebra::Matrix3<f64>, b: &nalgebra::Matrix3<f64>) -> f64 {
    let m = a * b.transpose();
    ((m.trace() - 1.0) / 2.0).clamp(-1.0, 1.0).acos()
}

/// RMS centre error (m) and RMS rotation error (rad) against the truth.
fn pose_errors(adj: &Block, truth: &Block) -> (f64, f64) {
    let (mut c, mut r) = (0.0, 0.0);
    for (id, p) in &adj.photos {
        let t = &truth.photos[id];
        c += (p.pose.center - t.pose.center).norm_squared();
        r += rotation_angle(&p.pose.rotation, &t.pose.rotation).powi(2);
    }
    let n = adj.photos.len() as f64;
    ((c / n).sqrt(), (r / n).sqrt())
}

#[test]
fn recovers_the_truth_and_sigma0_on_a_100_photo_block() {
    let o = SyntheticOptions::default();
    let syn = generate(&o);
    let mut b = syn.start.clone();
    assert!(b.photos.len() >= 100 && b.points.len() >= 20_000);
    let rep = adjust(&mut b, &[], None, &AdjustOptions::default()).unwrap();
    let (ce, re) = pose_errors(&b, &syn.truth);
    eprintln!(
        "σ0 {:.4} rmse {:.4} px, centre RMS {:.4} m, rotation RMS {:.2e} rad, {} it, {} rejected, {:.2} s, datum {}",
        rep.sigma0, rep.rmse_px, ce, re, rep.iterations, rep.rejected.count, rep.time_s, rep.datum
    );
    // A-priori σ is 1 px and the injected noise 0.5 px: σ0 estimates 0.5.
    assert!((rep.sigma0 / 0.5 - 1.0).abs() < 0.10, "σ0 = {}", rep.sigma0);
    assert_eq!(rep.datum, "control");
    assert!(rep.converged);
    // The reduced camera system: six unknowns a photo (control fixes the datum), a full
    // 6 × 6 block for every pair of photos that see a common point, counted here from the
    // block itself.
    let pairs: std::collections::BTreeSet<(u32, u32)> = syn
        .start
        .points
        .values()
        .flat_map(|p| {
            let ids: Vec<u32> = p.observations.iter().map(|o| o.photo).collect();
            let mut v = Vec::new();
            for (i, &a) in ids.iter().enumerate() {
                for &b in &ids[i + 1..] {
                    v.push((a.min(b), a.max(b)));
                }
            }
            v
        })
        .collect();
    let rs = rep.reduced_system.as_ref().expect("the system's report");
    let n = 6 * b.photos.len();
    assert_eq!(rs.unknowns, n);
    assert_eq!(rs.ordering, "AMD");
    assert_eq!(rs.nonzeros, b.photos.len() * 21 + pairs.len() * 36);
    assert!(rs.factor_nonzeros >= rs.nonzeros && rs.factor_nonzeros <= n * (n + 1) / 2);
    // Truth to the noise level: each photo's centre error against its own σ.
    let mut chi = 0.0;
    let mut n = 0.0;
    for pp in &rep.photo_precision {
        let t = &syn.truth.photos[&pp.photo];
        let a = &b.photos[&pp.photo];
        for k in 0..3 {
            let e = a.pose.center[k] - t.pose.center[k];
            chi += (e / pp.sigma_center_m[k]).powi(2);
            n += 1.0;
        }
    }
    let ratio = (chi / n).sqrt();
    eprintln!("RMS of centre error / σ: {ratio:.3}");
    assert!(
        ratio > 0.5 && ratio < 2.0,
        "errors are not at the noise level: {ratio}"
    );
    assert!(ce < 0.5, "centre RMS {ce} m");
    assert!(re < 5e-4, "rotation RMS {re} rad");
    // Few false rejections without gross errors.
    let n_img = rep.observations as f64;
    assert!((rep.rejected.count as f64) < 0.01 * n_img / 2.0);
    let chk = rep.check.expect("check points");
    eprintln!(
        "check: plan {:.3} m height {:.3} m max {:.3} m",
        chk.rmse_plan_m, chk.rmse_height_m, chk.max_m
    );
    // Expected σ_z ≈ H/B · GSD · σ ≈ 0.31 m for two rays.
    assert!(chk.rmse_plan_m < 0.15 && chk.rmse_height_m < 0.4);
}

#[test]
fn robust_path_finds_gross_errors_in_image_and_control_points() {
    let o = SyntheticOptions {
        control_grid: (5, 4),
        // A gross error in a two-ray tie point cannot be told from its partner ray; the
        // detection rate is measured on tracks of three rays or more.
        min_rays: 3,
        tie_points: 12_000,
        ..Default::default()
    };
    let syn = generate(&o);
    let mut b = syn.start.clone();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(99);
    let mut bad: BTreeSet<String> = BTreeSet::new();
    let mut n_image = 0usize;
    // 5 % of the image points get 5–30 px gross errors.
    for pt in b.points.values_mut() {
        if pt.kind == PointKind::Check {
            continue;
        }
        for ob in &mut pt.observations {
            n_image += 1;
            if rng.gen_bool(0.05) {
                let a: f64 = rng.gen_range(0.0..std::f64::consts::TAU);
                let m: f64 = rng.gen_range(5.0..30.0);
                ob.pixel[0] += m * a.cos();
                ob.pixel[1] += m * a.sin();
                bad.insert(format!(
                    "{:?}",
                    ObservationRef::Image {
                        point: pt.id,
                        photo: ob.photo
                    }
                ));
            }
        }
    }
    // 30 % of the control points get 1–5 m errors in their surveyed coordinates.
    let ctrl: Vec<PointId> = b
        .points
        .values()
        .filter(|p| p.kind == PointKind::Control)
        .map(|p| p.id)
        .collect();
    for (k, id) in ctrl.iter().enumerate() {
        if k % 10 < 3 {
            let p = b.points.get_mut(id).unwrap();
            let a: f64 = rng.gen_range(0.0..std::f64::consts::TAU);
            let m: f64 = rng.gen_range(1.0..5.0);
            p.position += Vector3::new(m * a.cos(), m * a.sin(), rng.gen_range(-m..m));
            bad.insert(format!("{:?}", ObservationRef::ControlPrior { point: *id }));
        }
    }
    let injected = b.clone();
    for loss in [Loss::Huber(2.0), Loss::Cauchy(2.0)] {
        let mut b = injected.clone();
        eprintln!("{loss:?}");
        let opts = AdjustOptions {
            loss,
            rejection: Rejection::Threshold(3.0),
            ..Default::default()
        };
        let rep = adjust(&mut b, &[], None, &opts).unwrap();
        let found: BTreeSet<String> = rep
            .rejected
            .list
            .iter()
            .map(|r| format!("{:?}", r.observation))
            .collect();
        let hits = found.intersection(&bad).count();
        // Rays that left with a tie point whose rays cannot tell the wrong one are not
        // claimed wrong: counted apart from the false rejections.
        let with_point: BTreeSet<String> = rep
            .rejected
            .list
            .iter()
            .filter(|r| r.with_point)
            .map(|r| format!("{:?}", r.observation))
            .collect();
        let lost = with_point.difference(&bad).count();
        let false_rej = found.len() - hits - lost;
        let n_good = n_image + ctrl.len() - bad.len();
        eprintln!(
            "{lost} good rays ({:.2} %) left with their tie points",
            100.0 * lost as f64 / n_good as f64
        );
        let (ce, re) = pose_errors(&b, &syn.truth);
        eprintln!(
            "{} injected, {} found ({:.1} %), {} false ({:.2} %), σ0 {:.3}, centre RMS {:.3} m, rot {:.1e}, {} rounds, {:.1} s",
            bad.len(), hits, 100.0 * hits as f64 / bad.len() as f64, false_rej,
            100.0 * false_rej as f64 / n_good as f64, rep.sigma0, ce, re, rep.rounds, rep.time_s
        );
        let bad_points: BTreeSet<String> = bad
            .iter()
            .filter_map(|b| {
                b.split("point: ").nth(1).map(|x| {
                    x.split(',')
                        .next()
                        .unwrap()
                        .trim_end_matches(" }")
                        .to_string()
                })
            })
            .collect();
        let mut same_point = 0;
        let mut rounds = std::collections::BTreeMap::new();
        for r in &rep.rejected.list {
            let key = format!("{:?}", r.observation);
            if !bad.contains(&key) && !r.with_point {
                *rounds.entry(r.round).or_insert(0) += 1;
                if let ObservationRef::Image { point, .. } = r.observation {
                    if bad_points.contains(&point.to_string()) {
                        same_point += 1;
                    }
                }
            }
        }
        eprintln!(
            "false rejections sharing a point with a gross error: {same_point}; per round {rounds:?}"
        );
        let ctrl_hits = rep
            .rejected
            .list
            .iter()
            .filter(|r| matches!(r.observation, ObservationRef::ControlPrior { .. }))
            .count();
        eprintln!("control priors rejected: {ctrl_hits}");
        assert!(hits as f64 >= 0.95 * bad.len() as f64);
        assert!((false_rej as f64) < 0.01 * n_good as f64);
        assert!((lost as f64) < 0.03 * n_good as f64);
        assert!((rep.sigma0 / 0.5 - 1.0).abs() < 0.15, "σ0 {}", rep.sigma0);
        assert!(ce < 0.5 && re < 5e-4);
        for r in &rep.rejected.list {
            assert!(r.reason.contains("standardised residual"), "{}", r.reason);
        }
    }
}
