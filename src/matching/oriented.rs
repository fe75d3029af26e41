//! Tie points of a block from approximate orientations (POS/EO): each Förstner point of
//! a photo is carried through its approximate exterior orientation onto a DEM (or a mean
//! terrain height) and projected into every overlapping photo, and only a window around
//! that prediction is searched, its radius from the orientation's uncertainty. The
//! pairwise matches then pass the robust relative orientation (LMedS or RANSAC), are
//! linked into multi-photo tracks, and are written into the [`Block`] as tie points with
//! their observations, σ and provenance; each photo's coverage of the standard positions
//! is reported.

use super::image::Pixels;
use super::pair_matching::{plan_pairs, InMemory, MatchedPairs, PairMatching, PhotoPairs};
use super::ties::{coverage, PairPrediction, RobustMethod, TieOptions, TieResult, Track};
use super::{invalid, Result};
use crate::block::{Block, ObjectPoint, Observation, PhotoId, PointKind};
use crate::geometry::{
    back_project, dlt_null_matrix, hartley_normalisation, project, Camera, Dem, Pose, Ray,
};
use nalgebra::{DMatrix, Matrix3, Vector3};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// The terrain the predictions are carried over, in block-local coordinates.
#[derive(Debug, Clone, Copy)]
pub enum Surface<'a> {
    /// A DEM in world coordinates; `origin` is the block's local origin (world = local +
    /// origin). `sigma_m` is its height uncertainty.
    Dem {
        dem: &'a Dem,
        origin: Vector3<f64>,
        sigma_m: f64,
    },
    /// A horizontal plane at a mean terrain height (block-local), with the σ of the
    /// relief about it (it enlarges the search by the parallax it causes).
    Plane { height: f64, sigma_m: f64 },
}

impl Surface<'_> {
    /// First intersection of a block-local ray with the surface.
    pub fn intersect(&self, ray: &Ray) -> Option<Vector3<f64>> {
        match self {
            Surface::Dem { dem, origin, .. } => {
                let world = Ray {
                    origin: ray.origin + origin,
                    direction: ray.direction,
                };
                dem.intersect(&world).ok().map(|x| x - origin)
            }
            Surface::Plane { height, .. } => {
                if ray.direction.z.abs() < 1e-9 {
                    return None;
                }
                let t = (height - ray.origin.z) / ray.direction.z;
                (t > 0.0).then(|| ray.at(t))
            }
        }
    }

    fn sigma_m(&self) -> f64 {
        match self {
            Surface::Dem { sigma_m, .. } | Surface::Plane { sigma_m, .. } => *sigma_m,
        }
    }
}

/// A photo with its approximate orientation and that orientation's uncertainty.
#[derive(Debug, Clone, Copy)]
pub struct OrientedPhoto<'a> {
    /// Its pixels, decoded when its pairs are matched; the size is the camera's.
    pub image: Pixels<'a>,
    pub camera: &'a Camera,
    pub pose: Pose,
    /// σ of each coordinate of the projection centre (m).
    pub center_sigma_m: f64,
    /// σ of each attitude angle (rad).
    pub angle_sigma_rad: f64,
}

impl OrientedPhoto<'_> {
    /// Width and height (px): the camera's, which the image must match.
    pub(super) fn size(&self) -> (f64, f64) {
        let (w, h) = self.usize_size();
        (w as f64, h as f64)
    }

    fn usize_size(&self) -> (usize, usize) {
        let (w, h) = self.camera.image_size();
        (w as usize, h as usize)
    }

    /// Pixel of photo `b` seen at pixel `p` of `self`, through the surface.
    pub fn transfer(&self, b: &OrientedPhoto, surface: &Surface, p: [f64; 2]) -> Option<[f64; 2]> {
        let ray = back_project(self.camera, &self.pose, p).ok()?;
        let x = surface.intersect(&ray)?;
        let q = project(b.camera, &b.pose, &x).ok()?;
        Some([q.pixel.x, q.pixel.y])
    }
}

