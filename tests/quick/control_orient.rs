//! The orientation loop with exact stand-ins for the matcher and the resection: it must
//! converge from a rough POS, grow its matches as windows shrink, and drop gross errors.

use cloudcontrol::control::orient::*;
use cloudcontrol::control::predict::{pos_covariance, Prediction};
use cloudcontrol::geometry::{self, Camera, FrameCamera, Pose};
use nalgebra::{DMatrix, DVector, Matrix3, SMatrix, Vector2, Vector3};

/// Finds a patch when its true position lies inside the search window; patches with
/// id % 7 == 0 are mismatched by 15 px (gross errors the resection must reject).
struct TruthMatcher {
    camera: Camera,
    truth: Pose,
}

impl PatchMatcher for TruthMatcher {
    fn find(
        &mut self,
        p: &ControlPatch,
        _pose: &Pose,
        pred: &Prediction,
        half: [f64; 2],
    ) -> Option<PatchMatch> {
        let t = geometry::project(&self.camera, &self.truth, &p.position)
            .ok()?
            .pixel;
        if (t.x - pred.pixel.x).abs() > half[0] || (t.y - pred.pixel.y).abs() > half[1] {
            return None;
        }
        let wobble = 0.2 * ((p.id as f64) * 1.7).sin();
        let gross = if p.id % 7 == 0 { 15.0 } else { 0.0 };
        Some(PatchMatch {
            pixel: t + Vector2::new(wobble + gross, -wobble),
            sigma_px: 0.2,
            ncc: 0.9,
        })
    }
}

/// Gauss–Newton resection with iterative rejection at 3σ (a stand-in for adjust's).
struct GnResector;

impl Resector for GnResector {
    fn resect(
        &mut self,
        cam: &Camera,
        pose0: &Pose,
        obs: &[(Vector3<f64>, Vector2<f64>, f64)],
    ) -> Result<Resection, String> {
        let mut pose = *pose0;
        let mut inl = vec![true; obs.len()];
        let mut cov = SMatrix::<f64, 6, 6>::zeros();
        for round in 0..12 {
            for _ in 0..15 {
                let n = inl.iter().filter(|b| **b).count();
                let mut a = DMatrix::zeros(2 * n, 6);
                let mut r = DVector::zeros(2 * n);
                for (k, ((x, px, s), _)) in obs.iter().zip(&inl).filter(|(_, b)| **b).enumerate() {
                    let (p, j) = geometry::project_with_jacobians(cam, &pose, x)
                        .map_err(|e| e.to_string())?;
                    for row in 0..2 {
                        for c in 0..6 {
                            a[(2 * k + row, c)] = j.pose[(row, c)] / s;
                        }
                        r[2 * k + row] = (px[row] - p.pixel[row]) / s;
                    }
                }
                let n_mat = a.transpose() * &a;
                let d = n_mat
                    .clone()
                    .cholesky()
                    .ok_or("singular")?
                    .solve(&(a.transpose() * r));
                pose = pose.perturbed(
                    &Vector3::new(d[0], d[1], d[2]),
                    &Vector3::new(d[3], d[4], d[5]),
                );
                cov = SMatrix::<f64, 6, 6>::from_iterator(
                    n_mat.try_inverse().ok_or("singular")?.iter().cloned(),
                );
                if d.norm() < 1e-10 {
                    break;
                }
            }
            let res: Vec<f64> = obs
                .iter()
                .map(|(x, px, s)| {
                    geometry::project(cam, &pose, x)
                        .map(|p| (p.pixel - px).norm() / s)
                        .unwrap_or(f64::INFINITY)
                })
                .collect();
            let worst = (0..obs.len())
                .filter(|&i| inl[i])
                .max_by(|&a, &b| res[a].total_cmp(&res[b]))
                .unwrap();
            if res[worst] < 3.0 * 1.5 || round == 11 {
                break;
            }
            inl[worst] = false;
        }
        Ok(Resection {
            pose,
            covariance: cov,
            inliers: inl,
        })
    }
}

/// Film-like geometry: 0.5 m GSD from 3000 m; the true pose.
fn film_like() -> (Camera, Pose) {
    (
        Camera::Frame(FrameCamera::pinhole(4000, 4000, 6000.0)),
        Pose::from_opk(0.01, -0.015, 0.4, Vector3::new(100.0, -50.0, 3000.0)),
    )
}

/// `n` control points in rows of `cols` from `origin`, `step` apart, on gentle relief;
/// patch `i` has the id `id(i)`.
fn grid_patches(
    n: usize,
    cols: usize,
    origin: [f64; 2],
    step: [f64; 2],
    id: impl Fn(usize) -> usize,
) -> Vec<ControlPatch> {
    (0..n)
        .map(|i| ControlPatch {
            id: id(i),
            position: Vector3::new(
                origin[0] + step[0] * (i % cols) as f64,
                origin[1] + step[1] * (i / cols) as f64,
                20.0 * ((i as f64) * 0.3).sin(),
            ),
            covariance: Matrix3::from_diagonal_element(0.05f64.powi(2)),
        })
        .collect()
}

