//! The reference epoch's tie matching as tasks: each `pairs` task matches a run of
//! consecutive photos with the later photos each overlaps (`matching::pair_matching`),
//! preparing each photo and its partners once; the stage links the matches of every
//! photo, in photo order, and adjusts the block itself (ICP, LiDAR planes), as the epoch
//! does in one process.

use super::{
    bad_task_file, epoch_of, has_item, read_result, write_result, ContextCache, StageTasks, Task,
    TaskData,
};
use super::{TaskKind, TaskMode, TaskSummary};
use crate::block::{Block, PhotoId};
use crate::control::epoch::EpochInput;
use crate::control::reference::{self, tie_error, ReferenceOptions};
use crate::lidar::GroundSurface;
use crate::matching::oriented::{BlockTieOptions, OrientedPhoto, Surface, TiePhotos};
use crate::matching::pair_matching::{
    match_photo_pairs, plan_pairs, MatchedPairs, PairMatching, PhotoPairs, PreparedPhotos,
};
use crate::pipeline::ground::ControlGround;
use crate::pipeline::stages::WorkError;
use crate::pipeline::tasks::EpochPlan;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// A `pairs` task's result: what each photo's pairs of its run gave, in order.
#[derive(Serialize, Deserialize)]
struct PairsResult {
    item: String,
    matched: Vec<MatchedPairs>,
}

has_item!(PairsResult => item);

impl TaskData for PairsResult {
    fn check(&self) -> Result<(), String> {
        use crate::control::task_checks as c;
        for m in self.matched.iter().flat_map(|m| &m.matches) {
            if m.inliers.len() != m.candidates.len() {
                return Err(format!(
                    "pair {}–{}: {} inlier flags for {} candidates",
                    m.a,
                    m.b,
                    m.inliers.len(),
                    m.candidates.len()
                ));
            }
            for t in &m.candidates {
                c::finite("tie candidate pixel", &[t.a[0], t.a[1], t.b[0], t.b[1]])?;
                c::finite("tie candidate ncc", &[t.ncc])?;
                c::sigma("tie candidate σ", t.sigma_px)?;
            }
            if let Some(f) = &m.fundamental {
                c::finite("fundamental matrix", f)?;
            }
            c::sigma("pair σ", m.sigma_px)?;
        }
        for r in self.matched.iter().flat_map(|m| &m.reports) {
            c::sigma("pair report σ", r.sigma_px)?;
            c::sigma("pair report overlap", r.overlap)?;
            c::sigma("pair report search radius", r.search_radius_px)?;
        }
        Ok(())
    }
}

/// A `pairs` result file read as the stage reads it ([`super::read_task_file`]).
pub(super) fn read_result_file(path: &Path) -> Result<(), WorkError> {
    super::read_msgpack::<PairsResult>(path).map(drop)
}

/// The reference epoch stage's tasks (a planning run: its photos' pairs are returned as
/// tasks for other processes).
pub(crate) struct ReferenceTasks {
    tasks: StageTasks,
    epoch: String,
}

impl ReferenceTasks {
    /// The tasks of stage `stage` under output folder `output`, for the stage inputs with
    /// fingerprint `key`; writes the plan (the archive epochs' plan, without packages).
    pub(crate) fn new(
        output: &Path,
        stage: &str,
        key: &str,
        plan: &EpochPlan,
    ) -> Result<Self, WorkError> {
        Ok(Self {
            tasks: StageTasks::new(output, stage, key, plan)?,
            epoch: plan.epoch.clone(),
        })
    }

    /// Removes the stage's task results (the stage has finished).
    pub(crate) fn clear(&self) {
        self.tasks.clear()
    }
}

impl PairMatching for ReferenceTasks {
    type Error = WorkError;

    /// Runs of photos with a pair to search are tasks; pairs skipped by their prediction
    /// alone are reported here (no image is read for them).
    fn match_pairs(
        &self,
        photos: &[OrientedPhoto],
        ids: &[PhotoId],
        jobs: &[PhotoPairs],
        surface: &Surface,
        opts: &BlockTieOptions,
    ) -> Result<Vec<MatchedPairs>, WorkError> {
        let runs = runs(jobs, opts);
        let tasks: Vec<Task> = runs
            .iter()
            .enumerate()
            .map(|(index, run)| Task {
                kind: TaskKind::Pairs,
                stage: self.tasks.stage().to_string(),
                folder: self.tasks.folder().to_path_buf(),
                index,
                item: run_item(run, jobs),
                scan_orientation: None,
                round: None,
            })
            .collect();
        self.tasks.ensure(&tasks, TaskMode::Plan, run_task)?;
        let mut found: Vec<Option<MatchedPairs>> = vec![None; jobs.len()];
        for (t, run) in tasks.iter().zip(&runs) {
            let r: PairsResult = read_result(t)?;
            if r.matched.len() != run.len() {
                return Err(crate::formats::FormatError::invalid(
                    t.result(),
                    format!(
                        "{} photos' pairs, the run has {}",
                        r.matched.len(),
                        run.len()
                    ),
                )
                .into());
            }
            // The pairs' photo indices are indices into the epoch's photos.
            if let Some(m) = r
                .matched
                .iter()
                .flat_map(|m| &m.matches)
                .find(|m| m.a >= photos.len() || m.b >= photos.len())
            {
                return Err(bad_task_file(
                    &t.result(),
                    format!(
                        "pair of photos {} and {}, the epoch has {}",
                        m.a,
                        m.b,
                        photos.len()
                    ),
                ));
            }
            for (&j, m) in run.iter().zip(r.matched) {
                found[j] = Some(m);
            }
        }
        jobs.iter()
            .zip(found)
            .map(|(job, m)| match m {
                Some(m) => Ok(m),
                None => {
                    let mut none = PreparedPhotos::new(0);
                    match_photo_pairs(photos, ids, job, surface, opts, &mut none)
                        .map_err(|e| WorkError::from(tie_error(&self.epoch, e)))
                }
            })
            .collect()
    }
}

