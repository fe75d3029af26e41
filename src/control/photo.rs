//! Orientation of one photo from control patches (seed 001): the film scan's fiducial
//! interior orientation, the footprint of the approximate orientation on the DEM, the
//! iterative prediction / matching / resection loop of [`super::orient::orient_photo`]
//! with the real chip matcher and resector, and a relaxed retry for photos whose first
//! round found too few unambiguous patches. The epoch runs this per photo
//! ([`super::archive::orient_epoch`]); the C ABI offers it alone (`ccp_orient_photo`) so
//! callers can orient photos one by one or in parallel processes.

use super::chips::{ChipMatchOptions, ChipMatcher, ChipStore, MatchStats};
use super::epoch::{EpochCamera, PhotoInput};
use super::orient::{self, IterationRecord, OrientOptions, Resection, Resector};
use super::predict;
use super::scan_cameras::ScanCameras;
use crate::adjust;
use crate::block::{PhotoFailure, PosPrior};
use crate::estimators::similarity2::{Similarity2, Similarity2Estimator};
use crate::estimators::{RobustMethod, RobustOptions};
use crate::geometry::{Camera, Dem, Pose};
use crate::matching::{GreyImage, IoOptions, MatchOptions, Pyramid};
use nalgebra::{Matrix3, SMatrix, Vector2, Vector3};
use serde::{Deserialize, Serialize};

/// Options of the orientation of one photo.
#[derive(Debug, Clone)]
pub struct PhotoOptions {
    pub orient: OrientOptions,
    pub patch: ChipMatchOptions,
    /// Smallest RANSAC threshold of the resection (px); the threshold is also ≥ 4σ.
    pub resection_threshold_px: f64,
    /// Least number of resection inliers for a photo to count as oriented: four matches
    /// leave a resection two redundant observations, too few to expose one mismatch
    /// among them once the control points' own σ absorbs part of it.
    pub min_inliers: usize,
    /// Floor of the matching σ (px): LSM's σ ignores model errors (relief, chip alignment).
    pub sigma_floor_px: f64,
    pub io: IoOptions,
    /// Retry a photo that could not be oriented with every patch's best peak (however
    /// ambiguous) and let RANSAC sort them, requiring `relaxed_min_inliers`.
    pub relaxed_retry: bool,
    pub relaxed_ncc_threshold: f64,
    pub relaxed_min_inliers: usize,
    /// A resected pose further than this many σ of the navigation from it (largest over
    /// the centre coordinates and the attitude angle) is not accepted.
    pub max_prior_sigmas: f64,
    /// Test a resection against the navigation with the resection's own covariance added
    /// to the navigation's (see `prior_distance`); off for the relaxed retries.
    pub prior_test_with_resection_sigma: bool,
    /// The epoch self-calibrates the principal distance: the resection's offset from the
    /// navigation along the optical axis is tested beyond what a nominal focal length can
    /// cause ([`NOMINAL_FOCAL_TOLERANCE`]).
    pub focal_free: bool,
}

impl Default for PhotoOptions {
    fn default() -> Self {
        Self {
            // Windows follow the navigation's σ through the camera (3σ); the search runs
            // coarse-to-fine over the pyramid, so a 570 px window (3° on a 42 µm scan of
            // a 153 mm camera) costs little more than a small one.
            orient: OrientOptions {
                min_half_px: 6.0,
                max_half_px: f64::INFINITY,
                ..OrientOptions::default()
            },
            patch: ChipMatchOptions::default(),
            resection_threshold_px: 3.0,
            min_inliers: 6,
            sigma_floor_px: 0.3,
            io: IoOptions::default(),
            relaxed_retry: true,
            relaxed_ncc_threshold: 0.5,
            relaxed_min_inliers: 6,
            max_prior_sigmas: 5.0,
            prior_test_with_resection_sigma: true,
            focal_free: false,
        }
    }
}

/// Per-photo outcome, for the report.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PhotoReport {
    pub name: String,
    pub oriented: bool,
    pub reason: Option<PhotoFailure>,
    pub iterations: Vec<IterationRecord>,
    /// Control matches kept by the final resection.
    pub control_matches: usize,
    /// Final σ (px): RMS image residual after the block adjustment, else the resection's.
    pub sigma_px: f64,
    /// Film: the fiducial interior orientation of the scan.
    pub io: Option<ScanIo>,
    /// Control points predicted inside the photo in the first round.
    pub predicted: usize,
    pub matching: MatchStats,
    /// Oriented only by the relaxed retry (ambiguous first-round matches).
    pub relaxed: bool,
    /// Oriented in the second pass, from the epoch's own oriented photos.
    pub second_pass: bool,
    /// Oriented through tie points with the epoch's oriented photos, having found too few
    /// control patches from its navigation (`control_matches`: those found afterwards
    /// from the tie pose).
    pub tie_pass: bool,
}

