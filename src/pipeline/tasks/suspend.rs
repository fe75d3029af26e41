//! A planning run kept suspended between planning calls, so the global part of a stage is
//! computed once. Without it each call replays the run from its start: finished stages
//! are skipped by their fingerprints, but an epoch's global passes are recomputed up to
//! the round whose tasks are missing, reading every earlier round's results back (on the
//! medium preset's film epoch about 4 s per call, 13 calls; an earlier stop's note).
//!
//! [`plan`] runs the project on a thread of its own. Where a stage finds tasks missing
//! ([`super::StageTasks::ensure`]), the thread hands them to the planning call and waits;
//! the next planning call for the same project resumes it, and it goes on from there once
//! the results are in the output folder (what is still missing is handed out again).
//! A call for a project that changed meanwhile, or a thread whose caller went away, ends
//! the suspended run as a replaying run ends (its tasks pending), and the call starts
//! afresh: the results on disk are what counts, so this is an optimisation of the
//! replay, never another outcome.

use super::Task;
use crate::pipeline::project::Project;
use crate::pipeline::run::{run_project_with, RunError, RunSummary};
use std::cell::RefCell;
use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::mpsc::{channel, Receiver, Sender};
use std::sync::Mutex;

/// What a planning call returns: tasks to run, or the finished run.
pub enum Planned {
    Pending { stage: String, tasks: Vec<Task> },
    Done(Box<RunSummary>),
}

/// What the run's thread tells the planning call.
enum Message {
    Pending {
        stage: String,
        tasks: Vec<Task>,
    },
    /// The run's result, or the payload of its panic (raised again in the planning call).
    Done(Box<std::thread::Result<Result<RunSummary, RunError>>>),
}

/// A run waiting for its tasks: the project it runs, how to resume it, where it reports.
struct Suspended {
    project: Project,
    resume: Sender<()>,
    messages: Receiver<Message>,
}

/// Suspended runs by output folder (what a run owns while it runs).
static SUSPENDED: Mutex<Option<HashMap<PathBuf, Suspended>>> = Mutex::new(None);

/// The planning call's side of a run's thread: where to hand out missing tasks, and
/// where the resumption comes from.
struct Hook {
    to_planner: Sender<Message>,
    resume: Receiver<()>,
}

thread_local! {
    static HOOK: RefCell<Option<Hook>> = const { RefCell::new(None) };
}

/// Hands `missing` (of `stage`) to the planning call and waits to be resumed. False when
/// this thread is not a suspendable run's, or its planning side is gone: the caller then
/// ends the run with its tasks pending.
pub(super) fn wait_for(stage: &str, missing: &[Task]) -> bool {
    HOOK.with(|h| {
        let h = h.borrow();
        let Some(h) = h.as_ref() else {
            return false;
        };
        let sent = h.to_planner.send(Message::Pending {
            stage: stage.to_string(),
            tasks: missing.to_vec(),
        });
        sent.is_ok() && h.resume.recv().is_ok()
    })
}

/// Runs `project` as [`run_project_with`] in [`super::TaskMode::Plan`] does, up to the
/// first tasks missing, resuming the run an earlier call left suspended when there is one
/// for the same project.
pub fn plan(project: Project) -> Result<Planned, RunError> {
    let key = project.output.clone();
    let earlier = take(&key);
    let messages = match earlier {
        Some(s) if s.project == project && s.resume.send(()).is_ok() => {
            (s.messages, s.resume, s.project)
        }
        other => {
            // A changed project (or a thread gone): end the old run before a new one
            // takes the output folder (it returns once it sees no one resumes it).
            if let Some(s) = other {
                drop(s.resume);
                while let Ok(m) = s.messages.recv() {
                    if matches!(m, Message::Done(_)) {
                        break;
                    }
                }
            }
            start(project)
        }
    };
    let (rx, resume, project) = messages;
    match rx.recv() {
        Ok(Message::Pending { stage, tasks }) => {
            put(
                key,
                Suspended {
                    project,
                    resume,
                    messages: rx,
                },
            );
            Ok(Planned::Pending { stage, tasks })
        }
        // A run whose hook could not wait ends as a replaying run does.
        Ok(Message::Done(r)) => match *r {
            Ok(Err(RunError::Pending { stage, tasks })) => Ok(Planned::Pending { stage, tasks }),
            Ok(r) => r.map(|s| Planned::Done(Box::new(s))),
            Err(payload) => std::panic::resume_unwind(payload),
        },
        Err(_) => panic!("the planning run's thread ended without a result"),
    }
}

/// A new run of `project` on its own thread.
fn start(project: Project) -> (Receiver<Message>, Sender<()>, Project) {
    let (to_planner, messages) = channel();
    let (resume, resumed) = channel();
    let p = project.clone();
    let done = to_planner.clone();
    std::thread::spawn(move || {
        HOOK.with(|h| {
            *h.borrow_mut() = Some(Hook {
                to_planner,
                resume: resumed,
            })
        });
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            run_project_with(&p, &mut |_| {}, None, super::TaskMode::Plan)
        }));
        let _ = done.send(Message::Done(Box::new(r)));
    });
    (messages, resume, project)
}

fn take(key: &PathBuf) -> Option<Suspended> {
    let mut m = SUSPENDED.lock().unwrap_or_else(|p| p.into_inner());
    m.as_mut().and_then(|m| m.remove(key))
}

fn put(key: PathBuf, s: Suspended) {
    let mut m = SUSPENDED.lock().unwrap_or_else(|p| p.into_inner());
    m.get_or_insert_with(HashMap::new).insert(key, s);
}
