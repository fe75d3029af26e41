//! The workflow through the C ABI: run a project file and get its report as JSON (a
//! string owned by the library, released with `ccp_string_free`).

use super::{guard, CcpStatus, FfiError};
use crate::pipeline::project::{Project, ProjectError};
use crate::pipeline::run::{run_project, RunError};
use crate::pipeline::stages::{StageError, WorkError};
use crate::pipeline::tasks::suspend::{self, Planned};
use crate::pipeline::tasks::{self, Task};
use std::ffi::{c_char, CString};
use std::path::PathBuf;

impl From<RunError> for FfiError {
    fn from(e: RunError) -> Self {
        let message = e.to_string();
        let status = match e {
            RunError::Project(ProjectError::Io { .. }) => CcpStatus::Io,
            RunError::Project(_) => CcpStatus::InvalidArgument,
            // Another run writes the output folder.
            RunError::Stage(StageError::Busy { .. }) => CcpStatus::Busy,
            // The output folder is not a run's to write (the project's `output`).
            RunError::Stage(StageError::Output { .. }) => CcpStatus::InvalidArgument,
            RunError::Inputs(_) => CcpStatus::InvalidArgument,
            RunError::Stage(StageError::Format(f)) => FfiError::from(f).status,
            // The status of the module error the stage failed on.
            RunError::Stage(StageError::Failed { source, .. }) => FfiError::from(*source).status,
            // Not reached through the C ABI: it never stops a run early, and a planning
            // run returns its pending tasks instead.
            RunError::Stopped(_) | RunError::Pending { .. } => CcpStatus::Numeric,
        };
        FfiError::new(status, message)
    }
}

/// A stage's error by the module that failed: a file not there is NOT_FOUND, unreadable
/// IO, malformed FORMAT, inputs that do not fit together INVALID_ARGUMENT, and only a
/// numeric failure (an adjustment that did not converge) NUMERIC.
impl From<WorkError> for FfiError {
    fn from(e: WorkError) -> Self {
        use crate::control::checkpoints::EvaluationError as Eval;
        match e {
            WorkError::Epoch(e) => e.into(),
            WorkError::Lidar(e) => e.into(),
            WorkError::Format(e) => e.into(),
            WorkError::Dcp(e) => e.into(),
            WorkError::Dense(e) => e.into(),
            WorkError::Change(e) => {
                use crate::change::ChangeError as C;
                match e {
                    C::Geometry(g) => g.into(),
                    C::Format(f) => f.into(),
                    C::TooLittle(_) => FfiError::new(CcpStatus::Numeric, e.to_string()),
                    C::InvalidInput { .. } => FfiError::invalid(e.to_string()),
                }
            }
            WorkError::Checkpoints(e) => {
                let status = match &e {
                    Eval::UnknownPhoto { .. } | Eval::UnknownPoint { .. } => {
                        CcpStatus::InvalidArgument
                    }
                    Eval::Gsd(_) | Eval::TooFewRays => CcpStatus::Numeric,
                };
                FfiError::new(status, e.to_string())
            }
            WorkError::Inconsistent(m) => FfiError::invalid(m),
            // A planning run's tasks are returned, not failed on; a task that needs tasks
            // of its own is not one `ccp_project_plan` gave.
            e @ WorkError::Pending(_) => FfiError::invalid(e.to_string()),
        }
    }
}

/// Runs the project file `project_path` (TOML, formats/project/) — restartable: finished
/// stages whose inputs did not change are skipped — and returns in `*out_json` a
/// NUL-terminated JSON object `{"output", "ran", "skipped", "products", "partial",
/// "report"}`, owned by the library: release it with `ccp_string_free`. A run in which an
/// epoch oriented fewer photos than it has returns `CCP_STATUS_PARTIAL` with `*out_json`
/// set all the same (its `partial` lists each such epoch: `epoch`, `oriented`, `total`,
/// `not_oriented` photos with their reasons) and the last error saying so. An invalid
/// project file fails before
/// any work with `CCP_STATUS_INVALID_ARGUMENT` and a message naming the key, and so does an
/// `output` a run may not write (`/`, the home folder, a file, a folder cloudcontrol did
/// not make, an input's folder; formats/project/README.md, "The output folder"). While
/// another run writes the same output folder, the call returns `CCP_STATUS_BUSY` at once.
#[no_mangle]
pub unsafe extern "C" fn ccp_project_run(
    project_path: *const c_char,
    out_json: *mut *mut c_char,
) -> CcpStatus {
    guard(|| {
        clear_out_json(out_json)?;
        let path = super::control::path_arg(project_path, "project_path")?;
        let project = Project::load(&PathBuf::from(path)).map_err(RunError::from)?;
        let s = run_project(&project, &mut |_| {}, None)?;
        hand_out_json(&s.to_json(), out_json)?;
        partial(&s.partial)
    })
}

