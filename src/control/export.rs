//! Digital Control Photos from an oriented block (seed 000 §2.2 (2)): cloud control
//! points selected where the photos are textured and the ground is planar and stable,
//! measured in every oriented photo that sees them, written with their chips as a DCP
//! package for older epochs. The input is a [`Block`] whose oriented photos carry their
//! image files, with the control surface of its LiDAR ([`OrientedBlock`] reads both from
//! an epoch's `block.json` / `images.json`).

use super::cloud::{
    self, CloudOptions, ControlPointRecord, ControlSurface, CutChip, ExportInfo, ExportPlan,
    PhotoChips,
};
use super::dcp::{encode_chip, Accuracy, DcpPackage, EpochInfo};
use super::epoch::{input_err, EpochError};
use crate::block::{Block, PhotoId};
use crate::lidar::{lidar_surfaces, GroundSurface};
use crate::matching::{forstner, ForstnerOptions, GreyImage, Pyramid};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Options of [`select_control_points`] and [`export_dcp`].
#[derive(Debug, Clone)]
pub struct DcpExportOptions {
    pub cloud: CloudOptions,
    /// Chip side (px, odd): large enough to hold a template rescaled to a coarser photo.
    /// It also keeps the points half a chip away from the photo borders.
    pub chip_size: u32,
    pub accuracy: Accuracy,
    pub source: String,
    /// Pyramid level of the reference photos the interest operator runs on (2 = 4×
    /// coarser ground pixel).
    pub interest_level: usize,
}

impl Default for DcpExportOptions {
    fn default() -> Self {
        Self {
            cloud: CloudOptions::default(),
            // The workflow's default (project `thresholds.chip_size_px`), so a package
            // made by hand matches one made by `cloudcontrol run`.
            chip_size: 193,
            accuracy: Accuracy {
                plan_m: 0.05,
                height_m: 0.05,
            },
            source: "photos oriented against LiDAR".into(),
            interest_level: 2,
        }
    }
}

impl DcpExportOptions {
    /// Refuses options that would fail only after every photo was read, or that cannot
    /// select anything.
    pub fn validate(&self) -> Result<(), String> {
        let c = &self.cloud;
        if !(c.interval_px.is_finite() && c.interval_px >= 1.0 && c.interval_px <= 1000.0) {
            return Err(format!(
                "interval_px {} is outside [1, 1000]",
                c.interval_px
            ));
        }
        if !(c.max_coplanarity.is_finite() && c.max_coplanarity > 0.0) {
            return Err(format!(
                "max_coplanarity {} must be positive",
                c.max_coplanarity
            ));
        }
        if c.min_photos == 0 {
            return Err("min_photos must be at least 1".into());
        }
        if self.chip_size < 9 || self.chip_size % 2 == 0 {
            return Err(format!(
                "chip_size {} must be odd and at least 9 (the point sits on the centre pixel)",
                self.chip_size
            ));
        }
        if self.interest_level > 8 {
            return Err(format!(
                "interest_level {} is above 8 (256× coarser than the photos)",
                self.interest_level
            ));
        }
        for (name, v) in [
            ("accuracy plan_m", self.accuracy.plan_m),
            ("accuracy height_m", self.accuracy.height_m),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("{name} {v} must be positive"));
            }
        }
        Ok(())
    }
}

/// The cloud control points of an oriented block (`cloudcontrol dcp generate`): what
/// [`export_dcp`] writes into a package, without the chips.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControlPointSet {
    pub crs: String,
    /// Mean ground pixel of the photos the points were picked in (m).
    pub gsd_m: f64,
    pub accuracy: Accuracy,
    pub points: Vec<ControlPointRecord>,
}

