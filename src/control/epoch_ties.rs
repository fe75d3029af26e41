//! Tie points of an archive epoch: Förstner points of its oriented photos, put on the DEM
//! through their ray, or beyond it where two rays of oriented photos meet, each with a
//! chip cut from its photo (seed 003: points where the image is textured, spread over the
//! frame).
//!
//! They serve twice. [`epoch_ties`] ties the oriented photos to one another in the block
//! adjustment (optional). [`tie_pass`] orients the photos that no control patch reached:
//! a strip-end photo over changed ground, a photo beyond the control area. Its oriented
//! neighbours show the same scene state, with the same film or sensor, so their points
//! are matched in it (search windows from its navigation, the same NCC, LSM and
//! resection as the control patches), and the block adjustment then holds it through
//! those tie points, as aerial triangulation bridges a photo without control. A photo
//! oriented that way can itself pass points on in the next round.

use super::archive::{ground_pixel, ArchiveOptions};
use super::chips::{ChipMatchOptions, ChipStore, ChipView, ControlPoint, PointKey};
use super::epoch::EpochCamera;
use super::orient::ControlPatch;
use super::photo::{PhotoOptions, PhotoOrientation};
use super::predict::Prediction;
use super::rounds::{EpochEnv, EpochRounds, OrientRound, Round, RoundKind};
use crate::adjust::rays::{intersect_rays, intersect_robust, intersection_cofactor, Ray};
use crate::block::{Observation, PhotoFailure, PhotoId};
use crate::geometry::{self, Camera, Dem, Pose};
use crate::matching::pyramid::downsample;
use crate::matching::{forstner, ForstnerOptions, GreyImage, MatchOptions, Pyramid};
use nalgebra::{Matrix3, Vector2, Vector3};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// A tie point's approximate block-local position and its observations (photo ids).
pub type TieTrack = (Vector3<f64>, Vec<Observation>);

/// Where a track is searched in a photo: the predicted pixel and the window's half size.
type Search = (Vector2<f64>, [f64; 2]);

/// At most this many tie points a side of a photo: a film scan of 5.5k pixels would
/// otherwise give thousands of chips per photo at the frame camera's interval.
const MAX_POINTS_PER_SIDE: f64 = 32.0;

/// How far (m) a tie point's DEM height may be from the epoch's ground: its ray meets the
/// DEM of the present, and the point may sit on a roof or tree of its own time.
const TIE_HEIGHT_SIGMA_M: f64 = 2.0;

/// How tie points are placed and matched: one per `cell_px` cell of the source photo,
/// searched ±`window_px` around their prediction where the poses are known, accepted at
/// `ncc_threshold`.
#[derive(Debug, Clone, Copy)]
pub struct TieParams {
    pub cell_px: f64,
    pub window_px: f64,
    pub ncc_threshold: f64,
}

impl TieParams {
    pub fn of(opts: &ArchiveOptions) -> Self {
        Self {
            cell_px: opts.tie_interval_px,
            window_px: opts.tie_window_px,
            ncc_threshold: opts.tie_ncc_threshold,
        }
    }
}

/// Same epoch, same scene: a tie found where the poses predict it must correlate clearly
/// and unambiguously, there is no resection behind it to catch a mismatch.
fn tie_match_options(opts: &PhotoOptions, ties: &TieParams) -> ChipMatchOptions {
    ChipMatchOptions {
        matching: MatchOptions {
            ncc_threshold: ties.ncc_threshold,
            max_ambiguity: 0.8,
            ..opts.patch.matching.clone()
        },
        template_half: opts.patch.template_half.min(15),
        ..opts.patch.clone()
    }
}

/// Förstner's working arrays take about 48 bytes a pixel: on a 5.5k-pixel film scan at
/// full resolution that is 1.5 GB a photo, and the small block's film epoch peaked at
/// 4.5 GB with two threads. Interest is found on the first pyramid level of at most this
/// many pixels (a film scan's level 2, a frame photo's level 0). A tie's observation in
/// its source photo is the centre of its chip, matched by LSM in the other photos, so the
/// coarser level's precision does not enter the adjustment.
const INTEREST_MAX_PIXELS: usize = 4_000_000;

/// The points of one photo: those whose ray meets the DEM, placed there, and those
/// beyond it, placed on the middle of the [`Band`] until other rays intersect them.
#[derive(Default, Serialize, Deserialize)]
pub struct PhotoPoints {
    on_dem: Vec<ControlPoint>,
    beyond: Vec<ControlPoint>,
}

