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

#[test]
fn rough_pos_converges_with_shrinking_windows_and_rejects_mismatches() {
    // Film-like geometry: 0.5 m GSD from 3000 m.
    let camera = Camera::Frame(FrameCamera::pinhole(4000, 4000, 6000.0));
    let truth = Pose::from_opk(0.01, -0.015, 0.4, Vector3::new(100.0, -50.0, 3000.0));
    // POS about 10 m / 2° off; its stated quality is 10 m / 3°.
    let approx = truth.perturbed(
        &Vector3::new(0.02, -0.025, 0.03),
        &Vector3::new(8.0, -6.0, 5.0),
    );
    let cov = pos_covariance(10.0, 3f64.to_radians());
    let patches: Vec<ControlPatch> = (0..60)
        .map(|i| ControlPatch {
            id: i + 1,
            position: Vector3::new(
                -800.0 + 220.0 * (i % 8) as f64,
                -700.0 + 200.0 * (i / 8) as f64,
                20.0 * ((i as f64) * 0.3).sin(),
            ),
            covariance: Matrix3::from_diagonal_element(0.05f64.powi(2)),
        })
        .collect();
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