/// A film scan's fiducial interior orientation, as reported (`matching::IoResult` without
/// the marks; the fields after `pixel_source` are absent, 0 or `null`, in older files).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ScanIo {
    /// RMS of the fiducial marks after the affine fit (µm).
    pub rmse_um: f64,
    /// Scan pixel size used (µm).
    pub pixel_um: f64,
    /// Where it came from: given in the epoch, or estimated (and from what).
    pub pixel_source: String,
    /// Pixel size the fitted transform measures (µm): the marks' own scale.
    #[serde(default)]
    pub measured_pixel_um: Option<f64>,
    /// Marks measured and used in the transform, of the camera's marks.
    #[serde(default)]
    pub marks_used: usize,
    #[serde(default)]
    pub marks_total: usize,
    /// Largest residual of a used mark (µm).
    #[serde(default)]
    pub max_residual_um: Option<f64>,
    /// The scan orientation taken, how it was decided, and its margin (cost of the best
    /// other orientation over this one's).
    #[serde(default)]
    pub orientation: Option<crate::matching::ScanOrientation>,
    #[serde(default)]
    pub orientation_source: String,
    #[serde(default)]
    pub orientation_margin: Option<f64>,
    #[serde(default)]
    pub orientation_ambiguous: bool,
    /// The interior orientation's warnings (`matching::IoResult::warnings`).
    #[serde(default)]
    pub warnings: Vec<String>,
}

/// The orientation of one photo: the resected pose with its covariance and the matches
/// that support it, or the reason it failed. Serialisable: a distributed run's per-photo
/// task returns it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PhotoOrientation {
    pub report: PhotoReport,
    /// The photo's camera (film: the certificate with this scan's interior orientation).
    pub camera: Option<Camera>,
    /// Block-local pose (the approximate one when not oriented).
    pub pose: Pose,
    /// 6×6 covariance of the pose (rotation vector, centre).
    pub covariance: SMatrix<f64, 6, 6>,
    /// Accepted matches: store point index, pixel, σ (px).
    pub matches: Vec<(usize, Vector2<f64>, f64)>,
    /// First-round candidates before any resection: (predicted pixel, matched pixel).
    first_round: Vec<(Vector2<f64>, Vector2<f64>)>,
}

impl PhotoReport {
    /// The report of a photo oriented (`reason` None) or not by other means than control
    /// patches (tie points, the adjustment), with its final σ (px; NaN when unknown).
    pub fn without_patches(name: &str, reason: Option<PhotoFailure>, sigma_px: f64) -> Self {
        Self {
            name: name.to_string(),
            oriented: reason.is_none(),
            reason,
            iterations: Vec::new(),
            control_matches: 0,
            sigma_px,
            io: None,
            predicted: 0,
            matching: MatchStats::default(),
            relaxed: false,
            second_pass: false,
            tie_pass: false,
        }
    }
}

impl PhotoOrientation {
    /// Checks an orientation read back from a task file ([`super::task_checks`]): pose,
    /// camera and numbers sane, covariance finite when oriented, and every match's point
    /// index below `points` (the store it indexes).
    pub fn check(&self, points: usize) -> Result<(), String> {
        use super::task_checks as c;
        let r = &self.report;
        c::sigma("sigma_px", r.sigma_px)?;
        if let Some(io) = &r.io {
            c::sigma("io.rmse_um", io.rmse_um)?;
            if !(io.pixel_um.is_finite() && io.pixel_um > 0.0) {
                return Err(format!("io.pixel_um = {} is not a pixel size", io.pixel_um));
            }
        }
        for it in &r.iterations {
            c::sigma("iterations[].success_ratio", it.success_ratio)?;
            c::sigma("iterations[].mean_window_px", it.mean_window_px)?;
        }
        if let Some(cam) = &self.camera {
            c::camera("camera", cam)?;
        }
        c::pose("pose", &self.pose)?;
        if r.oriented {
            c::covariance("covariance", &self.covariance)?;
        }
        for (i, px, s) in &self.matches {
            c::index("match of point", *i, points)?;
            c::pixel("match pixel", px)?;
            c::finite("match σ", &[*s])?;
            c::sigma("match σ", *s)?;
        }
        for (a, b) in &self.first_round {
            c::pixel("first-round prediction", a)?;
            c::pixel("first-round match", b)?;
        }
        Ok(())
    }