/// The heights a tie point beyond the DEM is searched over. The DEM of the present is
/// the only ground known; the terrain beyond it is taken to lie within its height range
/// widened by half that range either side (at least [`BAND_MIN_HALF_M`]): a film block of
/// kilometres reaches far beyond a LiDAR survey of a few hundred metres, over the same
/// landscape.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
struct Band {
    lo: f64,
    hi: f64,
}

/// Half the height band beyond the DEM at least (m): a flat DEM says little about the
/// hills a kilometre away.
const BAND_MIN_HALF_M: f64 = 10.0;

impl Band {
    fn of(dem: &Dem) -> Self {
        let (lo, hi) = dem.z_range();
        let half = (hi - lo).max(2.0 * BAND_MIN_HALF_M);
        let mid = 0.5 * (lo + hi);
        Self {
            lo: mid - half,
            hi: mid + half,
        }
    }

    fn mid(&self) -> f64 {
        0.5 * (self.lo + self.hi)
    }

    /// Where a ray meets the horizontal plane at height `z`, if in front of its origin.
    fn at(ray: &geometry::Ray, z: f64) -> Option<Vector3<f64>> {
        let t = (z - ray.origin.z) / ray.direction.z;
        (t.is_finite() && t > 0.0).then(|| ray.at(t))
    }
}

/// Förstner points of oriented photo `n` (image `img`; one per cell of `cell` px, at
/// most [`MAX_POINTS_PER_SIDE`] a side), each with a chip of half size `half`, that fall
/// in one of the `footprints` (all points without).
#[allow(clippy::too_many_arguments)]
fn photo_points(
    env: &EpochEnv,
    n: usize,
    (cam, pose): (&Camera, &Pose),
    img: &GreyImage,
    cell: f64,
    half: usize,
    footprints: Option<&[(Camera, Pose)]>,
) -> PhotoPoints {
    let (input, dem) = (env.input, env.dem);
    let side = img.width.max(img.height) as f64;
    let cell = cell.max(16.0).max(side / MAX_POINTS_PER_SIDE);
    let gsd = ground_pixel(cam, pose, dem);
    let mut interest: Option<GreyImage> = None;
    let mut f = 1.0;
    while interest.as_ref().unwrap_or(img).data.len() > INTEREST_MAX_PIXELS {
        interest = Some(downsample(interest.as_ref().unwrap_or(img)));
        f *= 2.0;
    }
    let fo = ForstnerOptions {
        grid: (
            ((img.width as f64 / cell).ceil() as usize).max(1),
            ((img.height as f64 / cell).ceil() as usize).max(1),
        ),
        per_cell: 1,
        border: ((half + 2) as f64 / f).ceil() as usize,
        ..ForstnerOptions::default()
    };
    let band = Band::of(dem);
    let mut points = PhotoPoints::default();
    for ip in forstner(interest.as_ref().unwrap_or(img), &fo) {
        // Level-L pixel i is centred on level-0 pixels 2^L·i … 2^L·i + 2^L − 1.
        let px = [(ip.x + 0.5) * f - 0.5, (ip.y + 0.5) * f - 0.5];
        let Ok(ray) = geometry::back_project(cam, pose, px) else {
            continue;
        };
        let (x, on_dem) = match dem.intersect(&ray) {
            Ok(x) => (x, true),
            Err(_) => match Band::at(&ray, band.mid()) {
                // Beyond the DEM only: a ray that misses it inside its extent is not
                // guessed at.
                Some(x) if dem.height_at(x.x, x.y).is_none() => (x, false),
                _ => continue,
            },
        };
        if footprints.is_some_and(|f| !in_footprints(&x, f)) {
            continue;
        }
        let Some(view) = ChipView::cut(cam, pose, img, px, half, Some(n)) else {
            continue;
        };
        let k = points.on_dem.len() + points.beyond.len();
        let p = ControlPoint {
            key: None,
            label: format!("tie:{}:{}", input.photos[n].name, k),
            position: x,
            sigma: [gsd, gsd, TIE_HEIGHT_SIGMA_M],
            normal: Vector3::z(),
            views: vec![view],
        };
        if on_dem {
            points.on_dem.push(p);
        } else {
            points.beyond.push(ControlPoint {
                sigma: [gsd, gsd, 0.5 * (band.hi - band.lo)],
                ..p
            });
        }
    }
    points
}

/// Whether a point falls in some photo's approximate footprint (`cam`, `pose` from its
/// navigation, off by its σ: the frame is widened by a tenth).
fn in_footprints(x: &Vector3<f64>, footprints: &[(Camera, Pose)]) -> bool {
    footprints.iter().any(|(cam, pose)| {
        let (w, h) = cam.image_size();
        let (mx, my) = (0.1 * w as f64, 0.1 * h as f64);
        geometry::project(cam, pose, x).is_ok_and(|p| {
            p.pixel.x > -mx
                && p.pixel.y > -my
                && p.pixel.x < w as f64 + mx
                && p.pixel.y < h as f64 + my
        })
    })
}