#[derive(Debug, Clone)]
pub struct BlockTieOptions {
    pub ties: TieOptions,
    /// Search radius in multiples of the predicted position's σ.
    pub n_sigma: f64,
    /// Pairs whose predicted overlap is below this fraction of photo a are not matched.
    pub min_overlap: f64,
    pub min_radius_px: f64,
    /// Larger predicted uncertainty than this means the orientation is too poor for a
    /// guided search; the pair is skipped with that reason.
    pub max_radius_px: f64,
    /// Used for photos without a POS prior.
    pub default_center_sigma_m: f64,
    pub default_angle_sigma_rad: f64,
    /// Lower bound of an observation's σ: the LSM a-posteriori σ of a well-textured
    /// patch can be a few hundredths of a pixel, which overstates what a tie point
    /// measures once the model errors of the adjustment are counted.
    pub sigma_floor_px: f64,
    /// Fewer accepted matches than this leave the relative orientation unverified; the
    /// pair contributes nothing.
    pub min_pair_matches: usize,
    /// Bytes of prepared photos (pyramid and interest points) kept between pairs; the
    /// photos of one photo's pairs are held even beyond it.
    pub image_cache_bytes: u64,
}

impl Default for BlockTieOptions {
    fn default() -> Self {
        let mut ties = TieOptions::default();
        // A 16 × 16 grid of 4 Förstner points (1,024 per photo) instead of the strip
        // matcher's 8 × 8: a block's strength is its cross-strip pairs, whose 15–25 %
        // overlap held 13–52 of 256 points, mostly fewer than the 12 matches that verify
        // a pair, so the strips hung together by the POS alone. Measured on the small
        // preset, seeds 1–10 (12 photos): the reference's error at the checkpoints
        // against the truth fell from 0.32 / 0.39 GSD (plan / height, mean over seeds)
        // to 0.27 / 0.29; medium seed 1: 2.4 times the tie points, the same 25 s.
        ties.forstner.grid = (16, 16);
        Self {
            ties,
            n_sigma: 3.0,
            min_overlap: 0.05,
            min_radius_px: 3.0,
            max_radius_px: 150.0,
            default_center_sigma_m: 5.0,
            default_angle_sigma_rad: 1.0f64.to_radians(),
            sigma_floor_px: 0.25,
            min_pair_matches: 12,
            image_cache_bytes: crate::cache::DEFAULT_IMAGE_CACHE_BYTES,
        }
    }
}

/// The predicted geometry of a pair: the a → b plane homography fitted to the transfer
/// over a grid (for coverage and reporting), the overlap, and the search radius.
#[derive(Debug, Clone, Copy)]
pub struct OrientedPair {
    pub prediction: PairPrediction,
    /// Fraction of a grid over photo a whose transfer lands inside photo b.
    pub overlap: f64,
}

/// An `n × n` grid of photo a's pixel centres carried through the surface into photo b.
pub struct GridTransfer {
    /// Grid pixels of a whose ray meets the surface and projects into b's image plane.
    pub pa: Vec<[f64; 2]>,
    /// Their pixels in b (inside b or not).
    pub pb: Vec<[f64; 2]>,
    /// Share of the grid whose pixel in b lies inside b: the pair's overlap seen from a.
    pub overlap: f64,
    /// The same share of the grid pixels whose ray meets the surface: the overlap where
    /// the surface is known (a DEM may cover less than a photo).
    pub overlap_on_surface: f64,
}

