//! Orientation of the reference epoch against the LiDAR alone (seed 000 §2.2 (1)–(3)):
//! tie points guided by the POS over the LiDAR DEM, a first adjustment on the POS,
//! point-to-plane ICP of the tie points onto the LiDAR (7-parameter similarity applied to
//! the whole block), then the bundle adjustment with LiDAR point-to-plane constraints
//! (planes re-fitted between rounds, weights from their coplanarity), POS priors and
//! self-calibration. No surveyed point enters: checkpoints only evaluate the result.
//!
//! The result is an [`EpochResult`] like an archive epoch's, so DCP export, outputs and
//! the report treat every epoch alike.

use super::archive::{mean_gsd, EpochResult};
use super::epoch::{EpochCamera, EpochError, EpochInput, Navigation};
use super::photo::PhotoReport;
use crate::adjust::support::{take_unsupported, MIN_POINTS_PER_PHOTO};
use crate::adjust::{self, AdjustOptions, AdjustReport, PlaneConstraint, PlaneRefitter, Rejection};
use crate::block::{
    Block, BlockCamera, Photo, PhotoFailure, PhotoId, PhotoStatus, PointId, PointKind, PosPrior,
};
use crate::formats::pos::photo_key;
use crate::geometry::{matrix_from_opk, Camera, Dem, Pose, Similarity};
use crate::lidar::{icp_point_to_plane, IcpOptions, IcpResult, PlaneIndex};
use crate::matching::oriented::{
    write_ties, BlockTieOptions, BlockTieReport, OrientedPhoto, Surface, TiePhotos,
};
use crate::matching::pair_matching::{
    plan_pairs, InMemory, MatchedPairs, PairMatching, PhotoPairs,
};
use crate::matching::Pixels;
use nalgebra::Vector3;
use rayon::prelude::*;
use serde::Serialize;
use std::collections::{BTreeMap, BTreeSet};
use std::time::Instant;

/// σ of a LiDAR survey's datum (m, per axis) when its report states none: the absolute
/// accuracy airborne LiDAR is commonly delivered with after strip adjustment (USGS 3DEP
/// QL1/QL2 ask RMSE_z ≤ 10 cm; 5 cm is the usual figure).
pub const DEFAULT_LIDAR_DATUM_SIGMA_M: f64 = 0.05;

/// Options of [`orient_reference`].
#[derive(Debug, Clone)]
pub struct ReferenceOptions {
    pub ties: BlockTieOptions,
    /// Tie points wanted near each standard position of a photo that lies in an overlap.
    pub min_per_position: usize,
    /// σ of the height of the DEM the tie search is predicted over (m).
    pub dem_sigma_m: f64,
    /// Point-to-plane ICP of the tie points onto the LiDAR before the final adjustment
    /// (None: the POS alone places the block).
    pub icp: Option<IcpOptions>,
    /// σ of a LiDAR plane as a surface (m): noise and strip residuals. A plane's weight is
    /// its coplanarity weight / σ².
    pub lidar_sigma_m: f64,
    /// Tie points farther than this from their plane get no constraint (m): they are on
    /// something the LiDAR does not describe (cars, edges, mismatches).
    pub plane_gate_m: f64,
    pub adjust: AdjustOptions,
    /// Interior parameters adjusted with the block (self-calibration).
    pub self_calibration: Vec<String>,
    /// A photo counts as oriented with at least this many tie observations kept.
    pub min_observations: usize,
}

impl Default for ReferenceOptions {
    fn default() -> Self {
        Self {
            ties: BlockTieOptions::default(),
            min_per_position: 3,
            dem_sigma_m: 0.5,
            icp: Some(IcpOptions {
                initial_gate: 5.0,
                min_gate: 0.25,
                // Tie points are far sparser and noisier than LiDAR: directions only a few
                // walls and roofs determine are left to the bundle adjustment.
                min_eigenvalue_ratio: 2e-2,
                ..IcpOptions::default()
            }),
            lidar_sigma_m: 0.05,
            plane_gate_m: 0.5,
            adjust: AdjustOptions {
                rejection: Rejection::DataSnooping(3.29),
                lidar_datum_sigma_m: Some([DEFAULT_LIDAR_DATUM_SIGMA_M; 3]),
                ..AdjustOptions::default()
            },
            self_calibration: Vec::new(),
            min_observations: 12,
        }
    }
}