    fn failed(name: &str, pose: Pose, reason: PhotoFailure) -> Self {
        Self {
            report: PhotoReport::without_patches(name, Some(reason), f64::NAN),
            camera: None,
            pose,
            covariance: SMatrix::zeros(),
            matches: Vec::new(),
            first_round: Vec::new(),
        }
    }
}

/// The [`Resector`] of real photos: P3P inside RANSAC, Levenberg–Marquardt refinement,
/// data snooping and the covariance, from [`adjust::resect`].
pub struct AdjustResector {
    pub threshold_px: f64,
    pub sigma_floor_px: f64,
    pub min_inliers: usize,
    pub last_rmse_px: f64,
}

impl AdjustResector {
    pub fn new(opts: &PhotoOptions) -> Self {
        Self {
            threshold_px: opts.resection_threshold_px,
            sigma_floor_px: opts.sigma_floor_px,
            min_inliers: opts.min_inliers,
            last_rmse_px: f64::NAN,
        }
    }
}

impl Resector for AdjustResector {
    fn resect(
        &mut self,
        camera: &Camera,
        approximate: &Pose,
        observations: &[(Vector3<f64>, Vector2<f64>, f64)],
    ) -> Result<Resection, String> {
        if observations.is_empty() {
            return Err("resection without observations".into());
        }
        let mut sig: Vec<f64> = observations
            .iter()
            .map(|o| o.2.max(self.sigma_floor_px))
            .collect();
        sig.sort_by(f64::total_cmp);
        let sigma = sig[sig.len() / 2];
        let opts = adjust::ResectionOptions {
            threshold_px: self.threshold_px.max(4.0 * sigma),
            approximate: Some(*approximate),
            ..adjust::ResectionOptions::default()
        };
        let pixels: Vec<[f64; 2]> = observations.iter().map(|o| [o.1.x, o.1.y]).collect();
        let points: Vec<[f64; 3]> = observations.iter().map(|o| [o.0.x, o.0.y, o.0.z]).collect();
        let r =
            adjust::resect(camera, &pixels, &points, sigma, &opts).map_err(|e| e.to_string())?;
        if r.num_inliers < self.min_inliers {
            return Err(format!(
                "resection kept {} of {} matches, {} needed",
                r.num_inliers,
                observations.len(),
                self.min_inliers
            ));
        }
        self.last_rmse_px = r.rmse_px;
        let mut cov = SMatrix::<f64, 6, 6>::zeros();
        for (a, row) in r.covariance.iter().enumerate() {
            for (b, v) in row.iter().enumerate() {
                cov[(a, b)] = *v;
            }
        }
        Ok(Resection {
            pose: r.pose,
            covariance: cov,
            inliers: r.inliers,
        })
    }
}

/// The polygon pushed outwards from its centroid by `margin` (m): the footprint of an
/// uncertain orientation may be off by the centre σ.
fn grow(poly: &[[f64; 2]], margin: f64) -> Vec<[f64; 2]> {
    let n = poly.len() as f64;
    let c = poly
        .iter()
        .fold([0.0, 0.0], |a, p| [a[0] + p[0] / n, a[1] + p[1] / n]);
    poly.iter()
        .map(|p| {
            let d = [p[0] - c[0], p[1] - c[1]];
            let l = (d[0] * d[0] + d[1] * d[1]).sqrt().max(1e-9);
            [p[0] + d[0] / l * margin, p[1] + d[1] / l * margin]
        })
        .collect()
}

