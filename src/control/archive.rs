//! Orientation of an archive epoch from Digital Control Photos (seed 001 whole, seed 000
//! §2.2 (3)–(5)): every photo oriented from the control patches of the packages
//! ([`super::photo::orient_photo`]), a second pass for the photos left over with the
//! control points as the epoch's own oriented photos show them, the tie pass for those
//! still left (oriented through tie points with their oriented neighbours,
//! [`super::epoch_ties`]), optional tie points among all oriented photos, and the robust
//! archive block adjustment with rejection at k·σ0.
//! The result is the epoch's [`Block`]: every photo with its image, approximate
//! orientation, status (oriented, or failed with its reason) and provenance.

use super::chips::{ChipStore, ChipView, ControlPoint, PointKey};
use super::dcp::DcpPackage;
use super::epoch::{
    approximate_orientations, EpochCamera, EpochError, EpochInput, NavigationSigma, PhotoInput,
};
use super::epoch_ties::CutRound;
use super::epoch_ties::{epoch_ties, tie_pass};
use super::photo::{
    orient_photo, search_area, KnownPose, PhotoOptions, PhotoOrientation, PhotoReport,
    KNOWN_POSE_MIN_MATCHES,
};
use super::rounds::{EpochEnv, EpochRounds, InMemory, OrientRound, Round};
use super::scan_cameras::ScanCameras;
use crate::adjust::support::{take_unsupported, MIN_POINTS_PER_PHOTO};
use crate::adjust::{self, AdjustOptions, AdjustReport, Loss, Rejection};
use crate::block::{
    Block, BlockCamera, ObjectPoint, Observation, Photo, PhotoFailure, PhotoId, PhotoStatus,
    PointKind,
};
use crate::formats::crs::Crs;
use crate::geometry::{Camera, Dem};
use nalgebra::{Vector2, Vector3};
use rayon::prelude::*;
use serde::Serialize;
use std::collections::BTreeMap;
use std::time::Instant;

/// Options of [`orient_epoch`].
#[derive(Debug, Clone)]
pub struct ArchiveOptions {
    pub photo: PhotoOptions,
    pub navigation: NavigationSigma,
    /// Rejection in the block adjustment at k·σ0 (seed 000: 2–3).
    pub reject_k: f64,
    pub loss: Loss,
    /// Interior parameters of frame cameras adjusted with the block (archive cameras are
    /// rarely calibrated: the focal length too, since its error goes straight into the
    /// heights, H·Δf/f); empty = fixed.
    pub self_calibration: Vec<String>,
    /// Interior parameters of a film camera adjusted with the block (`f_mm`, `x0_mm`,
    /// `y0_mm`, `k1`…): one value for every scan, each scan keeping its own fiducial
    /// interior orientation (one calibration group). Empty = the certificate holds.
    pub film_self_calibration: Vec<String>,
    /// Photos not oriented from the packages try again with the control points as the
    /// epoch's own oriented photos show them.
    pub epoch_second_pass: bool,
    /// Photos that neither pass oriented are oriented through tie points with the epoch's
    /// oriented photos ([`super::epoch_ties::tie_pass`]), one per `tie_interval_px` cell
    /// of the source photo, and held by them in the block adjustment.
    pub tie_pass: bool,
    /// Image tie points among the oriented photos of the epoch in the block adjustment,
    /// one per `tie_interval_px` cell, searched ±`tie_window_px` around their prediction
    /// (the tie pass uses the same interval, window and NCC threshold). They hold the
    /// photos whose control patches cluster in part of the frame: on the small preset,
    /// seeds 1–10, the digital epoch's worst checkpoint height went from 1.78 to
    /// 0.73 GSD with them, the film's worst from 0.34 to 0.39 (bench accuracy).
    pub ties: bool,
    /// 25 px by default: a 1000 × 666 frame then carries up to 40 × 27 points, about one
    /// a matching template (31 px), the densest spacing at which neighbouring points'
    /// templates stay mostly their own. The self-calibration and the epoch's surface rest
    /// on them. From 50 px (small seeds 1–10, pipeline runs, `benches/dense_epochs.rs
    /// --run`) the digital epoch's worst checkpoint height went from 0.86 to 0.73 GSD
    /// (mean 0.59 → 0.54), its DSM's worst |median| from 0.76 to 0.37 GSD (mean 0.27 →
    /// 0.18) and worst NMAD from 1.18 to 1.04, run time unchanged (49.1 s both, seed 6);
    /// the median still follows each run's checkpoint height error (formats/dsm/); every
    /// photo of every seed oriented. From 100 to 50 px the worst checkpoint height had gone
    /// from 1.40 to 0.78 GSD (`bench accuracy`, seeds 1–10, other runs than those above;
    /// at 100 px, 5 of seed 10's 6 photos were short at a standard position). A film scan
    /// stays capped at `MAX_POINTS_PER_SIDE` a side.
    pub tie_interval_px: f64,
    pub tie_window_px: f64,
    pub tie_ncc_threshold: f64,
}

