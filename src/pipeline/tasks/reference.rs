//! The reference epoch's tie matching as tasks: one `pairs` task per photo whose pairs
//! with the later photos it overlaps need a search (`matching::pair_matching`). A task
//! prepares its photo and those partners and matches each pair; the stage links the
//! matches of every photo, in photo order, and adjusts the block itself (ICP, LiDAR
//! planes), as the epoch does in one process.

use super::{epoch_of, has_item, read_result, write_result, ContextCache, StageTasks, Task};
use super::{TaskKind, TaskMode, TaskSummary};
use crate::control::epoch::EpochInput;
use crate::control::reference::{self, ReferenceOptions};
use crate::lidar::GroundSurface;
use crate::matching::oriented::{BlockTieOptions, OrientedPhoto, Surface, TiePhotos};
use crate::matching::pair_matching::{
    match_photo_pairs, plan_pairs, MatchedPairs, PairMatching, PhotoPairs, PreparedPhotos,
};
use crate::pipeline::ground::ControlGround;
use crate::pipeline::stages::WorkError;
use crate::pipeline::tasks::EpochPlan;
use crate::{block::PhotoId, control::EpochError};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// A `pairs` task's result: what its photo's pairs gave.
#[derive(Serialize, Deserialize)]
struct PairsResult {
    photo: String,
    matched: MatchedPairs,
}

has_item!(PairsResult => photo);

/// The reference epoch stage's tasks (a planning run: its photos' pairs are returned as
/// tasks for other processes).
pub(crate) struct ReferenceTasks {
    tasks: StageTasks,
    /// Photo names in the epoch's order (a task's item).
    names: Vec<String>,
}

impl ReferenceTasks {
    /// The tasks of stage `stage` under output folder `output`, for the stage inputs with
    /// fingerprint `key`; writes the plan (the archive epochs' plan, without packages).
    pub(crate) fn new(
        output: &Path,
        stage: &str,
        key: &str,
        plan: &EpochPlan,
        input: &EpochInput,
    ) -> Result<Self, WorkError> {
        Ok(Self {
            tasks: StageTasks::new(output, stage, key, plan)?,
            names: input.photos.iter().map(|p| p.name.clone()).collect(),
        })
    }

    /// Removes the stage's task results (the stage has finished).
    pub(crate) fn clear(&self) {
        self.tasks.clear()
    }
}

impl PairMatching for ReferenceTasks {
    type Error = WorkError;

    /// Photos with a pair to search are tasks; pairs skipped by their prediction alone
    /// are reported here (no image is read for them).
    fn match_pairs(
        &self,
        photos: &[OrientedPhoto],
        ids: &[PhotoId],
        jobs: &[PhotoPairs],
        surface: &Surface,
        opts: &BlockTieOptions,
    ) -> Result<Vec<MatchedPairs>, WorkError> {
        let task = |job: &PhotoPairs| Task {
            kind: TaskKind::Pairs,
            stage: self.tasks.stage().to_string(),
            folder: self.tasks.folder().to_path_buf(),
            index: job.a,
            item: self.names[job.a].clone(),
            scan_orientation: None,
            round: None,
        };
        let tasks: Vec<Task> = jobs
            .iter()
            .filter(|j| j.has_search(opts))
            .map(task)
            .collect();
        self.tasks.ensure(&tasks, TaskMode::Plan, run_task)?;
        jobs.iter()
            .map(|job| {
                if job.has_search(opts) {
                    Ok(read_result::<PairsResult>(&task(job))?.matched)
                } else {
                    let mut none = PreparedPhotos::new(0);
                    match_photo_pairs(photos, ids, job, surface, opts, &mut none)
                        .map_err(|e| tie_error(self.tasks.stage(), e))
                }
            })
            .collect()
    }
}

/// A tie matching failure of the epoch of stage `stage`.
fn tie_error(stage: &str, e: impl std::fmt::Display) -> WorkError {
    EpochError::Epoch {
        epoch: stage.trim_start_matches("epoch-").to_string(),
        message: format!("tie points: {e}"),
    }
    .into()
}