/// Orients one photo from the control points of `store` (block-local, over the
/// block-local `dem`), starting from its approximate orientation `prior`. A film scan
/// takes its candidate cameras from `scans` when the epoch measured them, else measures
/// its fiducials here.
pub fn orient_photo(
    photo: &PhotoInput,
    camera: &EpochCamera,
    prior: Option<&PosPrior>,
    store: &ChipStore,
    dem: &Dem,
    opts: &PhotoOptions,
    scans: Option<&ScanCameras>,
) -> PhotoOrientation {
    let name = photo.name.as_str();
    let unknown = Pose::new(Matrix3::identity(), Vector3::zeros());
    let Some(prior) = prior else {
        return PhotoOrientation::failed(name, unknown, PhotoFailure::NoNavigation);
    };
    let (pose0, cov0) = (prior.pose(), prior.covariance());
    let img = match GreyImage::load(&photo.image) {
        Ok(i) => i,
        Err(e) => return PhotoOrientation::failed(name, pose0, image_failure(photo, e)),
    };
    // Candidate cameras: one for a frame photo; for a film scan the fiducial interior
    // orientation, plus the other scan orientations that fit the marks equally well when
    // the fiducial layout is symmetric (corner crosses and side dots of many metric
    // cameras): the control patches then decide which one is right.
    let candidates: Vec<(Camera, Option<ScanIo>)> = match camera {
        EpochCamera::Frame(f) => {
            if (f.width as usize, f.height as usize) != (img.width, img.height) {
                return PhotoOrientation::failed(
                    name,
                    pose0,
                    PhotoFailure::ImageSize {
                        path: photo.image.display().to_string(),
                        width: img.width,
                        height: img.height,
                        camera_width: f.width,
                        camera_height: f.height,
                    },
                );
            }
            vec![(Camera::Frame(f.clone()), None)]
        }
        EpochCamera::Film(def) => match scans
            .and_then(|s| s.of(name))
            .cloned()
            .unwrap_or_else(|| super::scan_cameras::cameras_of(def, &img, name, &opts.io))
        {
            Ok(v) => v
                .into_iter()
                .map(|(c, r)| (Camera::Film(c), Some(r)))
                .collect(),
            Err(message) => {
                return PhotoOrientation::failed(
                    name,
                    pose0,
                    PhotoFailure::InteriorOrientation { message },
                )
            }
        },
    };
    let pyramid = Pyramid::from_image(img, 6, 16);
    let mut best: Option<PhotoOrientation> = None;
    for (camera, io) in candidates {
        let out = orient_with_camera(
            name, camera, io, &pose0, &cov0, &pose0, store, dem, &pyramid, opts, None,
        );
        if matches!(out.report.reason, Some(PhotoFailure::Chip { .. })) {
            return out;
        }
        let score = |o: &PhotoOrientation| (o.report.oriented, o.report.control_matches);
        // A wrong scan orientation cannot gather many consistent patches: stop early
        // when one clearly works.
        let done = out.report.oriented && out.report.control_matches >= 8;
        if best.as_ref().is_none_or(|b| score(&out) > score(b)) {
            best = Some(out);
        }
        if done {
            break;
        }
    }
    let Some(best) = best else {
        unreachable!("a frame camera or a successful interior orientation gives a candidate")
    };
    if best.report.oriented || !opts.relaxed_retry || best.report.predicted == 0 {
        return best;
    }
    // Second chance for a photo whose first round found too few unambiguous patches: take
    // every patch's best correlation peak, however ambiguous, and let the resection's
    // RANSAC find the consistent ones — with a stricter inlier count, since most of the
    // candidates are now wrong.
    let relaxed = PhotoOptions {
        patch: ChipMatchOptions {
            matching: MatchOptions {
                max_ambiguity: 1.01,
                ncc_threshold: opts.relaxed_ncc_threshold,
                ..opts.patch.matching.clone()
            },
            ..opts.patch.clone()
        },
        min_inliers: opts.relaxed_min_inliers,
        // Nearly every patch "matches" at an ambiguity of 1.01, mostly wrongly: a quota
        // of matches would be a quota of patches, and the right ones are what RANSAC
        // needs many of.
        orient: OrientOptions {
            first_round_matches: None,
            ..opts.orient.clone()
        },
        relaxed_retry: false,
        // Its matches are the best peaks however ambiguous: with few of them, one wrong
        // match moves the pose beyond its stated σ (small seed 10, digital_s02_001: 6
        // matches, 20 m from the truth at a stated 5 m), so its covariance does not vouch
        // for it and the navigation, the one independent check, is taken at its own σ.
        prior_test_with_resection_sigma: false,
        ..opts.clone()
    };
    let Some(camera) = best.camera.clone() else {
        return best;
    };
    let io = best.report.io.clone();
    let retry = orient_with_camera(
        name,
        camera.clone(),
        io.clone(),
        &pose0,
        &cov0,
        &pose0,
        store,
        dem,
        &pyramid,
        &relaxed,
        None,
    );
    if retry.report.oriented {
        let mut r = retry;
        r.report.relaxed = true;
        return r;
    }
    // Every patch's best peak, however ambiguous, is mostly wrong in windows of hundreds
    // of pixels, but the right ones agree: over the photo, the error of a navigation pose
    // is close to one shift, swing and scale. A 2-D similarity found by RANSAC among the
    // candidates maps the predictions; the patches are then searched again in small
    // windows around the mapped positions, where a repeat of the texture is no longer
    // in reach (the relaxed correlation threshold, but not its tolerance of ambiguity).
    let tolerance = alignment_tolerance(&camera, &retry.first_round, &cov0);
    if let Some(guide) = align_candidates(&retry.first_round, tolerance, &opts.orient) {
        let guided = PhotoOptions {
            patch: ChipMatchOptions {
                matching: MatchOptions {
                    ncc_threshold: opts.relaxed_ncc_threshold,
                    ..opts.patch.matching.clone()
                },
                ..opts.patch.clone()
            },
            // Seeded by ambiguous peaks, at the relaxed correlation threshold: as the
            // relaxed retry, tested against the navigation at its own σ.
            prior_test_with_resection_sigma: false,
            ..opts.clone()
        };
        // The alignment's swing goes into the approximate attitude, so that the templates
        // are warped as the photo shows them; the guide keeps the rest (shift, scale).
        let (pose_g, guide) = swing_into_pose(&camera, &pose0, &guide);
        let r = orient_with_camera(
            name,
            camera.clone(),
            io.clone(),
            &pose_g,
            &cov0,
            &pose0,
            store,
            dem,
            &pyramid,
            &guided,
            Some(&guide),
        );
        tracing::debug!(
            photo = name,
            oriented = r.report.oriented,
            rounds = ?r.report.iterations.iter().map(|i| (i.predicted, i.matched, i.accepted)).collect::<Vec<_>>(),
            "guided search"
        );
        if r.report.oriented {
            let mut r = r;
            r.report.relaxed = true;
            return r;
        }
    }
    // The templates are warped by the approximate attitude: a swing (κ) error of 5° turns
    // a 61 px template by 2.6 px at its edge, enough to lose the correlation of fine
    // texture among changed surroundings, while ω and φ errors mostly shift it (small
    // block, seed 5: the three photos of a strip with κ off by 3–5° failed, the other
    // strip's, 0.6–3° off, did not). Re-try from the prior turned by ±1σ and ±2σ of its
    // stated attitude σ, when 1σ turns the template edge by over a pixel.
    let sigma_kappa = cov0[(2, 2)].max(0.0).sqrt();
    if sigma_kappa * opts.patch.template_half as f64 > 1.0 {
        for k in [1.0, -1.0, 2.0, -2.0] {
            let turn = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), k * sigma_kappa);
            let pose_k = Pose::new(turn.matrix() * pose0.rotation, pose0.center);
            let r = orient_with_camera(
                name,
                camera.clone(),
                io.clone(),
                &pose_k,
                &cov0,
                &pose0,
                store,
                dem,
                &pyramid,
                opts,
                None,
            );
            if r.report.oriented {
                return r;
            }
        }
    }
    best
}