/// Chips cut from oriented photos: Förstner points (tie points), or chips at given pixels
/// (the control points as the second pass sees them in the epoch's own photos).
#[derive(Serialize, Deserialize)]
pub struct CutRound {
    /// Half size of every chip.
    half: usize,
    /// Förstner points of every photo, when tie points are cut.
    interest: Option<Interest>,
    jobs: Vec<CutJob>,
}

/// Where a [`CutRound`] looks for tie points: one per cell of `cell` px, those in one of
/// the `footprints` (all without).
#[derive(Serialize, Deserialize)]
struct Interest {
    cell: f64,
    footprints: Option<Vec<(Camera, Pose)>>,
}

/// One photo of a [`CutRound`]: its camera and pose, and the pixels chips are cut at.
#[derive(Serialize, Deserialize)]
struct CutJob {
    photo: usize,
    camera: Camera,
    pose: Pose,
    at: Vec<[f64; 2]>,
}

/// What a [`CutRound`] cut from one photo: its Förstner points, its chips at the pixels
/// asked for (`None` where a chip would leave the photo). Empty when the image cannot be
/// read.
#[derive(Default, Serialize, Deserialize)]
pub struct CutOutput {
    points: PhotoPoints,
    at: Vec<Option<ChipView>>,
}

impl CutRound {
    /// Förstner points of the oriented `photos` (one per `cell` px), those in one of the
    /// `footprints` (all without), with chips of half size `half`.
    fn interest(
        outcomes: &[PhotoOrientation],
        photos: &[usize],
        cell: f64,
        half: usize,
        footprints: Option<Vec<(Camera, Pose)>>,
    ) -> Self {
        Self {
            half,
            interest: Some(Interest { cell, footprints }),
            jobs: photos
                .iter()
                .filter_map(|&n| {
                    Some(CutJob {
                        photo: n,
                        camera: outcomes[n].camera.clone()?,
                        pose: outcomes[n].pose,
                        at: Vec::new(),
                    })
                })
                .collect(),
        }
    }

    /// Chips of half size `half` at the given pixels of oriented photos (camera, pose).
    pub(super) fn at(half: usize, jobs: Vec<(usize, Camera, Pose, Vec<[f64; 2]>)>) -> Self {
        Self {
            half,
            interest: None,
            jobs: jobs
                .into_iter()
                .map(|(photo, camera, pose, at)| CutJob {
                    photo,
                    camera,
                    pose,
                    at,
                })
                .collect(),
        }
    }
}

impl CutOutput {
    pub(super) fn into_at(self) -> Vec<Option<ChipView>> {
        self.at
    }
}

impl Round for CutRound {
    type Output = CutOutput;
    const KIND: RoundKind = RoundKind::Cut;

    fn photos(&self) -> Vec<usize> {
        self.jobs.iter().map(|j| j.photo).collect()
    }

    fn run(&self, k: usize, env: &EpochEnv) -> CutOutput {
        let j = &self.jobs[k];
        let Ok(img) = GreyImage::load(&env.input.photos[j.photo].image) else {
            return CutOutput::default();
        };
        let view = (&j.camera, &j.pose);
        CutOutput {
            points: match &self.interest {
                Some(i) => photo_points(
                    env,
                    j.photo,
                    view,
                    &img,
                    i.cell,
                    self.half,
                    i.footprints.as_deref(),
                ),
                None => PhotoPoints::default(),
            },
            at: j
                .at
                .iter()
                .map(|px| ChipView::cut(&j.camera, &j.pose, &img, *px, self.half, Some(j.photo)))
                .collect(),
        }
    }

    fn check_file(&self, photos: usize) -> Result<(), String> {
        use super::task_checks as c;
        c::at_most("chip half size", self.half, MAX_CUT_HALF)?;
        if let Some(i) = &self.interest {
            if !(i.cell.is_finite() && i.cell > 0.0) {
                return Err(format!("interest cell = {} px is not a cell size", i.cell));
            }
            for (cam, pose) in i.footprints.iter().flatten() {
                c::camera("footprint camera", cam)?;
                c::pose("footprint pose", pose)?;
            }
        }
        for j in &self.jobs {
            c::index("photo", j.photo, photos)?;
            c::camera("camera", &j.camera)?;
            c::pose("pose", &j.pose)?;
            for px in &j.at {
                c::finite("chip pixel", px)?;
            }
        }
        Ok(())
    }