/// The [`GridTransfer`] of photo a into photo b.
pub fn grid_transfer(
    a: (&Camera, &Pose),
    b: (&Camera, &Pose),
    surface: &Surface,
    n: usize,
) -> GridTransfer {
    let (wa, ha) = a.0.image_size();
    let (wb, hb) = b.0.image_size();
    let (wb, hb) = (wb as f64, hb as f64);
    let (mut pa, mut pb, mut inside) = (Vec::new(), Vec::new(), 0usize);
    for r in 0..n {
        for c in 0..n {
            let p = [
                (c as f64 + 0.5) / n as f64 * wa as f64,
                (r as f64 + 0.5) / n as f64 * ha as f64,
            ];
            let q = back_project(a.0, a.1, p)
                .ok()
                .and_then(|ray| surface.intersect(&ray))
                .and_then(|x| project(b.0, b.1, &x).ok());
            if let Some(q) = q {
                let q = [q.pixel.x, q.pixel.y];
                if q[0] >= 0.0 && q[1] >= 0.0 && q[0] <= wb && q[1] <= hb {
                    inside += 1;
                }
                pa.push(p);
                pb.push(q);
            }
        }
    }
    let overlap_on_surface = inside as f64 / pa.len().max(1) as f64;
    GridTransfer {
        pa,
        pb,
        overlap: inside as f64 / (n * n).max(1) as f64,
        overlap_on_surface,
    }
}

/// Predicts the pair (a, b) from the approximate orientations; `None` when the photos do
/// not overlap (by at least `min_overlap`).
pub fn predict_oriented_pair(
    photos: &[OrientedPhoto],
    ia: usize,
    ib: usize,
    surface: &Surface,
    opts: &BlockTieOptions,
) -> Option<OrientedPair> {
    let (a, b) = (&photos[ia], &photos[ib]);
    let (wa, ha) = a.size();
    let GridTransfer {
        pa, pb, overlap, ..
    } = grid_transfer((a.camera, &a.pose), (b.camera, &b.pose), surface, 11);
    if overlap < opts.min_overlap || pa.len() < 4 {
        return None;
    }
    let homography = fit_homography(&pa, &pb)?;
    // Uncertainty of the predicted position in b, per image axis: an attitude error of
    // either photo moves the point by f·δθ; a centre error by f·δC/H; a height error by
    // the parallax f·B·δh/H² it causes over the base B.
    let ca = back_project(a.camera, &a.pose, [wa / 2.0, ha / 2.0]).ok()?;
    let ground = surface.intersect(&ca)?;
    let height = (a.pose.center - ground).norm().max(1.0);
    let base = (a.pose.center - b.pose.center).norm();
    let f = b.camera.focal_px();
    let angle = f * a.angle_sigma_rad.hypot(b.angle_sigma_rad);
    let centre = f / height * a.center_sigma_m.hypot(b.center_sigma_m);
    let relief = f * base * surface.sigma_m() / (height * height);
    let sigma = (angle * angle + centre * centre + relief * relief).sqrt();
    let radius = (opts.n_sigma * sigma).max(opts.min_radius_px);
    Some(OrientedPair {
        prediction: PairPrediction {
            a: ia,
            b: ib,
            homography,
            search_radius_px: radius,
        },
        overlap,
    })
}

/// Normalised DLT homography from point correspondences (least squares over all).
fn fit_homography(pa: &[[f64; 2]], pb: &[[f64; 2]]) -> Option<Matrix3<f64>> {
    let ((ta, _), (tb, _)) = (hartley_normalisation(pa), hartley_normalisation(pb));
    let mut m = DMatrix::<f64>::zeros(2 * pa.len(), 9);
    for (k, (p, q)) in pa.iter().zip(pb).enumerate() {
        let u = ta * Vector3::new(p[0], p[1], 1.0);
        let v = tb * Vector3::new(q[0], q[1], 1.0);
        let (x, y, xp, yp) = (u.x, u.y, v.x, v.y);
        let r0 = [-x, -y, -1.0, 0.0, 0.0, 0.0, xp * x, xp * y, xp];
        let r1 = [0.0, 0.0, 0.0, -x, -y, -1.0, yp * x, yp * y, yp];
        for j in 0..9 {
            m[(2 * k, j)] = r0[j];
            m[(2 * k + 1, j)] = r1[j];
        }
    }
    let hn = dlt_null_matrix(m)?;
    let hm = tb.try_inverse()? * hn * ta;
    let s = hm[(2, 2)];
    (s.abs() > 1e-12 && hm.iter().all(|v| v.is_finite())).then(|| hm / s)
}

