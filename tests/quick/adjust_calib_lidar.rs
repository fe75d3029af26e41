//! Self-calibration and LiDAR point-to-plane datum on synthetic blocks.

use cloudcontrol::adjust::synthetic::{generate, terrain, terrain_normal, SyntheticOptions};
use cloudcontrol::adjust::{
    adjust, adjust_determinable, chi2, AdjustOptions, HeldBecause, PlaneConstraint, PlaneRefitter,
    CALIBRATION_SIGNIFICANCE,
};
use cloudcontrol::block::{PointId, PointKind};
use cloudcontrol::geometry::{Brown, Camera};
use nalgebra::{Matrix3, Vector3};

fn calib_block(relief: f64) -> (cloudcontrol::adjust::synthetic::SyntheticBlock, f64) {
    let o = SyntheticOptions {
        strips: 4,
        photos_per_strip: 15,
        tie_points: 12_000,
        relief_m: relief,
        distortion: Brown {
            k1: -0.05,
            k2: 0.01,
            ..Default::default()
        },
        control_grid: (4, 3),
        check_points: 0,
        seed: 5,
        ..Default::default()
    };
    let syn = generate(&o);
    (syn, o.focal_px)
}

fn run_selfcal(relief: f64) -> (f64, f64, Vec<cloudcontrol::adjust::CalibrationReport>) {
    let (syn, f_true) = calib_block(relief);
    let mut b = syn.start.clone();
    let cam = b.cameras.get_mut(&1).unwrap();
    let mut p = cam.model.params();
    p[0] *= 1.003;
    p[1] *= 1.003;
    p[4] = 0.0;
    p[5] = 0.0;
    cam.model.set_params(&p).unwrap();
    cam.free_params = ["fx", "fy", "cx", "cy", "k1", "k2"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    let rep = adjust(&mut b, &[], None, &AdjustOptions::default()).unwrap();
    let Camera::Frame(c) = &b.cameras[&1].model else {
        unreachable!()
    };
    let f_err = (0.5 * (c.fx + c.fy) / f_true - 1.0).abs();
    let k1_err = (c.distortion.k1 / -0.05 - 1.0).abs();
    eprintln!(
        "relief {relief} m: f error {:.4} %, k1 error {:.2} %, σ0 {:.3}, {:.1} s",
        100.0 * f_err,
        100.0 * k1_err,
        rep.sigma0,
        rep.time_s
    );
    for c in &rep.calibration {
        eprintln!(
            "  {} = {:.6} ± {:.2e}  corr {:.4} ({}) {}",
            c.param, c.value, c.sigma, c.max_correlation, c.correlated_with, c.determinable
        );
    }
    (f_err, k1_err, rep.calibration)
}

#[test]
fn self_calibration_recovers_f_and_k1_with_relief_and_flags_a_flat_block() {
    let (_, _, cal_flat) = run_selfcal(0.0);
    let (f_err, k1_err, cal) = run_selfcal(250.0);
    assert!(f_err < 5e-4, "f error {f_err}");
    assert!(k1_err < 0.05, "k1 error {k1_err}");
    assert!(cal
        .iter()
        .filter(|c| c.param == "fx" || c.param == "k1")
        .all(|c| c.determinable));
    // Flat terrain, nadir photos: f and the flying height are not separable.
    let fx = cal_flat.iter().find(|c| c.param == "fx").unwrap();
    assert!(
        !fx.determinable,
        "f must be flagged on a flat block (corr {})",
        fx.max_correlation
    );
}

/// Grün's significance test of the additional parameters: a parameter whose prior is
/// the truth comes out within noise of it and is held there; one whose prior is far off
/// is significant and adjusted.
#[test]
fn a_self_calibration_parameter_the_data_do_not_show_is_held_at_its_prior() {
    let (syn, _) = calib_block(250.0);
    let mut b = syn.start.clone();
    let cam = b.cameras.get_mut(&1).unwrap();
    let truth = cam.model.params();
    let names = cam.model.param_names();
    let at = |n: &str| names.iter().position(|m| *m == n).unwrap();
    let mut p = truth.clone();
    p[at("k1")] = 0.0; // truth −0.05
    cam.model.set_params(&p).unwrap();
    let free = ["cx", "cy", "k1", "k2"];
    cam.free_params = free.iter().map(|s| s.to_string()).collect();
    let rep = adjust_determinable(&mut b, &AdjustOptions::default()).unwrap();
    let limit = chi2::critical(1, CALIBRATION_SIGNIFICANCE).sqrt();
    let adjusted = b.cameras[&1].model.params();
    for c in &rep.calibration {
        eprintln!(
            "{} = {:.6} ± {:.2e}, t {:?}, held {:?}",
            c.param, c.value, c.sigma, c.t_prior, c.held_because
        );
    }
    assert_eq!(rep.calibration.len(), free.len());
    let mut held = 0;
    for c in &rep.calibration {
        let k = at(&c.param);
        let t = c.t_prior.expect("tested against its prior");
        if c.held_because == Some(HeldBecause::NotSignificant) {
            held += 1;
            assert!(t < limit && c.fixed && c.sigma == 0.0, "{c:?}");
            assert_eq!(adjusted[k], p[k], "{} held at its prior", c.param);
        } else {
            assert!(t >= limit && !c.fixed && c.held_because.is_none(), "{c:?}");
        }
    }
    // k1 from 0 to −0.05 is significant and recovered; of the three whose prior is the
    // truth, the test keeps at least one at it (each passes with probability 95 %).
    let k1 = rep.calibration.iter().find(|c| c.param == "k1").unwrap();
    assert!(
        !k1.fixed && (adjusted[at("k1")] / -0.05 - 1.0).abs() < 0.05,
        "{k1:?}"
    );
    assert!(held >= 1, "{:?}", rep.calibration);
}

#[test]
fn lidar_planes_alone_fix_the_datum() {
    let relief = 120.0;
    let o = SyntheticOptions {
        relief_m: relief,
        tie_points: 20_000,
        check_points: 0,
        seed: 11,
        ..Default::default()
    };
    let syn = generate(&o);
    let mut b = syn.start.clone();
    // No control: the datum comes only from the LiDAR planes. The start is off by a
    // similarity (3 m shift, 0.05° rotation, 0.05 % scale).
    let rot = cloudcontrol::geometry::rotation_from_vector(&Vector3::new(0.0, 0.0, 0.0009));
    let t = Vector3::new(3.0, -2.0, 1.5);
    let apply = |x: &Vector3<f64>| rot * x * 1.0005 + t;
    for p in b.photos.values_mut() {
        p.pose.center = apply(&p.pose.center);
        p.pose.rotation *= rot.transpose();
    }
    let mut ids = Vec::new();
    for p in b.points.values_mut() {
        if p.kind != PointKind::Tie {
            p.kind = PointKind::Tie;
            p.sigma = None;
        }
        p.position = apply(&p.position);
        if p.id % 4 == 0 {
            ids.push(p.id);
        }
    }
    let mut refit = TerrainLidar {
        relief,
        bias: Vector3::zeros(),
        ids,
        calls: 0,
    };
    let planes: Vec<PlaneConstraint> = refit
        .ids
        .iter()
        .map(|id| {
            let x = b.points[id].position;
            refit.plane(*id, x.x, x.y)
        })
        .collect();
    let rep = adjust(&mut b, &planes, Some(&mut refit), &AdjustOptions::default()).unwrap();
    assert_eq!(rep.datum, "lidar_planes");
    let mut mean = Vector3::zeros();
    let mut rms = 0.0;
    for (id, p) in &b.photos {
        let e = p.pose.center - syn.truth.photos[id].pose.center;
        mean += e;
        rms += e.norm_squared();
    }
    let n = b.photos.len() as f64;
    mean /= n;
    rms = (rms / n).sqrt();
    eprintln!(
        "datum from planes: mean centre offset {:.3?} m, RMS {:.3} m, {} refits, σ0 {:.3}, {:.1} s",
        mean.as_slice(),
        rms,
        refit.calls,
        rep.sigma0,
        rep.time_s
    );
    assert!(refit.calls >= 1);
    assert!(mean.norm() < 0.15, "datum offset {mean:?}");
    assert!(rms < 0.6, "centre RMS {rms}");
    let _ = Matrix3::<f64>::identity();
}

/// Cameras of one calibration group are one camera to the adjustment: a block whose photos
/// each have their own camera (as film scans with their own interior orientation) in one
/// group adjusts exactly as the same block with one shared camera, and the group is
/// reported once.
#[test]
fn a_calibration_group_adjusts_as_one_shared_camera() {
    let o = SyntheticOptions {
        strips: 2,
        photos_per_strip: 8,
        tie_points: 3_000,
        relief_m: 250.0,
        control_grid: (3, 2),
        check_points: 0,
        seed: 9,
        ..Default::default()
    };
    let syn = generate(&o);
    let free: Vec<String> = ["fx", "fy", "k1"].iter().map(|s| s.to_string()).collect();
    let mut one = syn.start.clone();
    {
        let cam = one.cameras.get_mut(&1).unwrap();
        let mut p = cam.model.params();
        p[0] *= 1.005;
        p[1] *= 1.005;
        cam.model.set_params(&p).unwrap();
        cam.free_params = free.clone();
    }
    let mut grouped = one.clone();
    let shared = grouped.cameras.remove(&1).unwrap();
    let ids: Vec<u32> = grouped.photos.keys().copied().collect();
    for id in ids {
        let cid = 100 + id;
        grouped.cameras.insert(
            cid,
            cloudcontrol::block::BlockCamera {
                id: cid,
                name: format!("scan {id}"),
                calibration_group: Some("lens".into()),
                ..shared.clone()
            },
        );
        grouped.photos.get_mut(&id).unwrap().camera = cid;
    }
    let opts = AdjustOptions::default();
    let ra = adjust(&mut one, &[], None, &opts).unwrap();
    let rb = adjust(&mut grouped, &[], None, &opts).unwrap();
    let f = one.cameras[&1].model.params()[0];
    // From 0.5 % off to within 0.1 % and its stated σ (a 16-photo block with relief).
    let sf = ra
        .calibration
        .iter()
        .find(|c| c.param == "fx")
        .unwrap()
        .sigma;
    assert!(
        (f / o.focal_px - 1.0).abs() < 1e-3 && (f - o.focal_px).abs() < 4.0 * sf,
        "f {f} ± {sf} against {}",
        o.focal_px
    );
    for c in grouped.cameras.values() {
        assert!(
            (c.model.params()[0] - f).abs() < 1e-6 * f,
            "camera {}",
            c.id
        );
    }
    for (a, b) in one.photos.values().zip(grouped.photos.values()) {
        assert!((a.pose.center - b.pose.center).norm() < 1e-6);
    }
    assert!((ra.sigma0 - rb.sigma0).abs() < 1e-9);
    assert_eq!(ra.calibration.len(), 3);
    assert_eq!(rb.calibration.len(), 3, "the group is reported once");

    // A member with other free parameters than its group is refused, naming the group.
    let first = *grouped.cameras.keys().next().unwrap();
    grouped.cameras.get_mut(&first).unwrap().free_params = vec!["fx".into()];
    let e = adjust(&mut grouped, &[], None, &opts)
        .unwrap_err()
        .to_string();
    assert!(e.contains("calibration group") && e.contains("lens"), "{e}");
}

/// A LiDAR of the (known) terrain whose datum is off by `bias` (its surface is the
/// terrain displaced by it): each tie point's plane re-fitted at its current plan
/// position, as the LiDAR module does from its nearest LiDAR points.
struct TerrainLidar {
    relief: f64,
    bias: Vector3<f64>,
    ids: Vec<PointId>,
    calls: usize,
}

impl TerrainLidar {
    fn plane(&self, id: PointId, x: f64, y: f64) -> PlaneConstraint {
        let (u, v) = (x - self.bias.x, y - self.bias.y);
        let p = Vector3::new(x, y, terrain(self.relief, u, v) + self.bias.z);
        let n = terrain_normal(self.relief, u, v);
        PlaneConstraint {
            point: id,
            normal: [n.x, n.y, n.z],
            d: n.dot(&p),
            weight: 1.0 / (0.05f64 * 0.05),
        }
    }
}

impl PlaneRefitter for TerrainLidar {
    fn refit(&mut self, points: &[(PointId, Vector3<f64>)]) -> Vec<PlaneConstraint> {
        self.calls += 1;
        points
            .iter()
            .filter(|(id, _)| self.ids.binary_search(id).is_ok())
            .map(|(id, x)| self.plane(*id, x.x, x.y))
            .collect()
    }
}

/// Mean object-point error (m) and the LiDAR datum report of an adjustment of a
/// POS-controlled block (5 cm centres) against a LiDAR whose datum is off by `bias`.
fn adjust_against_biased_lidar(
    bias: Vector3<f64>,
    datum_sigma: Option<f64>,
) -> (Vector3<f64>, Option<cloudcontrol::adjust::LidarDatumReport>) {
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};
    let relief = 60.0;
    let o = SyntheticOptions {
        relief_m: relief,
        tie_points: 8_000,
        check_points: 0,
        seed: 17,
        ..Default::default()
    };
    let syn = generate(&o);
    let mut b = syn.start.clone();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let pos = Normal::new(0.0, 0.05).unwrap();
    for (id, p) in b.photos.iter_mut() {
        let c = syn.truth.photos[id].pose.center;
        p.prior = Some(cloudcontrol::block::PosPrior {
            center: c + Vector3::from_fn(|_, _| pos.sample(&mut rng)),
            center_sigma: [0.05; 3],
            rotation: None,
            rotation_sigma_rad: 0.01,
        });
    }
    let mut ids = Vec::new();
    for p in b.points.values_mut() {
        if p.kind != PointKind::Tie {
            p.kind = PointKind::Tie;
            p.sigma = None;
        }
        if p.id % 4 == 0 {
            ids.push(p.id);
        }
    }
    let mut lidar = TerrainLidar {
        relief,
        bias,
        ids,
        calls: 0,
    };
    let pts: Vec<(PointId, Vector3<f64>)> = b.points.values().map(|p| (p.id, p.position)).collect();
    let planes = lidar.refit(&pts);
    let opts = AdjustOptions {
        lidar_datum_sigma_m: datum_sigma.map(|s| [s; 3]),
        ..Default::default()
    };
    let rep = adjust(&mut b, &planes, Some(&mut lidar), &opts).unwrap();
    let mut mean = Vector3::zeros();
    let mut n = 0.0;
    for (id, p) in &b.points {
        if let Some(t) = syn.truth.points.get(id) {
            mean += p.position - t.position;
            n += 1.0;
        }
    }
    (mean / n, rep.lidar_datum)
}

