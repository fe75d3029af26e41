//! The products of an epoch as tasks: a film epoch's `resample` (a scan into its frame
//! image, [`FrameJob::resample`]) for every oriented scan, then `ortho` (a run of
//! [`ORTHO_TILES_PER_TASK`] consecutive orthophoto tiles, [`TileRenderer`]) over the
//! whole orthophoto. The stage writes the GeoTIFF from the tiles (one at a time, in the
//! order it would render them itself), the COLMAP model and the BlocksExchange XML, and
//! moves the frame images (made in the task folder's `resampled/`) into its own.

use super::{
    epoch_of, has_item, not_of, read_result, write_result, ContextCache, StageTasks, Task,
    TaskData, TaskKind, TaskMode, TaskSummary,
};
use crate::block::Block;
use crate::control::task_checks as c;
use crate::formats::ortho::{OrthoGrid, OrthoOptions, PhotoImages, RenderedTile, TileRenderer};
use crate::geometry::Dem;
use crate::matching::fiducial::FrameImageReport;
use crate::pipeline::film_frames::{FramePlan, RESAMPLED_DIR};
use crate::pipeline::ground::ControlGround;
use crate::pipeline::products;
use crate::pipeline::project::Project;
use crate::pipeline::stages::WorkError;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Orthophoto tiles (256 px) a task renders: 2 M pixels, a few seconds' work, and runs of
/// consecutive tiles along the Hilbert curve share their photos in the task's cache.
pub const ORTHO_TILES_PER_TASK: usize = 32;

/// What every task of an epoch's products shares (`plan.json`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct OutputsPlan {
    /// The project, its paths resolved.
    pub project: Project,
    pub epoch: String,
    /// The `sources` stage's folder (the ground to rectify onto).
    pub sources: PathBuf,
    /// The epoch stage's folder (the oriented block).
    pub epoch_dir: PathBuf,
    pub origin: [f64; 3],
    /// The epoch's surface stage folder, when the orthophoto is rectified onto its DSM.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub surface_dir: Option<PathBuf>,
}

/// Everything the tasks of one products stage read: the block of the products (a film
/// epoch's moved into its frame images, made in the task folder), the DEM in world
/// coordinates and the orthophoto options.
pub(crate) struct OutputsContext {
    pub block: Block,
    pub frames: Option<FramePlan>,
    pub dem: Dem,
    pub ortho: OrthoOptions,
}

impl OutputsContext {
    /// The photos' image files by photo id.
    pub(crate) fn files(&self) -> BTreeMap<u32, PathBuf> {
        self.block
            .photos
            .iter()
            .filter_map(|(id, p)| Some((*id, p.image.clone()?)))
            .collect()
    }

