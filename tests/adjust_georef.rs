//! Georeferencing a free model onto control with blunders: wrong measurements are found
//! as measurements, control points with wrong coordinates as whole points, and the
//! adjustment that follows reaches the accuracy of one told which control is good.

use cloudcontrol::adjust::georef::{georeference, GeorefOptions, SurveyedInput};
use cloudcontrol::adjust::synthetic::{generate, SyntheticOptions};
use cloudcontrol::adjust::{
    adjust, adjust_with_rejected, AdjustOptions, AdjustReport, ObservationRef,
};
use cloudcontrol::block::{Block, PointId, PointKind};
use cloudcontrol::geometry::project_with_jacobians;
use cloudcontrol::geometry::{rotation_from_vector, Similarity};
use nalgebra::{DMatrix, Matrix3, Vector2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::{BTreeMap, BTreeSet};

struct Case {
    /// The block in an arbitrary SfM frame, control points without coordinates.
    model: Block,
    surveyed: Vec<SurveyedInput>,
    bad_points: BTreeSet<PointId>,
    /// (point, photo) of displaced control measurements.
    bad_control_obs: BTreeSet<(PointId, u32)>,
    /// (point, photo) of displaced tie observations.
    bad_tie_obs: BTreeSet<(PointId, u32)>,
    /// Their displacement (px).
    tie_blunder: BTreeMap<(PointId, u32), Vector2<f64>>,
    truth: Block,
}

fn case(seed: u64, photos: (usize, usize), bad_tie_fraction: f64) -> Case {
    let syn = generate(&SyntheticOptions {
        strips: photos.0,
        photos_per_strip: photos.1,
        tie_points: 400 * photos.0 * photos.1,
        control_grid: (4, 3),
        check_points: 8,
        noise_px: 0.5,
        sigma_px: 0.5,
        seed,
        ..Default::default()
    });
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed);
    let sfm = Similarity::new(
        0.013,
        rotation_from_vector(&Vector3::new(0.3, -0.2, 1.1)),
        Vector3::new(4.0, -2.0, 7.0),
    );
    let mut model = syn.start.clone();
    for p in model.photos.values_mut() {
        p.pose = sfm.apply_pose(&p.pose);
        p.prior = None;
    }
    let mut surveyed = Vec::new();
    let mut bad_points = BTreeSet::new();
    let mut bad_control_obs = BTreeSet::new();
    let mut bad_tie_obs = BTreeSet::new();
    let mut tie_blunder = BTreeMap::new();
    let control: Vec<PointId> = model
        .points
        .values()
        .filter(|p| p.kind == PointKind::Control)
        .map(|p| p.id)
        .collect();
    for p in model.points.values_mut() {
        let truth = syn.truth.points[&p.id].position;
        match p.kind {
            PointKind::Tie => {
                p.position = sfm.apply(&p.position);
                for o in &mut p.observations {
                    if rng.gen_bool(bad_tie_fraction) {
                        let d =
                            rng.gen_range(5.0..50.0) * if rng.gen_bool(0.5) { 1.0 } else { -1.0 };
                        let axis = rng.gen_range(0..2);
                        o.pixel[axis] += d;
                        bad_tie_obs.insert((p.id, o.photo));
                        let mut v = Vector2::zeros();
                        v[axis] = d;
                        tie_blunder.insert((p.id, o.photo), v);
                    }
                }
            }
            kind => {
                let mut position = truth;
                // 30 % of the control points (every third) moved 2–10 m.
                if kind == PointKind::Control
                    && control.iter().position(|&c| c == p.id).unwrap() % 3 == 1
                {
                    let dir = Vector3::new(
                        rng.gen_range(-1.0..1.0),
                        rng.gen_range(-1.0..1.0),
                        rng.gen_range(-1.0..1.0),
                    )
                    .normalize();
                    position += dir * rng.gen_range(2.0..10.0);
                    bad_points.insert(p.id);
                } else if kind == PointKind::Control
                    && p.observations.len() >= 3
                    && rng.gen_bool(0.4)
                {
                    // One wrong measurement on some of the good points.
                    let k = rng.gen_range(0..p.observations.len());
                    p.observations[k].pixel[0] += 30.0;
                    bad_control_obs.insert((p.id, p.observations[k].photo));
                }
                surveyed.push(SurveyedInput {
                    point: p.id,
                    position,
                    sigma: p.sigma.unwrap_or([0.02, 0.02, 0.03]),
                    kind,
                });
                p.position = Vector3::zeros();
                p.kind = PointKind::Tie;
                p.sigma = None;
            }
        }
    }
    Case {
        model,
        surveyed,
        bad_points,
        bad_control_obs,
        bad_tie_obs,
        tie_blunder,
        truth: syn.truth,
    }
}

