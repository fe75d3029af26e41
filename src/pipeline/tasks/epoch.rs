//! The per-photo tasks of an archive epoch: a film epoch's `scan` round (the scans'
//! fiducials, [`measure_scan`]) and the `orient` round (each photo's first orientation from
//! the control patches; a film epoch's task carries the epoch's majority scan orientation,
//! taken once from the `scan` results). The epoch-wide part (second pass, tie points,
//! block adjustment) then runs on the results.

use super::{
    bad_task_file, epoch_of, has_item, not_of, read_result, write_result, ContextCache, StageTasks,
    Task, TaskData, TaskKind, TaskMode, TaskSummary,
};
use crate::control::archive::{ArchiveContext, ArchiveOptions, FirstPass};
use crate::control::dcp::DcpPackage;
use crate::control::epoch::{EpochCamera, EpochInput};
use crate::control::photo::PhotoOrientation;
use crate::control::scan_cameras::{
    epoch_majority, measure_scan, resolve_scan, Candidates, ScanCameras, ScanMeasure,
};
use crate::control::task_checks as tc;
use crate::geometry::Camera;
use crate::lidar::GroundSurface;
use crate::matching::ScanOrientation;
use crate::pipeline::ground::ControlGround;
use crate::pipeline::project::Project;
use crate::pipeline::stages::WorkError;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

/// What every task of an epoch stage shares (`plan.json`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EpochPlan {
    /// The project, its paths resolved.
    pub project: Project,
    pub epoch: String,
    /// The `sources` stage's folder (origin, cleaned LiDAR).
    pub sources: PathBuf,
    /// The DCP packages the epoch is oriented from, in the run's order.
    pub packages: Vec<PathBuf>,
    pub origin: [f64; 3],
}

/// An `orient` task's result: the photo's first orientation and, for a film scan, the
/// candidate cameras it was oriented with (the epoch's second pass and tie pass use them).
#[derive(Debug, Clone, Serialize, Deserialize)]
struct OrientResult {
    photo: String,
    orientation: PhotoOrientation,
    candidates: Option<Candidates>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct ScanResult {
    photo: String,
    measure: Option<ScanMeasure>,
}

/// Everything the tasks of one epoch stage read, built once per process.
pub struct EpochContext {
    pub plan: EpochPlan,
    pub input: EpochInput,
    pub opts: ArchiveOptions,
    pub surface: Arc<GroundSurface>,
    pub packages: Vec<DcpPackage>,
}

impl EpochContext {
    /// Builds the context from a plan, reading what it names (a worker's way).
    pub fn load(plan: EpochPlan) -> Result<Self, WorkError> {
        let e = epoch_of(&plan.project, &plan.epoch)?;
        let input = EpochInput::build(&e.spec(), &plan.project.crs, plan.origin)?;
        let opts = crate::pipeline::run::archive_options(&plan.project, e);
        let surface = ControlGround::new(&plan.project, &plan.sources, plan.origin)
            .surface_arc()?
            .clone();
        let packages = open_packages(&plan.packages)?;
        Ok(Self {
            plan,
            input,
            opts,
            surface,
            packages,
        })
    }
}

pub fn open_packages(dirs: &[PathBuf]) -> Result<Vec<DcpPackage>, WorkError> {
    Ok(dirs
        .iter()
        .map(|d| DcpPackage::open(&d.join("package")))
        .collect::<Result<Vec<_>, _>>()?)
}

/// The tasks of one archive epoch stage of a run.
pub(crate) struct EpochTasks(StageTasks);

impl EpochTasks {
    /// The tasks of stage `stage` under output folder `output`, for the stage inputs with
    /// fingerprint `key`; writes the plan.
    pub(crate) fn new(
        output: &Path,
        stage: &str,
        key: &str,
        plan: &EpochPlan,
    ) -> Result<Self, WorkError> {
        Ok(Self(StageTasks::new(output, stage, key, plan)?))
    }

    fn tasks(
        &self,
        kind: TaskKind,
        input: &EpochInput,
        scan_orientation: Option<ScanOrientation>,
    ) -> Vec<Task> {
        self.0.tasks(
            kind,
            input.photos.iter().map(|p| p.name.as_str()),
            scan_orientation,
        )
    }