/// What the `pairs` tasks of a reference epoch read, built once per process: the epoch,
/// its ground and every photo's pairs as the epoch plans them.
struct ReferenceContext {
    input: EpochInput,
    surface: Arc<GroundSurface>,
    opts: ReferenceOptions,
    jobs: Vec<PhotoPairs>,
}

impl ReferenceContext {
    fn load(plan: EpochPlan, stage: &str) -> Result<Self, WorkError> {
        let e = epoch_of(&plan.project, &plan.epoch)?;
        let input = EpochInput::build(&e.spec(), &plan.project.crs, plan.origin)?;
        let surface = ControlGround::new(&plan.project, &plan.sources, plan.origin)
            .surface_arc()?
            .clone();
        let opts = crate::pipeline::run::reference_options(e);
        let jobs = {
            let (block, images) = reference::tie_photos(&input)?;
            let tp = TiePhotos::of(&block, &images, &opts.ties).map_err(|e| tie_error(stage, e))?;
            let ground = reference::tie_surface(&surface.ground, &opts);
            plan_pairs(&tp.photos(), &ground, &opts.ties)
        };
        Ok(Self {
            input,
            surface,
            opts,
            jobs,
        })
    }
}

static CONTEXT: ContextCache<ReferenceContext> = ContextCache::new();

/// The photos of the last `pairs` task a process ran, kept for its next one (a worker runs
/// photos in about their order, so a photo's partners serve its neighbours too), and
/// dropped when it runs a task of another kind. A task takes them while it runs; a task
/// running beside it prepares its own.
static PREPARED: Mutex<Option<(PathBuf, PreparedPhotos)>> = Mutex::new(None);

/// Runs one `pairs` task (see [`super::run_task`]): the photo's pairs as the epoch plans
/// them, matched.
pub(super) fn run_task(task: &Task) -> Result<TaskSummary, WorkError> {
    if task.kind != TaskKind::Pairs {
        return Err(super::not_of(task, "a reference epoch"));
    }
    let t0 = Instant::now();
    let ctx = CONTEXT.get(task, |plan, _| ReferenceContext::load(plan, &task.stage))?;
    if ctx.input.photos.get(task.index).map(|p| &p.name) != Some(&task.item) {
        return Err(WorkError::Inconsistent(format!(
            "task {}: photo {} is not photo {} of the epoch",
            task.name(),
            task.item,
            task.index
        )));
    }
    let opts = &ctx.opts.ties;
    let job = ctx
        .jobs
        .get(task.index)
        .filter(|j| j.a == task.index && j.has_search(opts))
        .ok_or_else(|| {
            WorkError::Inconsistent(format!(
                "task {}: photo {} has no pair to search",
                task.name(),
                task.item
            ))
        })?;
    let (block, images) = reference::tie_photos(&ctx.input)?;
    let surface = reference::tie_surface(&ctx.surface.ground, &ctx.opts);
    let tp = TiePhotos::of(&block, &images, opts).map_err(|e| tie_error(&task.stage, e))?;
    let photos = tp.photos();
    let taken = PREPARED.lock().unwrap_or_else(|p| p.into_inner()).take();
    let mut prepared = match taken {
        Some((folder, p)) if folder == task.folder => p,
        // Another stage's photos are dropped before this one's are prepared.
        _ => PreparedPhotos::new(opts.image_cache_bytes),
    };
    let matched = match_photo_pairs(&photos, tp.ids(), job, &surface, opts, &mut prepared)
        .map_err(|e| tie_error(&task.stage, e));
    prepared.keep_job(job);
    *PREPARED.lock().unwrap_or_else(|p| p.into_inner()) = Some((task.folder.clone(), prepared));
    let matched = matched?;
    write_result(
        task,
        &PairsResult {
            photo: task.item.clone(),
            matched,
        },
    )?;
    Ok(TaskSummary::done(task, t0))
}

/// Drops the photos kept for the next `pairs` task (the process runs other work now).
pub(super) fn release() {
    PREPARED.lock().unwrap_or_else(|p| p.into_inner()).take();
}
