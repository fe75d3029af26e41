//! The rounds of an archive epoch's global passes (second pass, tie pass, tie points) as
//! tasks: one task per photo of a round, the round's data written once to the stage's
//! folder for the processes that run them. A planning run waits, suspended, for each
//! round's results ([`super::suspend`]); one that cannot (a planning call in another
//! process) replays the epoch's global part from its first pass: rounds whose results are
//! all there are read back, the first one that is not is written and its tasks returned.
//! The rounds are the same in every replay (their inputs are the results before them), so
//! round `n` of one replay is round `n` of the next.

use super::epoch::{own_scans, EpochContext};
use super::{bad_task_file, read_msgpack, read_result, write_msgpack, write_result};
use super::{StageTasks, Task, TaskData, TaskKind};
use super::{TaskMode, TaskSummary};
use crate::control::archive::ArchiveContext;
use crate::control::epoch_ties::{CutRound, MatchRound};
use crate::control::rounds::{EpochEnv, EpochRounds, OrientRound, Round, RoundKind};
use crate::matching::ScanOrientation;
use crate::pipeline::stages::WorkError;
use serde::{Deserialize, Serialize};
use std::cell::Cell;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Instant;

fn task_kind(kind: RoundKind) -> TaskKind {
    match kind {
        RoundKind::Cut => TaskKind::Cut,
        RoundKind::Match => TaskKind::Match,
        RoundKind::Reorient => TaskKind::Reorient,
    }
}

/// The file holding round `round` of a stage, for the processes running its tasks.
fn round_file(folder: &Path, kind: TaskKind, round: usize) -> PathBuf {
    folder.join(format!("round-{round:03}-{}.msgpack", kind.label()))
}

/// The file holding the part of round `round` that photo `index` needs ([`Round::part`]).
fn part_file(folder: &Path, kind: TaskKind, round: usize, index: usize) -> PathBuf {
    folder.join(format!(
        "round-{round:03}-{}-{index:05}.msgpack",
        kind.label()
    ))
}

/// A round task's result: the photo's output.
#[derive(Serialize, Deserialize)]
struct RoundResult<T> {
    photo: String,
    output: T,
}

impl<T> super::HasItem for RoundResult<T> {
    fn item(&self) -> &str {
        &self.photo
    }
}

/// The output is checked by its round ([`Round::check_output`]) where the round is at
/// hand ([`TaskRounds::run`]).
impl<T> TaskData for RoundResult<T> {
    fn check(&self) -> Result<(), String> {
        Ok(())
    }
}

/// Rounds read from their files: checked without the epoch here, with its photo count
/// where a task runs them ([`run_task`]).
macro_rules! round_data {
    ($($t:ty),*) => {
        $(impl TaskData for $t {
            fn check(&self) -> Result<(), String> {
                self.check_file(usize::MAX)
            }
        })*
    };
}
round_data!(CutRound, MatchRound, OrientRound);

/// An epoch's rounds as tasks of its stage (a planning run: [`TaskMode::Plan`]).
pub(crate) struct TaskRounds<'a> {
    tasks: &'a StageTasks,
    ctx: &'a EpochContext,
    mode: TaskMode,
    /// A film epoch's majority scan orientation (its tasks carry it, as `orient` tasks do).
    majority: Option<ScanOrientation>,
    next: Cell<usize>,
}

impl<'a> TaskRounds<'a> {
    pub(crate) fn new(
        tasks: &'a StageTasks,
        ctx: &'a EpochContext,
        mode: TaskMode,
        majority: Option<ScanOrientation>,
    ) -> Self {
        Self {
            tasks,
            ctx,
            mode,
            majority,
            next: Cell::new(0),
        }
    }
}

impl EpochRounds for TaskRounds<'_> {
    type Error = WorkError;

    fn run<R: Round>(&self, round: &R, env: &EpochEnv) -> Result<Vec<R::Output>, WorkError> {
        let r = self.next.get();
        self.next.set(r + 1);
        let photos = round.photos();
        let kind = task_kind(R::KIND);
        let tasks: Vec<Task> = photos
            .iter()
            .map(|&n| Task {
                kind,
                stage: self.tasks.stage().to_string(),
                folder: self.tasks.folder().to_path_buf(),
                index: n,
                item: self.ctx.input.photos[n].name.clone(),
                scan_orientation: self.majority,
                round: Some(r),
            })
            .collect();
        if self.mode == TaskMode::Plan {
            // Each unfinished photo's part of the round, or the whole round once when a
            // photo needs all of it.
            let file = round_file(self.tasks.folder(), kind, r);
            for (k, t) in tasks.iter().enumerate() {
                let part = part_file(self.tasks.folder(), kind, r, t.index);
                if t.result().is_file() || part.is_file() || file.is_file() {
                    continue;
                }
                match round.part(k, env) {
                    Some(p) => write_msgpack(&part, &p)?,
                    None => write_msgpack(&file, round)?,
                }
            }
        }
        self.tasks
            .ensure(&tasks, self.mode, |t| run_from(t, round, env))?;
        tasks
            .iter()
            .enumerate()
            .map(|(k, t)| {
                let r = read_result::<RoundResult<R::Output>>(t)?;
                round
                    .check_output(k, &r.output)
                    .map_err(|e| bad_task_file(&t.result(), e))?;
                Ok(r.output)
            })
            .collect()
    }
}