/// `CCP_STATUS_PARTIAL`, the summary already handed out, when an epoch oriented fewer
/// photos than it has; the message says which, how many and why.
fn partial(p: &[crate::pipeline::partial::PartialEpoch]) -> Result<(), FfiError> {
    if p.is_empty() {
        return Ok(());
    }
    Err(FfiError::new(
        CcpStatus::Partial,
        format!(
            "partial run: {} epoch(s) oriented fewer photos than they have\n{}",
            p.len(),
            crate::pipeline::partial::describe_all(p)
        ),
    ))
}

/// Refuses a null `out_json` and clears `*out_json`, so a failed call leaves NULL there.
unsafe fn clear_out_json(out_json: *mut *mut c_char) -> Result<(), FfiError> {
    if out_json.is_null() {
        return Err(FfiError::new(
            CcpStatus::NullPointer,
            "out_json is a null pointer",
        ));
    }
    *out_json = std::ptr::null_mut();
    Ok(())
}

/// The JSON text of `v` into `*out_json`, owned by the library.
unsafe fn hand_out_json(v: &serde_json::Value, out_json: *mut *mut c_char) -> Result<(), FfiError> {
    let c = CString::new(v.to_string()).map_err(|_| FfiError::invalid("JSON holds a NUL byte"))?;
    *out_json = super::handles::hand_out_string(c);
    Ok(())
}

/// Runs the project file `project_path` as `ccp_project_run` does, except that the
/// per-tile tasks of the LiDAR cleaning, the per-photo tasks of archive epochs and the
/// per-scan and per-tile tasks of the products are not run here: the run stops at the first stage
/// with unfinished tasks and `*out_json` is `{"pending": {"stage": S, "tasks": [T, ...]}}`.
/// Run every task with `ccp_task_run` (in any process that sees the output folder), then
/// call again; when nothing is pending, `*out_json` is the summary `ccp_project_run`
/// gives (with the status `CCP_STATUS_PARTIAL` when it is partial). Release the string
/// with `ccp_string_free`. It fails as `ccp_project_run` does (`CCP_STATUS_BUSY` while
/// another run writes the output folder).
///
/// Between calls the run waits on a thread of the library, suspended where its tasks were
/// missing, and holds the output folder; the next call with the same project resumes it
/// (a project that changed meanwhile ends it and starts afresh). So a stage's global part
/// is computed once, not replayed on each call; a run in another process replays from the
/// results in the folder, with the same outcome.
#[no_mangle]
pub unsafe extern "C" fn ccp_project_plan(
    project_path: *const c_char,
    out_json: *mut *mut c_char,
) -> CcpStatus {
    guard(|| {
        clear_out_json(out_json)?;
        let path = super::control::path_arg(project_path, "project_path")?;
        let project = Project::load(&PathBuf::from(path)).map_err(RunError::from)?;
        let (v, partial_epochs) = match suspend::plan(project)? {
            Planned::Done(s) => (s.to_json(), s.partial),
            Planned::Pending { stage, tasks } => (
                serde_json::json!({ "pending": { "stage": stage, "tasks": tasks } }),
                Vec::new(),
            ),
        };
        hand_out_json(&v, out_json)?;
        partial(&partial_epochs)
    })
}

/// Runs one task that `ccp_project_plan` returned (`task_json`: the task object as given)
/// and writes its result into the run's output folder, atomically: a task killed midway
/// leaves nothing, and a task run twice writes the same result. `*out_json` receives
/// `{"task", "item", "ok", "reason", "seconds"}` (`item` the photo, the LiDAR tile or the
/// run of orthophoto tiles; `ok`
/// false with the reason when the photo could not be oriented or its scan measured: that
/// is a result, not an error).
/// Release the string with `ccp_string_free`.
#[no_mangle]
pub unsafe extern "C" fn ccp_task_run(
    task_json: *const c_char,
    out_json: *mut *mut c_char,
) -> CcpStatus {
    guard(|| {
        clear_out_json(out_json)?;
        let text = super::control::path_arg(task_json, "task_json")?;
        let task: Task =
            serde_json::from_str(text).map_err(|e| FfiError::invalid(format!("task_json: {e}")))?;
        let summary = tasks::run_task(&task).map_err(|e| {
            let message = format!("task {}: {e}", task.name());
            FfiError::new(FfiError::from(e).status, message)
        })?;
        let v = serde_json::to_value(&summary)
            .map_err(|e| FfiError::invalid(format!("task summary: {e}")))?;
        hand_out_json(&v, out_json)
    })
}
