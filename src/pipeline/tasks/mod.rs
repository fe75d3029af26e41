//! The parallel work of the stages as tasks: data a process can run anywhere the output
//! folder is shared (a Dask worker, `bindings/python/cloudcontrol/distributed.py`), or the
//! run itself in this process. Either way each task writes one result file, atomically,
//! and the stage reads every result back before its global part, so a run's products do
//! not depend on where or in what order the tasks ran.
//!
//! A stage's tasks live in `tasks/<stage>/<key>/`, `key` the first 16 hex digits of the
//! stage's input fingerprint: `plan.json` (what every task of the stage shares) and one
//! `<kind>-<index>.msgpack` per finished task. MessagePack keeps every f64 exact and NaN
//! as NaN (a failed photo's σ), which JSON does not. The folder is removed when the stage
//! has finished.
//!
//! The kinds, by stage:
//! - `sources` ([`lidar`]): `screen` (a LiDAR tile's noise points and its share of the
//!   strip sample), then, after the strip offsets, `clean` (the tile rewritten);
//! - archive epochs ([`epoch`]): a film epoch's `scan` (the scan's fiducials), then
//!   `orient` (a photo's first orientation from the control patches); then the rounds of
//!   the epoch's global passes ([`rounds`]): `cut` (chips cut from an oriented photo),
//!   `match` (tie tracks found in a photo), `reorient` (a photo oriented from a store of
//!   the epoch's own chips), each round's data in `round-<n>-<kind>.msgpack`;
//! - the reference epoch ([`reference`]): `pairs` (a photo's tie matching with the later
//!   photos it overlaps);
//! - `dcp-<epoch>` ([`dcp`]): `chips` (one photo's chips of the package, cut and encoded);
//! - an epoch's products ([`outputs`]): a film epoch's `resample` (a scan into its frame
//!   image), then `ortho` (a run of orthophoto tiles);
//! - `surface-<epoch>` ([`surface`]): `stereo` (a stereo pair matched into samples of the
//!   epoch's DSM grid), one pair at a time in this process (each uses every thread).

pub mod dcp;
pub mod epoch;
pub mod lidar;
pub mod outputs;
pub mod reference;
pub mod rounds;
pub mod surface;
pub mod suspend;

pub(crate) use epoch::EpochTasks;
pub use epoch::{open_packages, EpochContext, EpochPlan};

use super::stages::WorkError;
use crate::formats::{write_bytes_atomically, FormatError};
use crate::matching::ScanOrientation;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

/// What a task does.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TaskKind {
    /// A film scan's fiducial interior orientation.
    Scan,
    /// A photo's first orientation from the control patches.
    Orient,
    /// A LiDAR tile's noise points and strip sample.
    Screen,
    /// A LiDAR tile rewritten, noise classified and strip offsets removed.
    Clean,
    /// A film scan resampled into its fiducial-frame image.
    Resample,
    /// A run of consecutive orthophoto tiles rendered.
    Ortho,
    /// Chips cut from an oriented photo of an epoch (a round of its global passes).
    Cut,
    /// Tie tracks found in a photo of an epoch (a round).
    Match,
    /// A photo oriented from the epoch's own chips (a round).
    Reorient,
    /// One photo's chips of a DCP package, cut and encoded.
    Chips,
    /// The reference epoch's tie matching of a photo with the later photos it overlaps.
    Pairs,
    /// A stereo pair of an epoch matched into samples of its surface.
    Stereo,
}

impl TaskKind {
    const ALL: [TaskKind; 12] = [
        TaskKind::Scan,
        TaskKind::Orient,
        TaskKind::Screen,
        TaskKind::Clean,
        TaskKind::Resample,
        TaskKind::Ortho,
        TaskKind::Cut,
        TaskKind::Match,
        TaskKind::Reorient,
        TaskKind::Chips,
        TaskKind::Pairs,
        TaskKind::Stereo,
    ];

    fn of_label(label: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.label() == label)
    }

    fn label(self) -> &'static str {
        match self {
            TaskKind::Scan => "scan",
            TaskKind::Orient => "orient",
            TaskKind::Screen => "screen",
            TaskKind::Clean => "clean",
            TaskKind::Resample => "resample",
            TaskKind::Ortho => "ortho",
            TaskKind::Cut => "cut",
            TaskKind::Match => "match",
            TaskKind::Reorient => "reorient",
            TaskKind::Chips => "chips",
            TaskKind::Pairs => "pairs",
            TaskKind::Stereo => "stereo",
        }
    }
}