/// Photos (with a pair to search) per `pairs` task. Consecutive photos share most of
/// their partners, so a run of them prepares each photo about once; one photo per task,
/// spread over two workers, prepared each about three times (medium seed 1: 60 s of
/// tasks against 24 s on one worker).
const PHOTOS_PER_TASK: usize = 8;

/// The `pairs` tasks: runs of consecutive photos (indices into `jobs`) with a pair to
/// search, the same in every process.
fn runs(jobs: &[PhotoPairs], opts: &BlockTieOptions) -> Vec<Vec<usize>> {
    let searched: Vec<usize> = (0..jobs.len())
        .filter(|&j| jobs[j].has_search(opts))
        .collect();
    searched
        .chunks(PHOTOS_PER_TASK)
        .map(<[usize]>::to_vec)
        .collect()
}

/// A run's task item: `photos-<first>-<last>`, the epoch's photo indices.
fn run_item(run: &[usize], jobs: &[PhotoPairs]) -> String {
    let a = |k: Option<&usize>| k.map_or(0, |&j| jobs[j].a);
    format!("photos-{}-{}", a(run.first()), a(run.last()))
}

/// What the `pairs` tasks of a reference epoch read, built once per process: the epoch,
/// its block at the POS (its photos' files checked once), its ground and every photo's
/// pairs as the epoch plans them.
struct ReferenceContext {
    input: EpochInput,
    block: Block,
    surface: Arc<GroundSurface>,
    opts: ReferenceOptions,
    jobs: Vec<PhotoPairs>,
}

impl ReferenceContext {
    fn load(plan: EpochPlan) -> Result<Self, WorkError> {
        let e = epoch_of(&plan.project, &plan.epoch)?;
        let input = EpochInput::build(&e.spec(), &plan.project.crs, plan.origin)?;
        let surface = ControlGround::new(&plan.project, &plan.sources, plan.origin)
            .surface_arc()?
            .clone();
        let opts = crate::pipeline::run::reference_options(&plan.project, e);
        let (block, images) = reference::tie_photos(&input)?;
        let tp =
            TiePhotos::of(&block, &images, &opts.ties).map_err(|e| tie_error(&input.name, e))?;
        let ground = reference::tie_surface(&surface.ground, &opts);
        let jobs = plan_pairs(&tp.photos(), &ground, &opts.ties);
        drop((tp, images));
        Ok(Self {
            input,
            block,
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
    let ctx = CONTEXT.get(task, |plan, _| ReferenceContext::load(plan))?;
    let opts = &ctx.opts.ties;
    let run = runs(&ctx.jobs, opts)
        .into_iter()
        .nth(task.index)
        .filter(|run| run_item(run, &ctx.jobs) == task.item)
        .ok_or_else(|| {
            WorkError::Inconsistent(format!(
                "task {}: not a run of photos of the epoch's pairs",
                task.name()
            ))
        })?;
    let images = reference::tie_images(&ctx.input);
    let surface = reference::tie_surface(&ctx.surface.ground, &ctx.opts);
    let tp = TiePhotos::of(&ctx.block, &images, opts).map_err(|e| tie_error(&ctx.input.name, e))?;
    let photos = tp.photos();
    let taken = PREPARED.lock().unwrap_or_else(|p| p.into_inner()).take();
    let mut prepared = match taken {
        Some((folder, p)) if folder == task.folder => p,
        // Another stage's photos are dropped before this one's are prepared.
        _ => PreparedPhotos::new(opts.image_cache_bytes),
    };
    let matched: Result<Vec<MatchedPairs>, WorkError> = run
        .iter()
        .map(|&j| {
            match_photo_pairs(
                &photos,
                tp.ids(),
                &ctx.jobs[j],
                &surface,
                opts,
                &mut prepared,
            )
            .map_err(|e| WorkError::from(tie_error(&ctx.input.name, e)))
        })
        .collect();
    if let Some(&last) = run.last() {
        prepared.keep_job(&ctx.jobs[last]);
    }
    *PREPARED.lock().unwrap_or_else(|p| p.into_inner()) = Some((task.folder.clone(), prepared));
    let matched = matched?;
    write_result(
        task,
        &PairsResult {
            item: task.item.clone(),
            matched,
        },
    )?;
    Ok(TaskSummary::done(task, t0))
}

/// Drops the photos kept for the next `pairs` task (the process runs other work now).
pub(super) fn release() {
    PREPARED.lock().unwrap_or_else(|p| p.into_inner()).take();
}
