//! An existing oriented block as an epoch (seed 000's second control source: results of
//! an earlier aerial triangulation). A mapping agency's production block, exported as
//! BlocksExchange XML or as a COLMAP model with its side file, is taken as oriented: its
//! photos are matched to the epoch's images, it is moved into the project's block-local
//! frame, and, where LiDAR is given, checked against it by point-to-plane ICP of its tie
//! points (the 7-parameter similarity reported as the block's offset from the LiDAR, and
//! applied on request). DCPs are then exported from it as from a block we oriented.

use super::archive::{mean_gsd, EpochResult};
use super::epoch::{input_err, EpochError, PhotoInput};
use super::photo::PhotoReport;
use super::reference::{move_block, summarise_icp, IcpSummary};
use crate::block::{Block, PhotoFailure, PhotoStatus, PointKind};
use crate::formats::crs::Crs;
use crate::formats::pos::photo_key;
use crate::geometry::{Dem, Similarity};
use crate::lidar::{icp_point_to_plane, IcpOptions, PlaneIndex};
use nalgebra::Vector3;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::Path;
use std::time::Instant;

/// Options of [`existing_epoch`].
#[derive(Debug, Clone, Copy)]
pub struct ExistingOptions {
    /// Point-to-plane ICP of the block's tie points onto the LiDAR (None: no check).
    pub lidar_check: Option<IcpOptions>,
    /// Move the block by the similarity the check found (otherwise only reported).
    pub apply_offset: bool,
}

impl Default for ExistingOptions {
    fn default() -> Self {
        Self {
            // A production block is within decimetres of the LiDAR when both are right;
            // the first gate still covers a block a few metres off (a datum or geoid slip).
            // Every direction the relief determines at all is estimated (the reference
            // orientation leaves weak ones to its adjustment, this check has none): on the
            // small preset's gentle slopes a 1.5 m horizontal slip is found to 2 mm, where
            // the reference's ratio of 2e-2 freezes both horizontal axes.
            lidar_check: Some(IcpOptions {
                initial_gate: 10.0,
                min_gate: 0.25,
                min_eigenvalue_ratio: 1e-3,
                ..IcpOptions::default()
            }),
            apply_offset: false,
        }
    }
}

/// The block's agreement with the LiDAR.
#[derive(Debug, Clone, Serialize)]
pub struct LidarCheck {
    pub icp: IcpSummary,
    /// Mean displacement of the tie points by the similarity (world metres, x y z): how
    /// far the block lies from the LiDAR.
    pub mean_offset_m: [f64; 3],
    /// Largest displacement of a tie point by the similarity (m).
    pub max_offset_m: f64,
    /// Tie points (seen in two photos at least) the check used.
    pub tie_points: usize,
    pub applied: bool,
}

/// What taking the block did.
#[derive(Debug, Clone, Serialize)]
pub struct ExistingReport {
    /// The block file or model folder.
    pub source: String,
    /// The block's CRS as its file states it (None: taken to be the project's).
    pub crs: Option<String>,
    pub photos_in_block: usize,
    /// Photos of the block with an image in the epoch's folder (the epoch's oriented ones).
    pub photos_with_image: usize,
    /// Photos of the block without an image: they cannot give DCPs.
    pub photos_without_image: Vec<String>,
    /// Images of the folder that the block does not hold.
    pub images_not_in_block: Vec<String>,
    pub tie_points: usize,
    /// Check points of the block, left out (the project's checkpoints evaluate the epoch).
    pub check_points_dropped: usize,
    pub lidar: Option<LidarCheck>,
}