/// Selects cloud control points in an oriented block: Förstner candidates at the scale of
/// pyramid level `interest_level`, one per `interval_px` cell, on planar and stable
/// ground of `surface`, measured in every oriented photo with an image that sees them.
pub fn select_control_points(
    block: &Block,
    surface: &dyn ControlSurface,
    opts: &DcpExportOptions,
) -> Result<ControlPointSet, EpochError> {
    opts.validate()
        .map_err(|m| EpochError::Block(format!("options: {m}")))?;
    block
        .validate()
        .map_err(|e| EpochError::Block(e.to_string()))?;
    let crs = block
        .crs
        .clone()
        .ok_or_else(|| EpochError::Block("has no CRS".into()))?;
    // Photos that are not oriented or have no image would give measurements nobody can
    // cut a chip from or trust: the selection sees the others only.
    let mut seen = Block {
        crs: block.crs.clone(),
        origin: block.origin,
        cameras: block.cameras.clone(),
        ..Block::default()
    };
    let mut interest = BTreeMap::new();
    let mut gsd = Vec::new();
    for (&pid, ph) in &block.photos {
        let (true, Some(path)) = (ph.is_oriented(), &ph.image) else {
            continue;
        };
        let cam = &block.cameras[&ph.camera].model;
        let full = GreyImage::load(path).map_err(|e| input_err(path, e.to_string()))?;
        let (w, h) = cam.image_size();
        // The border below keeps chips inside photos of the camera's size only.
        if (full.width, full.height) != (w as usize, h as usize) {
            return Err(input_err(
                path,
                format!(
                    "is {}×{} pixels, the camera of photo {pid} ({}) is {w}×{h}",
                    full.width, full.height, ph.name
                ),
            ));
        }
        // Interest is taken at the scale of the coarser archive photos the package is
        // for: fine texture (crop rows, tiles) that is distinct at the reference scale
        // aliases into ambiguous patterns there, while corners of parcels and roads stay.
        let pyr = Pyramid::new(&full, opts.interest_level + 1, 32);
        let level = pyr.levels.len() - 1;
        let f = (1usize << level) as f64;
        let img = &pyr.levels[level];
        let cell = (opts.cloud.interval_px / f).max(4.0);
        let fo = ForstnerOptions {
            grid: (
                ((img.width as f64 / cell).ceil() as usize).max(1),
                ((img.height as f64 / cell).ceil() as usize).max(1),
            ),
            per_cell: 8,
            border: ((opts.chip_size / 2 + 2) as f64 / f).ceil() as usize,
            ..ForstnerOptions::default()
        };
        let cands: Vec<cloud::Candidate> = forstner(img, &fo)
            .into_iter()
            .map(|p| ([p.x * f, p.y * f], p.w))
            .collect();
        interest.insert(pid, cands);
        gsd.push(ph.pose.center.z.abs() / cam.focal_px());
        seen.photos.insert(pid, ph.clone());
    }
    if seen.photos.is_empty() {
        return Err(EpochError::Block("no oriented photo has an image".into()));
    }
    let cloud_opts = CloudOptions {
        border_px: opts.cloud.border_px.max((opts.chip_size / 2 + 1) as f64),
        ..opts.cloud.clone()
    };
    let points = cloud::select(&seen, surface, &interest, &cloud_opts)
        .map_err(|e| EpochError::Block(e.to_string()))?;
    if points.is_empty() {
        return Err(EpochError::Block(format!(
            "no cloud control point found in {} photos (no textured, planar, stable ground \
             under the LiDAR)",
            seen.photos.len()
        )));
    }
    Ok(ControlPointSet {
        crs,
        gsd_m: gsd.iter().sum::<f64>() / gsd.len() as f64,
        accuracy: opts.accuracy,
        points: cloud::records(&seen, &points, &opts.accuracy),
    })
}