/// What happened to one pair.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PairReport {
    pub a: PhotoId,
    pub b: PhotoId,
    pub overlap: f64,
    pub search_radius_px: f64,
    /// Förstner points of a predicted inside b.
    pub points: usize,
    pub candidates: usize,
    pub accepted: usize,
    /// Robust σ of the epipolar distances (px).
    pub sigma_px: f64,
    /// Why the pair contributed nothing, if it did not.
    pub skipped: Option<String>,
}

/// Coverage of one photo's standard positions by the tie points written.
#[derive(Debug, Clone, Serialize)]
pub struct PhotoCoverage {
    pub photo: PhotoId,
    pub name: String,
    pub observations: usize,
    /// Positions in row order (top-left, top-centre, …, bottom-right): whether each lies
    /// in an overlap (so needs points) and how many points lie near it.
    pub required: [bool; 9],
    pub counts: [usize; 9],
    /// Required positions with fewer than `min_per_position` points.
    pub missing: Vec<usize>,
}

#[derive(Debug, Clone, Serialize)]
pub struct BlockTieReport {
    pub pairs: Vec<PairReport>,
    pub tracks: usize,
    pub points_added: usize,
    pub observations_added: usize,
    /// Number of tracks by their number of photos.
    pub track_lengths: BTreeMap<usize, usize>,
    pub coverage: Vec<PhotoCoverage>,
    pub min_per_position: usize,
    /// Photos decoded and prepared for matching (again after leaving the bounded cache
    /// counts again).
    pub photos_prepared: usize,
}

/// Pairwise matches and tracks of a set of oriented photos (indices into `photos`): the
/// tie points as [`TieResult`] (`matches`, `tracks`, `coverage` read through it), with the
/// overlapping pairs and what each gave.
#[derive(Debug, Clone)]
pub struct OrientedTies {
    pub pairs: Vec<OrientedPair>,
    /// Photos decoded and prepared for matching, counting each time again.
    pub prepared: usize,
    pub reports: Vec<PairReport>,
    pub ties: TieResult,
}

impl std::ops::Deref for OrientedTies {
    type Target = TieResult;
    fn deref(&self) -> &TieResult {
        &self.ties
    }
}

/// Tie points of oriented photos: every overlapping pair (a < b) is matched a → b by a
/// guided search, filtered by robust relative orientation, and linked into tracks.
/// `ids` name the photos in the reports.
pub fn oriented_tie_points(
    photos: &[OrientedPhoto],
    ids: &[PhotoId],
    surface: &Surface,
    opts: &BlockTieOptions,
) -> Result<OrientedTies> {
    check_ids(photos, ids)?;
    let jobs = plan_pairs(photos, surface, opts);
    let matched = InMemory.match_pairs(photos, ids, &jobs, surface, opts)?;
    Ok(link_pairs(photos, jobs, matched, opts))
}

fn check_ids(photos: &[OrientedPhoto], ids: &[PhotoId]) -> Result<()> {
    if ids.len() != photos.len() {
        return Err(invalid(
            "photo ids",
            format!("{} ids for {} photos", ids.len(), photos.len()),
        ));
    }
    Ok(())
}

/// The photos' matches, in photo order, linked into tracks.
fn link_pairs(
    photos: &[OrientedPhoto],
    jobs: Vec<PhotoPairs>,
    matched: Vec<MatchedPairs>,
    opts: &BlockTieOptions,
) -> OrientedTies {
    let pairs: Vec<OrientedPair> = jobs
        .into_iter()
        .flat_map(|j| j.pairs.into_iter().map(|(_, p)| p))
        .collect();
    let (mut matches, mut reports, mut prepared) = (Vec::new(), Vec::new(), 0);
    for m in matched {
        matches.extend(m.matches);
        reports.extend(m.reports);
        prepared += m.prepared;
    }
    tracing::debug!(
        photos = photos.len(),
        prepared,
        "photos prepared for tie matching"
    );
    let sizes: Vec<(usize, usize)> = photos.iter().map(|p| p.usize_size()).collect();
    let preds: Vec<PairPrediction> = pairs.iter().map(|p| p.prediction).collect();
    OrientedTies {
        prepared,
        ties: TieResult::link(matches, &sizes, &preds, opts.ties.merge_px),
        pairs,
        reports,
    }
}