/// One task: an item (a photo of an epoch, a tile of the LiDAR, a run of orthophoto
/// tiles) of a stage, and the
/// folder of the stage's tasks (its `plan.json` says the rest).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Task {
    pub kind: TaskKind,
    pub stage: String,
    pub folder: PathBuf,
    /// Index of the item in the stage (a photo in its sorted photo folder, a tile in the
    /// selection).
    pub index: usize,
    /// The item's name: the photo's, the tile's file name, or `tiles-<first>-<last>`.
    #[serde(alias = "photo")]
    pub item: String,
    /// `orient` tasks of a film epoch: the epoch's majority scan orientation, taken once
    /// from its `scan` round (an undecided scan takes it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scan_orientation: Option<ScanOrientation>,
    /// Tasks of an epoch's global passes: the round they belong to (rounds are numbered
    /// in the order the epoch runs them, the same in every run).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub round: Option<usize>,
}

impl Task {
    /// A name unique within a run (Dask keys): stage, kind (and round), item.
    pub fn name(&self) -> String {
        match self.round {
            Some(r) => format!("{}/{}-{r}/{}", self.stage, self.kind.label(), self.item),
            None => format!("{}/{}/{}", self.stage, self.kind.label(), self.item),
        }
    }

    /// The task's result file.
    pub fn result(&self) -> PathBuf {
        let kind = self.kind.label();
        let index = self.index;
        self.folder.join(match self.round {
            Some(r) => format!("{kind}-{r:03}-{index:05}.msgpack"),
            None => format!("{kind}-{index:05}.msgpack"),
        })
    }
}

/// What a finished task reports (small, JSON: what a Dask future returns).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TaskSummary {
    pub task: String,
    pub item: String,
    /// Orient: whether the photo was oriented; scan: whether its fiducials gave a camera;
    /// screen, clean: whether the tile was read and written.
    pub ok: bool,
    /// Why not, when not.
    pub reason: Option<String>,
    pub seconds: f64,
}

impl TaskSummary {
    /// A task that did its work, started at `t0`.
    fn done(task: &Task, t0: std::time::Instant) -> Self {
        Self {
            task: task.name(),
            item: task.item.clone(),
            ok: true,
            reason: None,
            seconds: t0.elapsed().as_secs_f64(),
        }
    }
}

/// A task handed to a stage it is not of.
fn not_of(task: &Task, stage: &str) -> WorkError {
    WorkError::Inconsistent(format!("task {}: not a task of {stage}", task.name()))
}

/// Epoch `name` of a plan's project.
fn epoch_of<'a>(
    project: &'a super::project::Project,
    name: &str,
) -> Result<&'a super::project::Epoch, WorkError> {
    project
        .epochs()
        .find(|e| e.name == name)
        .ok_or_else(|| WorkError::Inconsistent(format!("the project has no epoch {name}")))
}

/// Where the tasks run: here (the run does the work itself) or elsewhere (the run stops
/// at the first stage with unfinished tasks and returns them).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TaskMode {
    InProcess,
    Plan,
}

/// The task folder of one stage of a run.
pub(crate) struct StageTasks {
    stage: String,
    root: PathBuf,
    folder: PathBuf,
}

impl StageTasks {
    /// The tasks of stage `stage` under output folder `output`, for the stage inputs with
    /// fingerprint `key`; writes the plan.
    pub(crate) fn new<P: Serialize>(
        output: &Path,
        stage: &str,
        key: &str,
        plan: &P,
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

    pub(crate) fn folder(&self) -> &Path {
        &self.folder
    }

    pub(crate) fn stage(&self) -> &str {
        &self.stage
    }

    /// One task of `kind` per item (index, name).
    pub(crate) fn tasks<'a>(
        &self,
        kind: TaskKind,
        items: impl IntoIterator<Item = &'a str>,
        scan_orientation: Option<ScanOrientation>,
    ) -> Vec<Task> {
        items
            .into_iter()
            .enumerate()
            .map(|(index, item)| Task {
                kind,
                stage: self.stage.clone(),
                folder: self.folder.clone(),
                index,
                item: item.to_string(),
                scan_orientation,
                round: None,
            })
            .collect()
    }