impl Default for ArchiveOptions {
    fn default() -> Self {
        Self {
            photo: PhotoOptions::default(),
            navigation: NavigationSigma::default(),
            reject_k: 2.5,
            loss: Loss::Huber(2.0),
            self_calibration: vec!["fx".into(), "fy".into(), "k1".into(), "k2".into()],
            film_self_calibration: Vec::new(),
            epoch_second_pass: true,
            tie_pass: true,
            ties: true,
            tie_interval_px: 25.0,
            tie_window_px: 10.0,
            tie_ncc_threshold: 0.8,
        }
    }
}

/// An oriented epoch.
#[derive(Debug, Clone, Serialize)]
pub struct EpochResult {
    pub epoch: String,
    /// Every photo (block-local, `block.origin`) with its status and image; the DCP
    /// control points and tie points with their observations, after the adjustment.
    #[serde(skip)]
    pub block: Block,
    pub photos: Vec<PhotoReport>,
    pub adjustment: Option<AdjustReport>,
    /// Mean ground pixel of the oriented photos (m).
    pub gsd_m: f64,
    pub time_s: f64,
}

impl EpochResult {
    pub fn oriented_fraction(&self) -> f64 {
        if self.photos.is_empty() {
            return 0.0;
        }
        self.photos.iter().filter(|p| p.oriented).count() as f64 / self.photos.len() as f64
    }
}

/// What the per-photo work of an archive epoch shares: the control points of the
/// packages and the photos' approximate orientations. Built the same way in the process
/// that adjusts the epoch and in every process that orients one of its photos (a
/// distributed run), so a photo's match indices mean the same point everywhere.
pub struct ArchiveContext<'a> {
    pub store: ChipStore<'a>,
    pub priors: BTreeMap<String, crate::block::PosPrior>,
    photo_opts: PhotoOptions,
}

/// The interior parameters the epoch's adjustment self-calibrates.
fn self_calibrated<'o>(input: &EpochInput, opts: &'o ArchiveOptions) -> &'o [String] {
    match &input.camera {
        EpochCamera::Frame(_) => &opts.self_calibration,
        EpochCamera::Film(_) => &opts.film_self_calibration,
    }
}