/// ICP of the tie points onto the LiDAR, for the report.
#[derive(Debug, Clone, Serialize)]
pub struct IcpSummary {
    pub scale: f64,
    /// Rotation angle of the similarity (degrees).
    pub rotation_deg: f64,
    pub translation_m: [f64; 3],
    pub rmse_m: f64,
    pub inliers: usize,
    pub converged: bool,
    pub degenerate_directions: usize,
    pub iterations: Vec<crate::lidar::IcpIteration>,
}

/// What the reference orientation did, beyond the adjustment report.
#[derive(Debug, Clone, Serialize)]
pub struct ReferenceReport {
    pub ties: BlockTieReport,
    /// Adjustment on the POS alone (before ICP and planes).
    pub pos_adjustment: AdjustReport,
    pub icp: Option<IcpSummary>,
    /// Tie points with a LiDAR plane constraint in the final adjustment.
    pub plane_constraints: usize,
}

/// LiDAR planes for the adjustment: each tie point's plane is re-fitted at its current
/// position from the LiDAR (block-local; the index's origin is the block's).
pub struct LidarPlanes<'a> {
    pub index: &'a PlaneIndex,
    pub sigma_m: f64,
    pub gate_m: f64,
    /// Only these points are constrained (tie points).
    pub points: BTreeSet<PointId>,
}

impl PlaneRefitter for LidarPlanes<'_> {
    fn refit(&mut self, points: &[(PointId, Vector3<f64>)]) -> Vec<PlaneConstraint> {
        let w0 = 1.0 / (self.sigma_m * self.sigma_m);
        points
            .par_iter()
            .filter(|(id, _)| self.points.contains(id))
            .filter_map(|(id, x)| {
                let pl = self.index.plane_at(x)?;
                (pl.distance(x).abs() <= self.gate_m).then(|| PlaneConstraint {
                    point: *id,
                    normal: pl.normal.into(),
                    d: pl.normal.dot(&pl.centroid),
                    weight: pl.weight * w0,
                })
            })
            .collect()
    }
}

/// Block of the reference epoch at its POS (block-local), every photo with its prior.
fn pos_block(input: &EpochInput) -> Result<Block, EpochError> {
    let ep = |message: String| EpochError::Epoch {
        epoch: input.name.clone(),
        message,
    };
    let EpochCamera::Frame(frame) = &input.camera else {
        return Err(ep(
            "the reference epoch needs a digital frame camera (film references are oriented as archive epochs)".into(),
        ));
    };
    let Navigation::Pos(records) = &input.navigation else {
        return Err(ep(
            "the reference epoch needs a POS (strip end points cannot guide its tie points)".into(),
        ));
    };
    let origin = Vector3::from(input.origin);
    let mut block = Block {
        crs: Some(input.crs.clone()),
        origin: input.origin,
        ..Block::default()
    };
    block.cameras.insert(
        1,
        BlockCamera {
            id: 1,
            name: format!("{}_camera", input.name),
            model: Camera::Frame(frame.clone()),
            free_params: Vec::new(),
            calibration_group: None,
        },
    );
    let by_name: BTreeMap<&str, _> = records.iter().map(|r| (photo_key(&r.name), r)).collect();
    for (k, ph) in input.photos.iter().enumerate() {
        let r = by_name.get(ph.name.as_str()).ok_or_else(|| {
            ep(format!(
                "photo {} ({}) has no POS record: the reference epoch needs one for every photo",
                ph.name,
                ph.image.display()
            ))
        })?;
        let c = Vector3::from(r.center) - origin;
        let rot = matrix_from_opk(r.opk[0], r.opk[1], r.opk[2]);
        let sc = r.sigma_xyz.unwrap_or(0.1);
        let id = k as PhotoId + 1;
        let mut photo = Photo::new(id, ph.name.clone(), 1, Pose::new(rot, c));
        photo.prior = Some(PosPrior {
            center: c,
            center_sigma: [sc; 3],
            rotation: Some(rot),
            rotation_sigma_rad: r.sigma_angle.unwrap_or(0.01f64.to_radians()),
        });
        photo.date = input.date.clone();
        photo.image = Some(ph.image.clone());
        photo.provenance = "POS".into();
        block.photos.insert(id, photo);
    }
    Ok(block)
}