/// Why a photo's image could not be read; the reason names the path once, itself.
fn image_failure(photo: &PhotoInput, e: crate::matching::MatchingError) -> PhotoFailure {
    PhotoFailure::Image {
        path: photo.image.display().to_string(),
        message: match e {
            crate::matching::MatchingError::Read { message, .. } => message,
            other => other.to_string(),
        },
    }
}

/// Where a photo already oriented by other means (tie points) starts a search of the
/// control patches: its camera (a scan's with its interior orientation) and pose, with
/// the pose's covariance (rotation vector, centre) as the search's σ.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct KnownPose {
    pub camera: Camera,
    pub io: Option<ScanIo>,
    pub pose: Pose,
    pub covariance: SMatrix<f64, 6, 6>,
}

/// Control matches that count for a photo searched from a pose it already has
/// ([`orient_from_pose`]). The known pose is six more observations of the resection (its
/// test against that pose), so four matches are not a resection left with two redundant
/// observations: each is checked against the pose the photo already has, and again in
/// the adjustment beside that photo's tie points (small seed 5: 5 patches found, where a
/// photo of its own needs 6).
pub const KNOWN_POSE_MIN_MATCHES: usize = 4;

/// The control patches of `store` searched in a photo from a pose it already has, the
/// windows following that pose's σ. The resection is tested against that pose as against
/// a navigation prior (both covariances): control that disagrees with how the photo was
/// oriented is not taken.
pub fn orient_from_pose(
    photo: &PhotoInput,
    start: &KnownPose,
    store: &ChipStore,
    dem: &Dem,
    opts: &PhotoOptions,
) -> PhotoOrientation {
    let img = match GreyImage::load(&photo.image) {
        Ok(i) => i,
        Err(e) => {
            return PhotoOrientation::failed(&photo.name, start.pose, image_failure(photo, e))
        }
    };
    let pyramid = Pyramid::from_image(img, 6, 16);
    let opts = PhotoOptions {
        prior_test_with_resection_sigma: true,
        min_inliers: KNOWN_POSE_MIN_MATCHES,
        ..opts.clone()
    };
    orient_with_camera(
        &photo.name,
        start.camera.clone(),
        start.io.clone(),
        &start.pose,
        &start.covariance,
        &start.pose,
        store,
        dem,
        &pyramid,
        &opts,
        None,
    )
}