    /// Makes sure every task has its result: runs the missing ones here with `exec`, as
    /// many at a time as rayon has threads, or returns them as pending.
    pub(crate) fn ensure(
        &self,
        tasks: &[Task],
        mode: TaskMode,
        exec: impl Fn(&Task) -> Result<TaskSummary, WorkError> + Sync,
    ) -> Result<(), WorkError> {
        self.ensure_with(tasks, mode, true, exec)
    }

    /// [`Self::ensure`] running the missing tasks here one at a time: for tasks that use
    /// every thread themselves and whose memory must not be doubled (a stereo pair).
    pub(crate) fn ensure_in_turn(
        &self,
        tasks: &[Task],
        mode: TaskMode,
        exec: impl Fn(&Task) -> Result<TaskSummary, WorkError> + Sync,
    ) -> Result<(), WorkError> {
        self.ensure_with(tasks, mode, false, exec)
    }

    fn ensure_with(
        &self,
        tasks: &[Task],
        mode: TaskMode,
        parallel: bool,
        exec: impl Fn(&Task) -> Result<TaskSummary, WorkError> + Sync,
    ) -> Result<(), WorkError> {
        let missing_of = || -> Vec<Task> {
            tasks
                .iter()
                .filter(|t| !t.result().is_file())
                .cloned()
                .collect()
        };
        let mut missing = missing_of();
        if missing.is_empty() {
            return Ok(());
        }
        match mode {
            // A suspended planning run waits here for its tasks ([`suspend`]); any other
            // ends with them pending, and a later run replays up to here.
            TaskMode::Plan => loop {
                if !suspend::wait_for(&self.stage, &missing) {
                    return Err(WorkError::Pending(missing));
                }
                missing = missing_of();
                if missing.is_empty() {
                    return Ok(());
                }
            },
            TaskMode::InProcess => {
                // Each task in the caller's span (its epoch), and its end as a progress
                // event (target `cloudcontrol::progress`: the CLI's per-photo progress).
                let (span, done) = (tracing::Span::current(), AtomicUsize::new(0));
                let run = |t: &Task| {
                    let _in = span.enter();
                    exec(t)?;
                    tracing::info!(
                        target: "cloudcontrol::progress",
                        work = t.kind.label(),
                        item = %t.item,
                        done = done.fetch_add(1, Ordering::Relaxed) + 1,
                        total = missing.len(),
                    );
                    Ok(())
                };
                if parallel {
                    missing.par_iter().map(run).collect()
                } else {
                    missing.iter().try_for_each(run)
                }
            }
        }
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

/// A task result names its item, so a result file that landed in the wrong place is
/// caught rather than used.
pub(crate) trait HasItem {
    fn item(&self) -> &str;
}

/// `HasItem` for result types, each naming the field that holds its item.
macro_rules! has_item {
    ($($t:ty => $field:ident),* $(,)?) => {
        $(impl $crate::pipeline::tasks::HasItem for $t {
            fn item(&self) -> &str {
                &self.$field
            }
        })*
    };
}
pub(crate) use has_item;

/// What a task file holds, checked where it is decoded ([`read_msgpack`]): numbers finite
/// where the work needs them so, counts and sizes bounded, indices that need no context in
/// range (`control::task_checks`). The stages add the checks that need their context
/// (a point index against the store it indexes) where they read the results. A damaged or
/// crafted task file is a format error naming it, never a panic.
pub(crate) trait TaskData {
    /// What is wrong, naming the field.
    fn check(&self) -> Result<(), String>;
}

/// The error of a task file whose contents fail a check.
pub(crate) fn bad_task_file(path: &Path, message: impl std::fmt::Display) -> WorkError {
    FormatError::invalid(path, format!("task file: {message}")).into()
}

pub(crate) fn read_result<T: for<'de> Deserialize<'de> + HasItem + TaskData>(
    task: &Task,
) -> Result<T, WorkError> {
    let path = task.result();
    let r: T = read_msgpack(&path)?;
    if r.item() != task.item {
        return Err(FormatError::invalid(
            &path,
            format!("result of {}, expected {}", r.item(), task.item),
        )
        .into());
    }
    Ok(r)
}

/// Reads one task file as the stage that wrote it reads it back: the type its name says
/// (`<kind>-<index>.msgpack`, a round's `<kind>-<round>-<index>.msgpack`,
/// `round-<round>-<kind>[-<index>].msgpack`, `strip_offsets.msgpack`) with the checks made
/// on reading. For the fuzz target `task_files` (fuzz/src/lib.rs); any other name is an
/// error.
#[doc(hidden)]
pub fn read_task_file(path: &Path) -> Result<(), WorkError> {
    let not_task = || WorkError::from(FormatError::invalid(path, "not a task file's name"));
    let name = path
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or_default();
    let stem = name.strip_suffix(".msgpack").ok_or_else(not_task)?;
    let kind = |label: &str| TaskKind::of_label(label).ok_or_else(not_task);
    match stem.split('-').collect::<Vec<_>>().as_slice() {
        ["strip_offsets"] => lidar::read_offsets(path).map(drop),
        ["round", _, k] | ["round", _, k, _] => rounds::read_round(path, kind(k)?).map(drop),
        [k, _, _] => rounds::read_result_file(kind(k)?, path),
        [k, _] => match kind(k)? {
            k @ (TaskKind::Screen | TaskKind::Clean) => lidar::read_result_file(k, path),
            k @ (TaskKind::Scan | TaskKind::Orient) => epoch::read_result_file(k, path),
            k @ (TaskKind::Resample | TaskKind::Ortho) => outputs::read_result_file(k, path),
            TaskKind::Chips => dcp::read_result_file(path),
            TaskKind::Pairs => reference::read_result_file(path),
            TaskKind::Stereo => surface::read_result_file(path),
            TaskKind::Cut | TaskKind::Match | TaskKind::Reorient => Err(not_task()),
        },
        _ => Err(not_task()),
    }
}

/// Reads a task file and checks what it holds ([`TaskData`]).
pub(crate) fn read_msgpack<T: for<'de> Deserialize<'de> + TaskData>(
    path: &Path,
) -> Result<T, WorkError> {
    let bytes = crate::formats::input::read_bytes(path, crate::formats::input::Cap::document())?;
    let v: T = rmp_serde::from_slice(&bytes).map_err(|e| bad_task_file(path, e))?;
    v.check().map_err(|e| bad_task_file(path, e))?;
    Ok(v)
}

pub(crate) fn write_msgpack<T: Serialize>(path: &Path, v: &T) -> Result<(), WorkError> {
    let bytes = rmp_serde::to_vec_named(v)
        .map_err(|e| FormatError::invalid(path, format!("task file: {e}")))?;
    Ok(write_bytes_atomically(path, &bytes)?)
}

pub(crate) fn write_result<T: Serialize>(task: &Task, v: &T) -> Result<(), WorkError> {
    write_msgpack(&task.result(), v)
}

/// The context of the last stage a process ran tasks of, kept for the next task: a worker
/// runs many tasks of one stage, and reading the LiDAR surface, the packages or the block
/// once is most of a small task's cost otherwise.
pub(crate) struct ContextCache<C>(Mutex<Option<(PathBuf, Arc<C>)>>);

impl<C> ContextCache<C> {
    pub(crate) const fn new() -> Self {
        Self(Mutex::new(None))
    }

    /// The context of `task`'s stage: the cached one, or `load` from its plan.
    pub(crate) fn get<P: for<'de> Deserialize<'de>>(
        &self,
        task: &Task,
        load: impl FnOnce(P, &Path) -> Result<C, WorkError>,
    ) -> Result<Arc<C>, WorkError> {
        let mut cache = self.0.lock().unwrap_or_else(|p| p.into_inner());
        if let Some((folder, ctx)) = &*cache {
            if *folder == task.folder {
                return Ok(ctx.clone());
            }
        }
        let plan: P = super::epoch_files::read_json(&task.folder.join("plan.json"))?;
        let ctx = Arc::new(load(plan, &task.folder)?);
        *cache = Some((task.folder.clone(), ctx.clone()));
        Ok(ctx)
    }
}

/// Runs one task (a worker's entry point): reads its stage's plan, runs it, writes its
/// result atomically. A task whose result exists already (a retried task whose worker
/// died after writing it) is run again and writes the same result.
pub fn run_task(task: &Task) -> Result<TaskSummary, WorkError> {
    if task.kind != TaskKind::Pairs {
        reference::release();
    }
    match task.kind {
        TaskKind::Scan
        | TaskKind::Orient
        | TaskKind::Cut
        | TaskKind::Match
        | TaskKind::Reorient => epoch::run_task(task),
        TaskKind::Screen | TaskKind::Clean => lidar::run_task(task),
        TaskKind::Resample | TaskKind::Ortho => outputs::run_task(task),
        TaskKind::Chips => dcp::run_task(task),
        TaskKind::Pairs => reference::run_task(task),
        TaskKind::Stereo => surface::run_task(task),
    }
}