impl<'a> ArchiveContext<'a> {
    /// Checks the packages against the epoch (CRS, any at all) and gathers their points.
    pub fn new(
        input: &EpochInput,
        dcp: &'a [DcpPackage],
        dem: &Dem,
        opts: &ArchiveOptions,
    ) -> Result<Self, EpochError> {
        let ep = |message: String| EpochError::Epoch {
            epoch: input.name.clone(),
            message,
        };
        if dcp.is_empty() {
            return Err(ep("no DCP package given".into()));
        }
        if input.photos.is_empty() {
            return Err(ep("no photo given".into()));
        }
        let crs = Crs::parse(&input.crs).map_err(|e| ep(format!("CRS: {e}")))?;
        for p in dcp {
            let c = Crs::parse(&p.manifest.crs).map_err(|e| ep(e.to_string()))?;
            if c.label() != crs.label() {
                return Err(ep(format!(
                    "DCP package {} is in {}, the epoch in {}",
                    p.dir.display(),
                    c.label(),
                    crs.label()
                )));
            }
        }
        let store = ChipStore::from_packages(dcp, Vector3::from(input.origin));
        let priors = approximate_orientations(input, dem, &opts.navigation)?;
        let mut photo_opts = opts.photo.clone();
        photo_opts.focal_free = self_calibrated(input, opts)
            .iter()
            .any(|p| matches!(p.as_str(), "f_mm" | "fx" | "fy"));
        if let Some(um) = input.scan_pixel_um {
            photo_opts.io.pixel_mm = Some(um / 1000.0);
        }
        Ok(Self {
            store,
            priors,
            photo_opts,
        })
    }

    /// The photo options of the epoch; a film epoch's undecided scans take the majority
    /// orientation of its measured scans unless the epoch fixes one.
    pub fn photo_options(&self, scans: Option<&ScanCameras>) -> PhotoOptions {
        let mut o = self.photo_opts.clone();
        if let Some(s) = scans {
            if o.io.orientation.is_none() {
                o.io.fallback_orientation = s.majority;
            }
        }
        o
    }

    /// The photo options the epoch's scans are measured with (before any majority).
    pub fn io_options(&self) -> &crate::matching::IoOptions {
        &self.photo_opts.io
    }

    /// The first orientation of one photo of the epoch from the control patches.
    pub fn orient(
        &self,
        photo: &PhotoInput,
        camera: &EpochCamera,
        dem: &Dem,
        scans: Option<&ScanCameras>,
    ) -> PhotoOrientation {
        orient_photo(
            photo,
            camera,
            self.priors.get(&photo.name),
            &self.store,
            dem,
            &self.photo_options(scans),
            scans,
        )
    }
}

/// The per-photo part of an archive epoch: the film scans measured (`None` for a frame
/// camera) and every photo's first orientation, in the order of the epoch's photos.
pub struct FirstPass {
    pub scans: Option<ScanCameras>,
    pub outcomes: Vec<PhotoOrientation>,
}

/// The per-photo part of an archive epoch in this process (rayon over the photos).
pub fn first_pass(input: &EpochInput, ctx: &ArchiveContext, dem: &Dem) -> FirstPass {
    let scans = match &input.camera {
        EpochCamera::Film(def) => Some(ScanCameras::measure(def, &input.photos, ctx.io_options())),
        EpochCamera::Frame(_) => None,
    };
    // Each photo's end as a progress event (target `cloudcontrol::progress`, as the
    // pipeline's tasks and rounds give them: the CLI's per-photo progress).
    let (span, done) = (
        tracing::Span::current(),
        std::sync::atomic::AtomicUsize::new(0),
    );
    let outcomes = input
        .photos
        .par_iter()
        .map(|ph| {
            let _in = span.enter();
            let o = ctx.orient(ph, &input.camera, dem, scans.as_ref());
            tracing::info!(
                target: "cloudcontrol::progress",
                work = "orient",
                item = %ph.name,
                done = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1,
                total = input.photos.len(),
            );
            o
        })
        .collect();
    FirstPass { scans, outcomes }
}

/// Orients an archive epoch from DCP packages over a DEM (block-local coordinates with the
/// epoch's origin): per-photo orientation, the second pass, then the robust archive block
/// adjustment of all oriented photos with the DCP control (object σ from the packages).
pub fn orient_epoch(
    input: &EpochInput,
    dcp: &[DcpPackage],
    dem: &Dem,
    opts: &ArchiveOptions,
) -> Result<EpochResult, EpochError> {
    let t0 = Instant::now();
    let ctx = ArchiveContext::new(input, dcp, dem, opts)?;
    let first = first_pass(input, &ctx, dem);
    finish_epoch(input, &ctx, dem, opts, first, t0, &InMemory)
}