/// The LiDAR's datum error is estimated, not spread into the block: against a LiDAR 20 cm
/// off in plan and 30 cm in height (σ 30 cm stated), the ground of 100 photos with 5 cm
/// POS stays where the POS puts it and the shift is found within 3σ; holding the LiDAR
/// as the datum drags the ground towards it instead (the POS holding the cameras, the
/// block stretches).
#[test]
fn a_lidar_datum_error_is_estimated_against_the_pos() {
    let bias = Vector3::new(0.2, 0.0, 0.3);
    let (held, none) = adjust_against_biased_lidar(bias, None);
    assert!(none.is_none());
    let (free, rep) = adjust_against_biased_lidar(bias, Some(0.3));
    let rep = rep.expect("LiDAR datum report");
    eprintln!(
        "LiDAR as datum: mean point error {:.3?} m; datum estimated: {:.3?} m, shift {:.3?} ± {:.3?} m",
        held.as_slice(),
        free.as_slice(),
        rep.shift_m,
        rep.sigma_m
    );
    for k in 0..3 {
        assert!(
            (rep.shift_m[k] - bias[k]).abs() < 3.0 * rep.sigma_m[k] + 0.01,
            "axis {k}: shift {:?} ± {:?}, bias {bias:?}",
            rep.shift_m,
            rep.sigma_m
        );
        assert!(rep.sigma_m[k] < 0.3 && rep.prior_sigma_m[k] == 0.3);
    }
    assert!(free.norm() < 0.03, "ground moved by {free:?}");
    assert!(
        held.z > 0.15,
        "the LiDAR as datum should drag the ground: {held:?}"
    );
}
