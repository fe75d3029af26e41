//! An epoch's surface as tasks: `stereo`, one stereo pair of the epoch's plan
//! ([`crate::dense::epoch::plan_surface`]) matched into samples of the DSM grid (cell and
//! height, 8 bytes a matched pixel). The stage (`pipeline::surface`) fuses every pair's
//! samples in pair order, so the DSM does not depend on where the pairs were matched.

use super::{
    bad_task_file, epoch_of, has_item, not_of, read_result, write_result, ContextCache, StageTasks,
    Task, TaskData, TaskKind, TaskMode, TaskSummary,
};
use crate::block::{Block, Photo};
use crate::dense::epoch::{match_plan_pair, plan_surface, DsmOptions, PairReport, SurfacePlan};
use crate::dense::DenseError;
use crate::lidar::GroundSurface;
use crate::matching::oriented::Surface;
use crate::matching::GreyImage;
use crate::pipeline::epoch_files::load_block;
use crate::pipeline::ground::ControlGround;
use crate::pipeline::project::Project;
use crate::pipeline::stages::WorkError;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

/// What every task of an epoch's surface shares (`plan.json`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SurfaceTaskPlan {
    /// The project, its paths resolved.
    pub project: Project,
    pub epoch: String,
    /// The `sources` stage's folder (the control's surface model, the prior).
    pub sources: PathBuf,
    /// The epoch stage's folder (the oriented block).
    pub epoch_dir: PathBuf,
    pub origin: [f64; 3],
    pub options: DsmOptions,
}

/// What the tasks of one surface stage read: the oriented block, the prior surface
/// (block-local) and the plan made from them (`Err`: why the epoch has no surface).
pub(crate) struct SurfaceContext {
    pub block: Block,
    pub ground: Arc<GroundSurface>,
    pub options: DsmOptions,
    pub plan: Result<SurfacePlan, String>,
}

impl SurfaceContext {
    /// Builds the context from a plan (a worker's way; the stage builds the same).
    pub(crate) fn load(plan: &SurfaceTaskPlan) -> Result<Self, WorkError> {
        epoch_of(&plan.project, &plan.epoch)?;
        let block = load_block(&plan.epoch_dir)?;
        let control = ControlGround::new(&plan.project, &plan.sources, plan.origin);
        let ground = control.surface_arc()?.clone();
        // On the project's lattice: the DSM lines up with every other raster of the run.
        let mut options = plan.options.clone();
        options.corner = Some(control.lattice()?.corner);
        let surface = prior(&ground);
        let made = match plan_surface(&block, &surface, None, &options) {
            Ok(p) => Ok(p),
            Err(DenseError::NoSurface(reason)) => Err(reason),
            Err(e) => return Err(e.into()),
        };
        Ok(Self {
            block,
            ground,
            options,
            plan: made,
        })
    }

    /// The prior the search is bounded by.
    pub(crate) fn prior(&self) -> Surface<'_> {
        prior(&self.ground)
    }
}

fn prior(ground: &GroundSurface) -> Surface<'_> {
    Surface::Dem {
        dem: &ground.surface,
        origin: Vector3::zeros(),
        sigma_m: 0.0,
    }
}

/// A `stereo` task's result: the pair's report and its samples, each a little-endian
/// `u32` cell index then an `f32` height.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(crate) struct StereoResult {
    pair: String,
    pub report: PairReport,
    #[serde(with = "serde_bytes")]
    samples: Vec<u8>,
}

has_item!(StereoResult => pair);

/// Bytes of a sample in [`StereoResult`].
const SAMPLE_BYTES: usize = 8;

impl StereoResult {
    /// The samples, their cells below `cells` (the grid's) or an error naming the first
    /// that is not.
    pub(crate) fn samples(&self, cells: usize) -> Result<Vec<(u32, f32)>, String> {
        self.samples
            .chunks_exact(SAMPLE_BYTES)
            .map(|b| {
                let cell = u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
                let z = f32::from_le_bytes([b[4], b[5], b[6], b[7]]);
                if cell as usize >= cells {
                    return Err(format!("sample in cell {cell} of a grid of {cells}"));
                }
                Ok((cell, z))
            })
            .collect()
    }
}

impl TaskData for StereoResult {
    fn check(&self) -> Result<(), String> {
        if self.samples.len() % SAMPLE_BYTES != 0 {
            return Err(format!(
                "{} bytes of samples are not samples of {SAMPLE_BYTES} bytes",
                self.samples.len()
            ));
        }
        let n = self.samples.len() / SAMPLE_BYTES;
        if self.report.points != n {
            return Err(format!(
                "{} points reported, {n} samples held",
                self.report.points
            ));
        }
        if let Some(k) = self
            .samples
            .chunks_exact(SAMPLE_BYTES)
            .position(|b| !f32::from_le_bytes([b[4], b[5], b[6], b[7]]).is_finite())
        {
            return Err(format!("sample {k}: height not finite"));
        }
        let r = &self.report;
        if !(r.matched.is_finite() && (0.0..=1.0).contains(&r.matched)) {
            return Err(format!("matched share {}", r.matched));
        }
        Ok(())
    }
}

