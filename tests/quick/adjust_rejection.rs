//! Gross-error elimination that does not eat good data (issue 16): Baarda data snooping
//! against the a-priori σ by default, its guard against a too optimistic σ, a clean
//! output model, variance components, and control points of unknown height.

use cloudcontrol::adjust::synthetic::{generate, SyntheticBlock, SyntheticOptions};
use cloudcontrol::adjust::{adjust, AdjustError, AdjustOptions, AdjustReport, ObservationRef};
use cloudcontrol::block::{Block, PointKind, PosPrior};
use cloudcontrol::geometry::project;
use rand::{Rng, SeedableRng};
use std::collections::BTreeSet;

/// √χ²(2) at α0 = 0.1 %: no image residual of the output model may exceed it (in units of
/// the σ the test used). |v| ≤ w holds because every redundancy number is at most 1.
const W_LIMIT: f64 = 3.717;

fn block(seed: u64, sigma_px: f64, min_rays: usize, tie_points: usize) -> SyntheticBlock {
    generate(&SyntheticOptions {
        strips: 5,
        photos_per_strip: 10,
        tie_points,
        min_rays,
        noise_px: 0.5,
        sigma_px,
        check_points: 0,
        seed,
        ..Default::default()
    })
}

fn image_observations(b: &Block) -> usize {
    b.points
        .values()
        .filter(|p| p.kind != PointKind::Check)
        .map(|p| p.observations.len())
        .sum()
}

/// The output model read back independently: tie points with fewer than two rays, and
/// the largest reprojection residual of a tie observation in units of its σ.
fn output_model(b: &Block) -> (usize, f64) {
    let mut one_ray = 0;
    let mut worst: f64 = 0.0;
    for p in b.points.values().filter(|p| p.kind == PointKind::Tie) {
        if p.observations.len() < 2 {
            one_ray += 1;
        }
        for o in &p.observations {
            let ph = &b.photos[&o.photo];
            let q = project(&b.cameras[&ph.camera].model, &ph.pose, &p.position).unwrap();
            let v = ((q.pixel.x - o.pixel[0]).powi(2) + (q.pixel.y - o.pixel[1]).powi(2)).sqrt();
            worst = worst.max(v / o.sigma_px);
        }
    }
    (one_ray, worst)
}

fn image_sigma0(rep: &AdjustReport) -> f64 {
    let g = rep
        .variance_components
        .iter()
        .find(|g| g.group == "image")
        .expect("image group");
    g.sigma0.expect("redundancy")
}

/// Every observation missing from the output model is listed as rejected or belonged to
/// a tie point that left the block; the count of those points is reported.
fn accounted(input: &Block, output: &Block, rep: &AdjustReport) {
    let listed: BTreeSet<String> = rep
        .rejected
        .list
        .iter()
        .map(|r| format!("{:?}", r.observation))
        .collect();
    let mut removed_points = 0;
    for (id, p) in &input.points {
        let Some(q) = output.points.get(id) else {
            removed_points += 1;
            assert_eq!(p.kind, PointKind::Tie, "point {id} left the block");
            continue;
        };
        for o in &p.observations {
            if !q.observations.iter().any(|k| k.photo == o.photo) {
                let key = format!(
                    "{:?}",
                    ObservationRef::Image {
                        point: *id,
                        photo: o.photo
                    }
                );
                assert!(listed.contains(&key), "{key} vanished without being listed");
            }
        }
    }
    assert_eq!(removed_points, rep.removed_tie_points);
}

