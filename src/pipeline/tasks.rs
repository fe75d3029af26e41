//! The per-photo work of an archive epoch as tasks: data a process can run anywhere the
//! output folder is shared (a Dask worker, `bindings/python/cloudcontrol/distributed.py`),
//! or the run itself in this process. Either way each task writes one result file,
//! atomically, and the epoch stage reads every result back before its epoch-wide part
//! (second pass, tie points, block adjustment), so a run's products do not depend on
//! where or in what order the tasks ran.
//!
//! A stage's tasks live in `tasks/<stage>/<key>/`, `key` the first 16 hex digits of the
//! stage's input fingerprint: `plan.json` (what every task of the stage shares) and one
//! `<kind>-<photo index>.msgpack` per finished task. MessagePack keeps every f64 exact and
//! NaN as NaN (a failed photo's σ), which JSON does not. The folder is removed when the
//! stage has finished.
//!
//! A film epoch has two kinds, run one after the other: `scan` (the scan's fiducials,
//! [`measure_scan`]) and `orient` (the photo's first orientation from the control patches;
//! its task carries the epoch's majority scan orientation, taken once from the `scan`
//! results).

use super::ground::ControlGround;
use super::project::Project;
use super::stages::WorkError;
use crate::control::archive::{ArchiveContext, ArchiveOptions, FirstPass};
use crate::control::dcp::DcpPackage;
use crate::control::epoch::{EpochCamera, EpochInput};
use crate::control::photo::PhotoOrientation;
use crate::control::scan_cameras::{
    epoch_majority, measure_scan, resolve_scan, Candidates, ScanCameras, ScanMeasure,
};
use crate::formats::{write_bytes_atomically, FormatError};
use crate::lidar::GroundSurface;
use crate::matching::ScanOrientation;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// What a task does.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TaskKind {
    /// A film scan's fiducial interior orientation.
    Scan,
    /// A photo's first orientation from the control patches.
    Orient,
}

impl TaskKind {
    fn label(self) -> &'static str {
        match self {
            TaskKind::Scan => "scan",
            TaskKind::Orient => "orient",
        }
    }
}

/// One task: a photo of an epoch stage, the folder of the stage's tasks (its `plan.json`
/// says the rest).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Task {
    pub kind: TaskKind,
    pub stage: String,
    pub folder: PathBuf,
    /// Index of the photo in the epoch (its photo folder, sorted).
    pub index: usize,
    pub photo: String,
    /// `orient` tasks of a film epoch: the epoch's majority scan orientation, taken once
    /// from its `scan` round (an undecided scan takes it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scan_orientation: Option<ScanOrientation>,
}

impl Task {
    /// A name unique within a run (Dask keys): stage, kind, photo.
    pub fn name(&self) -> String {
        format!("{}/{}/{}", self.stage, self.kind.label(), self.photo)
    }

    /// The task's result file.
    pub fn result(&self) -> PathBuf {
        result_path(&self.folder, self.kind, self.index)
    }
}

fn result_path(folder: &Path, kind: TaskKind, index: usize) -> PathBuf {
    folder.join(format!("{}-{index:05}.msgpack", kind.label()))
}

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

/// What a finished task reports (small, JSON: what a Dask future returns).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TaskSummary {
    pub task: String,
    pub photo: String,
    /// Orient: whether the photo was oriented; scan: whether its fiducials gave a camera.
    pub ok: bool,
    /// Why not, when not.
    pub reason: Option<String>,
    pub seconds: f64,
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
        let e = plan
            .project
            .epochs()
            .find(|e| e.name == plan.epoch)
            .ok_or_else(|| {
                WorkError::Inconsistent(format!("the project has no epoch {}", plan.epoch))
            })?;
        let input = EpochInput::build(&e.spec(), &plan.project.crs, plan.origin)?;
        let opts = super::run::archive_options(&plan.project, e);
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

pub(crate) fn open_packages(dirs: &[PathBuf]) -> Result<Vec<DcpPackage>, WorkError> {
    Ok(dirs
        .iter()
        .map(|d| DcpPackage::open(&d.join("package")))
        .collect::<Result<Vec<_>, _>>()?)
}

/// Where the tasks run: here (the run orients the photos itself) or elsewhere (the run
/// stops at the first stage with unfinished tasks and returns them).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TaskMode {
    InProcess,
    Plan,
}

/// The tasks of one archive epoch stage of a run.
pub(crate) struct EpochTasks {
    stage: String,
    root: PathBuf,
    folder: PathBuf,
}

impl EpochTasks {
    /// The tasks of stage `stage` under output folder `output`, for the stage inputs with
    /// fingerprint `key`; writes the plan.
    pub(crate) fn new(
        output: &Path,
        stage: &str,
        key: &str,
        plan: &EpochPlan,
    ) -> Result<Self, WorkError> {
        let root = output.join("tasks").join(stage);
        let folder = root.join(&key[..key.len().min(16)]);
        std::fs::create_dir_all(&folder).map_err(|e| FormatError::io(&folder, e))?;
        super::epoch_files::write_json(&folder.join("plan.json"), plan)?;
        Ok(Self {
            stage: stage.to_string(),
            root,
            folder,
        })
    }

