//! Restartable stages. Each stage declares its inputs (files and parameters); its outputs
//! go to a folder of their own, written into a temporary sibling and renamed when the stage
//! succeeded. A ledger records each finished stage's input fingerprint, so a rerun skips a
//! stage whose inputs did not change and whose outputs are intact, and redoes it otherwise.
//! Killing a run mid-way therefore loses at most the stage that was running.
//!
//! A run holds a lock on its output folder (`flock` on the folder itself, released by the
//! system when the process ends, killed or not), so two runs never write one folder; the
//! temporary folders and files a killed run left behind (`.STAGE.part-PID`,
//! `.stages.part-PID.json`) are removed when the next run takes the lock.

use crate::formats::{input, write_bytes_atomically, FormatError};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum StageError {
    #[error("stage {stage}: {source}")]
    Failed {
        stage: String,
        // Boxed: the error travels through every stage's Result.
        #[source]
        source: Box<WorkError>,
    },
    #[error(transparent)]
    Format(#[from] FormatError),
}

/// What a stage's work failed on: the error of the module that failed, kept typed so that
/// callers (the C ABI above all) can tell a missing file from a numeric failure.
#[derive(Debug, thiserror::Error)]
pub enum WorkError {
    #[error(transparent)]
    Epoch(#[from] crate::control::EpochError),
    #[error(transparent)]
    Lidar(#[from] crate::lidar::LidarError),
    #[error(transparent)]
    Format(#[from] FormatError),
    #[error(transparent)]
    Dcp(#[from] crate::control::DcpError),
    #[error(transparent)]
    Checkpoints(#[from] crate::control::checkpoints::EvaluationError),
    /// Inputs that are each valid but do not fit together (LiDAR in another CRS, no tile
    /// under the photos).
    #[error("{0}")]
    Inconsistent(String),
    /// Per-photo tasks the stage needs and a run that plans (rather than runs) its tasks
    /// leaves to others ([`super::tasks`]): not a failure, the stage is simply not done.
    #[error("{} task(s) to run first", .0.len())]
    Pending(Vec<super::tasks::Task>),
}

/// What a stage depends on: files (hashed by content) and parameters (any serialisable).
#[derive(Debug, Default, Clone)]
pub struct Inputs {
    files: Vec<PathBuf>,
    params: Vec<(String, String)>,
}

impl Inputs {
    pub fn new() -> Self {
        Self::default()
    }
    /// A file or a folder (every file below it, in sorted order).
    pub fn file(mut self, path: impl Into<PathBuf>) -> Self {
        self.files.push(path.into());
        self
    }
    pub fn param(mut self, name: &str, value: &impl Serialize) -> Self {
        self.params.push((
            name.into(),
            serde_json::to_string(value).unwrap_or_default(),
        ));
        self
    }

    /// SHA-256 over every input file's path and content digest (each file streamed
    /// through the hash, never read whole; only regular files, [`input::open`]) and the
    /// parameters. A file reached by two paths is read once.
    fn fingerprint(&self) -> Result<String, FormatError> {
        let mut h = Sha256::new();
        let mut digests: BTreeMap<(u64, u64), [u8; 32]> = BTreeMap::new();
        for f in &self.files {
            for file in files_below(f)? {
                let digest = match digests.get(&file.id) {
                    Some(d) => *d,
                    None => {
                        let d = input::sha256(&file.path)?;
                        digests.insert(file.id, d);
                        d
                    }
                };
                h.update(file.path.to_string_lossy().as_bytes());
                h.update([0]);
                h.update(digest);
            }
        }
        for (k, v) in &self.params {
            h.update(k.as_bytes());
            h.update([0]);
            h.update(v.as_bytes());
            h.update([0]);
        }
        Ok(h.finalize().iter().map(|b| format!("{b:02x}")).collect())
    }
}

/// The regular files of a stage input, sorted by path: the file itself or every file
/// below the folder, links followed; FIFOs, devices, sockets, link cycles and oversized
/// trees refused ([`input::files_below`]).
fn files_below(p: &Path) -> Result<Vec<input::Found>, FormatError> {
    match std::fs::symlink_metadata(p) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            Err(FormatError::invalid(p, "stage input does not exist"))
        }
        _ => input::files_below(p),
    }
}

#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
struct Ledger {
    /// Stage name → input fingerprint and output fingerprint of a finished stage.
    stages: BTreeMap<String, (String, String)>,
}

/// Runs stages under one output folder.
pub struct Runner {
    root: PathBuf,
    /// The open output folder whose lock this run holds (released on drop).
    _lock: std::fs::File,
    ledger: Ledger,
    /// Names of the stages skipped in this run (for logs and tests).
    pub skipped: Vec<String>,
    pub ran: Vec<String>,
}

const LEDGER: &str = "stages.json";

impl Runner {
    pub fn new(root: &Path) -> Result<Self, FormatError> {
        std::fs::create_dir_all(root).map_err(|e| FormatError::io(root, e))?;
        let lock = lock_folder(root)?;
        remove_leftovers(root)?;
        let ledger = match std::fs::read(root.join(LEDGER)) {
            Ok(b) => serde_json::from_slice(&b).unwrap_or_default(),
            Err(_) => Ledger::default(),
        };
        Ok(Self {
            root: root.to_path_buf(),
            _lock: lock,
            ledger,
            skipped: Vec::new(),
            ran: Vec::new(),
        })
    }

    /// The output folder of a stage.
    pub fn dir(&self, stage: &str) -> PathBuf {
        self.root.join(stage)
    }

    /// Runs `work` into the stage's folder unless the stage finished before with the same
    /// inputs and its outputs are unchanged. `work` writes into the folder it is given.
    pub fn stage(
        &mut self,
        name: &str,
        inputs: &Inputs,
        work: impl FnOnce(&Path) -> Result<(), WorkError>,
    ) -> Result<PathBuf, StageError> {
        self.stage_keyed(name, inputs, |dir, _| work(dir))
    }

    /// [`Runner::stage`], `work` also given the fingerprint of the stage's inputs (the key
    /// of its per-photo task results).
    pub fn stage_keyed(
        &mut self,
        name: &str,
        inputs: &Inputs,
        work: impl FnOnce(&Path, &str) -> Result<(), WorkError>,
    ) -> Result<PathBuf, StageError> {
        let dir = self.dir(name);
        let fp = inputs.fingerprint()?;
        if let Some((done_fp, out_fp)) = self.ledger.stages.get(name) {
            if *done_fp == fp
                && dir.is_dir()
                && Inputs::new().file(&dir).fingerprint().ok().as_ref() == Some(out_fp)
            {
                tracing::info!(stage = name, "inputs unchanged, skipping");
                self.skipped.push(name.into());
                return Ok(dir);
            }
        }
        let tmp = self
            .root
            .join(format!(".{name}.part-{}", std::process::id()));
        if tmp.exists() {
            std::fs::remove_dir_all(&tmp).map_err(|e| FormatError::io(&tmp, e))?;
        }
        std::fs::create_dir_all(&tmp).map_err(|e| FormatError::io(&tmp, e))?;
        tracing::info!(stage = name, "running");
        if let Err(source) = work(&tmp, &fp) {
            let _ = std::fs::remove_dir_all(&tmp);
            return Err(StageError::Failed {
                stage: name.into(),
                source: Box::new(source),
            });
        }
        if dir.exists() {
            std::fs::remove_dir_all(&dir).map_err(|e| FormatError::io(&dir, e))?;
        }
        std::fs::rename(&tmp, &dir).map_err(|e| FormatError::io(&dir, e))?;
        let out_fp = Inputs::new().file(&dir).fingerprint()?;
        // Later stages depend on this one: their fingerprints include its outputs, so
        // changing it invalidates them without any bookkeeping here.
        self.ledger.stages.insert(name.into(), (fp, out_fp));
        let json = serde_json::to_vec_pretty(&self.ledger).expect("ledger serialises");
        write_bytes_atomically(&self.root.join(LEDGER), &json)?;
        self.ran.push(name.into());
        Ok(dir)
    }
}

/// Takes the run lock of an output folder, refusing a folder another run holds.
fn lock_folder(root: &Path) -> Result<std::fs::File, FormatError> {
    let dir = std::fs::File::open(root).map_err(|e| FormatError::io(root, e))?;
    #[cfg(unix)]
    {
        use std::os::unix::io::AsRawFd;
        // SAFETY: flock on a descriptor this function owns.
        if unsafe { libc::flock(dir.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } != 0 {
            let e = std::io::Error::last_os_error();
            if e.raw_os_error() == Some(libc::EWOULDBLOCK) {
                return Err(FormatError::invalid(
                    root,
                    "another cloudcontrol run is writing this output folder; wait for it to \
                     end or give another output",
                ));
            }
            return Err(FormatError::io(root, e));
        }
    }
    Ok(dir)
}

/// Whether `name` is a temporary output of a run (`.NAME.part-PID[.EXT]`).
fn is_leftover(name: &str) -> bool {
    let Some(rest) = name.strip_prefix('.') else {
        return false;
    };
    rest.rsplit_once(".part-").is_some_and(|(stem, tail)| {
        let pid = tail.split('.').next().unwrap_or("");
        !stem.is_empty() && !pid.is_empty() && pid.bytes().all(|b| b.is_ascii_digit())
    })
}

/// Removes the temporary outputs of runs that ended without cleaning up (killed): under
/// the run lock, no other run can be writing them.
fn remove_leftovers(root: &Path) -> Result<(), FormatError> {
    for e in std::fs::read_dir(root).map_err(|e| FormatError::io(root, e))? {
        let e = e.map_err(|e| FormatError::io(root, e))?;
        if !is_leftover(&e.file_name().to_string_lossy()) {
            continue;
        }
        let path = e.path();
        let is_dir = e.file_type().is_ok_and(|t| t.is_dir());
        let removed = if is_dir {
            std::fs::remove_dir_all(&path)
        } else {
            std::fs::remove_file(&path)
        };
        removed.map_err(|e| FormatError::io(&path, e))?;
        tracing::info!(path = %path.display(), "removed the leftover of an interrupted run");
    }
    Ok(())
}