#[test]
fn clean_block_keeps_its_tails() {
    let syn = block(1, 0.5, 2, 12_500);
    let mut input = syn.start.clone();
    // A control point measured in a single photo stays a valid single-ray control point.
    let single = input
        .points
        .values_mut()
        .find(|p| p.kind == PointKind::Control && p.observations.len() >= 2)
        .unwrap();
    single.observations.truncate(1);
    let single = single.id;
    let mut b = input.clone();
    let n_img = image_observations(&b);
    let rep = adjust(&mut b, &[], None, &AdjustOptions::default()).unwrap();
    let frac = rep.rejected.count as f64 / n_img as f64;
    let s_img = image_sigma0(&rep);
    let (one_ray, worst) = output_model(&b);
    eprintln!(
        "clean 50-photo block: {} of {n_img} image observations rejected ({:.3} %), σ0 {:.4}, image σ0 {s_img:.4}, {} rounds, {} tie points removed, worst output residual {worst:.2} σ, {:.2} s; test {}",
        rep.rejected.count,
        100.0 * frac,
        rep.sigma0,
        rep.rounds,
        rep.removed_tie_points,
        rep.time_s,
        rep.rejection_test
    );
    for g in &rep.variance_components {
        eprintln!(
            "  {}: {} obs, {} components, Σr {:.1}, σ0 {:?}",
            g.group, g.observations, g.components, g.redundancy, g.sigma0
        );
    }
    assert!(frac <= 0.003, "{:.3} % rejected", 100.0 * frac);
    assert_eq!(
        rep.rejection_test,
        "baarda_data_snooping alpha=0.001 sigma=a_priori"
    );
    assert!((0.95..=1.05).contains(&s_img), "image σ0 {s_img}");
    assert_eq!(one_ray, 0);
    assert!(worst <= W_LIMIT, "output residual {worst} σ");
    assert_eq!(b.points[&single].observations.len(), 1);
    assert!(rep
        .residuals
        .iter()
        .any(|r| r.observation == ObservationRef::ControlPrior { point: single }));
    accounted(&input, &b, &rep);
}

#[test]
fn too_optimistic_sigma_engages_the_guard() {
    // A-priori 0.25 px, noise 0.5 px: twice too optimistic.
    let syn = block(2, 0.25, 2, 12_500);
    let input = syn.start.clone();
    let mut b = input.clone();
    let n_img = image_observations(&b);
    let rep = adjust(&mut b, &[], None, &AdjustOptions::default()).unwrap();
    let frac = rep.rejected.count as f64 / n_img as f64;
    let s_img = image_sigma0(&rep);
    let (one_ray, worst) = output_model(&b);
    eprintln!(
        "σ_px 0.25, noise 0.5: {} rejected ({:.3} %), image σ0 {s_img:.3}, worst {worst:.2} a-priori σ, test {}",
        rep.rejected.count,
        100.0 * frac,
        rep.rejection_test
    );
    let used: f64 = rep
        .rejection_test
        .strip_prefix("baarda_data_snooping alpha=0.001 sigma=first_round ")
        .unwrap_or_else(|| panic!("{}", rep.rejection_test))
        .parse()
        .unwrap();
    assert!((1.8..=2.2).contains(&used), "first-round σ0 {used}");
    assert!(frac <= 0.003, "{:.3} % rejected", 100.0 * frac);
    assert!((1.9..=2.1).contains(&s_img), "image σ0 {s_img}");
    assert_eq!(one_ray, 0);
    assert!(worst <= W_LIMIT * used, "output residual {worst} σ");
    accounted(&input, &b, &rep);
}