    fn tasks(
        &self,
        kind: TaskKind,
        input: &EpochInput,
        scan_orientation: Option<ScanOrientation>,
    ) -> Vec<Task> {
        input
            .photos
            .iter()
            .enumerate()
            .map(|(index, p)| Task {
                kind,
                stage: self.stage.clone(),
                folder: self.folder.clone(),
                index,
                photo: p.name.clone(),
                scan_orientation,
            })
            .collect()
    }

    /// Makes sure every task of `kind` has its result: runs the missing ones here, or
    /// returns them as pending.
    fn ensure(
        &self,
        tasks: Vec<Task>,
        ctx: &EpochContext,
        archive: &ArchiveContext,
        mode: TaskMode,
    ) -> Result<(), WorkError> {
        let missing: Vec<Task> = tasks
            .into_iter()
            .filter(|t| !t.result().is_file())
            .collect();
        if missing.is_empty() {
            return Ok(());
        }
        match mode {
            TaskMode::Plan => Err(WorkError::Pending(missing)),
            TaskMode::InProcess => missing
                .par_iter()
                .map(|t| execute_with(t, ctx, archive).map(|_| ()))
                .collect(),
        }
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
            self.ensure(scans.clone(), ctx, archive, mode)?;
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
        self.ensure(orients.clone(), ctx, archive, mode)?;
        let mut outcomes = Vec::with_capacity(orients.len());
        let mut by_photo = HashMap::new();
        for t in &orients {
            let r: OrientResult = read_result(t)?;
            if let Some(c) = r.candidates {
                by_photo.insert(r.photo.clone(), c);
            }
            outcomes.push(r.orientation);
        }
        let scans = film.then(|| ScanCameras::from_parts(by_photo, majority));
        Ok(FirstPass { scans, outcomes })
    }

    /// Removes the stage's task results (the stage has finished).
    pub(crate) fn clear(&self) {
        let _ = std::fs::remove_dir_all(&self.root);
        // `tasks/` itself when no other stage has tasks there (fails, harmlessly, if so).
        if let Some(parent) = self.root.parent() {
            let _ = std::fs::remove_dir(parent);
        }
    }
}

fn read_result<T: for<'de> Deserialize<'de> + HasPhoto>(task: &Task) -> Result<T, WorkError> {
    let path = task.result();
    let bytes = std::fs::read(&path).map_err(|e| FormatError::io(&path, e))?;
    let r: T = rmp_serde::from_slice(&bytes)
        .map_err(|e| FormatError::invalid(&path, format!("task result: {e}")))?;
    if r.photo() != task.photo {
        return Err(FormatError::invalid(
            &path,
            format!("result of photo {}, expected {}", r.photo(), task.photo),
        )
        .into());
    }
    Ok(r)
}

trait HasPhoto {
    fn photo(&self) -> &str;
}
impl HasPhoto for OrientResult {
    fn photo(&self) -> &str {
        &self.photo
    }
}
impl HasPhoto for ScanResult {
    fn photo(&self) -> &str {
        &self.photo
    }
}

fn write_result<T: Serialize>(task: &Task, v: &T) -> Result<(), WorkError> {
    let path = task.result();
    let bytes = rmp_serde::to_vec_named(v)
        .map_err(|e| FormatError::invalid(&path, format!("task result: {e}")))?;
    Ok(write_bytes_atomically(&path, &bytes)?)
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
        .filter(|p| p.name == task.photo)
        .ok_or_else(|| {
            WorkError::Inconsistent(format!(
                "task {}: photo {} is not photo {} of epoch {}",
                task.name(),
                task.photo,
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
        photo: task.photo.clone(),
        ok,
        reason,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// The context of the last stage this process ran tasks of: a worker runs many tasks of
/// one stage, and reading the LiDAR surface and the packages once is most of a small
/// task's cost otherwise.
static CONTEXT: Mutex<Option<(PathBuf, Arc<EpochContext>)>> = Mutex::new(None);

/// Runs one task (a worker's entry point): reads its stage's plan, runs it, writes its
/// result atomically. A task whose result exists already (a retried task whose worker
/// died after writing it) is run again and writes the same result.
pub fn run_task(task: &Task) -> Result<TaskSummary, WorkError> {
    let ctx = {
        let mut cache = CONTEXT.lock().unwrap_or_else(|p| p.into_inner());
        match &*cache {
            Some((folder, ctx)) if *folder == task.folder => ctx.clone(),
            _ => {
                let plan: EpochPlan =
                    super::epoch_files::read_json(&task.folder.join("plan.json"))?;
                let ctx = Arc::new(EpochContext::load(plan)?);
                *cache = Some((task.folder.clone(), ctx.clone()));
                ctx
            }
        }
    };
    let archive = ArchiveContext::new(&ctx.input, &ctx.packages, &ctx.surface.ground, &ctx.opts)?;
    execute_with(task, &ctx, &archive)
}