/// Takes `block`, read from `source`, as the oriented epoch `name` with the images in
/// `photos`, in the project CRS `crs` and the block-local frame of `origin`. `lidar`
/// (block-local, same origin) checks it; `dem` gives its ground pixel.
#[allow(clippy::too_many_arguments)]
pub fn existing_epoch(
    name: &str,
    date: Option<&str>,
    source: &Path,
    mut block: Block,
    photos: &[PhotoInput],
    crs: &str,
    origin: [f64; 3],
    lidar: Option<&PlaneIndex>,
    dem: &Dem,
    opts: &ExistingOptions,
) -> Result<(EpochResult, ExistingReport), EpochError> {
    let t0 = Instant::now();
    let project_crs = Crs::parse(crs).map_err(|e| input_err(source, e.to_string()))?;
    let block_crs = block.crs.clone();
    if let Some(def) = &block_crs {
        let c = Crs::parse(def).map_err(|e| input_err(source, format!("the block's CRS: {e}")))?;
        let same = c
            .same_horizontal(&project_crs)
            .map_err(|e| input_err(source, e.to_string()))?;
        if !same {
            // Poses do not move between projections by a point transform (meridian
            // convergence turns them): the block must come in the project's CRS.
            return Err(input_err(
                source,
                format!(
                    "the block is in {} but the project in {}; export it in the project CRS",
                    c.label(),
                    project_crs.label()
                ),
            ));
        }
    } else {
        tracing::warn!(source = %source.display(), "the block states no CRS; taken to be the project's");
    }
    if block.photos.is_empty() {
        return Err(input_err(source, "the block holds no photo"));
    }
    if let Err(e) = block.validate() {
        return Err(input_err(source, e.to_string()));
    }

    // Into the project's block-local frame (world = local + origin).
    let shift = Vector3::from(block.origin) - Vector3::from(origin);
    for p in block.photos.values_mut() {
        p.pose.center += shift;
    }
    for p in block.points.values_mut() {
        p.position += shift;
    }
    block.origin = origin;
    block.crs = Some(crs.to_string());

    // Check points are the project's business (the checkpoint evaluation), not the block's.
    let before = block.points.len();
    block.points.retain(|_, p| p.kind != PointKind::Check);
    let check_points_dropped = before - block.points.len();

    // Photos to images by name (file name or stem, as everywhere).
    let images: BTreeMap<&str, &PhotoInput> = photos.iter().map(|p| (p.name.as_str(), p)).collect();
    let mut photos_without_image = Vec::new();
    let mut reports = Vec::new();
    let mut in_block = std::collections::BTreeSet::new();
    for ph in block.photos.values_mut() {
        let key = photo_key(&ph.name).to_string();
        ph.date = ph.date.take().or_else(|| date.map(str::to_string));
        ph.provenance = format!("existing block {}", source.display());
        match images.get(key.as_str()) {
            Some(input) => {
                ph.image = Some(input.image.clone());
                ph.name = key.clone();
                ph.status = PhotoStatus::Oriented;
                in_block.insert(key);
                reports.push(PhotoReport::without_patches(&ph.name, None, f64::NAN));
            }
            None => {
                let reason = PhotoFailure::Image {
                    path: ph.name.clone(),
                    message: "the existing block holds this photo, but the epoch's folder has no image of it".into(),
                };
                ph.status = PhotoStatus::Failed(reason.clone());
                photos_without_image.push(ph.name.clone());
                reports.push(PhotoReport::without_patches(
                    &ph.name,
                    Some(reason),
                    f64::NAN,
                ));
            }
        }
    }
    let images_not_in_block: Vec<String> = photos
        .iter()
        .filter(|p| !in_block.contains(&p.name))
        .map(|p| p.name.clone())
        .collect();
    if in_block.is_empty() {
        return Err(input_err(
            source,
            format!(
                "none of the block's {} photos has an image in the epoch's folder (photos are matched by file name or stem)",
                block.photos.len()
            ),
        ));
    }
    for n in &images_not_in_block {
        tracing::warn!(epoch = name, photo = %n, "image not in the existing block: not oriented");
    }

    let lidar_check = match (lidar, &opts.lidar_check) {
        (Some(index), Some(icp_opts)) => Some(check_against_lidar(
            &mut block,
            index,
            icp_opts,
            opts.apply_offset,
            source,
        )?),
        _ => None,
    };
    let tie_points = block
        .points
        .values()
        .filter(|p| p.kind == PointKind::Tie)
        .count();
    let gsd_m = mean_gsd(&block, dem);
    let report = ExistingReport {
        source: source.display().to_string(),
        crs: block_crs,
        photos_in_block: block.photos.len(),
        photos_with_image: in_block.len(),
        photos_without_image,
        images_not_in_block,
        tie_points,
        check_points_dropped,
        lidar: lidar_check,
    };
    Ok((
        EpochResult {
            epoch: name.to_string(),
            block,
            photos: reports,
            adjustment: None,
            gsd_m,
            time_s: t0.elapsed().as_secs_f64(),
        },
        report,
    ))
}

/// ICP of the block's tie points onto the LiDAR; the block moves only when `apply`.
fn check_against_lidar(
    block: &mut Block,
    lidar: &PlaneIndex,
    icp_opts: &IcpOptions,
    apply: bool,
    source: &Path,
) -> Result<LidarCheck, EpochError> {
    let origin = Vector3::from(block.origin);
    if (lidar.origin() - origin).norm() > 1e-6 {
        return Err(input_err(
            source,
            format!(
                "the LiDAR index origin {:?} differs from the block's {:?}",
                lidar.origin(),
                block.origin
            ),
        ));
    }
    let ties: Vec<Vector3<f64>> = block
        .points
        .values()
        .filter(|p| p.kind == PointKind::Tie && p.observations.len() >= 2)
        .map(|p| p.position + origin)
        .collect();
    if ties.len() < icp_opts.min_correspondences.max(3) {
        return Err(input_err(
            source,
            format!(
                "the block has {} tie points seen in two photos; checking it against the LiDAR needs at least {}",
                ties.len(),
                icp_opts.min_correspondences.max(3)
            ),
        ));
    }
    let pts: Vec<[f64; 3]> = ties.iter().map(|p| (*p).into()).collect();
    let r = icp_point_to_plane(lidar, &pts, &Similarity::identity(), icp_opts).map_err(|e| {
        input_err(
            source,
            format!("ICP of the block's tie points onto the LiDAR: {e}"),
        )
    })?;
    let moved: Vec<Vector3<f64>> = ties.iter().map(|p| r.transform.apply(p) - p).collect();
    let mean = moved.iter().sum::<Vector3<f64>>() / moved.len() as f64;
    let max = moved.iter().map(|d| d.norm()).fold(0.0, f64::max);
    if apply {
        move_block(block, &r.transform);
    }
    tracing::info!(
        source = %source.display(),
        offset_m = ?mean,
        rmse_m = r.rmse_m,
        applied = apply,
        "existing block against the LiDAR"
    );
    Ok(LidarCheck {
        icp: summarise_icp(&r),
        mean_offset_m: mean.into(),
        max_offset_m: max,
        tie_points: ties.len(),
        applied: apply,
    })
}