#[test]
fn rough_pos_converges_with_shrinking_windows_and_rejects_mismatches() {
    let (camera, truth) = film_like();
    // POS about 10 m / 2° off; its stated quality is 10 m / 3°.
    let approx = truth.perturbed(
        &Vector3::new(0.02, -0.025, 0.03),
        &Vector3::new(8.0, -6.0, 5.0),
    );
    let cov = pos_covariance(10.0, 3f64.to_radians());
    let patches = grid_patches(60, 8, [-800.0, -700.0], [220.0, 200.0], |i| i + 1);
    let mut matcher = TruthMatcher {
        camera: camera.clone(),
        truth,
    };
    // Windows capped at 150 px: the ≈ 2° attitude error (110–280 px) hides many patches at first.
    let opts = OrientOptions {
        max_half_px: 150.0,
        ..Default::default()
    };
    let out = orient_photo(
        &camera,
        &approx,
        &cov,
        &patches,
        &mut matcher,
        &mut GnResector,
        &opts,
        None,
    );
    assert!(out.oriented);
    let first = &out.iterations[0];
    let last = out.iterations.last().unwrap();
    assert!(out.iterations.len() >= 2);
    assert!(
        last.success_ratio > first.success_ratio + 0.2,
        "{:?}",
        out.iterations
    );
    assert!(last.accepted >= 45, "{:?}", out.iterations);
    assert!(
        last.mean_window_px < 0.2 * first.mean_window_px,
        "{:?}",
        out.iterations
    );
    // Gross errors out, truth recovered to the matching noise.
    assert!(out.matches.iter().all(|(id, _, _)| id % 7 != 0));
    // The pose reproduces the true image geometry to a fraction of a pixel, and its error
    // is consistent with the covariance the resection reports.
    for p in &patches {
        if let (Ok(a), Ok(b)) = (
            geometry::project(&camera, &out.pose, &p.position),
            geometry::project(&camera, &truth, &p.position),
        ) {
            assert!(
                (a.pixel - b.pixel).norm() < 0.3,
                "reprojection differs by {}",
                (a.pixel - b.pixel).norm()
            );
        }
    }
    let dc = out.pose.center - truth.center;
    for i in 0..3 {
        let s = out.covariance[(3 + i, 3 + i)].sqrt();
        assert!(
            dc[i].abs() < 4.0 * s + 0.05,
            "centre error {} m vs σ {s} m",
            dc[i]
        );
    }
    let before = (approx.center - truth.center).norm();
    assert!(before > 10.0);
}

#[test]
fn first_round_searches_a_spread_share_of_dense_control_then_every_patch() {
    let (camera, truth) = film_like();
    let approx = truth.perturbed(
        &Vector3::new(0.01, -0.012, 0.015),
        &Vector3::new(8.0, -6.0, 5.0),
    );
    let cov = pos_covariance(10.0, 1f64.to_radians());
    // 40 × 40 control points over the footprint: dense control, as a film frame over
    // LiDAR-derived DCPs. No id is a multiple of 7: no gross errors, which the stand-in
    // resection removes one a round.
    let patches = grid_patches(1600, 40, [-900.0, -850.0], [45.0, 42.0], |i| 7 * i + 1);
    let run = |quota: Option<usize>| {
        let mut matcher = TruthMatcher {
            camera: camera.clone(),
            truth,
        };
        let opts = OrientOptions {
            first_round_matches: quota,
            ..Default::default()
        };
        orient_photo(
            &camera,
            &approx,
            &cov,
            &patches,
            &mut matcher,
            &mut GnResector,
            &opts,
            None,
        )
    };
    let quota = run(Some(200));
    let all = run(None);
    assert!(quota.oriented && all.oriented);
    let (q0, a0) = (&quota.iterations[0], &all.iterations[0]);
    assert_eq!(q0.predicted, a0.predicted);
    assert!(a0.matched > 1000, "{a0:?}");
    assert_eq!(q0.matched, 200, "{q0:?}");
    assert!(q0.searched < a0.searched / 4, "{q0:?} vs {a0:?}");
    assert_eq!(a0.searched, a0.predicted);
    assert_eq!(quota.first_round.len(), 200);
    // The first round's matches cover the photo: each quarter holds a fair share.
    let mut quarters = [0usize; 4];
    for (_, m) in &quota.first_round {
        quarters[usize::from(m.x > 2000.0) + 2 * usize::from(m.y > 2000.0)] += 1;
    }
    assert!(quarters.iter().all(|&n| n >= 30), "{quarters:?}");
    // After the first resection every patch is searched, and the outcome is the same.
    let q1 = &quota.iterations[1];
    assert_eq!(q1.searched, q1.predicted);
    // (A patch at the edge of the photo may fall either side of it.)
    assert!(quota.matches.len().abs_diff(all.matches.len()) <= 3);
    for p in &patches {
        if let (Ok(a), Ok(b)) = (
            geometry::project(&camera, &quota.pose, &p.position),
            geometry::project(&camera, &all.pose, &p.position),
        ) {
            let d = (a.pixel - b.pixel).norm();
            assert!(d < 0.02, "the poses differ by {d} px");
        }
    }
}