/// Selects cloud control points in an oriented block ([`select_control_points`]) and
/// writes them with their chips as a DCP package at `out`, the photos' chips cut on this
/// process's threads.
pub fn export_dcp(
    block: &Block,
    surface: &dyn ControlSurface,
    epoch: EpochInfo,
    out: &Path,
    opts: &DcpExportOptions,
) -> Result<DcpPackage, EpochError> {
    export_dcp_with(block, surface, epoch, out, opts, |plan, size| {
        plan.photos
            .par_iter()
            .map(|job| {
                let image = block
                    .photos
                    .get(&job.photo)
                    .and_then(|p| p.image.as_deref())
                    .ok_or_else(|| format!("no image for photo {}", job.photo))?;
                cut_photo_chips(image, job, size)
            })
            .collect::<Result<Vec<_>, String>>()
            .map_err(|e| input_err(out, e))
    })
}

/// [`export_dcp`] with the photos' chips cut by `cut` (elsewhere, for a distributed run):
/// given the plan and the chip size, every photo's chips ([`cut_photo_chips`]) in the
/// plan's photo order.
pub fn export_dcp_with<E: From<EpochError>>(
    block: &Block,
    surface: &dyn ControlSurface,
    epoch: EpochInfo,
    out: &Path,
    opts: &DcpExportOptions,
    cut: impl FnOnce(&ExportPlan, u32) -> Result<Vec<Vec<CutChip<Vec<u8>>>>, E>,
) -> Result<DcpPackage, E> {
    let set = select_control_points(block, surface, opts)?;
    let info = ExportInfo {
        crs: set.crs.clone(),
        epoch,
        source: opts.source.clone(),
        gsd_m: set.gsd_m,
        accuracy: opts.accuracy,
        chip_size: opts.chip_size,
    };
    // Every chip fits (the selection's border is half a chip and the images have the
    // cameras' size), so the package holds exactly the points of `set`.
    let plan = ExportPlan::new(block, &set.points, &info).map_err(|e| input_err(out, e))?;
    let cuts = cut(&plan, info.chip_size)?;
    let (m, chips) = plan.assemble(&set.points, cuts);
    Ok(DcpPackage::write_encoded(out, m, &chips).map_err(EpochError::from)?)
}

/// The chips of one photo of an export plan, read from `image`, PNG-encoded as the
/// package stores them.
pub fn cut_photo_chips(
    image: &Path,
    job: &PhotoChips,
    size: u32,
) -> Result<Vec<CutChip<Vec<u8>>>, String> {
    let img = crate::formats::image_open::decode_image(image).map_err(|e| e.to_string())?;
    job.cut(&img, size)
        .into_iter()
        .map(|c| {
            let file = c.file.clone();
            c.map(|chip| {
                encode_chip(&chip).map_err(|e| format!("chip {file} cannot be encoded ({e})"))
            })
        })
        .collect()
}

/// An oriented block as the workflow writes each epoch — `block.json` (the [`Block`]) and
/// `images.json` (photo id → image path, formats/workflow/) — with the control surface of
/// its LiDAR: the
/// input of `cloudcontrol dcp generate|export`, `ccp_dcp_export` and the Python binding.
pub struct OrientedBlock {
    /// The `block.json` the block was read from (errors name it).
    pub block_json: PathBuf,
    /// The block, its photos' `image` set from `images.json`.
    pub block: Block,
    pub surface: GroundSurface,
}

impl OrientedBlock {
    /// Reads the two JSON files and builds the control surface from LAS/LAZ files or
    /// folders of them (grid cell `lidar_cell_m`, e.g. [`crate::lidar::LIDAR_CELL_M`]).
    pub fn load(
        block_json: &Path,
        images_json: &Path,
        lidar: &[PathBuf],
        lidar_cell_m: f64,
    ) -> Result<Self, EpochError> {
        if !(lidar_cell_m.is_finite() && lidar_cell_m > 0.0) {
            return Err(EpochError::Block(format!(
                "LiDAR grid cell {lidar_cell_m} m must be positive"
            )));
        }
        let block = read_oriented_block(block_json, images_json)?;
        let tiles = crate::lidar::catalogue::expand_inputs(lidar)?;
        let surface = lidar_surfaces(&tiles, block.origin, lidar_cell_m, None)?;
        Ok(Self {
            block_json: block_json.to_path_buf(),
            block,
            surface,
        })
    }

