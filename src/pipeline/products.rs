//! The products of an oriented epoch (`outputs-<epoch>/`): COLMAP model, BlocksExchange
//! XML, orthophoto and the LiDAR ground DEM as GeoTIFFs, and the report's preview. A film
//! epoch's products are made from its scans resampled into fiducial-frame images
//! (`resampled/`, [`super::film_frames`]), whose frame cameras every format takes exactly.

use super::epoch_files::{load_block, write_json};
use super::film_frames::{self, FramePlan, RESAMPLED_DIR};
use super::ground::ControlGround;
use super::project::{Epoch, Project};
use super::run::Checkpoints;
use super::stages::WorkError;
use super::tasks::outputs::{OutputTasks, OutputsContext};
use super::tasks::TaskMode;
use crate::block::{Block, ObjectPoint, Observation, PointKind};
use crate::control::epoch::EpochCamera;
use crate::control::EpochError;
use crate::formats::control_points::read_checkpoint_measurements;
use crate::formats::crs::Crs;
use crate::formats::pos::photo_key;
use crate::formats::{self, FormatError};
use crate::geometry::Camera;
use nalgebra::Vector3;
use std::collections::BTreeMap;
use std::path::Path;

/// The folder of the project's control surfaces (`control/`), written once for every
/// epoch on the project's lattice, and their key among the run summary's products.
pub const CONTROL_PRODUCTS: &str = "control";
/// The LiDAR's ground (class 2, holes filled), the DEM orthophotos are rectified onto.
pub const LIDAR_DEM: &str = "lidar_dem.tif";
/// The LiDAR's surface model (mean of all non-noise returns per cell): today's surface,
/// each epoch's DSM is compared with (`change-<epoch>/`).
pub const LIDAR_DSM: &str = "lidar_dsm.tif";
/// Where there is no LiDAR: the DEM of the control sources (`control.dem`).
pub const CONTROL_DEM: &str = "control_dem.tif";

/// The files and folders of `outputs-<epoch>/` that are products (listed in the run
/// summary when written).
pub const PRODUCT_FILES: [&str; 4] = [
    "colmap",
    "blocks_exchange.xml",
    "orthophoto.tif",
    RESAMPLED_DIR,
];

/// The files of `control/` (listed in the run summary under [`CONTROL_PRODUCTS`]).
pub const CONTROL_FILES: [&str; 3] = [LIDAR_DEM, LIDAR_DSM, CONTROL_DEM];

/// The control's surfaces in world coordinates, once for the project (`control/`): the
/// LiDAR's ground and surface model on the project's lattice, or the control DEM as given.
pub(crate) fn write_control_surfaces(
    project: &Project,
    control: &ControlGround,
    dir: &Path,
) -> Result<(), WorkError> {
    let crs = Crs::parse(&project.crs)?;
    let surface = control.surface()?;
    let back = {
        let o = control.origin;
        [-o[0], -o[1], -o[2]]
    };
    let opts = formats::raster::GeoTiffOptions::default();
    let world = |d: &crate::geometry::Dem| d.shifted(back).map_err(FormatError::Geometry);
    if control.dem_file() == LIDAR_DEM {
        formats::raster::write_dem(&dir.join(LIDAR_DEM), &world(&surface.ground)?, &crs, &opts)?;
        formats::raster::write_dem(&dir.join(LIDAR_DSM), &world(&surface.surface)?, &crs, &opts)?;
    } else {
        formats::raster::write_dem(
            &dir.join(CONTROL_DEM),
            &world(&surface.ground)?,
            &crs,
            &opts,
        )?;
    }
    Ok(())
}

/// Adds the project's checkpoints measured in the block's photos as check points: the
/// surveyed position (block-local) and σ, with the epoch's image measurements (the
/// checkpoint image file's rows of `epoch`) in the photos the block holds.
fn add_checkpoints(block: &mut Block, cps: &Checkpoints, epoch: &str) -> Result<(), WorkError> {
    let meas = read_checkpoint_measurements(&cps.images, epoch)?;
    let by_key: BTreeMap<&str, u32> = block
        .photos
        .values()
        .map(|p| (photo_key(&p.name), p.id))
        .collect();
    let mut next = block.next_point_id();
    for ((id, xyz), sigma) in cps.surveyed.iter().zip(&cps.sigma) {
        let observations: Vec<Observation> = meas
            .iter()
            .filter(|m| &m.id == id)
            .filter_map(|m| {
                Some(Observation {
                    photo: *by_key.get(photo_key(&m.photo))?,
                    pixel: m.pixel,
                    sigma_px: 1.0,
                    provenance: "checkpoint measurement".into(),
                })
            })
            .collect();
        if observations.is_empty() {
            continue;
        }
        block.points.insert(
            next,
            ObjectPoint {
                id: next,
                name: id.clone(),
                kind: PointKind::Check,
                position: block.to_local(&Vector3::from(*xyz)),
                sigma: Some(*sigma),
                color: [255, 0, 0],
                observations,
            },
        );
        next += 1;
    }
    Ok(())
}