/// Runs the `k`-th photo of `round` (task `task`) and writes its result.
fn execute<R: Round>(
    task: &Task,
    round: &R,
    k: usize,
    env: &EpochEnv,
) -> Result<TaskSummary, WorkError> {
    let t0 = Instant::now();
    let output = round.run(k, env);
    let reason = R::failure(&output);
    write_result(
        task,
        &RoundResult {
            photo: task.item.clone(),
            output,
        },
    )?;
    Ok(TaskSummary {
        ok: reason.is_none(),
        reason,
        ..TaskSummary::done(task, t0)
    })
}

/// A round as a process read it from its file.
#[derive(Clone)]
pub(super) enum Loaded {
    Cut(Arc<CutRound>),
    Match(Arc<MatchRound>),
    Reorient(Arc<OrientRound>),
}

/// The round (or a photo's part of it) a process last read, kept for its next task of
/// that round (a worker runs many photos of one round); one at a time, since a round can
/// hold thousands of chips.
static ROUND: Mutex<Option<(PathBuf, Loaded)>> = Mutex::new(None);

/// The round in `file`, of the kind of `task`.
fn load(file: &Path, task: &Task) -> Result<Loaded, WorkError> {
    let mut cache = ROUND.lock().unwrap_or_else(|p| p.into_inner());
    if let Some((f, r)) = &*cache {
        if f == file {
            return Ok(r.clone());
        }
    }
    // The last round's data is dropped before the next is read.
    *cache = None;
    if !matches!(
        task.kind,
        TaskKind::Cut | TaskKind::Match | TaskKind::Reorient
    ) {
        return Err(super::not_of(task, "an epoch's rounds"));
    }
    let r = read_round(file, task.kind)?;
    *cache = Some((file.to_path_buf(), r.clone()));
    Ok(r)
}

/// The round of `kind` (`cut`, `match`, `reorient`) in `file`, checked (uncached; also
/// [`super::read_task_file`]).
pub(super) fn read_round(file: &Path, kind: TaskKind) -> Result<Loaded, WorkError> {
    Ok(match kind {
        TaskKind::Cut => Loaded::Cut(Arc::new(read_msgpack(file)?)),
        TaskKind::Match => {
            let r: MatchRound = read_msgpack(file)?;
            r.check()
                .map_err(|e| crate::formats::FormatError::invalid(file, e))?;
            Loaded::Match(Arc::new(r))
        }
        TaskKind::Reorient => Loaded::Reorient(Arc::new(read_msgpack(file)?)),
        _ => {
            return Err(crate::formats::FormatError::invalid(
                file,
                "not a round's file (cut, match or reorient)",
            )
            .into())
        }
    })
}

/// A round task's result file (`<kind>-<round>-<index>.msgpack`) read as the stage reads
/// it ([`super::read_task_file`]).
pub(super) fn read_result_file(kind: TaskKind, path: &Path) -> Result<(), WorkError> {
    match kind {
        TaskKind::Cut => read_msgpack::<RoundResult<<CutRound as Round>::Output>>(path).map(drop),
        TaskKind::Match => {
            read_msgpack::<RoundResult<<MatchRound as Round>::Output>>(path).map(drop)
        }
        TaskKind::Reorient => {
            read_msgpack::<RoundResult<<OrientRound as Round>::Output>>(path).map(drop)
        }
        _ => Err(crate::formats::FormatError::invalid(path, "not a round task's result").into()),
    }
}

/// Runs one round task in a process of its own: the round read from its file, the photo's
/// environment built as the epoch's process built it.
pub(super) fn run_task(
    task: &Task,
    ctx: &EpochContext,
    archive: &ArchiveContext,
) -> Result<TaskSummary, WorkError> {
    let round = task.round.ok_or_else(|| {
        WorkError::Inconsistent(format!(
            "task {}: a round task without its round",
            task.name()
        ))
    })?;
    let part = part_file(&task.folder, task.kind, round, task.index);
    let file = if part.is_file() {
        part
    } else {
        round_file(&task.folder, task.kind, round)
    };
    let scans = own_scans(task, ctx)?;
    let env = EpochEnv::new(
        &ctx.input,
        &ctx.surface.ground,
        &archive.priors,
        archive.photo_options(scans.as_ref()),
        &ctx.opts,
        scans.as_ref(),
    );
    let photos = ctx.input.photos.len();
    let loaded = load(&file, task)?;
    let checked = match &loaded {
        Loaded::Cut(r) => r.check_file(photos),
        Loaded::Match(r) => r.check_file(photos),
        Loaded::Reorient(r) => r.check_file(photos),
    };
    checked.map_err(|e| bad_task_file(&file, e))?;
    match loaded {
        Loaded::Cut(r) => run_from(task, &*r, &env),
        Loaded::Match(r) => run_from(task, &*r, &env),
        Loaded::Reorient(r) => run_from(task, &*r, &env),
    }
}

fn run_from<R: Round>(task: &Task, round: &R, env: &EpochEnv) -> Result<TaskSummary, WorkError> {
    let k = round
        .photos()
        .iter()
        .position(|&n| n == task.index)
        .ok_or_else(|| {
            WorkError::Inconsistent(format!(
                "task {}: photo {} has no work in round {:?}",
                task.name(),
                task.item,
                task.round
            ))
        })?;
    execute(task, round, k, env)
}