/// The epoch-wide part of an archive epoch after its per-photo part (`first`, made here
/// or by per-photo tasks elsewhere): the second pass, the tie pass, tie points and the
/// block adjustment, the per-photo work of each pass a round of `rounds`. `t0` is when the
/// epoch started (its reported time).
pub fn finish_epoch<R: EpochRounds>(
    input: &EpochInput,
    ctx: &ArchiveContext,
    dem: &Dem,
    opts: &ArchiveOptions,
    first: FirstPass,
    t0: Instant,
    rounds: &R,
) -> Result<EpochResult, R::Error> {
    let ep = |message: String| EpochError::Epoch {
        epoch: input.name.clone(),
        message,
    };
    if first.outcomes.len() != input.photos.len() {
        return Err(ep(format!(
            "{} per-photo results for {} photos",
            first.outcomes.len(),
            input.photos.len()
        ))
        .into());
    }
    let FirstPass {
        scans,
        mut outcomes,
    } = first;
    let (store, priors) = (&ctx.store, &ctx.priors);
    let env = EpochEnv::new(
        input,
        dem,
        priors,
        ctx.photo_options(scans.as_ref()),
        opts,
        scans.as_ref(),
    );
    // A damaged package is an input error of the epoch, not a photo's misfortune.
    if let Some(e) = outcomes.iter().find_map(|o| match &o.report.reason {
        Some(r @ PhotoFailure::Chip { .. }) => Some(r.to_string()),
        _ => None,
    }) {
        return Err(ep(e).into());
    }
    // Matches refer to DCP points from here on.
    let mut keyed: Vec<Vec<(PointKey, Vector2<f64>, f64)>> =
        outcomes.iter().map(|o| store.keyed(&o.matches)).collect();
    if opts.epoch_second_pass {
        second_pass(rounds, &env, store, &mut outcomes, &mut keyed)?;
    }
    let pass_ties = if opts.tie_pass {
        let ties = tie_pass(rounds, &env, &mut outcomes, &mut keyed)?;
        control_after_ties(rounds, &env, store, &mut outcomes, &mut keyed)?;
        ties
    } else {
        Vec::new()
    };

    // The archive block: oriented photos, DCP control points with all their matches.
    let mut block = Block {
        crs: Some(input.crs.clone()),
        origin: input.origin,
        ..Block::default()
    };
    let free = self_calibrated(input, opts).to_vec();
    let mut control: BTreeMap<PointKey, Vec<Observation>> = BTreeMap::new();
    for (n, (o, ph)) in outcomes.iter().zip(&input.photos).enumerate() {
        let (true, Some(cam)) = (o.report.oriented, &o.camera) else {
            continue;
        };
        let pid = n as PhotoId + 1;
        add_photo(&mut block, input, n, o, cam, &free, priors.get(&ph.name));
        for (key, px, s) in &keyed[n] {
            control.entry(*key).or_default().push(Observation {
                photo: pid,
                pixel: [px.x, px.y],
                sigma_px: s.max(opts.photo.sigma_floor_px),
                provenance: "dcp".into(),
            });
        }
    }
    for (key, obs) in control {
        let id = block.next_point_id();
        let p = store
            .points
            .iter()
            .find(|p| p.key == Some(key))
            .expect("every match refers to a point of the store");
        block.points.insert(
            id,
            ObjectPoint {
                id,
                name: p.label.clone(),
                kind: PointKind::Control,
                position: p.position,
                sigma: Some(p.sigma),
                color: [0; 3],
                observations: obs,
            },
        );
    }
    let mut ties = pass_ties;
    if opts.ties {
        let among = epoch_ties(rounds, &env, &outcomes)?;
        tracing::info!(
            epoch = input.name,
            ties = among.len(),
            "tie points among the epoch's photos"
        );
        ties.extend(among);
    }
    for (x, obs) in ties {
        let id = block.next_point_id();
        block.points.insert(
            id,
            ObjectPoint {
                id,
                name: String::new(),
                kind: PointKind::Tie,
                position: x,
                sigma: None,
                color: [0; 3],
                observations: obs,
            },
        );
    }
    let mut photos: Vec<PhotoReport> = outcomes.iter().map(|o| o.report.clone()).collect();
    // A resected photo whose points the block cannot use (too few control points and tie
    // points with a second ray) is left out of the adjustment, not oriented, with its count.
    let mut lost = Vec::new();
    for (mut ph, points) in take_unsupported(&mut block, MIN_POINTS_PER_PHOTO) {
        let reason = PhotoFailure::LostSupport {
            points,
            needed: MIN_POINTS_PER_PHOTO,
        };
        tracing::warn!(epoch = %input.name, photo = %ph.name, points, "photo left out of the adjustment");
        if let Some(r) = photos.iter_mut().find(|r| r.name == ph.name) {
            r.oriented = false;
            r.reason = Some(reason.clone());
        }
        ph.status = PhotoStatus::Failed(reason);
        lost.push(ph);
    }
    // A single oriented photo keeps its resection: there is nothing to adjust jointly.
    let adjustment = if block.photos.len() < 2 {
        None
    } else {
        // Self-calibration needs more observations than a resection's handful per photo
        // (a photo's six unknowns and the camera's four shared ones). At 12 per photo the
        // small block's 6-photo digital epochs (≈ 10 control points a photo) were mostly
        // left uncalibrated, and seed 4's archive camera (f 0.16 % long, k1 −0.057) put its
        // checkpoints 5.15 GSD off in height; at 8, 0.49 GSD (bench accuracy, seeds 1–10).
        if block.num_observations() < 8 * block.photos.len() {
            for c in block.cameras.values_mut() {
                c.free_params.clear();
            }
        }
        // No LiDAR planes on the archive block's tie points (the reference's
        // `LidarPlanes`: ground and building points, σ 5 cm, gate 0.5 or 1 m, their common
        // datum offset σ 5 cm or free). On small seeds 1–5 they held the digital epoch's
        // tie points within 4 cm (NMAD) of its true surface, yet its DSM, matched on the
        // same photos, came out 0.19–0.69 GSD low (median of every seed with the offset's
        // σ 5 cm; seed 2 still −0.65 with it free; +0.02 to +0.17 without planes) and
        // 8–10 cm below its tie and control points (seed 2): the rays disagree with the
        // planes through a camera model the block cannot free (focal length correlated
        // 0.998 with the camera heights, k2 and the principal point not significant). The
        // film epoch, with 30–70 tie points near a plane, lost (centres RMS 0.5 → 3.5–4.5 m,
        // seed 3). `benches/dense_epochs.rs --run` measured each variant.
        let aopts = AdjustOptions {
            loss: opts.loss,
            rejection: Rejection::Threshold(opts.reject_k),
            max_rounds: 20,
            ..AdjustOptions::default()
        };
        let rep = adjust::adjust_determinable(&mut block, &aopts).map_err(|source| {
            EpochError::Adjust {
                epoch: input.name.clone(),
                source,
            }
        })?;
        for pr in &rep.photo_precision {
            if let Some(r) = photos.iter_mut().find(|r| r.name == pr.name) {
                r.sigma_px = pr.rmse_px;
            }
            if let Some(p) = block.photos.get_mut(&pr.photo) {
                p.provenance.push_str("; block adjustment");
            }
        }
        Some(rep)
    };
    // The photos that were not oriented join the block with their approximate pose and
    // their reason, after the adjustment that must not see them.
    for (n, (o, ph)) in outcomes.iter().zip(&input.photos).enumerate() {
        if o.report.oriented {
            continue;
        }
        let pid = n as PhotoId + 1;
        let cam = match (&input.camera, &o.camera) {
            (_, Some(c)) => Some((
                if matches!(c, Camera::Film(_)) { pid } else { 1 },
                c.clone(),
            )),
            (EpochCamera::Frame(f), None) => Some((1, Camera::Frame(f.clone()))),
            // A scan without interior orientation has no camera to hold it.
            (EpochCamera::Film(_), None) => None,
        };
        let Some((cid, model)) = cam else { continue };
        block.cameras.entry(cid).or_insert_with(|| BlockCamera {
            id: cid,
            name: format!("{}_{cid}", input.name),
            model,
            free_params: Vec::new(),
            calibration_group: None,
        });
        let mut photo = Photo::new(pid, ph.name.clone(), cid, o.pose);
        photo.status = PhotoStatus::Failed(
            o.report
                .reason
                .clone()
                .unwrap_or(PhotoFailure::NoNavigation),
        );
        photo.prior = priors.get(&ph.name).copied();
        photo.date = input.date.clone();
        photo.image = Some(ph.image.clone());
        photo.provenance = "approximate (navigation)".into();
        block.photos.insert(pid, photo);
    }
    for ph in lost {
        block.photos.insert(ph.id, ph);
    }
    let gsd_m = mean_gsd(&block, dem);
    Ok(EpochResult {
        epoch: input.name.clone(),
        block,
        photos,
        adjustment,
        gsd_m,
        time_s: t0.elapsed().as_secs_f64(),
    })
}