/// The block the products of `epoch` (its stage folder `edir`) are made of: the oriented
/// photos, with the project's checkpoints as check points when given, and a film epoch
/// moved into its frame images (to be made in `resampled`, [`FramePlan`]).
pub(crate) fn product_block(
    project: &Project,
    epoch: &Epoch,
    checkpoints: Option<&Checkpoints>,
    edir: &Path,
    resampled: &Path,
) -> Result<(Block, Option<FramePlan>), WorkError> {
    let block = load_block(edir)?;
    let o = &project.outputs;
    let mut named = block.oriented_only();
    // Before the move into the frames: their measurements move with the photos'.
    if let Some(c) = checkpoints {
        add_checkpoints(&mut named, c, &epoch.name)?;
    }
    let film = named
        .photos
        .values()
        .any(|p| matches!(named.camera_of(p).map(|c| &c.model), Some(Camera::Film(_))));
    if !(film && (o.colmap || o.blocks_exchange || o.orthophoto)) {
        return Ok((named, None));
    }
    let Some(camera) = &epoch.camera else {
        return Err(EpochError::Epoch {
            epoch: epoch.name.clone(),
            message: "an existing block with film cameras has no film camera file to resample its scans with".into(),
        }
        .into());
    };
    let def = match EpochCamera::load(camera)? {
        EpochCamera::Film(d) => d,
        EpochCamera::Frame(_) => {
            return Err(EpochError::Epoch {
                epoch: epoch.name.clone(),
                message: format!(
                    "{}: a frame camera, but the epoch's block has film cameras",
                    camera.display()
                ),
            }
            .into())
        }
    };
    let frames = film_frames::plan_frames(
        &named,
        def.format_mm,
        o.film_pixel_um.map(|um| um / 1000.0),
        &format!("{} ({})", def.name, epoch.name),
        resampled,
    )?;
    Ok((frames.block.clone(), Some(frames)))
}

/// The ground an epoch's orthophoto is rectified onto (the control surface's ground in
/// world coordinates) and the orthophoto's options (its GSD the photos' median ground
/// pixel times the project's `ortho_gsd_factor`).
pub(crate) fn ortho_ground(
    project: &Project,
    block: &Block,
    control: &ControlGround,
    origin: [f64; 3],
) -> Result<(crate::geometry::Dem, formats::ortho::OrthoOptions), WorkError> {
    // Back to world coordinates: shifting by the negated origin.
    let dem = control
        .surface()?
        .ground
        .shifted([-origin[0], -origin[1], -origin[2]])
        .map_err(FormatError::Geometry)?;
    let gsd =
        formats::ortho::default_gsd(block, &dem).map(|g| g * project.outputs.ortho_gsd_factor);
    Ok((
        dem,
        formats::ortho::OrthoOptions {
            gsd,
            lattice: Some(control.lattice()?),
            cog: true,
            ..Default::default()
        },
    ))
}

/// What an orthophoto was rectified onto (`surface` in `orthophoto.json`).
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct OrthoSurfaceReport {
    /// `control` (the control's ground) or `dsm` (the epoch's own surface).
    pub surface: String,
    /// Cells of the DSM with their own height, and holes given the control's ground.
    pub cells_from_dsm: usize,
    pub cells_from_control: usize,
    /// Why the control's ground stands in for a DSM that was asked for.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
}