/// Least-squares intersection of the observation rays (the point nearest to all of
/// them); `None` when the rays are (nearly) parallel or the point lies behind a camera.
fn intersect_rays(rays: &[Ray]) -> Option<Vector3<f64>> {
    let mut a = Matrix3::zeros();
    let mut r = Vector3::zeros();
    for ray in rays {
        let d = ray.direction.normalize();
        let m = Matrix3::identity() - d * d.transpose();
        a += m;
        r += m * ray.origin;
    }
    let eig = a.symmetric_eigen();
    let min = eig
        .eigenvalues
        .iter()
        .cloned()
        .fold(f64::INFINITY, f64::min);
    // Smallest eigenvalue ~ sin² of the intersection angle summed over rays; below
    // ~1.5° the depth is too weak to trust.
    if min < 1e-3 {
        return None;
    }
    let x = a.try_inverse()? * r;
    rays.iter()
        .all(|ray| (x - ray.origin).dot(&ray.direction) > 0.0)
        .then_some(x)
}

/// The photos of a block that have an image, as tie matching sees them: their ids,
/// cameras (cloned, so that the block can take the new points while they are in use),
/// approximate orientations and the σ of those.
pub struct TiePhotos<'a> {
    ids: Vec<PhotoId>,
    setup: Vec<(Pixels<'a>, Camera, Pose, f64, f64)>,
}

impl<'a> TiePhotos<'a> {
    /// The photos of `block` with an image in `images` (at least two); a photo without a
    /// prior takes the default σ of `opts`.
    pub fn of(
        block: &Block,
        images: &BTreeMap<PhotoId, Pixels<'a>>,
        opts: &BlockTieOptions,
    ) -> Result<Self> {
        let mut ids = Vec::new();
        let mut setup = Vec::new();
        for (id, img) in images {
            let photo = block.photos.get(id).ok_or_else(|| {
                invalid(
                    format!("image for photo {id}"),
                    "no such photo in the block",
                )
            })?;
            let cam = block.camera_of(photo).ok_or_else(|| {
                invalid(
                    format!("photo {id} ({})", photo.name),
                    format!("unknown camera {}", photo.camera),
                )
            })?;
            let (cs, rs) = match &photo.prior {
                Some(p) => (
                    p.center_sigma.iter().cloned().fold(0.0, f64::max),
                    if p.rotation.is_some() {
                        p.rotation_sigma_rad
                    } else {
                        opts.default_angle_sigma_rad
                    },
                ),
                None => (opts.default_center_sigma_m, opts.default_angle_sigma_rad),
            };
            ids.push(*id);
            setup.push((*img, cam.model.clone(), photo.pose, cs, rs));
        }
        if ids.len() < 2 {
            return Err(invalid(
                "tie points",
                format!("{} photo(s) with an image; at least 2 needed", ids.len()),
            ));
        }
        Ok(Self { ids, setup })
    }

    pub fn ids(&self) -> &[PhotoId] {
        &self.ids
    }

    pub fn photos(&self) -> Vec<OrientedPhoto<'_>> {
        self.setup
            .iter()
            .map(|(image, camera, pose, cs, rs)| OrientedPhoto {
                image: *image,
                camera,
                pose: *pose,
                center_sigma_m: *cs,
                angle_sigma_rad: *rs,
            })
            .collect()
    }
}