fn check_rmse(rep: &AdjustReport) -> (f64, f64) {
    let c = rep.check.as_ref().expect("check points");
    (c.rmse_plan_m, c.rmse_height_m)
}

/// The test statistic w² = ∇ᵀR∇/σ² a displacement ∇ of one image observation produces
/// in its point's intersection from the true geometry (R: the observation's block of the
/// redundancy matrix I − A(AᵀA)⁻¹Aᵀ with the orientations known). A tie point's rays have
/// no redundancy along the base in a two-ray point, so a displacement along it moves the
/// point and leaves no residual: no test of any rule can see it.
fn expected_w2(
    truth: &Block,
    point: PointId,
    photo: u32,
    blunder: &Vector2<f64>,
    sigma: f64,
) -> f64 {
    let p = &truth.points[&point];
    let jac: Vec<(u32, nalgebra::SMatrix<f64, 2, 3>)> = p
        .observations
        .iter()
        .map(|o| {
            let ph = &truth.photos[&o.photo];
            let cam = &truth.cameras[&ph.camera].model;
            let (_, j) = project_with_jacobians(cam, &ph.pose, &p.position).unwrap();
            (o.photo, j.point)
        })
        .collect();
    let n: Matrix3<f64> = jac.iter().map(|(_, a)| a.transpose() * a).sum();
    let a = DMatrix::from_fn(2 * jac.len(), 3, |r, c| jac[r / 2].1[(r % 2, c)]);
    let r = DMatrix::identity(2 * jac.len(), 2 * jac.len())
        - &a * DMatrix::from_column_slice(3, 3, n.try_inverse().unwrap().as_slice())
            * a.transpose();
    let k = jac.iter().position(|(ph, _)| *ph == photo).unwrap();
    let rk = r.fixed_view::<2, 2>(2 * k, 2 * k).into_owned();
    (blunder.transpose() * rk * blunder)[0] / (sigma * sigma)
}

#[test]
fn blunders_in_control_are_found_as_measurements_and_points() {
    for seed in [3, 11] {
        let mut c = case(seed, (4, 10), 0.0);
        let g = georeference(&mut c.model, &c.surveyed, &GeorefOptions::default()).unwrap();
        let found: BTreeSet<PointId> = g.rejected_points.iter().map(|r| r.point).collect();
        assert_eq!(found, c.bad_points, "seed {seed}: {:#?}", g.rejected_points);
        let found: BTreeSet<(PointId, u32)> = g
            .rejected_measurements
            .iter()
            .map(|r| (r.point, r.photo))
            .collect();
        assert_eq!(
            found, c.bad_control_obs,
            "seed {seed}: {:#?}",
            g.rejected_measurements
        );
        // The block is on the control: centres within a few decimetres of the truth.
        let worst = c
            .model
            .photos
            .values()
            .map(|p| (p.pose.center - c.truth.photos[&p.id].pose.center).norm())
            .fold(0.0, f64::max);
        assert!(worst < 1.0, "seed {seed}: centre {worst} m from the truth");
    }
}