/// A 2-D similarity from predicted to matched positions that at least
/// [`ALIGNMENT_MIN_INLIERS`] candidates agree with within `tolerance` (px), as a guide
/// for a strict second search; None when no such consensus exists or it implies an
/// implausible scale.
fn align_candidates(
    candidates: &[(Vector2<f64>, Vector2<f64>)],
    tolerance: f64,
    opts: &OrientOptions,
) -> Option<orient::Guide> {
    if candidates.len() < ALIGNMENT_MIN_INLIERS {
        return None;
    }
    let r = RobustMethod::Ransac
        .estimate(
            &Similarity2Estimator,
            candidates,
            &RobustOptions {
                threshold: tolerance,
                ..RobustOptions::default()
            },
        )
        .ok()?;
    let plausible = (0.8..1.25).contains(&r.model.scale());
    tracing::debug!(
        candidates = candidates.len(),
        inliers = r.num_inliers,
        tolerance,
        scale = r.model.scale(),
        shift_x = r.model.t.x,
        shift_y = r.model.t.y,
        "image alignment of the first-round candidates"
    );
    (r.num_inliers >= ALIGNMENT_MIN_INLIERS && plausible).then_some(orient::Guide {
        map: r.model,
        half_px: (2.0 * tolerance).max(opts.min_half_px),
    })
}

/// What a 2-D similarity cannot absorb of the navigation's attitude error over the
/// candidates (px): their predicted rays are tilted by 1σ about each image axis, the
/// best similarity is fitted to the moved positions, and the largest residual is taken,
/// plus [`ALIGNMENT_MATCH_PX`] for matching and relief. It grows with the candidates'
/// spread and their distance from the principal point over the focal length: about
/// 12 px for a 3° σ over a 1000 px frame photo at f = 1200 px, more on a wide film scan.
pub fn alignment_tolerance(
    camera: &Camera,
    candidates: &[(Vector2<f64>, Vector2<f64>)],
    cov: &SMatrix<f64, 6, 6>,
) -> f64 {
    let sigma = cov[(0, 0)].max(cov[(1, 1)]).max(0.0).sqrt();
    let rays: Vec<(Vector2<f64>, Vector3<f64>)> = candidates
        .iter()
        .filter_map(|(p, _)| Some((*p, camera.unproject([p.x, p.y]).ok()?)))
        .collect();
    let mut worst = 0.0f64;
    for axis in [Vector3::x_axis(), Vector3::y_axis()] {
        let tilt = nalgebra::Rotation3::from_axis_angle(&axis, sigma);
        let moved: Vec<(Vector2<f64>, Vector2<f64>)> = rays
            .iter()
            .filter_map(|(p, d)| Some((*p, camera.project(&(tilt * d)).ok()?)))
            .collect();
        let refs: Vec<&(Vector2<f64>, Vector2<f64>)> = moved.iter().collect();
        let Some(s) = Similarity2::fit(&refs) else {
            continue;
        };
        for (p, q) in &moved {
            worst = worst.max((s.apply(p) - q).norm());
        }
    }
    worst + ALIGNMENT_MATCH_PX
}

/// The pose turned about its optical axis by the rotation of `guide` (an image rotation
/// about the principal point), and the guide that remains for predictions of the turned
/// pose. The turn's sense in the image depends on the camera's axes; it is read off the
/// camera itself.
fn swing_into_pose(camera: &Camera, pose: &Pose, guide: &orient::Guide) -> (Pose, orient::Guide) {
    let theta = guide.map.b.atan2(guide.map.a);
    let turn = |g: f64| nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), g);
    let (Ok(c), Ok(p)) = (
        camera.project(&Vector3::new(0.0, 0.0, 1.0)),
        camera.project(&Vector3::new(0.2, 0.1, 1.0)),
    ) else {
        return (*pose, *guide);
    };
    let Ok(q) = camera.project(&(turn(theta) * Vector3::new(0.2, 0.1, 1.0))) else {
        return (*pose, *guide);
    };
    let (u, v) = (p - c, q - c);
    let seen = (u.x * v.y - u.y * v.x).atan2(u.dot(&v));
    let gamma = if (seen - theta).abs() <= (seen + theta).abs() {
        theta
    } else {
        -theta
    };
    let turned = Pose::new(turn(gamma).matrix() * pose.rotation, pose.center);
    // Predictions of the turned pose are those of the old one rotated by θ about c: undo
    // that, then apply the alignment.
    let (cos, sin) = ((-theta).cos(), (-theta).sin());
    let undo = Similarity2 {
        a: cos,
        b: sin,
        t: c - Vector2::new(cos * c.x - sin * c.y, sin * c.x + cos * c.y),
    };
    let map = guide.map.after(&undo);
    (
        turned,
        orient::Guide {
            map,
            half_px: guide.half_px,
        },
    )
}