    fn check_output(&self, k: usize, o: &CutOutput) -> Result<(), String> {
        use super::task_checks as c;
        let asked = self.jobs.get(k).map_or(0, |j| j.at.len());
        // An image that could not be read gives nothing at all.
        if o.at.len() != asked && !(o.at.is_empty() && o.points.is_empty()) {
            return Err(format!("{} chips for {asked} pixels asked", o.at.len()));
        }
        for v in o.at.iter().flatten() {
            c::chip_view("chip", v)?;
        }
        for p in o.points.on_dem.iter().chain(&o.points.beyond) {
            c::control_point("tie point", p)?;
        }
        Ok(())
    }
}

/// Largest chip half size a cut round may ask for (px): chips are 2·half + 1 a side, the
/// patches and tie windows of the workflow a few hundred pixels at most.
const MAX_CUT_HALF: usize = 2048;

impl PhotoPoints {
    fn is_empty(&self) -> bool {
        self.on_dem.is_empty() && self.beyond.is_empty()
    }
}

/// Tie points beyond the DEM, intersected: each point is searched in the other oriented
/// `photos` along its ray between the band's heights (the window spans the parallax of
/// the band), and kept where at least two rays agree, at their intersection with the σ
/// the rays give. These are the points a photo beyond the control is oriented from: in a
/// strip, the triple overlap of two oriented photos and the next; across strips, the side
/// lap seen by two photos of the oriented strip.
fn intersect_beyond<R: EpochRounds>(
    rounds: &R,
    env: &EpochEnv,
    outcomes: &[PhotoOrientation],
    photos: &[usize],
    points: Vec<ControlPoint>,
    band: Band,
) -> Result<Vec<(ControlPoint, TieTrack)>, R::Error> {
    if points.is_empty() {
        return Ok(Vec::new());
    }
    let floor = env.opts.sigma_floor_px;
    let store = ChipStore::from_points(Vector3::from(env.input.origin), points);
    let tracks: Vec<(usize, TieTrack)> = store
        .points
        .iter()
        .enumerate()
        .map(|(i, p)| (i, source_track(p, floor)))
        .collect();
    let (store, tracks) = extend_tracks(rounds, env, outcomes, photos, store, tracks, Some(band))?;
    // The tracks are in the store's order, one a point.
    Ok(store
        .into_points()
        .into_iter()
        .zip(tracks)
        .filter(|(_, (_, t))| t.1.len() >= 2)
        .filter_map(|(mut p, (_, (_, obs)))| {
            let (x, obs, cof) = intersect_consistent(outcomes, obs)?;
            if !(band.lo..=band.hi).contains(&x.z) {
                return None;
            }
            let gsd = p.sigma[0];
            p.position = x;
            p.sigma = [0, 1, 2].map(|k| cof[(k, k)].max(0.0).sqrt().max(gsd));
            Some((p, (x, obs)))
        })
        .collect())
}

/// The consistent rays of a track beyond the DEM: its robust intersection (each ray at
/// least [`CONSISTENCY_PX`] σ, since the poses are still single resections), the source
/// ray among the inliers, with the point's covariance (m²) from those rays and σ.
fn intersect_consistent(
    outcomes: &[PhotoOrientation],
    obs: Vec<Observation>,
) -> Option<(Vector3<f64>, Vec<Observation>, Matrix3<f64>)> {
    let rays: Vec<Ray> = obs
        .iter()
        .filter_map(|o| {
            let out = outcomes.get((o.photo as usize).checked_sub(1)?)?;
            Some(Ray {
                camera: out.camera.as_ref()?,
                pose: out.pose,
                pixel: o.pixel,
                sigma_px: o.sigma_px.max(CONSISTENCY_PX),
            })
        })
        .collect();
    if rays.len() != obs.len() {
        return None;
    }
    let r = intersect_robust(&rays, CHI2_2_999, 0)?;
    if !r.inliers[0] {
        return None;
    }
    let kept: Vec<Ray> = rays
        .iter()
        .zip(&r.inliers)
        .filter(|(_, &ok)| ok)
        .map(|(ray, _)| *ray)
        .collect();
    let refs: Vec<&Ray> = kept.iter().collect();
    let cof = intersection_cofactor(&refs, &r.position)?;
    let obs = obs
        .into_iter()
        .zip(&r.inliers)
        .filter(|(_, &ok)| ok)
        .map(|(o, _)| o)
        .collect();
    Some((r.position, obs, cof))
}

/// The σ (px) a ray of a tie beyond the DEM is at least given when its consistency with
/// the others is tested: the poses are the photos' own resections, not yet adjusted
/// together, and disagree by a fraction of a pixel where LSM measures to a tenth.
const CONSISTENCY_PX: f64 = 1.0;