/// A `stereo` result file read as the stage reads it ([`super::read_task_file`]).
pub(super) fn read_result_file(path: &Path) -> Result<(), WorkError> {
    super::read_msgpack::<StereoResult>(path).map(drop)
}

/// The tasks of one surface stage of a run.
pub(crate) struct SurfaceTasks(StageTasks);

impl SurfaceTasks {
    pub(crate) fn new(
        output: &Path,
        stage: &str,
        key: &str,
        plan: &SurfaceTaskPlan,
    ) -> Result<Self, WorkError> {
        Ok(Self(StageTasks::new(output, stage, key, plan)?))
    }

    /// Makes sure every pair of `plan` is matched (here, one pair at a time, or returned
    /// as pending); then hands each pair's report and samples to `take`, in pair order.
    pub(crate) fn stereo(
        &self,
        ctx: &SurfaceContext,
        plan: &SurfacePlan,
        mode: TaskMode,
        mut take: impl FnMut(PairReport, Vec<(u32, f32)>),
    ) -> Result<(), WorkError> {
        let names: Vec<String> = plan
            .pairs
            .iter()
            .map(|p| pair_name(&ctx.block, p))
            .collect();
        let tasks = self
            .0
            .tasks(TaskKind::Stereo, names.iter().map(String::as_str), None);
        self.0.ensure_in_turn(&tasks, mode, |t| execute(t, ctx))?;
        let cells = plan.grid.cells();
        for t in &tasks {
            let r: StereoResult = read_result(t)?;
            let samples = r
                .samples(cells)
                .map_err(|m| bad_task_file(&t.result(), m))?;
            take(r.report, samples);
        }
        Ok(())
    }

    pub(crate) fn clear(&self) {
        self.0.clear()
    }
}

/// A pair's item name: its photos' names.
fn pair_name(block: &Block, p: &crate::dense::pairs::StereoPair) -> String {
    let name = |id| {
        block
            .photos
            .get(&id)
            .map_or_else(|| id.to_string(), |ph: &Photo| ph.name.clone())
    };
    format!("{}+{}", name(p.left), name(p.right))
}

fn execute(task: &Task, ctx: &SurfaceContext) -> Result<TaskSummary, WorkError> {
    let t0 = Instant::now();
    if task.kind != TaskKind::Stereo {
        return Err(not_of(task, "an epoch's surface"));
    }
    let plan = ctx.plan.as_ref().map_err(|reason| {
        WorkError::Inconsistent(format!(
            "task {}: the epoch has no surface: {reason}",
            task.name()
        ))
    })?;
    let pair = plan
        .pairs
        .get(task.index)
        .filter(|p| pair_name(&ctx.block, p) == task.item)
        .ok_or_else(|| {
            WorkError::Inconsistent(format!(
                "task {}: not pair {} of the epoch's {}",
                task.name(),
                task.index,
                plan.pairs.len()
            ))
        })?;
    let load = |p: &Photo| -> crate::dense::Result<Arc<GreyImage>> {
        let path = p.image.as_ref().ok_or_else(|| {
            crate::dense::invalid(&p.name, format!("photo {} has no image file", p.name))
        })?;
        GreyImage::load(path)
            .map(Arc::new)
            .map_err(|e| crate::dense::invalid(&p.name, e.to_string()))
    };
    let mut samples = Vec::new();
    let report = match_plan_pair(
        &ctx.block,
        plan,
        pair,
        &ctx.prior(),
        &ctx.options,
        load,
        |s| {
            for &(cell, z) in s {
                samples.extend_from_slice(&cell.to_le_bytes());
                samples.extend_from_slice(&z.to_le_bytes());
            }
        },
    )?;
    tracing::info!(
        pair = task.index + 1,
        of = plan.pairs.len(),
        photos = %task.item,
        matched = report.matched,
        seconds = report.seconds,
        "pair matched"
    );
    write_result(
        task,
        &StereoResult {
            pair: task.item.clone(),
            report,
            samples,
        },
    )?;
    Ok(TaskSummary::done(task, t0))
}

static CONTEXT: ContextCache<SurfaceContext> = ContextCache::new();

/// Runs one task of a surface stage (see [`super::run_task`]).
pub(super) fn run_task(task: &Task) -> Result<TaskSummary, WorkError> {
    let ctx = CONTEXT.get(task, |plan: SurfaceTaskPlan, _| SurfaceContext::load(&plan))?;
    execute(task, &ctx)
}