    fn ensure(
        &self,
        tasks: &[Task],
        ctx: &EpochContext,
        archive: &ArchiveContext,
        mode: TaskMode,
    ) -> Result<(), WorkError> {
        self.0
            .ensure(tasks, mode, |t| execute_with(t, ctx, archive))
    }

    /// The epoch's per-photo part, from the task results (running or returning the
    /// missing tasks first).
    pub(crate) fn first_pass(
        &self,
        ctx: &EpochContext,
        archive: &ArchiveContext,
        mode: TaskMode,
    ) -> Result<FirstPass, WorkError> {
        let film = matches!(ctx.input.camera, EpochCamera::Film(_));
        let majority = if film {
            let scans = self.tasks(TaskKind::Scan, &ctx.input, None);
            self.ensure(&scans, ctx, archive, mode)?;
            let mut measures = Vec::new();
            for t in &scans {
                let r: ScanResult = read_result(t)?;
                measures.extend(r.measure);
            }
            epoch_majority(&measures, archive.io_options())
        } else {
            None
        };
        let orients = self.tasks(TaskKind::Orient, &ctx.input, majority);
        self.ensure(&orients, ctx, archive, mode)?;
        let mut outcomes = Vec::with_capacity(orients.len());
        let mut by_photo = HashMap::new();
        let points = archive.store.points.len();
        for t in &orients {
            let r: OrientResult = read_result(t)?;
            r.orientation
                .check(points)
                .map_err(|e| bad_task_file(&t.result(), e))?;
            if let Some(c) = r.candidates {
                by_photo.insert(r.photo.clone(), c);
            }
            outcomes.push(r.orientation);
        }
        let scans = film.then(|| ScanCameras::from_parts(by_photo, majority));
        Ok(FirstPass { scans, outcomes })
    }

    /// The rounds of the epoch's global passes as tasks of this stage (`majority`: a film
    /// epoch's majority scan orientation, from its first pass).
    pub(crate) fn rounds<'a>(
        &'a self,
        ctx: &'a EpochContext,
        mode: TaskMode,
        majority: Option<ScanOrientation>,
    ) -> super::rounds::TaskRounds<'a> {
        super::rounds::TaskRounds::new(&self.0, ctx, mode, majority)
    }

    /// Removes the stage's task results (the stage has finished).
    pub(crate) fn clear(&self) {
        self.0.clear()
    }
}

/// A film photo's candidate cameras as its `orient` task found them, with the epoch's
/// majority scan orientation (the task's): what a round task of the photo orients it
/// with. `None` for a frame camera.
pub(super) fn own_scans(task: &Task, ctx: &EpochContext) -> Result<Option<ScanCameras>, WorkError> {
    if !matches!(ctx.input.camera, EpochCamera::Film(_)) {
        return Ok(None);
    }
    let own: OrientResult = read_result(&Task {
        kind: TaskKind::Orient,
        round: None,
        ..task.clone()
    })?;
    let by_photo = own
        .candidates
        .into_iter()
        .map(|c| (own.photo.clone(), c))
        .collect();
    Ok(Some(ScanCameras::from_parts(
        by_photo,
        task.scan_orientation,
    )))
}

has_item!(OrientResult => photo, ScanResult => photo);

/// A scan's candidate cameras: film cameras and their fiducial fits sane.
fn check_candidates(c: &Option<Candidates>) -> Result<(), String> {
    for (cam, io) in c.iter().flat_map(|c| c.iter().flatten()) {
        tc::camera("candidate camera", &Camera::Film(cam.clone()))?;
        tc::sigma("candidate rmse_um", io.rmse_um)?;
        if !(io.pixel_um.is_finite() && io.pixel_um > 0.0) {
            return Err(format!(
                "candidate pixel_um = {} is not a pixel size",
                io.pixel_um
            ));
        }
    }
    Ok(())
}

impl TaskData for OrientResult {
    fn check(&self) -> Result<(), String> {
        // The match indices are checked against the epoch's store where it is at hand
        // ([`EpochTasks::first_pass`]).
        self.orientation.check(usize::MAX)?;
        check_candidates(&self.candidates)
    }
}