/// √χ²₂(0.999): the normalised residual a consistent ray stays below.
const CHI2_2_999: f64 = 3.72;

fn observation(n: usize, px: Vector2<f64>, sigma_px: f64) -> Observation {
    Observation {
        photo: n as PhotoId + 1,
        pixel: [px.x, px.y],
        sigma_px,
        provenance: "tie".into(),
    }
}

/// Tie points among the oriented photos of the epoch: each photo's points predicted in
/// every other oriented photo and matched there, ±`window_px` around the prediction,
/// with the same alignment, NCC and LSM as the control patches (the chip is cut from the
/// source photo). Points off the DEM (roofs, trees) are still true correspondences; the
/// block adjustment intersects them anew. Points beyond the DEM are searched along their
/// ray ([`intersect_beyond`]): they tie the photos beyond the control to one another.
pub(super) fn epoch_ties<R: EpochRounds>(
    rounds: &R,
    env: &EpochEnv,
    outcomes: &[PhotoOrientation],
) -> Result<Vec<TieTrack>, R::Error> {
    let oriented: Vec<usize> = (0..outcomes.len())
        .filter(|&n| outcomes[n].report.oriented && outcomes[n].camera.is_some())
        .collect();
    if oriented.len() < 2 {
        return Ok(Vec::new());
    }
    let (on_dem, beyond) = points_of(rounds, env, outcomes, &oriented, None)?;
    let store = ChipStore::from_points(Vector3::from(env.input.origin), on_dem);
    let tracks: Vec<(usize, TieTrack)> = store
        .points
        .iter()
        .enumerate()
        .map(|(i, p)| (i, source_track(p, env.opts.sigma_floor_px)))
        .collect();
    let (_, tracks) = extend_tracks(rounds, env, outcomes, &oriented, store, tracks, None)?;
    let band = Band::of(env.dem);
    let beyond = intersect_beyond(rounds, env, outcomes, &oriented, beyond, band)?;
    Ok(tracks
        .into_iter()
        .map(|(_, t)| t)
        .filter(|t| t.1.len() >= 2)
        .chain(beyond.into_iter().map(|(_, t)| t))
        .collect())
}

/// The points of photos `photos` (on the DEM, beyond it) that fall in one of the
/// `footprints` (all without), a round of one photo's image at a time.
fn points_of<R: EpochRounds>(
    rounds: &R,
    env: &EpochEnv,
    outcomes: &[PhotoOrientation],
    photos: &[usize],
    footprints: Option<Vec<(Camera, Pose)>>,
) -> Result<(Vec<ControlPoint>, Vec<ControlPoint>), R::Error> {
    let half = env.opts.patch.template_half + 8;
    let round = CutRound::interest(outcomes, photos, env.ties.cell_px, half, footprints);
    let mut on_dem = Vec::new();
    let mut beyond = Vec::new();
    for c in rounds.run(&round, env)? {
        on_dem.extend(c.points.on_dem);
        beyond.extend(c.points.beyond);
    }
    Ok((on_dem, beyond))
}

/// Adds to each track (a point of `store` and its observations) its match in every photo
/// of `photos` that does not observe it yet: predicted from the track's position through
/// the photo's pose, searched ±`window_px`; with a `band`, the track's height is unknown
/// within it, and the search spans where the source ray's stretch between the band's
/// heights falls in the photo. A round of one photo's image at a time, so a film epoch's
/// scans are never all held at once. Gives the store back with the tracks.
#[allow(clippy::type_complexity)]
fn extend_tracks<R: EpochRounds>(
    rounds: &R,
    env: &EpochEnv,
    outcomes: &[PhotoOrientation],
    photos: &[usize],
    store: ChipStore<'static>,
    tracks: Vec<(usize, TieTrack)>,
    band: Option<Band>,
) -> Result<(ChipStore<'static>, Vec<(usize, TieTrack)>), R::Error> {
    let round = MatchRound {
        store,
        tracks,
        views: outcomes
            .iter()
            .map(|o| o.camera.clone().map(|c| (c, o.pose)))
            .collect(),
        photos: photos.to_vec(),
        band,
        ids: Vec::new(),
    };
    let found = rounds.run(&round, env)?;
    let MatchRound {
        store, mut tracks, ..
    } = round;
    for (b, matches) in photos.iter().zip(found) {
        for (k, px, s) in matches {
            tracks[k].1 .1.push(observation(*b, px, s));
        }
    }
    Ok((store, tracks))
}