/// Displaces 5 % of the image observations of tie and control points by 5–50 px.
fn displace(b: &mut Block, seed: u64) -> BTreeSet<String> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut bad = BTreeSet::new();
    for pt in b.points.values_mut() {
        if pt.kind == PointKind::Check {
            continue;
        }
        for ob in &mut pt.observations {
            if rng.gen_bool(0.05) {
                let a: f64 = rng.gen_range(0.0..std::f64::consts::TAU);
                let m: f64 = rng.gen_range(5.0..50.0);
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
    bad
}

#[test]
fn gross_errors_are_found_and_good_data_kept() {
    // A gross error in a two-ray tie point cannot be told from its partner ray (one of
    // the two goes, and the point with it); detection is measured on tracks of three+.
    let syn = block(3, 0.5, 3, 8_000);
    let mut input = syn.start.clone();
    let bad = displace(&mut input, 31);
    let n_img = image_observations(&input);
    let mut b = input.clone();
    let rep = adjust(&mut b, &[], None, &AdjustOptions::default()).unwrap();
    let found: BTreeSet<String> = rep
        .rejected
        .list
        .iter()
        .map(|r| format!("{:?}", r.observation))
        .collect();
    let hits = found.intersection(&bad).count();
    let false_rej = found.len() - hits;
    let n_good = n_img - bad.len();
    let (one_ray, worst) = output_model(&b);
    eprintln!(
        "{} displaced, {hits} found ({:.1} %), {false_rej} good rejected ({:.3} %), image σ0 {:.3}, {} rounds, worst {worst:.2} σ, {:.1} s",
        bad.len(),
        100.0 * hits as f64 / bad.len() as f64,
        100.0 * false_rej as f64 / n_good as f64,
        image_sigma0(&rep),
        rep.rounds,
        rep.time_s
    );
    assert!(hits as f64 >= 0.95 * bad.len() as f64);
    assert!((false_rej as f64) < 0.01 * n_good as f64);
    assert_eq!(one_ray, 0);
    assert!(worst <= W_LIMIT, "output residual {worst} σ");
    assert!((0.95..=1.05).contains(&image_sigma0(&rep)));
    // The gross errors do not pass for a wrong a-priori σ. On the first solution, points
    // with several displaced rays read as tie points of differing precision; once the
    // rounds have removed them, the fit finds one σ again and the block ends with data
    // snooping against it.
    assert!(
        rep.rejection_test
            .starts_with("baarda_data_snooping alpha=0.001 sigma=a_priori"),
        "{}",
        rep.rejection_test
    );
    assert_eq!(rep.tie_point_prior, None);
    for r in &rep.rejected.list {
        assert!(
            r.reason.contains("χ²(") || r.reason.contains("(F("),
            "{}",
            r.reason
        );
    }
    accounted(&input, &b, &rep);

    // Rounds cut short: the final sweep rejects what is left and says so.
    let mut b = input.clone();
    let opts = AdjustOptions {
        max_rounds: 1,
        ..Default::default()
    };
    let rep = adjust(&mut b, &[], None, &opts).unwrap();
    let (one_ray, worst) = output_model(&b);
    let found: BTreeSet<String> = rep
        .rejected
        .list
        .iter()
        .map(|r| format!("{:?}", r.observation))
        .collect();
    let hits = found.intersection(&bad).count();
    let false_rej = found.len() - hits;
    eprintln!(
        "one round: {} rejected ({hits} displaced, {false_rej} good), test {}, worst {worst:.2} σ",
        rep.rejected.count, rep.rejection_test
    );
    // The sweep snoops each point with the orientations held: the good rays a gross
    // error smeared into stay.
    assert!(hits as f64 >= 0.95 * bad.len() as f64);
    assert!((false_rej as f64) < 0.01 * n_good as f64);
    assert!(
        rep.rejection_test.contains(", final sweep "),
        "{}",
        rep.rejection_test
    );
    assert!(rep
        .rejected
        .list
        .iter()
        .any(|r| r.reason.contains("final sweep")));
    assert_eq!(one_ray, 0);
    assert!(worst <= W_LIMIT, "output residual {worst} σ");
    accounted(&input, &b, &rep);
}

#[test]
fn control_of_unknown_height() {
    let syn = block(4, 0.5, 2, 6_000);
    let ctrl: Vec<u64> = syn
        .start
        .points
        .values()
        .filter(|p| p.kind == PointKind::Control)
        .map(|p| p.id)
        .collect();
    assert!(ctrl.len() >= 10);

    // Only 2-D control and no other height source: the datum is singular.
    let mut b = syn.start.clone();
    for id in &ctrl {
        b.points.get_mut(id).unwrap().sigma = Some([0.02, 0.02, f64::INFINITY]);
    }
    let e = adjust(&mut b, &[], None, &AdjustOptions::default()).unwrap_err();
    assert!(
        matches!(e, AdjustError::Degenerate(_)) && e.to_string().contains("2-D"),
        "{e}"
    );

    // Every other control point 2-D, its height given 30 m off: the others hold the
    // heights, the adjustment finds the 2-D points' heights from their rays.
    let mut b = syn.start.clone();
    let mut two_d = Vec::new();
    for (k, id) in ctrl.iter().enumerate() {
        let p = b.points.get_mut(id).unwrap();
        if k % 2 == 1 && p.observations.len() >= 2 {
            p.sigma = Some([0.02, 0.02, f64::INFINITY]);
            p.position.z += 30.0;
            two_d.push(*id);
        }
    }
    let rep = adjust(&mut b, &[], None, &AdjustOptions::default()).unwrap();
    assert_eq!(rep.datum, "control");
    assert!(rep.sigma0.is_finite() && rep.rmse_px.is_finite());
    for r in &rep.residuals {
        assert!(r.residual.iter().all(|v| v.is_finite()), "{r:?}");
        assert!(
            r.standardized.is_finite() && r.redundancy.is_finite(),
            "{r:?}"
        );
    }
    for id in &two_d {
        let r = rep
            .residuals
            .iter()
            .find(|r| r.observation == ObservationRef::ControlPrior { point: *id })
            .unwrap();
        // Adjusted minus given height: the given one was 30 m high.
        let truth_dz = syn.truth.points[id].position.z - b.points[id].position.z;
        eprintln!(
            "2-D control {id}: residual {:?}, true offset {truth_dz:.2} m",
            r.residual
        );
        assert_eq!(r.residual.len(), 3);
        assert!((r.residual[2] - truth_dz).abs() < 0.5, "{:?}", r.residual);
        assert!(r.residual[0].abs() < 0.1 && r.residual[1].abs() < 0.1);
    }
    // The 30 m are no gross error: the unknown axis is not tested.
    assert!(!rep
        .rejected
        .list
        .iter()
        .any(|r| matches!(r.observation, ObservationRef::ControlPrior { .. })));
    let c = rep
        .variance_components
        .iter()
        .find(|g| g.group == "control")
        .unwrap();
    assert_eq!(c.components, 3 * ctrl.len() - two_d.len());
    let c0 = c.sigma0.unwrap();
    eprintln!("control group: Σr {:.2}, σ0 {c0:.3}", c.redundancy);
    assert!(c0 > 0.2 && c0 < 3.0, "control σ0 {c0}");

    // 2-D control with POS priors for the heights: datum "control_plan+pos".
    let mut b = syn.start.clone();
    for id in &ctrl {
        b.points.get_mut(id).unwrap().sigma = Some([0.02, 0.02, f64::INFINITY]);
    }
    for (id, p) in b.photos.iter_mut() {
        p.prior = Some(PosPrior {
            center: syn.truth.photos[id].pose.center,
            center_sigma: [0.1; 3],
            rotation: None,
            rotation_sigma_rad: 0.0,
        });
    }
    let rep = adjust(&mut b, &[], None, &AdjustOptions::default()).unwrap();
    assert_eq!(rep.datum, "control_plan+pos");
    let pos = rep
        .variance_components
        .iter()
        .find(|g| g.group == "pos_center")
        .unwrap();
    eprintln!(
        "POS centre group: {} obs, Σr {:.2}, σ0 {:?}",
        pos.observations, pos.redundancy, pos.sigma0
    );
    // The POS centres are the truth: their residuals are the adjustment's own errors.
    assert!(pos.redundancy > 0.0 && pos.redundancy < 3.0 * pos.observations as f64);

    // Bad σ values are refused, naming the point.
    let mut b = syn.start.clone();
    let id = ctrl[0];
    for bad in [
        [f64::NAN, 0.02, 0.02],
        [0.02, 0.02, -1.0],
        [f64::INFINITY; 3],
    ] {
        b.points.get_mut(&id).unwrap().sigma = Some(bad);
        let e = adjust(&mut b.clone(), &[], None, &AdjustOptions::default()).unwrap_err();
        assert!(
            e.to_string().contains(&format!("control point {id}")),
            "{e}"
        );
    }
}

/// Gross errors among the checkpoints' own measurements (issue 52): a checkpoint is
/// intersected with data snooping, so its RMSE stays what the same adjustment gives with
/// those measurements removed, and every displaced measurement is listed.
#[test]
fn checkpoint_measurement_blunders_are_found_and_listed() {
    for seed in [5u64, 6, 7, 8] {
        let syn = generate(&SyntheticOptions {
            strips: 5,
            photos_per_strip: 10,
            tie_points: 4_000,
            noise_px: 0.5,
            sigma_px: 0.5,
            check_points: 40,
            seed,
            ..Default::default()
        });
        let mut input = syn.start.clone();
        // 5 % of every image observation, checkpoints' included, displaced by 5–50 px.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed * 100 + 1);
        let mut bad = BTreeSet::new();
        for pt in input.points.values_mut() {
            for ob in &mut pt.observations {
                let p = if pt.kind == PointKind::Check {
                    0.10
                } else {
                    0.05
                };
                if rng.gen_bool(p) {
                    let a: f64 = rng.gen_range(0.0..std::f64::consts::TAU);
                    let m: f64 = rng.gen_range(5.0..50.0);
                    ob.pixel[0] += m * a.cos();
                    ob.pixel[1] += m * a.sin();
                    if pt.kind == PointKind::Check {
                        bad.insert((pt.id, ob.photo));
                    }
                }
            }
        }
        let mut clean = input.clone();
        for pt in clean.points.values_mut() {
            pt.observations.retain(|o| !bad.contains(&(pt.id, o.photo)));
        }
        let mut b = input.clone();
        let rep = adjust(&mut b, &[], None, &AdjustOptions::default()).unwrap();
        let mut c = clean.clone();
        let rep_clean = adjust(&mut c, &[], None, &AdjustOptions::default()).unwrap();
        let (chk, chk_clean) = (rep.check.unwrap(), rep_clean.check.unwrap());
        let listed: BTreeSet<_> = chk.rejected.iter().map(|r| (r.point, r.photo)).collect();
        let good_listed = listed.difference(&bad).count();
        eprintln!(
            "seed {seed}: {} checkpoint rays displaced, {} listed ({good_listed} good), {} of {} checkpoints evaluated (clean {}); RMSE plan/height {:.3}/{:.3} m, clean {:.3}/{:.3} m",
            bad.len(),
            listed.len(),
            chk.count,
            chk.count + chk.not_evaluated,
            chk_clean.count,
            chk.rmse_plan_m,
            chk.rmse_height_m,
            chk_clean.rmse_plan_m,
            chk_clean.rmse_height_m
        );
        assert!(bad.len() >= 10, "{} displaced", bad.len());
        assert!(
            bad.is_subset(&listed),
            "missed: {:?}",
            bad.difference(&listed)
        );
        assert!(
            chk.rmse_plan_m <= 1.25 * chk_clean.rmse_plan_m + 0.02,
            "plan {} vs {}",
            chk.rmse_plan_m,
            chk_clean.rmse_plan_m
        );
        assert!(
            chk.rmse_height_m <= 1.25 * chk_clean.rmse_height_m + 0.02,
            "height {} vs {}",
            chk.rmse_height_m,
            chk_clean.rmse_height_m
        );
        // Good measurements are listed only as the partners of a blunder that no test can
        // localise or confirm (a checkpoint left with two rays): never more than two each.
        assert!(
            good_listed <= 2 * bad.len(),
            "{good_listed} good rays listed"
        );
        for r in &chk.rejected {
            assert!(!r.reason.is_empty());
        }
    }
}