#[test]
fn adjustment_after_georeferencing_matches_the_one_told_which_control_is_good() {
    let mut rows = Vec::new();
    for seed in [3, 11, 19] {
        let c = case(seed, (4, 10), 0.05);
        // Ours: everything given, blunders to be found.
        let mut ours = c.model.clone();
        let g = georeference(&mut ours, &c.surveyed, &GeorefOptions::default()).unwrap();
        // As `cloudcontrol adjust` runs it: without the free network's rejections, which
        // its final solution tests again.
        let rep = adjust_with_rejected(
            &mut ours,
            &[],
            None,
            &AdjustOptions::default(),
            &g.free_network_rejected,
        )
        .unwrap();
        // Oracle: the bad control points are not given.
        let mut oracle = c.model.clone();
        let good: Vec<SurveyedInput> = c
            .surveyed
            .iter()
            .filter(|s| !c.bad_points.contains(&s.point))
            .cloned()
            .collect();
        georeference(&mut oracle, &good, &GeorefOptions::default()).unwrap();
        let oracle_rep = adjust(&mut oracle, &[], None, &AdjustOptions::default()).unwrap();
        let (op, oh) = check_rmse(&rep);
        let (rp, rh) = check_rmse(&oracle_rep);
        // Injected gross errors found: tie observations rejected by the adjustment (as
        // themselves, or with their tie point when its rays cannot tell which one is
        // wrong), control measurements and points by the georeferencing.
        let image = |with_point: bool| -> BTreeSet<(PointId, u32)> {
            rep.rejected
                .list
                .iter()
                .filter(|r| r.with_point == with_point)
                .filter_map(|r| match r.observation {
                    ObservationRef::Image { point, photo } => Some((point, photo)),
                    _ => None,
                })
                .collect()
        };
        let listed: BTreeSet<(PointId, u32)> = image(false)
            .into_iter()
            .chain(g.rejected_measurements.iter().map(|r| (r.point, r.photo)))
            .collect();
        let with_point = image(true);
        let injected: BTreeSet<(PointId, u32)> =
            c.bad_tie_obs.union(&c.bad_control_obs).copied().collect();
        // A displacement the geometry cannot show (w² below four times the critical
        // value 13.8 of χ²(2) at 0.1 %, i.e. w under 7.4 for a perfect test) is counted
        // apart: along the base of a two-ray point it only moves the point.
        let undetectable: BTreeSet<(PointId, u32)> = c
            .tie_blunder
            .iter()
            .filter(|(&(p, ph), v)| expected_w2(&c.truth, p, ph, v, 0.5) < 4.0 * 13.82)
            .map(|(k, _)| *k)
            .collect();
        let found = |k: &(PointId, u32)| listed.contains(k) || with_point.contains(k);
        let detectable = injected.len() - undetectable.len() + c.bad_points.len();
        let hit = injected
            .iter()
            .filter(|k| !undetectable.contains(k) && found(k))
            .count()
            + g.rejected_points
                .iter()
                .filter(|r| c.bad_points.contains(&r.point))
                .count();
        let hit_all = injected.iter().filter(|k| found(k)).count();
        let false_listed = listed.difference(&injected).count();
        let lost_with_points = with_point.difference(&injected).count();
        let good_obs = c.model.num_observations() - injected.len();
        rows.push((
            seed,
            op,
            oh,
            rp,
            rh,
            hit as f64 / detectable as f64,
            false_listed as f64 / good_obs as f64,
            lost_with_points as f64 / good_obs as f64,
        ));
        eprintln!(
            "seed {seed}: ours plan {op:.3} height {oh:.3} m; oracle {rp:.3} {rh:.3} m; \
             found {hit}/{detectable} detectable gross errors ({hit_all}/{} injected, {} \
             undetectable); {false_listed} of {good_obs} good observations listed, \
             {lost_with_points} removed with {} tie points whose rays cannot tell the wrong one",
            injected.len() + c.bad_points.len(),
            undetectable.len(),
            rep.rejected
                .list
                .iter()
                .filter(|r| r.with_point)
                .filter_map(|r| match r.observation {
                    ObservationRef::Image { point, .. } => Some(point),
                    _ => None,
                })
                .collect::<BTreeSet<_>>()
                .len(),
        );
    }
    for (seed, op, oh, rp, rh, recall, false_rate, lost_rate) in rows {
        assert!(
            op <= 1.25 * rp + 0.02 && oh <= 1.25 * rh + 0.02,
            "seed {seed}: ours {op:.3}/{oh:.3} oracle {rp:.3}/{rh:.3}"
        );
        assert!(recall >= 0.95, "seed {seed}: {:.1} % found", 100.0 * recall);
        assert!(
            false_rate < 0.01,
            "seed {seed}: {:.2} % false",
            100.0 * false_rate
        );
        // Each point whose gross error cannot be localised takes one or two good rays
        // with it (5 % displaced: about a quarter of the displaced rays sit in two- and
        // three-ray points).
        assert!(
            lost_rate < 0.03,
            "seed {seed}: {:.2} % lost",
            100.0 * lost_rate
        );
    }
}