/// Tracks of tie points (a point of `store` and its observations) searched in photos.
#[derive(Serialize, Deserialize)]
pub struct MatchRound {
    store: ChipStore<'static>,
    tracks: Vec<(usize, TieTrack)>,
    /// Camera and pose of every photo of the epoch that has a camera.
    views: Vec<Option<(Camera, Pose)>>,
    photos: Vec<usize>,
    band: Option<Band>,
    /// A part of a round (one photo's, [`Round::part`]): the index in the whole round of
    /// each of `tracks`, which the photo's output names. Empty: the whole round.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    ids: Vec<usize>,
}

impl MatchRound {
    /// Whether a round read from a file is whole: every track's point in the store, every
    /// photo among the views (a damaged file is an error, not an index out of range).
    pub fn check(&self) -> Result<(), String> {
        let n = self.store.points.len();
        if let Some((i, _)) = self.tracks.iter().find(|(i, _)| *i >= n) {
            return Err(format!("a track of point {i}, the store has {n} points"));
        }
        if let Some(b) = self.photos.iter().find(|&&b| b >= self.views.len()) {
            return Err(format!(
                "photo {b}, the round has {} views",
                self.views.len()
            ));
        }
        if !self.ids.is_empty() && self.ids.len() != self.tracks.len() {
            return Err(format!(
                "{} track indices for {} tracks",
                self.ids.len(),
                self.tracks.len()
            ));
        }
        Ok(())
    }

    /// The tracks searched in photo `b` (those not observed in it whose prediction falls
    /// inside it), with where.
    fn wanted(&self, b: usize, env: &EpochEnv) -> Vec<(usize, Search)> {
        let pid = b as PhotoId + 1;
        self.tracks
            .iter()
            .enumerate()
            .filter(|(_, (_, t))| t.1.iter().all(|o| o.photo != pid))
            .filter_map(|(k, (_, t))| Some((k, self.predict(b, t, env)?)))
            .collect()
    }

    /// Index of track `k` in the whole round.
    fn track_id(&self, k: usize) -> usize {
        self.ids.get(k).copied().unwrap_or(k)
    }

    /// Where track `t` is searched in photo `b` (see [`extend_tracks`]), if it falls
    /// inside it.
    fn predict(&self, b: usize, t: &TieTrack, env: &EpochEnv) -> Option<Search> {
        let (cam, pose) = self.views.get(b)?.as_ref()?;
        let margin = env.opts.patch.template_half as f64 + 1.0;
        let (px, half) = match self.band {
            None => (geometry::project(cam, pose, &t.0).ok()?.pixel, [0.0; 2]),
            Some(band) => {
                let src = t.1.first()?;
                let (sc, sp) = self
                    .views
                    .get((src.photo as usize).checked_sub(1)?)?
                    .as_ref()?;
                let ray = geometry::back_project(sc, sp, src.pixel).ok()?;
                let a = geometry::project(cam, pose, &Band::at(&ray, band.lo)?)
                    .ok()?
                    .pixel;
                let b = geometry::project(cam, pose, &Band::at(&ray, band.hi)?)
                    .ok()?
                    .pixel;
                (
                    0.5 * (a + b),
                    [0.5 * (a.x - b.x).abs(), 0.5 * (a.y - b.y).abs()],
                )
            }
        };
        let half = half.map(|v| v + env.ties.window_px);
        let (w, h) = cam.image_size();
        (px.x >= margin + half[0]
            && px.y >= margin + half[1]
            && px.x <= w as f64 - margin - half[0]
            && px.y <= h as f64 - margin - half[1])
            .then_some((px, half))
    }
}

impl Round for MatchRound {
    /// Per photo: the tracks found in it (index), with pixel and σ (px).
    type Output = Vec<(usize, Vector2<f64>, f64)>;
    const KIND: RoundKind = RoundKind::Match;

    fn photos(&self) -> Vec<usize> {
        self.photos.clone()
    }

    /// Photo `k`'s tracks and only their points: a process running that photo holds its
    /// share of the epoch's tie points, not all of them.
    fn part(&self, k: usize, env: &EpochEnv) -> Option<Self> {
        let b = *self.photos.get(k)?;
        let mut of_store: BTreeMap<usize, usize> = BTreeMap::new();
        let mut points = Vec::new();
        let mut tracks = Vec::new();
        let mut ids = Vec::new();
        for (t, _) in self.wanted(b, env) {
            let (i, track) = &self.tracks[t];
            let j = *of_store.entry(*i).or_insert_with(|| {
                points.push(self.store.points[*i].clone());
                points.len() - 1
            });
            tracks.push((j, track.clone()));
            ids.push(self.track_id(t));
        }
        Some(Self {
            store: ChipStore::from_points(self.store.origin, points),
            tracks,
            views: self.views.clone(),
            photos: vec![b],
            band: self.band,
            ids,
        })
    }