/// The ground an epoch's orthophoto is rectified onto: `control` (world), or with
/// `surface_dir` (the epoch's surface stage folder) its own DSM where the photos gave a
/// height and the control's ground in its holes (an orthophoto has a value everywhere;
/// the DSM itself keeps its holes).
pub(crate) fn ortho_surface(
    control: &crate::geometry::Dem,
    surface_dir: Option<&Path>,
) -> Result<(crate::geometry::Dem, OrthoSurfaceReport), WorkError> {
    let of_control = |reason: Option<String>| OrthoSurfaceReport {
        surface: "control".into(),
        cells_from_dsm: 0,
        cells_from_control: control.data.len(),
        reason,
    };
    let Some(dir) = surface_dir else {
        return Ok((control.clone(), of_control(None)));
    };
    let path = dir.join(crate::dense::products::DSM_FILE);
    if !path.is_file() {
        let reason = "the epoch has no surface of its own (surface stage skipped.json)";
        tracing::warn!(reason, "orthophoto on the control's ground");
        return Ok((control.clone(), of_control(Some(reason.into()))));
    }
    let (mut dsm, _) = formats::raster::read_dem(&path)?;
    let (mut own, mut filled) = (0, 0);
    for i in 0..dsm.data.len() {
        if dsm.data[i].is_finite() {
            own += 1;
            continue;
        }
        let (c, r) = ((i % dsm.width) as f64 + 0.5, (i / dsm.width) as f64 + 0.5);
        let (x, y) = dsm.transform.pixel_to_world(c, r);
        if let Some(z) = control.height_at(x, y) {
            dsm.data[i] = z as f32;
            filled += 1;
        }
    }
    Ok((
        dsm,
        OrthoSurfaceReport {
            surface: "dsm".into(),
            cells_from_dsm: own,
            cells_from_control: filled,
            reason: None,
        },
    ))
}