/// LiDAR points of `classes` (e.g. ground and buildings: planar surfaces that do not
/// change between the LiDAR and the reference flight) from LAS/LAZ tiles, indexed for
/// plane fits in the block-local frame of `origin`.
pub fn lidar_plane_index(
    tiles: &[std::path::PathBuf],
    origin: [f64; 3],
    classes: &[u8],
    options: crate::lidar::PlaneOptions,
) -> Result<PlaneIndex, EpochError> {
    let mut local = Vec::new();
    for t in tiles {
        let b = crate::lidar::las::read_points(t, None, Some(classes)).map_err(|e| {
            EpochError::Input {
                path: t.clone(),
                message: e.to_string(),
            }
        })?;
        local.extend(
            b.xyz
                .iter()
                .map(|p| [p[0] - origin[0], p[1] - origin[1], p[2] - origin[2]]),
        );
    }
    let first = tiles.first().cloned().unwrap_or_default();
    PlaneIndex::from_local(local, Vector3::from(origin), options).map_err(|e| EpochError::Input {
        path: first,
        message: format!("LiDAR plane index: {e}"),
    })
}

/// Similarity in world coordinates → the same map in block-local coordinates.
fn to_local(s: &Similarity, origin: &Vector3<f64>) -> Similarity {
    let t = s.scale * s.rotation * origin + s.translation - origin;
    Similarity::new(s.scale, s.rotation, t)
}

/// Moves a block (block-local, `block.origin`) by a similarity in world coordinates: its
/// photos and tie points; control keeps its surveyed coordinates.
pub(crate) fn move_block(block: &mut Block, s: &Similarity) {
    let local = to_local(s, &Vector3::from(block.origin));
    for ph in block.photos.values_mut() {
        ph.pose = local.apply_pose(&ph.pose);
    }
    for p in block.points.values_mut() {
        if p.kind == PointKind::Tie {
            p.position = local.apply(&p.position);
        }
    }
}

pub(crate) fn summarise_icp(r: &IcpResult) -> IcpSummary {
    let angle = nalgebra::Rotation3::from_matrix_unchecked(r.transform.rotation).angle();
    IcpSummary {
        scale: r.transform.scale,
        rotation_deg: angle.to_degrees(),
        translation_m: r.transform.translation.into(),
        rmse_m: r.rmse_m,
        inliers: r.inliers,
        converged: r.converged,
        degenerate_directions: r.degenerate_directions,
        iterations: r.iterations.clone(),
    }
}

/// Orients the reference epoch against the LiDAR. `lidar` holds the LiDAR surface points
/// with the epoch's origin as its origin; `dem` is the ground DEM, block-local like the
/// DEM of [`super::archive::orient_epoch`].
pub fn orient_reference(
    input: &EpochInput,
    lidar: &PlaneIndex,
    dem: &Dem,
    opts: &ReferenceOptions,
) -> Result<(EpochResult, ReferenceReport), EpochError> {
    let here = HereMatching { epoch: &input.name };
    orient_reference_with(input, lidar, dem, opts, &here)
}

/// The epoch's photo pairs matched in this process; a failure names the epoch.
struct HereMatching<'a> {
    epoch: &'a str,
}

impl PairMatching for HereMatching<'_> {
    type Error = EpochError;

    fn match_pairs(
        &self,
        photos: &[OrientedPhoto],
        ids: &[PhotoId],
        jobs: &[PhotoPairs],
        surface: &Surface,
        opts: &BlockTieOptions,
    ) -> Result<Vec<MatchedPairs>, EpochError> {
        InMemory
            .match_pairs(photos, ids, jobs, surface, opts)
            .map_err(|e| tie_error(self.epoch, e))
    }
}