    fn run(&self, k: usize, env: &EpochEnv) -> Self::Output {
        let b = self.photos[k];
        let tie_patch = tie_match_options(&env.opts, &env.ties);
        let floor = env.opts.sigma_floor_px;
        let wanted = self.wanted(b, env);
        let mut out = Vec::new();
        let (Some((cam, pose)), false) = (
            self.views.get(b).and_then(|v| v.as_ref()),
            wanted.is_empty(),
        ) else {
            return out;
        };
        let Ok(img) = GreyImage::load(&env.input.photos[b].image) else {
            return out;
        };
        let pyr = Pyramid::from_image(img, 6, 16);
        let mut matcher = super::chips::ChipMatcher::new(cam, &pyr, &self.store, &tie_patch);
        for (k, (px, half)) in wanted {
            let (i, t) = &self.tracks[k];
            let pred = Prediction {
                pixel: px,
                covariance: nalgebra::Matrix2::identity(),
            };
            let patch = ControlPatch {
                id: *i,
                position: t.0,
                covariance: Matrix3::zeros(),
            };
            use super::orient::PatchMatcher;
            if let Some(mt) = matcher.find(&patch, pose, &pred, half) {
                out.push((self.track_id(k), mt.pixel, mt.sigma_px.max(floor)));
            }
        }
        out
    }

    fn check_file(&self, photos: usize) -> Result<(), String> {
        use super::task_checks as c;
        self.check()?;
        for &b in &self.photos {
            c::index("photo", b, photos)?;
        }
        for (cam, pose) in self.views.iter().flatten() {
            c::camera("view camera", cam)?;
            c::pose("view pose", pose)?;
        }
        if let Some(b) = self.band {
            c::finite("band", &[b.lo, b.hi])?;
            if b.lo > b.hi {
                return Err(format!("band [{}, {}] is empty", b.lo, b.hi));
            }
        }
        for p in &self.store.points {
            c::control_point("store point", p)?;
        }
        for (_, (x, obs)) in &self.tracks {
            c::point("track position", x)?;
            for o in obs {
                c::finite("track observation pixel", &o.pixel)?;
                c::sigma("track observation σ", o.sigma_px)?;
            }
        }
        Ok(())
    }

    fn check_output(&self, _k: usize, v: &Self::Output) -> Result<(), String> {
        use super::task_checks as c;
        for (t, px, s) in v {
            if self.ids.is_empty() {
                c::index("track", *t, self.tracks.len())?;
            } else if !self.ids.contains(t) {
                return Err(format!("track {t} is not a track of the round's part"));
            }
            c::pixel("track pixel", px)?;
            c::finite("track σ", &[*s])?;
            c::sigma("track σ", *s)?;
        }
        Ok(())
    }
}

/// A track holding a tie point's source observation: the Förstner point in the photo its
/// chip was cut from.
fn source_track(p: &ControlPoint, sigma_px: f64) -> TieTrack {
    let v = &p.views[0];
    (
        p.position,
        vec![observation(
            v.photo.unwrap_or(0),
            Vector2::from(v.pixel),
            sigma_px,
        )],
    )
}

/// The least-squares intersection of a track's rays through the photos' current poses.
fn intersect_track(outcomes: &[PhotoOrientation], obs: &[Observation]) -> Option<Vector3<f64>> {
    let rays: Vec<Ray> = obs
        .iter()
        .filter_map(|o| {
            let n = (o.photo as usize).checked_sub(1)?;
            let out = outcomes.get(n)?;
            Some(Ray {
                camera: out.camera.as_ref()?,
                pose: out.pose,
                pixel: o.pixel,
                sigma_px: o.sigma_px,
            })
        })
        .collect();
    if rays.len() < 2 {
        return None;
    }
    intersect_rays(&rays.iter().collect::<Vec<_>>())
}

/// Whether a photo's failure is one that points of its neighbours can help: the photo was
/// read, has a camera and navigation, and only its control was missing or weak.
fn ties_can_help(reason: Option<&PhotoFailure>) -> bool {
    match reason {
        None => false,
        Some(PhotoFailure::SecondPass { second, .. }) => ties_can_help(Some(second)),
        Some(
            PhotoFailure::NoNavigation
            | PhotoFailure::Image { .. }
            | PhotoFailure::ImageSize { .. }
            | PhotoFailure::InteriorOrientation { .. }
            | PhotoFailure::Chip { .. }
            | PhotoFailure::TiePass { .. },
        ) => false,
        Some(_) => true,
    }
}