/// Adds an oriented photo (epoch photo `n`) and its camera to the block: film scans each
/// have their own interior orientation, frame photos share one camera.
fn add_photo(
    block: &mut Block,
    input: &EpochInput,
    n: usize,
    o: &PhotoOrientation,
    cam: &Camera,
    free: &[String],
    prior: Option<&crate::block::PosPrior>,
) {
    let pid = n as PhotoId + 1;
    let cid = match cam {
        Camera::Film(_) => pid,
        Camera::Frame(_) => 1,
    };
    block.cameras.entry(cid).or_insert_with(|| BlockCamera {
        id: cid,
        name: format!("{}_{cid}", input.name),
        model: cam.clone(),
        free_params: free.to_vec(),
        // Every scan is the one film camera behind them.
        calibration_group: matches!(cam, Camera::Film(_))
            .then(|| format!("{} film camera", input.name)),
    });
    let mut photo = Photo::new(pid, input.photos[n].name.clone(), cid, o.pose).oriented();
    photo.date = input.date.clone();
    photo.image = Some(input.photos[n].image.clone());
    // The navigation enters the adjustment with its stated σ (GNSS/IMU-assisted
    // triangulation): weak beside the control points, it holds a photo whose control is
    // thin. On the small block's film epoch it brought the centres from 0.91 to 0.44 m of
    // the truth (tests of bindings/python/tests/test_orient_photo.py, seed 2).
    photo.prior = prior.copied();
    photo.provenance = if o.report.tie_pass {
        format!(
            "resection from {} tie points with the epoch's oriented photos (tie pass){}",
            o.matches.len(),
            match o.report.control_matches {
                0 => String::new(),
                n => format!(", then {n} control patches found from that pose"),
            }
        )
    } else {
        format!(
            "resection from {} control patches{}{}",
            o.report.control_matches,
            if o.report.relaxed {
                " (relaxed retry)"
            } else {
                ""
            },
            if o.report.second_pass {
                " (second pass, chips of the epoch's own photos)"
            } else {
                ""
            }
        )
    };
    block.photos.insert(pid, photo);
}