/// A failure of the tie matching of epoch `epoch`.
pub fn tie_error(epoch: &str, e: impl std::fmt::Display) -> EpochError {
    EpochError::Epoch {
        epoch: epoch.to_string(),
        message: format!("tie points: {e}"),
    }
}

/// The reference epoch's photos as its tie matching sees them: the block at the POS and
/// each photo's image file (checked to exist, so that a missing photo is named before
/// any work; the images are decoded when a pair needs them).
pub fn tie_photos(
    input: &EpochInput,
) -> Result<(Block, BTreeMap<PhotoId, Pixels<'_>>), EpochError> {
    let block = pos_block(input)?;
    if let Some(p) = input.photos.iter().find(|p| !p.image.is_file()) {
        return Err(EpochError::Input {
            path: p.image.clone(),
            message: "photo image not found".into(),
        });
    }
    Ok((block, tie_images(input)))
}

/// Each photo's image file by photo id (not checked: see [`tie_photos`]).
pub fn tie_images(input: &EpochInput) -> BTreeMap<PhotoId, Pixels<'_>> {
    (input.photos.iter().enumerate())
        .map(|(k, p)| (k as PhotoId + 1, Pixels::File(&p.image)))
        .collect()
}

/// The surface the reference epoch's tie search is predicted over: the LiDAR DEM.
pub fn tie_surface<'a>(dem: &'a Dem, opts: &ReferenceOptions) -> Surface<'a> {
    Surface::Dem {
        dem,
        origin: Vector3::zeros(),
        sigma_m: opts.dem_sigma_m,
    }
}