    /// Builds the context from a plan (a worker's way; the stage builds the same).
    fn load(plan: &OutputsPlan, folder: &Path) -> Result<Self, WorkError> {
        let epoch = epoch_of(&plan.project, &plan.epoch)?;
        let (block, frames) = products::product_block(
            &plan.project,
            epoch,
            None,
            &plan.epoch_dir,
            &folder.join(RESAMPLED_DIR),
        )?;
        let ground = ControlGround::new(&plan.project, &plan.sources, plan.origin);
        let (control, ortho) = products::ortho_ground(&plan.project, &block, &ground, plan.origin)?;
        let (dem, _) = products::ortho_surface(&control, plan.surface_dir.as_deref())?;
        Ok(Self {
            block,
            frames,
            dem,
            ortho,
        })
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct ResampleResult {
    photo: String,
    report: FrameImageReport,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct OrthoResult {
    tiles_of: String,
    tiles: Vec<RenderedTile>,
    image_loads: usize,
    peak_image_bytes: u64,
}

has_item!(ResampleResult => photo, OrthoResult => tiles_of);

impl TaskData for ResampleResult {
    fn check(&self) -> Result<(), String> {
        let f = &self.report.frame;
        if f.width == 0 || f.height == 0 || !(f.pixel_mm.is_finite() && f.pixel_mm > 0.0) {
            return Err(format!(
                "frame of {}×{} pixels of {} mm",
                f.width, f.height, f.pixel_mm
            ));
        }
        let pixels = u64::from(f.width) * u64::from(f.height);
        c::at_most("masked pixels", self.report.masked_pixels, pixels as usize)?;
        if !matches!(self.report.bits, 8 | 16) {
            return Err(format!("{} bits per pixel (8 or 16)", self.report.bits));
        }
        Ok(())
    }
}

impl TaskData for OrthoResult {
    fn check(&self) -> Result<(), String> {
        // Each tile's place and size are checked against the grid where it is written
        // (`formats::ortho::write_tiles`).
        for t in &self.tiles {
            if t.bands.len() % 4 != 0 {
                return Err(format!(
                    "tile {:?}: {} bytes are not four bands",
                    t.tile,
                    t.bands.len()
                ));
            }
            let pixels = t.bands.len() / 4;
            c::at_most("filled cells", t.filled, pixels)?;
            c::at_most("occluded cells", t.occluded, pixels)?;
            c::at_most(
                "cells of the photos",
                t.per_photo
                    .values()
                    .fold(0usize, |a, &v| a.saturating_add(v)),
                pixels,
            )?;
        }
        Ok(())
    }
}

/// A `resample` or `ortho` result file read as the stage reads it
/// ([`super::read_task_file`]).
pub(super) fn read_result_file(kind: TaskKind, path: &Path) -> Result<(), WorkError> {
    match kind {
        TaskKind::Resample => super::read_msgpack::<ResampleResult>(path).map(drop),
        _ => super::read_msgpack::<OrthoResult>(path).map(drop),
    }
}

/// The tasks of one products stage of a run.
pub(crate) struct OutputTasks(StageTasks);

impl OutputTasks {
    pub(crate) fn new(
        output: &Path,
        stage: &str,
        key: &str,
        plan: &OutputsPlan,
    ) -> Result<Self, WorkError> {
        Ok(Self(StageTasks::new(output, stage, key, plan)?))
    }

    /// Where a film epoch's frame images are made.
    pub(crate) fn resampled(&self) -> PathBuf {
        self.0.folder().join(RESAMPLED_DIR)
    }

    /// Every scan resampled into its frame image (run here, or returned as pending); the
    /// reports in job order.
    pub(crate) fn resample(
        &self,
        ctx: &OutputsContext,
        mode: TaskMode,
    ) -> Result<Vec<FrameImageReport>, WorkError> {
        let Some(frames) = &ctx.frames else {
            return Ok(Vec::new());
        };
        let tasks = self.0.tasks(
            TaskKind::Resample,
            frames.jobs.iter().map(|j| j.name.as_str()),
            None,
        );
        // A result whose frame image has gone (moved by a stage that did not finish) is
        // made again.
        for (t, j) in tasks.iter().zip(&frames.jobs) {
            if t.result().is_file() && !j.target.is_file() {
                let _ = std::fs::remove_file(t.result());
            }
        }
        self.0.ensure(&tasks, mode, |t| execute(t, ctx))?;
        tasks
            .iter()
            .map(|t| read_result::<ResampleResult>(t).map(|r| r.report))
            .collect()
    }

    /// Makes sure every run of tiles of `grid` is rendered (here, or returned as
    /// pending); then `tile(k)` reads the k-th tile of [`OrthoGrid::tiles`] back, one run
    /// in memory at a time, and `loads()` sums the tasks' image counts.
    pub(crate) fn ortho(
        &self,
        grid: &OrthoGrid,
        ctx: &OutputsContext,
        mode: TaskMode,
    ) -> Result<OrthoTiles, WorkError> {
        let runs = grid.tiles().len().div_ceil(ORTHO_TILES_PER_TASK);
        let names: Vec<String> = (0..runs).map(run_name).collect();
        let tasks = self
            .0
            .tasks(TaskKind::Ortho, names.iter().map(String::as_str), None);
        self.0.ensure(&tasks, mode, |t| execute(t, ctx))?;
        Ok(OrthoTiles {
            tasks,
            current: None,
            image_loads: 0,
            peak_image_bytes: 0,
        })
    }

    pub(crate) fn clear(&self) {
        self.0.clear()
    }
}

fn run_name(k: usize) -> String {
    let first = k * ORTHO_TILES_PER_TASK;
    format!("tiles-{first:05}-{:05}", first + ORTHO_TILES_PER_TASK - 1)
}

/// The rendered tiles of an orthophoto, read back run by run.
pub(crate) struct OrthoTiles {
    tasks: Vec<Task>,
    current: Option<(usize, std::vec::IntoIter<RenderedTile>)>,
    pub image_loads: usize,
    pub peak_image_bytes: u64,
}

impl OrthoTiles {
    /// Tile `k` (asked for in order).
    pub(crate) fn tile(&mut self, k: usize) -> crate::formats::Result<RenderedTile> {
        let run = k / ORTHO_TILES_PER_TASK;
        if self.current.as_ref().map(|c| c.0) != Some(run) {
            let folder = self
                .tasks
                .first()
                .map(|t| t.folder.clone())
                .unwrap_or_default();
            let task = self.tasks.get(run).ok_or_else(|| {
                crate::formats::FormatError::invalid(folder, format!("no task renders tile {k}"))
            })?;
            // read_result fails only reading or decoding the file (a format error).
            let r: OrthoResult = read_result(task).map_err(|e| match e {
                WorkError::Format(f) => f,
                e => crate::formats::FormatError::invalid(task.result(), e.to_string()),
            })?;
            self.image_loads += r.image_loads;
            self.peak_image_bytes = self.peak_image_bytes.max(r.peak_image_bytes);
            self.current = Some((run, r.tiles.into_iter()));
        }
        let path = self.tasks[run].result();
        self.current
            .as_mut()
            .and_then(|c| c.1.next())
            .ok_or_else(|| crate::formats::FormatError::invalid(&path, format!("tile {k} missing")))
    }
}

fn execute(task: &Task, ctx: &OutputsContext) -> Result<TaskSummary, WorkError> {
    let t0 = Instant::now();
    match task.kind {
        TaskKind::Resample => {
            let job = ctx
                .frames
                .as_ref()
                .and_then(|f| f.jobs.get(task.index))
                .filter(|j| j.name == task.item)
                .ok_or_else(|| {
                    WorkError::Inconsistent(format!(
                        "task {}: photo {} is not scan {} of the epoch",
                        task.name(),
                        task.item,
                        task.index
                    ))
                })?;
            let frame = &ctx.frames.as_ref().expect("a job has its frames").frame;
            let report = job.resample(frame)?;
            write_result(
                task,
                &ResampleResult {
                    photo: task.item.clone(),
                    report,
                },
            )?;
        }
        TaskKind::Ortho => {
            let out = task.result();
            let files = ctx.files();
            let grid = OrthoGrid::new(
                &out,
                &ctx.block,
                &ctx.dem,
                &PhotoImages::Files(&files),
                &ctx.ortho,
            )?;
            let all = grid.tiles();
            let first = task.index * ORTHO_TILES_PER_TASK;
            if task.item != run_name(task.index) || first >= all.len() {
                return Err(WorkError::Inconsistent(format!(
                    "task {}: the orthophoto has {} tiles",
                    task.name(),
                    all.len()
                )));
            }
            let mut renderer = TileRenderer::new(
                &grid,
                PhotoImages::Files(&files),
                ctx.ortho.image_cache_bytes,
                &out,
            );
            let tiles = all[first..(first + ORTHO_TILES_PER_TASK).min(all.len())]
                .iter()
                .map(|&t| renderer.render(t))
                .collect::<crate::formats::Result<Vec<_>>>()?;
            write_result(
                task,
                &OrthoResult {
                    tiles_of: task.item.clone(),
                    tiles,
                    image_loads: renderer.image_loads(),
                    peak_image_bytes: renderer.peak_image_bytes(),
                },
            )?;
        }
        _ => return Err(not_of(task, "an epoch's products")),
    }
    Ok(TaskSummary::done(task, t0))
}

static CONTEXT: ContextCache<OutputsContext> = ContextCache::new();

/// Runs one task of a products stage (see [`super::run_task`]).
pub(super) fn run_task(task: &Task) -> Result<TaskSummary, WorkError> {
    let ctx = CONTEXT.get(task, |plan, folder| OutputsContext::load(&plan, folder))?;
    execute(task, &ctx)
}