/// Photos left unoriented (scene change, ambiguity) try again with the control points as
/// the epoch's own oriented photos show them — same scene state, same radiometry, similar
/// scale — with chips cut from those photos (a round), then a round orienting them.
fn second_pass<R: EpochRounds>(
    rounds: &R,
    env: &EpochEnv,
    store: &ChipStore,
    outcomes: &mut [PhotoOrientation],
    keyed: &mut [Vec<(PointKey, Vector2<f64>, f64)>],
) -> Result<(), R::Error> {
    let unoriented: Vec<usize> = (0..outcomes.len())
        .filter(|&i| !outcomes[i].report.oriented)
        .collect();
    if unoriented.is_empty() || !outcomes.iter().any(|o| o.report.oriented) {
        return Ok(());
    }
    // Same epoch, similar scale: the chip needs little more than the largest template.
    let half = env.opts.patch.template_half + 8;
    let jobs: Vec<(usize, Camera, crate::geometry::Pose, Vec<[f64; 2]>)> = outcomes
        .iter()
        .enumerate()
        .filter(|(_, o)| o.report.oriented)
        .filter_map(|(n, o)| {
            let at = keyed[n].iter().map(|(_, px, _)| [px.x, px.y]).collect();
            Some((n, o.camera.clone()?, o.pose, at))
        })
        .collect();
    let cut = CutRound::at(half, jobs);
    let mut seen: BTreeMap<PointKey, Vec<ChipView>> = BTreeMap::new();
    for (n, views) in Round::photos(&cut).into_iter().zip(rounds.run(&cut, env)?) {
        for ((key, _, _), v) in keyed[n].iter().zip(views.into_at()) {
            if let Some(v) = v {
                seen.entry(*key).or_default().push(v);
            }
        }
    }
    let points: Vec<ControlPoint> = seen
        .into_iter()
        .filter_map(|(key, views)| {
            let p = store.points.iter().find(|p| p.key == Some(key))?;
            Some(ControlPoint { views, ..p.clone() })
        })
        .collect();
    if points.is_empty() {
        return Ok(());
    }
    let round = OrientRound {
        store: ChipStore::from_points(store.origin, points),
        photos: unoriented,
        known: Vec::new(),
    };
    let retried = rounds.run(&round, env)?;
    let own = &round.store;
    for (&i, mut o) in round.photos.iter().zip(retried) {
        if o.report.oriented {
            keyed[i] = own.keyed(&o.matches);
            o.report.second_pass = true;
            outcomes[i] = o;
        } else if let (Some(first), Some(second)) =
            (outcomes[i].report.reason.clone(), o.report.reason)
        {
            outcomes[i].report.reason = Some(PhotoFailure::SecondPass {
                first: Box::new(first),
                second: Box::new(second),
            });
        }
    }
    Ok(())
}