/// COLMAP model, BlocksExchange XML, orthophoto and LiDAR DEM of the oriented epoch
/// `epoch` in `edir`, written into `dir`; `surface` is the LiDAR ground (block-local with
/// `origin`), `checkpoints` the project's, added to the models as check points;
/// `surface_dir` the epoch's surface folder when the orthophoto is rectified onto its own
/// DSM ([`ortho_surface`]). A film epoch's frame images and the orthophoto's tiles are
/// made as `tasks` (here, or returned as pending in `mode` Plan) before anything is
/// written.
#[allow(clippy::too_many_arguments)]
pub(crate) fn write_products(
    project: &Project,
    epoch: &Epoch,
    checkpoints: Option<&Checkpoints>,
    (control, surface_dir): (&ControlGround, Option<&Path>),
    origin: [f64; 3],
    edir: &Path,
    dir: &Path,
    (tasks, mode): (&OutputTasks, TaskMode),
) -> Result<(), WorkError> {
    let o = &project.outputs;
    let (mut named, frames) = product_block(project, epoch, checkpoints, edir, &tasks.resampled())?;
    let (control_dem, ortho_opts) = ortho_ground(project, &named, control, origin)?;
    let (dem, surface_report) = ortho_surface(&control_dem, surface_dir)?;
    let film = frames.is_some();
    // An epoch that oriented no photo still has its LiDAR DEM, but nothing to orthorectify.
    let orthophoto = o.orthophoto && !named.photos.is_empty();
    let ctx = OutputsContext {
        block: named.clone(),
        frames,
        dem,
        ortho: ortho_opts,
    };
    // The tasks first: a planning run that must wait for them has written nothing.
    let frame_reports = tasks.resample(&ctx, mode)?;
    let ortho_path = dir.join("orthophoto.tif");
    let files = ctx.files();
    let grid = if orthophoto {
        Some(formats::ortho::OrthoGrid::new(
            &ortho_path,
            &ctx.block,
            &ctx.dem,
            &formats::ortho::PhotoImages::Files(&files),
            &ctx.ortho,
        )?)
    } else {
        None
    };
    let mut rendered = match &grid {
        Some(g) => Some(tasks.ortho(g, &ctx, mode)?),
        None => None,
    };
    let mut pixel_mm = BTreeMap::new();
    if let Some(f) = &ctx.frames {
        pixel_mm = f.pixel_mm.clone();
    }
    // Products name the photos by their image file, as COLMAP and ContextCapture expect.
    for p in named.photos.values_mut() {
        if let Some(f) = p.image.as_ref().and_then(|i| i.file_name()) {
            p.name = f.to_string_lossy().into_owned();
        }
    }
    // A product a camera cannot be written to (none today: film is resampled first) is
    // skipped with the reason recorded; the orthophoto and block JSON hold the epoch.
    let mut skipped: BTreeMap<&str, String> = BTreeMap::new();
    // Reasons name files relative to the stage folder (its temporary name is per process).
    let reason =
        |e: &dyn std::fmt::Display| e.to_string().replace(&format!("{}/", dir.display()), "");
    // An epoch that oriented no photo has no model to give: none is written (nor listed),
    // the reason is (the run then ends partial, naming the epoch).
    let nothing = named.photos.is_empty();
    for (product, wanted) in [("colmap", o.colmap), ("blocks_exchange", o.blocks_exchange)] {
        if wanted && nothing {
            skipped.insert(product, "no photo of the epoch was oriented".into());
        }
    }
    if o.colmap && !nothing {
        if let Err(e) = formats::colmap::write(
            &dir.join("colmap"),
            &named,
            &formats::colmap::WriteOptions::default(),
        ) {
            let _ = std::fs::remove_dir_all(dir.join("colmap"));
            tracing::warn!("COLMAP model not written: {e}");
            skipped.insert("colmap", reason(&e));
        }
    }
    if o.blocks_exchange && !nothing {
        let mut bx = named.clone();
        // Every ImagePath is relative to the XML's folder, as the format defaults when no
        // BaseImagePath is given: frame images lie beside it, photos where they are. An
        // absolute path of this machine would tie the block to it (ContextCapture runs on
        // Windows); a relative one moves with the project's folders.
        for p in bx.photos.values_mut() {
            p.name = if film {
                format!("{RESAMPLED_DIR}/{}", p.name)
            } else {
                match &p.image {
                    Some(image) => relative_image_path(image, dir),
                    None => p.name.clone(),
                }
            };
        }
        let base = None;
        if let Err(e) = formats::blocks_exchange::write(
            &dir.join("blocks_exchange.xml"),
            &bx,
            &formats::blocks_exchange::WriteOptions {
                base_image_path: base,
                block_name: Some(project.name.clone()),
                pixel_mm,
            },
        ) {
            tracing::warn!("BlocksExchange XML not written: {e}");
            skipped.insert("blocks_exchange", reason(&e));
        }
    }
    if o.orthophoto && !orthophoto {
        skipped.insert("orthophoto", "no photo of the epoch was oriented".into());
    }
    write_json(&dir.join("skipped.json"), &skipped)?;
    if let (Some(grid), Some(tiles)) = (&grid, rendered.as_mut()) {
        let crs = Crs::parse(&project.crs)?;
        let mut rep =
            formats::ortho::write_tiles(&ortho_path, grid, &crs, &ctx.ortho, |k| tiles.tile(k))?;
        rep.image_loads = tiles.image_loads;
        rep.peak_image_bytes = tiles.peak_image_bytes;
        let mut json = serde_json::to_value(&rep)
            .map_err(|e| FormatError::invalid(dir.join("orthophoto.json"), e.to_string()))?;
        json["surface"] = serde_json::to_value(&surface_report)
            .map_err(|e| FormatError::invalid(dir.join("orthophoto.json"), e.to_string()))?;
        write_json(&dir.join("orthophoto.json"), &json)?;
        let (png, extent) = formats::ortho::preview(&ortho_path, 800)?;
        std::fs::write(dir.join("preview.png"), png)
            .map_err(|e| FormatError::io(dir.join("preview.png"), e))?;
        write_json(&dir.join("preview.json"), &extent)?;
    }
    // The frame images into the stage's folder, with their report.
    if let Some(f) = &ctx.frames {
        let to = dir.join(RESAMPLED_DIR);
        std::fs::create_dir_all(&to).map_err(|e| FormatError::io(&to, e))?;
        for j in &f.jobs {
            let name = j.target.file_name().unwrap_or_default();
            std::fs::rename(&j.target, to.join(name)).map_err(|e| FormatError::io(&j.target, e))?;
        }
        write_json(&to.join("frames.json"), &f.report(frame_reports, &to))?;
    }
    tasks.clear();
    Ok(())
}

/// `image` relative to the folder `from` ([`crate::formats::paths::relative_to`]), with
/// `/` separators (BlocksExchange readers on Windows take them).
fn relative_image_path(image: &Path, from: &Path) -> String {
    let rel = crate::formats::paths::relative_to(image, from);
    if rel.is_absolute() {
        return rel.display().to_string();
    }
    rel.components()
        .map(|c| c.as_os_str().to_string_lossy())
        .collect::<Vec<_>>()
        .join("/")
}