    fn named(&self, e: EpochError) -> EpochError {
        match e {
            EpochError::Block(m) => input_err(&self.block_json, m),
            e => e,
        }
    }

    /// The control points a package of this block would hold ([`select_control_points`]).
    pub fn select(&self, opts: &DcpExportOptions) -> Result<ControlPointSet, EpochError> {
        select_control_points(&self.block, &self.surface, opts).map_err(|e| self.named(e))
    }

    /// Writes the DCP package of this block at `out` ([`export_dcp`]).
    pub fn export(
        &self,
        epoch: EpochInfo,
        out: &Path,
        opts: &DcpExportOptions,
    ) -> Result<DcpPackage, EpochError> {
        export_dcp(&self.block, &self.surface, epoch, out, opts).map_err(|e| self.named(e))
    }
}

/// Reads an oriented block's `block.json` and `images.json`. An image path that is
/// relative is taken from the folder of its file, as the workflow writes it (so a project
/// moved whole still finds its photos), and else from the working directory (a file
/// written by hand before that rule). Every oriented photo needs an existing image, and
/// every image a photo of the block. The images are set as the photos' `image`.
pub fn read_oriented_block(block_json: &Path, images_json: &Path) -> Result<Block, EpochError> {
    let mut block: Block = serde_json::from_value(read_json(block_json)?)
        .map_err(|e| input_err(block_json, e.to_string()))?;
    block
        .validate()
        .map_err(|e| input_err(block_json, e.to_string()))?;
    if block.crs.is_none() {
        return Err(input_err(
            block_json,
            "the block has no CRS (a DCP package needs a projected one)",
        ));
    }
    let listed: BTreeMap<PhotoId, PathBuf> = serde_json::from_value(read_json(images_json)?)
        .map_err(|e| {
            input_err(
                images_json,
                format!("{e} (expected an object of photo id → image path)"),
            )
        })?;
    let base = crate::formats::paths::folder_of(images_json);
    let block_folder = crate::formats::paths::folder_of(block_json);
    for p in block.photos.values_mut() {
        if let Some(image) = &mut p.image {
            *image = crate::formats::paths::resolve_from(block_folder, image);
        }
    }
    let mut images = BTreeMap::new();
    for (pid, path) in listed {
        let Some(photo) = block.photos.get(&pid) else {
            return Err(input_err(
                images_json,
                format!(
                    "photo {pid} is not in {} (a block and its images.json from different epochs?)",
                    block_json.display()
                ),
            ));
        };
        let from_file = crate::formats::paths::resolve_from(base, &path);
        let found = if from_file.exists() || !path.exists() {
            from_file
        } else {
            path.clone()
        };
        if !found.is_file() {
            if !photo.is_oriented() {
                continue;
            }
            return Err(input_err(
                images_json,
                format!(
                    "image {} of photo {pid} ({}) does not exist",
                    path.display(),
                    photo.name
                ),
            ));
        }
        images.insert(pid, found);
    }
    if let Some(p) = block
        .photos
        .values()
        .find(|p| p.is_oriented() && !images.contains_key(&p.id))
    {
        return Err(input_err(
            images_json,
            format!("no image for oriented photo {} ({})", p.id, p.name),
        ));
    }
    for (pid, path) in images {
        if let Some(p) = block.photos.get_mut(&pid) {
            p.image = Some(path);
        }
    }
    Ok(block)
}

fn read_json(path: &Path) -> Result<serde_json::Value, EpochError> {
    let text = crate::formats::input::read_text(path, crate::formats::input::Cap::document())
        .map_err(|e| input_err(path, e.detail()))?;
    serde_json::from_str(&text).map_err(|e| input_err(path, e.to_string()))
}

/// The epoch name a package takes by default: its folder's name without extension.
pub fn package_epoch_name(out: &Path) -> String {
    out.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "dcp".into())
}