/// Photos the tie pass oriented found no control of their own from their navigation (too
/// few matches for a resection, or a resection the navigation refuted). From the pose the
/// ties gave them, in windows of that pose's σ, the control patches of their ground are
/// searched again; those found join the adjustment as the photo's control. Held by tie
/// points alone, a photo hangs on its neighbours' relative orientation, and nothing holds
/// the heights of what it sees against a tilt: the small preset's digital epochs with such
/// a photo went from 0.65 to 0.43 GSD of checkpoint height RMSE (seed 9, 8 patches found)
/// and from 0.55 to 0.47 (seed 5, 5 patches).
fn control_after_ties<R: EpochRounds>(
    rounds: &R,
    env: &EpochEnv,
    store: &ChipStore,
    outcomes: &mut [PhotoOrientation],
    keyed: &mut [Vec<(PointKey, Vector2<f64>, f64)>],
) -> Result<(), R::Error> {
    let mut todo: Vec<(usize, KnownPose, Vec<usize>)> = Vec::new();
    for (i, o) in outcomes.iter().enumerate() {
        let (true, true, Some(camera)) = (o.report.oriented, o.report.tie_pass, &o.camera) else {
            continue;
        };
        // A footprint the DEM cannot give, or ground with fewer control points than could
        // count, leaves the photo as the tie pass made it, its image not read again (the
        // large preset's film frames beyond the LiDAR: 72 of 80 through ties, 0 patches).
        let Ok(area) = search_area(camera, &o.pose, &o.covariance, env.dem) else {
            continue;
        };
        let near = store.query_polygon(&area);
        if near.len() < KNOWN_POSE_MIN_MATCHES {
            continue;
        }
        let known = KnownPose {
            camera: camera.clone(),
            io: o.report.io.clone(),
            pose: o.pose,
            covariance: o.covariance,
        };
        let cells = CONTROL_AFTER_TIES_CELLS;
        let near = if near.len() > cells * cells {
            store.spread(&near, cells)
        } else {
            near
        };
        todo.push((i, known, near));
    }
    // The round carries its chips in memory: a few photos at a time, each with its
    // points spread over its ground, keep that bounded where the DCPs are dense.
    for batch in todo.chunks(CONTROL_AFTER_TIES_BATCH) {
        let wanted: std::collections::BTreeSet<usize> = batch
            .iter()
            .flat_map(|(_, _, near)| near.iter().copied())
            .collect();
        let indices: Vec<usize> = wanted.into_iter().collect();
        // A damaged package is an input error of the epoch, as in the first pass.
        let own = store.owned(&indices).map_err(|e| EpochError::Epoch {
            epoch: env.input.name.clone(),
            message: e.to_string(),
        })?;
        let round = OrientRound {
            store: own,
            photos: batch.iter().map(|(i, _, _)| *i).collect(),
            known: batch.iter().map(|(_, k, _)| k.clone()).collect(),
        };
        let results = rounds.run(&round, env)?;
        for (&i, o) in round.photos.iter().zip(results) {
            let name = &env.input.photos[i].name;
            if !o.report.oriented {
                tracing::debug!(epoch = %env.input.name, photo = %name, reason = ?o.report.reason, "no control from the tie pass's pose");
                continue;
            }
            keyed[i] = round.store.keyed(&o.matches);
            outcomes[i].report.control_matches = keyed[i].len();
            tracing::info!(epoch = %env.input.name, photo = %name, control = keyed[i].len(), "control patches found from the tie pass's pose");
        }
    }
    Ok(())
}