/// Tie points for a whole block from its approximate orientations: matches every
/// overlapping pair of the photos that have an image, and appends one tie
/// [`ObjectPoint`] per track with its observations (σ from the match, at least
/// `sigma_floor_px`; provenance naming the method). The object point's initial position
/// is the intersection of its rays through the approximate orientations, or the
/// surface point under its first observation when the rays intersect too obliquely.
pub fn block_tie_points(
    block: &mut Block,
    images: &BTreeMap<PhotoId, Pixels>,
    surface: &Surface,
    min_per_position: usize,
    opts: &BlockTieOptions,
) -> Result<BlockTieReport> {
    let tp = TiePhotos::of(block, images, opts)?;
    let photos = tp.photos();
    let jobs = plan_pairs(&photos, surface, opts);
    let matched = InMemory.match_pairs(&photos, tp.ids(), &jobs, surface, opts)?;
    Ok(write_ties(
        block,
        &tp,
        jobs,
        matched,
        surface,
        min_per_position,
        opts,
    ))
}

/// The matches of the photos' pairs (what [`PairMatching`] gave for `jobs`, from
/// [`plan_pairs`]), linked into tracks and written into the block as tie points
/// (see [`block_tie_points`]).
pub fn write_ties(
    block: &mut Block,
    tp: &TiePhotos,
    jobs: Vec<PhotoPairs>,
    matched: Vec<MatchedPairs>,
    surface: &Surface,
    min_per_position: usize,
    opts: &BlockTieOptions,
) -> BlockTieReport {
    let photos = tp.photos();
    let ids = tp.ids();
    let ties = link_pairs(&photos, jobs, matched, opts);
    let provenance = format!(
        "ties: Förstner + NCC + LSM, guided by approximate EO, {} relative orientation",
        match opts.ties.robust {
            RobustMethod::Lmeds => "LMedS",
            RobustMethod::Ransac => "RANSAC",
        }
    );
    let mut next = block.next_point_id();
    let (mut added, mut observations) = (0usize, 0usize);
    let mut lengths = BTreeMap::new();
    // Tracks whose rays meet neither each other nor the surface are not written; the
    // coverage is then counted over the written ones only.
    let mut written: Vec<Track> = Vec::new();
    for t in &ties.ties.tracks {
        let rays: Vec<Ray> = t
            .observations
            .iter()
            .filter_map(|(k, p)| back_project(photos[*k].camera, &photos[*k].pose, *p).ok())
            .collect();
        if rays.len() != t.observations.len() {
            continue;
        }
        let Some(position) = intersect_rays(&rays).or_else(|| surface.intersect(&rays[0])) else {
            continue;
        };
        *lengths.entry(t.observations.len()).or_insert(0) += 1;
        written.push(t.clone());
        let obs: Vec<Observation> = t
            .observations
            .iter()
            .zip(&t.sigma_px)
            .map(|((k, p), s)| Observation {
                photo: ids[*k],
                pixel: *p,
                sigma_px: if s.is_finite() {
                    s.max(opts.sigma_floor_px)
                } else {
                    opts.sigma_floor_px
                },
                provenance: provenance.clone(),
            })
            .collect();
        observations += obs.len();
        block.points.insert(
            next,
            ObjectPoint {
                id: next,
                name: String::new(),
                kind: PointKind::Tie,
                position,
                sigma: None,
                color: [0, 0, 0],
                observations: obs,
            },
        );
        next += 1;
        added += 1;
    }
    let sizes: Vec<(usize, usize)> = photos.iter().map(|p| p.usize_size()).collect();
    let preds: Vec<PairPrediction> = ties.pairs.iter().map(|p| p.prediction).collect();
    let coverage = coverage(&sizes, &preds, &written)
        .iter()
        .map(|c| PhotoCoverage {
            photo: ids[c.photo],
            name: block.photos[&ids[c.photo]].name.clone(),
            observations: c.total,
            required: c.required,
            counts: c.counts,
            missing: c.missing(min_per_position),
        })
        .collect();
    BlockTieReport {
        pairs: ties.reports,
        tracks: ties.ties.tracks.len(),
        points_added: added,
        observations_added: observations,
        track_lengths: lengths,
        coverage,
        min_per_position,
        photos_prepared: ties.prepared,
    }
}