/// How far the resected `pose` lies from the navigation `prior`, in σ of their
/// difference (`prior_cov` and `pose_cov`: rotation vector, then centre; the two are
/// independent estimates, so their covariances add): the largest of the centre
/// coordinates' and the attitude angle's. `axis_tolerance_m`: an offset along the optical
/// axis up to this is not counted (see [`NOMINAL_FOCAL_TOLERANCE`]).
fn prior_distance(
    pose: &Pose,
    pose_cov: &SMatrix<f64, 6, 6>,
    prior: &Pose,
    prior_cov: &SMatrix<f64, 6, 6>,
    axis_tolerance_m: f64,
) -> f64 {
    let mut d = pose.center - prior.center;
    if axis_tolerance_m > 0.0 {
        let axis = pose.rotation.transpose() * Vector3::z();
        let along = axis.dot(&d);
        d -= axis * along.signum() * along.abs().min(axis_tolerance_m);
    }
    let var = |i: usize| (prior_cov[(i, i)] + pose_cov[(i, i)].max(0.0)).max(1e-24);
    let centre = (0..3)
        .map(|i| d[i].abs() / var(i + 3).sqrt())
        .fold(0.0, f64::max);
    let angle =
        nalgebra::Rotation3::from_matrix_unchecked(pose.rotation * prior.rotation.transpose())
            .angle();
    let sigma_rot = (0..3).map(var).fold(0.0, f64::max).sqrt();
    centre.max(angle / sigma_rot)
}

/// How far a camera file's nominal principal distance (a lens's engraved value, a sister
/// camera's certificate) may be from the truth when the epoch self-calibrates it. A
/// resection with it is displaced along the optical axis by that fraction of the flying
/// height (0.5 % at 1.8 km: 9 m, 60σ of GNSS camera centres), which is the epoch
/// adjustment's to remove, not a reason to refuse the photo.
pub const NOMINAL_FOCAL_TOLERANCE: f64 = 0.02;

/// Candidates that must agree on an alignment: two fix a similarity, two more confirm it
/// (a chance agreement of two wrong peaks within the tolerance in a window of ±250 px is
/// under one in a thousand).
const ALIGNMENT_MIN_INLIERS: usize = 4;
/// Matching error and relief displacement differences left after the alignment (px).
pub const ALIGNMENT_MATCH_PX: f64 = 3.0;

/// The ground a photo's control patches are looked for on (block-local plan polygon):
/// its footprint on the DEM from `pose`, grown by 3σ of the centre's plan position.
pub fn search_area(
    camera: &Camera,
    pose: &Pose,
    cov: &SMatrix<f64, 6, 6>,
    dem: &Dem,
) -> crate::geometry::Result<Vec<[f64; 2]>> {
    let fp = predict::footprint(camera, pose, dem, 8)?;
    Ok(grow(&fp, 3.0 * cov[(3, 3)].max(cov[(4, 4)]).sqrt()))
}