/// The control pass after the tie pass takes, of more than 144 points on a photo's
/// ground, one per cell of this many a side (the 6-photo digital epochs' photos hold 8–25
/// of their own), and runs this many photos a round: a round's chips are in memory,
/// about 0.2 MB a view, so at most some 8 · 144 · 3 views ≈ 0.7 GB where the DCPs are
/// dense (the large preset's reference package holds 7,063 points with 23,476 views).
const CONTROL_AFTER_TIES_CELLS: usize = 12;
const CONTROL_AFTER_TIES_BATCH: usize = 8;

/// Ground pixel (m) of a photo: its height above the DEM under its centre (the DEM's
/// middle height where it has none) over the focal length in pixels.
pub(crate) fn ground_pixel(cam: &Camera, pose: &crate::geometry::Pose, dem: &Dem) -> f64 {
    let (z0, z1) = dem.z_range();
    let g = dem
        .height_at(pose.center.x, pose.center.y)
        .unwrap_or(0.5 * (z0 + z1));
    (pose.center.z - g).abs() / cam.focal_px()
}

/// Mean ground pixel (m) of a block's oriented photos over a DEM: flying height above the
/// ground under the projection centre over the focal length in pixels.
pub fn mean_gsd(block: &Block, dem: &Dem) -> f64 {
    // The oriented photos' poses, or the approximate ones when none could be oriented
    // (the ground pixel is the flight's, known to a few percent from its navigation).
    let any_oriented = block.photos.values().any(|p| p.is_oriented());
    let v: Vec<f64> = block
        .photos
        .values()
        .filter(|p| p.is_oriented() || !any_oriented)
        .filter_map(|p| {
            Some(ground_pixel(
                &block.cameras.get(&p.camera)?.model,
                &p.pose,
                dem,
            ))
        })
        .collect();
    if v.is_empty() {
        f64::NAN
    } else {
        v.iter().sum::<f64>() / v.len() as f64
    }
}
