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
use crate::adjust;
use crate::block::{PhotoFailure, PosPrior};
use crate::geometry::{Brown, Camera, Dem, FilmCamera, Pose};
use crate::matching::{self, CameraDefinition, GreyImage, IoOptions, MatchOptions, Pyramid};
use nalgebra::{Matrix3, SMatrix, Vector2, Vector3};
use serde::Serialize;

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
}

impl Default for PhotoOptions {
    fn default() -> Self {
        Self {
            orient: OrientOptions {
                min_half_px: 6.0,
                max_half_px: 400.0,
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
        }
    }
}

/// Per-photo outcome, for the report.
#[derive(Debug, Clone, Serialize)]
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
}

/// A film scan's fiducial interior orientation, as reported.
#[derive(Debug, Clone, Serialize)]
pub struct ScanIo {
    /// RMS of the fiducial marks after the affine fit (µm).
    pub rmse_um: f64,
    /// Scan pixel size used (µm).
    pub pixel_um: f64,
    /// Where it came from: given in the epoch, or estimated (and from what).
    pub pixel_source: String,
}

/// The orientation of one photo: the resected pose with its covariance and the matches
/// that support it, or the reason it failed.
#[derive(Debug, Clone)]
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
}

impl PhotoOrientation {
    fn failed(name: &str, pose: Pose, reason: PhotoFailure) -> Self {
        Self {
            report: PhotoReport {
                name: name.to_string(),
                oriented: false,
                reason: Some(reason),
                iterations: Vec::new(),
                control_matches: 0,
                sigma_px: f64::NAN,
                io: None,
                predicted: 0,
                matching: MatchStats::default(),
                relaxed: false,
                second_pass: false,
            },
            camera: None,
            pose,
            covariance: SMatrix::zeros(),
            matches: Vec::new(),
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

/// Film cameras of one scan: the best fiducial interior orientation first, then, when the
/// fiducial layout is symmetric, every other scan orientation whose marks fit within
/// twice the best RMSE (plus 10 µm).
pub fn film_cameras(
    def: &CameraDefinition,
    img: &GreyImage,
    name: &str,
    io: &IoOptions,
) -> Result<Vec<(FilmCamera, ScanIo)>, String> {
    let r = matching::interior_orientation(def, img, name, io).map_err(|e| e.to_string())?;
    let mut out = vec![(film_from_io(def, img, &r), scan_io(&r))];
    if r.orientation_ambiguous && io.orientation.is_none() {
        for o in matching::ScanOrientation::all() {
            if o == r.orientation {
                continue;
            }
            let forced = IoOptions {
                orientation: Some(o),
                ..io.clone()
            };
            if let Ok(r2) = matching::interior_orientation(def, img, name, &forced) {
                if r2.rmse_um <= 2.0 * r.rmse_um + 10.0 {
                    out.push((film_from_io(def, img, &r2), scan_io(&r2)));
                }
            }
        }
    }
    Ok(out)
}

fn scan_io(r: &matching::IoResult) -> ScanIo {
    ScanIo {
        rmse_um: r.rmse_um,
        pixel_um: r.pixel_um,
        pixel_source: r.pixel_source.clone(),
    }
}

fn film_from_io(def: &CameraDefinition, img: &GreyImage, r: &matching::IoResult) -> FilmCamera {
    let d = &def.distortion;
    FilmCamera {
        width: img.width as u32,
        height: img.height as u32,
        focal_mm: def.focal_mm,
        principal_point_mm: def.principal_point_mm,
        distortion: Brown::from_array([d.k1, d.k2, d.k3, d.p1, d.p2]),
        interior: r.transform.clone(),
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
/// block-local `dem`), starting from its approximate orientation `prior`.
pub fn orient_photo(
    photo: &PhotoInput,
    camera: &EpochCamera,
    prior: Option<&PosPrior>,
    store: &ChipStore,
    dem: &Dem,
    opts: &PhotoOptions,
) -> PhotoOrientation {
    let name = photo.name.as_str();
    let unknown = Pose::new(Matrix3::identity(), Vector3::zeros());
    let Some(prior) = prior else {
        return PhotoOrientation::failed(name, unknown, PhotoFailure::NoNavigation);
    };
    let (pose0, cov0) = (prior.pose(), prior.covariance());
    let img = match GreyImage::load(&photo.image) {
        Ok(i) => i,
        Err(e) => {
            return PhotoOrientation::failed(
                name,
                pose0,
                PhotoFailure::Image {
                    path: photo.image.display().to_string(),
                    message: e.to_string(),
                },
            )
        }
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
        EpochCamera::Film(def) => match film_cameras(def, &img, name, &opts.io) {
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
    let pyramid = Pyramid::new(&img, 6, 16);
    let mut best: Option<PhotoOrientation> = None;
    for (camera, io) in candidates {
        let out = orient_with_camera(name, camera, io, &pose0, &cov0, store, dem, &pyramid, opts);
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
        relaxed_retry: false,
        ..opts.clone()
    };
    let Some(camera) = best.camera.clone() else {
        return best;
    };
    let io = best.report.io.clone();
    let retry = orient_with_camera(
        name, camera, io, &pose0, &cov0, store, dem, &pyramid, &relaxed,
    );
    if retry.report.oriented {
        let mut r = retry;
        r.report.relaxed = true;
        r
    } else {
        best
    }
}

#[allow(clippy::too_many_arguments)]
fn orient_with_camera(
    name: &str,
    camera: Camera,
    io: Option<ScanIo>,
    pose0: &Pose,
    cov0: &SMatrix<f64, 6, 6>,
    store: &ChipStore,
    dem: &Dem,
    pyramid: &Pyramid,
    opts: &PhotoOptions,
) -> PhotoOrientation {
    let fp = match predict::footprint(&camera, pose0, dem, 8) {
        Ok(f) => f,
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
    let margin = 3.0 * cov0[(3, 3)].max(cov0[(4, 4)]).sqrt();
    let patches = store.patches_in(&grow(&fp, margin));
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
    );
    let predicted = o.iterations.first().map_or(0, |r| r.predicted);
    let reason = if let Some(e) = &matcher.chip_error {
        Some(PhotoFailure::Chip {
            message: e.to_string(),
        })
    } else if o.oriented {
        None
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
        },
        camera: Some(camera),
        pose: o.pose,
        covariance: o.covariance,
        matches: if oriented { o.matches } else { Vec::new() },
    }
}