#[allow(clippy::too_many_arguments)]
fn orient_with_camera(
    name: &str,
    camera: Camera,
    io: Option<ScanIo>,
    pose0: &Pose,
    cov0: &SMatrix<f64, 6, 6>,
    prior: &Pose,
    store: &ChipStore,
    dem: &Dem,
    pyramid: &Pyramid,
    opts: &PhotoOptions,
    guide: Option<&orient::Guide>,
) -> PhotoOrientation {
    let area = match search_area(&camera, pose0, cov0, dem) {
        Ok(a) => a,
        Err(e) => {
            return PhotoOrientation::failed(
                name,
                *pose0,
                PhotoFailure::Footprint {
                    message: e.to_string(),
                },
            )
        }
    };
    let patches = store.patches_in(&area);
    let mut matcher = ChipMatcher::new(&camera, pyramid, store, &opts.patch);
    let mut resector = AdjustResector::new(opts);
    let o = orient::orient_photo(
        &camera,
        pose0,
        cov0,
        &patches,
        &mut matcher,
        &mut resector,
        &opts.orient,
        guide,
    );
    let predicted = o.iterations.first().map_or(0, |r| r.predicted);
    let reason = if let Some(e) = &matcher.chip_error {
        Some(PhotoFailure::Chip {
            message: e.to_string(),
        })
    } else if o.oriented {
        let axis_tolerance_m = if opts.focal_free {
            let (z0, z1) = dem.z_range();
            NOMINAL_FOCAL_TOLERANCE * (prior.center.z - 0.5 * (z0 + z1)).abs()
        } else {
            0.0
        };
        let pose_cov = if opts.prior_test_with_resection_sigma {
            o.covariance
        } else {
            SMatrix::zeros()
        };
        let sigmas = prior_distance(&o.pose, &pose_cov, prior, cov0, axis_tolerance_m);
        (sigmas > opts.max_prior_sigmas).then_some(PhotoFailure::FarFromPrior {
            sigmas,
            limit: opts.max_prior_sigmas,
        })
    } else if let Some((round, message)) = &o.refuted {
        let r = &o.iterations[*round];
        Some(PhotoFailure::Unconfirmed {
            round: *round,
            matched: r.matched,
            predicted: r.predicted,
            message: message.clone(),
        })
    } else if predicted == 0 {
        Some(PhotoFailure::NoControlInView {
            in_footprint: patches.len(),
        })
    } else {
        Some(PhotoFailure::TooFewMatches {
            matched: o.iterations.iter().map(|r| r.matched).max().unwrap_or(0),
            predicted,
            needed: opts.min_inliers,
        })
    };
    let oriented = reason.is_none();
    PhotoOrientation {
        report: PhotoReport {
            name: name.to_string(),
            oriented,
            reason,
            iterations: o.iterations.clone(),
            control_matches: o.matches.len(),
            sigma_px: resector.last_rmse_px,
            io,
            predicted,
            matching: matcher.stats.clone(),
            relaxed: false,
            second_pass: false,
            tie_pass: false,
        },
        camera: Some(camera),
        pose: if oriented { o.pose } else { *prior },
        covariance: o.covariance,
        matches: if oriented { o.matches } else { Vec::new() },
        first_round: o.first_round,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cov(sigma_rot: f64, sigma_xyz: f64) -> SMatrix<f64, 6, 6> {
        let mut c = SMatrix::<f64, 6, 6>::zeros();
        for i in 0..3 {
            c[(i, i)] = sigma_rot * sigma_rot;
            c[(i + 3, i + 3)] = sigma_xyz * sigma_xyz;
        }
        c
    }

    #[test]
    fn prior_distance_tests_the_difference_of_two_estimates() {
        let prior = Pose::from_opk(0.0, 0.0, 0.0, Vector3::new(0.0, 0.0, 1800.0));
        // Precise navigation (0.15 m), a resection known to 4 m: a 12 m offset is 3σ of
        // the difference, though 80σ of the navigation alone.
        let (nav, res) = (cov(1e-3, 0.15), cov(1e-4, 4.0));
        let mut pose = prior;
        pose.center.x += 12.0;
        let d = prior_distance(&pose, &res, &prior, &nav, 0.0);
        assert!(
            (d - 12.0 / (0.15f64.powi(2) + 16.0).sqrt()).abs() < 1e-9,
            "{d}"
        );
        // A wrong solution (a mirrored fiducial fit 250 m away, well determined) stays far.
        pose.center.x = 250.0;
        assert!(prior_distance(&pose, &cov(1e-4, 0.5), &prior, &cov(0.05, 10.0), 0.0) > 20.0);
        // With f self-calibrated, an offset along the optical axis up to what the nominal
        // focal length may cause (2 % of 1.8 km: 36 m) is not counted; beyond it and
        // across the axis it is.
        let axis = prior.rotation.transpose() * Vector3::z();
        assert!(axis.z.abs() > 0.999);
        let mut pose = prior;
        pose.center += axis * 9.0;
        assert!(prior_distance(&pose, &res, &prior, &nav, 36.0) < 1e-9);
        assert!(prior_distance(&pose, &res, &prior, &nav, 0.0) > 2.0);
        pose.center -= axis * 60.0;
        let d = prior_distance(&pose, &res, &prior, &nav, 36.0);
        assert!(
            (d - 15.0 / (0.15f64.powi(2) + 16.0).sqrt()).abs() < 1e-9,
            "{d}"
        );
        pose.center += axis * 51.0;
        pose.center.y += 30.0;
        assert!(prior_distance(&pose, &res, &prior, &nav, 36.0) > 7.0);
        // The attitude: 0.5° against 0.1° of navigation and 0.01° of resection.
        let turned = Pose::from_opk(0.5f64.to_radians(), 0.0, 0.0, prior.center);
        let d = prior_distance(
            &turned,
            &cov(1e-2f64.to_radians(), 1.0),
            &prior,
            &cov(0.1f64.to_radians(), 1.0),
            0.0,
        );
        assert!(
            (d - 0.5 / (0.01f64.powi(2) + 0.01).sqrt()).abs() < 1e-6,
            "{d}"
        );
    }
}