impl TaskData for ScanResult {
    fn check(&self) -> Result<(), String> {
        match &self.measure {
            Some(m) => check_candidates(&m.candidates),
            None => Ok(()),
        }
    }
}

/// A `scan` or `orient` result file read as the stage reads it ([`super::read_task_file`]).
pub(super) fn read_result_file(kind: TaskKind, path: &Path) -> Result<(), WorkError> {
    match kind {
        TaskKind::Scan => super::read_msgpack::<ScanResult>(path).map(drop),
        _ => super::read_msgpack::<OrientResult>(path).map(drop),
    }
}

/// Runs one task with the stage's context and writes its result.
fn execute_with(
    task: &Task,
    ctx: &EpochContext,
    archive: &ArchiveContext,
) -> Result<TaskSummary, WorkError> {
    let t0 = Instant::now();
    let photo = ctx
        .input
        .photos
        .get(task.index)
        .filter(|p| p.name == task.item)
        .ok_or_else(|| {
            WorkError::Inconsistent(format!(
                "task {}: photo {} is not photo {} of epoch {}",
                task.name(),
                task.item,
                task.index,
                ctx.plan.epoch
            ))
        })?;
    let dem = &ctx.surface.ground;
    let (ok, reason) = match (task.kind, &ctx.input.camera) {
        (TaskKind::Scan, EpochCamera::Film(def)) => {
            let measure = measure_scan(def, photo, archive.io_options());
            let reason = match &measure {
                None => Some("the scan cannot be read".to_string()),
                Some(ScanMeasure {
                    candidates: Some(Err(e)),
                    ..
                }) => Some(e.clone()),
                _ => None,
            };
            write_result(
                task,
                &ScanResult {
                    photo: photo.name.clone(),
                    measure,
                },
            )?;
            (reason.is_none(), reason)
        }
        (
            TaskKind::Screen
            | TaskKind::Clean
            | TaskKind::Resample
            | TaskKind::Ortho
            | TaskKind::Chips
            | TaskKind::Pairs
            | TaskKind::Stereo,
            _,
        ) => return Err(not_of(task, "an archive epoch")),
        (TaskKind::Cut | TaskKind::Match | TaskKind::Reorient, _) => {
            return super::rounds::run_task(task, ctx, archive)
        }
        (TaskKind::Scan, EpochCamera::Frame(_)) => {
            return Err(WorkError::Inconsistent(format!(
                "task {}: epoch {} has a frame camera, no scans",
                task.name(),
                ctx.plan.epoch
            )))
        }
        (TaskKind::Orient, camera) => {
            let (scans, candidates) = match camera {
                EpochCamera::Film(def) => {
                    let majority = task.scan_orientation;
                    let own: ScanResult = read_result(&Task {
                        kind: TaskKind::Scan,
                        ..task.clone()
                    })?;
                    let c = own
                        .measure
                        .as_ref()
                        .and_then(|m| resolve_scan(def, photo, m, majority, archive.io_options()));
                    let by_photo = c.iter().map(|c| (photo.name.clone(), c.clone())).collect();
                    (Some(ScanCameras::from_parts(by_photo, majority)), c)
                }
                EpochCamera::Frame(_) => (None, None),
            };
            let orientation = archive.orient(photo, camera, dem, scans.as_ref());
            let summary = (
                orientation.report.oriented,
                orientation.report.reason.as_ref().map(|r| r.to_string()),
            );
            write_result(
                task,
                &OrientResult {
                    photo: photo.name.clone(),
                    orientation,
                    candidates,
                },
            )?;
            summary
        }
    };
    Ok(TaskSummary {
        task: task.name(),
        item: task.item.clone(),
        ok,
        reason,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

static CONTEXT: ContextCache<EpochContext> = ContextCache::new();

/// Runs one task of an epoch stage (see [`super::run_task`]).
pub(super) fn run_task(task: &Task) -> Result<TaskSummary, WorkError> {
    let ctx = CONTEXT.get(task, |plan, _| EpochContext::load(plan))?;
    let archive = ArchiveContext::new(&ctx.input, &ctx.packages, &ctx.surface.ground, &ctx.opts)?;
    execute_with(task, &ctx, &archive)
}