/// The tie pass: rounds in which every photo still without an orientation that ties can
/// help is oriented from the tie points of the epoch's oriented photos that fall in its
/// approximate footprint, until a round orients none. A photo oriented so gets
/// `tie_pass` in its report and no control matches; the returned tracks (the source
/// photo's point and the new photo's match) are its observations for the adjustment. A
/// photo that fails keeps its reason, with what the tie pass found added.
pub(super) fn tie_pass<R: EpochRounds>(
    rounds: &R,
    env: &EpochEnv,
    outcomes: &mut [PhotoOrientation],
    keyed: &mut [Vec<(PointKey, Vector2<f64>, f64)>],
) -> Result<Vec<TieTrack>, R::Error> {
    let input = env.input;
    let floor = env.opts.sigma_floor_px;
    let mut tracks = Vec::new();
    let mut tried: BTreeMap<usize, PhotoFailure> = BTreeMap::new();
    loop {
        // The photos waiting, with the camera and approximate pose their footprint is
        // predicted with (a film scan's camera comes from its interior orientation).
        let waiting: Vec<(usize, Camera, Pose)> = (0..outcomes.len())
            .filter(|&i| ties_can_help(outcomes[i].report.reason.as_ref()))
            .filter_map(|i| {
                let prior = env.priors.get(&input.photos[i].name)?;
                let cam = match (&outcomes[i].camera, &input.camera) {
                    (Some(c), _) => c.clone(),
                    (None, EpochCamera::Frame(f)) => Camera::Frame(f.clone()),
                    (None, EpochCamera::Film(_)) => return None,
                };
                Some((i, cam, prior.pose()))
            })
            .collect();
        let sources: Vec<usize> = (0..outcomes.len())
            .filter(|&n| outcomes[n].report.oriented && outcomes[n].camera.is_some())
            .collect();
        if waiting.is_empty() || sources.is_empty() {
            break;
        }
        // A point is worth a chip when it falls in some waiting photo's approximate
        // footprint.
        let footprints = waiting.iter().map(|(_, c, p)| (c.clone(), *p)).collect();
        let (mut points, beyond) = points_of(rounds, env, outcomes, &sources, Some(footprints))?;
        let band = Band::of(env.dem);
        let beyond = intersect_beyond(rounds, env, outcomes, &sources, beyond, band)?;
        points.extend(beyond.into_iter().map(|(p, _)| p));
        if points.is_empty() {
            break;
        }
        let round = OrientRound {
            store: ChipStore::from_points(Vector3::from(input.origin), points),
            photos: waiting.iter().map(|(i, _, _)| *i).collect(),
            known: Vec::new(),
        };
        let results = rounds.run(&round, env)?;
        let store = round.store;
        let mut round: BTreeMap<usize, TieTrack> = BTreeMap::new();
        let mut oriented_any = false;
        for ((i, _, _), mut o) in waiting.iter().zip(results) {
            let i = *i;
            if !o.report.oriented {
                if let Some(r) = o.report.reason.take() {
                    tried.insert(i, r);
                }
                continue;
            }
            oriented_any = true;
            for (j, px, s) in &o.matches {
                let t = round
                    .entry(*j)
                    .or_insert_with(|| source_track(&store.points[*j], floor));
                t.1.push(observation(i, *px, s.max(floor)));
            }
            tracing::info!(
                epoch = input.name,
                photo = input.photos[i].name,
                ties = o.matches.len(),
                "oriented through tie points with the epoch's oriented photos"
            );
            o.report.tie_pass = true;
            o.report.control_matches = 0;
            keyed[i].clear();
            outcomes[i] = o;
        }
        // A track of the source and the new photo alone has two rays: they fix the new
        // photo's relative orientation to the source, but not its distance along the
        // base, which only the point's position gives. Every other oriented photo that
        // sees the point adds its ray, from where the two rays put it.
        let round: Vec<(usize, TieTrack)> = round
            .into_iter()
            .map(|(j, (x, obs))| (j, (intersect_track(outcomes, &obs).unwrap_or(x), obs)))
            .collect();
        let oriented: Vec<usize> = (0..outcomes.len())
            .filter(|&n| outcomes[n].report.oriented && outcomes[n].camera.is_some())
            .collect();
        let (_, round) = extend_tracks(rounds, env, outcomes, &oriented, store, round, None)?;
        tracks.extend(round.into_iter().map(|(_, t)| t));
        if !oriented_any {
            break;
        }
    }
    for (i, ties) in tried {
        let o = &mut outcomes[i];
        if o.report.oriented {
            continue;
        }
        if let Some(before) = o.report.reason.take() {
            o.report.reason = Some(PhotoFailure::TiePass {
                before: Box::new(before),
                ties: Box::new(ties),
            });
        }
    }
    Ok(tracks)
}