/// [`orient_reference`] with the tie matching of its photo pairs run by `matcher` (the
/// pipeline runs each photo's pairs as a task).
pub fn orient_reference_with<M: PairMatching>(
    input: &EpochInput,
    lidar: &PlaneIndex,
    dem: &Dem,
    opts: &ReferenceOptions,
    matcher: &M,
) -> Result<(EpochResult, ReferenceReport), M::Error>
where
    M::Error: From<EpochError>,
{
    let t0 = Instant::now();
    let ep = |message: String| EpochError::Epoch {
        epoch: input.name.clone(),
        message,
    };
    let origin = Vector3::from(input.origin);
    if (lidar.origin() - origin).norm() > 1e-6 {
        return Err(ep(format!(
            "the LiDAR index origin {:?} differs from the epoch origin {:?}",
            lidar.origin(),
            input.origin
        ))
        .into());
    }
    let (mut block, images) = tie_photos(input)?;

    // 1. Tie points, searched around their POS prediction over the LiDAR ground.
    let surface = tie_surface(dem, opts);
    let tp = TiePhotos::of(&block, &images, &opts.ties).map_err(|e| tie_error(&input.name, e))?;
    let photos = tp.photos();
    let jobs = plan_pairs(&photos, &surface, &opts.ties);
    let matched = matcher.match_pairs(&photos, tp.ids(), &jobs, &surface, &opts.ties)?;
    drop(photos);
    let ties = write_ties(
        &mut block,
        &tp,
        jobs,
        matched,
        &surface,
        opts.min_per_position,
        &opts.ties,
    );
    drop((tp, images));
    tracing::info!(
        epoch = %input.name,
        points = ties.points_added,
        observations = ties.observations_added,
        "tie points"
    );
    let adjust_err = |source| EpochError::Adjust {
        epoch: input.name.clone(),
        source,
    };

    // A photo without enough tie points does not stop the epoch: it leaves the block
    // with its count and comes back, not oriented, after the adjustment.
    let lost = take_unsupported(&mut block, MIN_POINTS_PER_PHOTO);
    for (ph, n) in &lost {
        tracing::warn!(epoch = %input.name, photo = %ph.name, points = n, "photo left out of the adjustment");
    }

    // 2. Adjustment on the POS alone: tie points get object positions.
    let first_opts = AdjustOptions {
        covariance: false,
        ..opts.adjust.clone()
    };
    let pos_adjustment = adjust::adjust(&mut block, &[], None, &first_opts).map_err(adjust_err)?;

    // 3. ICP of the tie points onto the LiDAR; the similarity moves the whole block.
    let icp = match &opts.icp {
        Some(icp_opts) => {
            let source: Vec<[f64; 3]> = block
                .points
                .values()
                .filter(|p| p.kind == PointKind::Tie && p.observations.len() >= 2)
                .map(|p| (p.position + origin).into())
                .collect();
            let r = icp_point_to_plane(lidar, &source, &Similarity::identity(), icp_opts)
                .map_err(|e| ep(format!("ICP of the tie points onto the LiDAR: {e}")))?;
            move_block(&mut block, &r.transform);
            tracing::info!(
                epoch = %input.name,
                rmse_m = r.rmse_m,
                scale = r.transform.scale,
                "ICP onto the LiDAR"
            );
            Some(summarise_icp(&r))
        }
        None => None,
    };

    // 4. Bundle adjustment with LiDAR planes, POS priors and self-calibration.
    if let Some(c) = block.cameras.get_mut(&1) {
        c.free_params = opts.self_calibration.clone();
    }
    let mut planes = LidarPlanes {
        index: lidar,
        sigma_m: opts.lidar_sigma_m,
        gate_m: opts.plane_gate_m,
        points: block
            .points
            .values()
            .filter(|p| p.kind == PointKind::Tie)
            .map(|p| p.id)
            .collect(),
    };
    let current: Vec<(PointId, Vector3<f64>)> =
        block.points.values().map(|p| (p.id, p.position)).collect();
    let initial = planes.refit(&current);
    let plane_constraints = initial.len();
    if plane_constraints < 3 {
        return Err(ep(format!(
            "only {plane_constraints} tie points lie on planar LiDAR surfaces; the LiDAR cannot control the block"
        ))
        .into());
    }
    let report = adjust::adjust(
        &mut block,
        &initial,
        Some(&mut planes as &mut dyn PlaneRefitter),
        &opts.adjust,
    )
    .map_err(adjust_err)?;

    // Photos count as oriented when enough of their tie observations survived.
    let mut per_photo: BTreeMap<PhotoId, usize> = BTreeMap::new();
    for p in block.points.values() {
        for o in &p.observations {
            *per_photo.entry(o.photo).or_default() += 1;
        }
    }
    let precision: BTreeMap<PhotoId, f64> = report
        .photo_precision
        .iter()
        .map(|p| (p.photo, p.rmse_px))
        .collect();
    let mut photos = Vec::new();
    for ph in block.photos.values_mut() {
        let n = per_photo.get(&ph.id).copied().unwrap_or(0);
        let reason = (n < opts.min_observations).then_some(PhotoFailure::TooFewTieObservations {
            kept: n,
            needed: opts.min_observations,
        });
        ph.status = match &reason {
            None => PhotoStatus::Oriented,
            Some(r) => PhotoStatus::Failed(r.clone()),
        };
        ph.provenance = "tie points, ICP onto the LiDAR, adjustment with LiDAR planes".into();
        photos.push(PhotoReport::without_patches(
            &ph.name,
            reason,
            precision.get(&ph.id).copied().unwrap_or(f64::NAN),
        ));
    }
    for (mut ph, points) in lost {
        let reason = PhotoFailure::LostSupport {
            points,
            needed: MIN_POINTS_PER_PHOTO,
        };
        ph.status = PhotoStatus::Failed(reason.clone());
        photos.push(PhotoReport::without_patches(
            &ph.name,
            Some(reason),
            f64::NAN,
        ));
        block.photos.insert(ph.id, ph);
    }
    let gsd_m = mean_gsd(&block, dem);
    Ok((
        EpochResult {
            epoch: input.name.clone(),
            block,
            photos,
            adjustment: Some(report),
            gsd_m,
            time_s: t0.elapsed().as_secs_f64(),
        },
        ReferenceReport {
            ties,
            pos_adjustment,
            icp,
            plane_constraints,
        },
    ))
}
