//! Restartable stages. Each stage declares its inputs (files and parameters); its outputs
//! go to a folder of their own, written into a temporary sibling and renamed when the stage
//! succeeded. A ledger records each finished stage's input fingerprint, so a rerun skips a
//! stage whose inputs did not change and whose outputs are intact, and redoes it otherwise.
//! Killing a run mid-way therefore loses at most the stage that was running.
//!
//! The output folder is the product's: a run writes only into a folder it made or found
//! empty (its marker, [`MARKER`], says so), never into `/`, the home folder or a folder of
//! the user's. The ledger lists every name each stage wrote, and a run removes nothing
//! else: a stage is redone only when its folder holds nothing but its own names.
//!
//! A run holds a lock on its output folder (`flock` on the folder itself, released by the
//! system when the process ends, killed or not), so two runs never write one folder; the
//! temporary folders and files a killed run left behind (`.STAGE.part-PID-THREAD-N`, listed
//! in the ledger before they are made, and `.stages.part-PID-THREAD-N.json`) are removed
//! when the next run takes the lock.
//!
//! A fingerprint does not depend on where the project lies: each input file enters it by
//! its name relative to the input it was given under (a folder's files by their path below
//! it, a file by its name) with its content's SHA-256, so a project folder copied or moved
//! elsewhere, its output with it, skips every finished stage. The content digests are kept
//! in the output folder's digest cache ([`DIGESTS`]), keyed by each file's canonical path
//! and trusted while its size, modification and change times, inode and device are those
//! it was hashed with: a restart reads no unchanged input again.

use crate::formats::{input, write_bytes_atomically, FormatError};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::collections::{BTreeMap, HashMap, HashSet};
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
    /// The output folder, or a name in it, is not the run's to write: `/`, the home
    /// folder, a file, a folder cloudcontrol did not make, an input of the project, or a
    /// stage folder holding a file cloudcontrol did not write.
    #[error("{path}: {message}")]
    Output { path: PathBuf, message: String },
    /// Another run holds the output folder's lock.
    #[error(
        "{path}: another cloudcontrol run is writing this output folder; wait for it to end \
         or give another output"
    )]
    Busy { path: PathBuf },
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
    #[error(transparent)]
    Dense(#[from] crate::dense::DenseError),
    #[error(transparent)]
    Change(#[from] crate::change::ChangeError),
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
    /// [`Self::file`] when there is one.
    pub fn file_if(self, path: Option<&Path>) -> Self {
        match path {
            Some(p) => self.file(p),
            None => self,
        }
    }
    pub fn param(mut self, name: &str, value: &impl Serialize) -> Self {
        self.params.push((
            name.into(),
            serde_json::to_string(value).unwrap_or_default(),
        ));
        self
    }

    /// SHA-256 over, input by input in the order given, whether it is a file or a folder
    /// and each of its files' name relative to it (a folder's files by their
    /// `/`-separated path below it, a file by its file name) with the SHA-256 of the
    /// file's content, then the parameters. Where the inputs lie does not enter it: a
    /// project folder copied elsewhere has the same fingerprints. Content digests come
    /// from `digests` when the file is unchanged since it was hashed, else the file is
    /// streamed through the hash (never read whole; only regular files, [`input::open`]).
    /// A file reached by two paths is read once.
    fn fingerprint(&self, digests: &mut Digests) -> Result<String, FormatError> {
        let mut h = Sha256::new();
        let mut by_id: BTreeMap<(u64, u64), [u8; 32]> = BTreeMap::new();
        for root in &self.files {
            let files = files_below(root)?;
            let single = files.len() == 1 && files[0].path == *root;
            h.update(if single {
                &b"file\0"[..]
            } else {
                &b"folder\0"[..]
            });
            for file in files {
                let digest = match by_id.get(&file.id) {
                    Some(d) => *d,
                    None => {
                        let d = digests.digest(&file)?;
                        by_id.insert(file.id, d);
                        d
                    }
                };
                h.update(relative_name(root, &file.path).as_bytes());
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
        Ok(hex(&h.finalize()))
    }
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// The name a file of an input enters a fingerprint by: its `/`-separated path below the
/// input folder `root`, or its file name when it is the input itself.
fn relative_name(root: &Path, file: &Path) -> String {
    match file.strip_prefix(root) {
        Ok(rel) if !rel.as_os_str().is_empty() => rel
            .components()
            .map(|c| c.as_os_str().to_string_lossy())
            .collect::<Vec<_>>()
            .join("/"),
        _ => file
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default(),
    }
}

/// The digest cache of an output folder, beside the ledger (formats/project/README.md,
/// "Restarts"): each input's content SHA-256 by its canonical path, with the file's
/// size, modification and change times (ns), inode and device when it was hashed. A
/// restart takes the digest of a file whose stat is unchanged instead of reading it.
pub const DIGESTS: &str = ".cloudcontrol-digests.json";
/// [`DIGESTS`]'s stem, as its temporary files name it.
const DIGESTS_STEM: &str = ".cloudcontrol-digests";
const DIGESTS_FORMAT: u32 = 1;
/// A file modified less than this before it was hashed is not cached: a write in the same
/// tick of the file system's clock after the hash would leave its modification time as
/// it was ("racy" entries, as git calls them). 2 s covers the coarsest timestamps of
/// common file systems (FAT's 2 s; ext3's, HFS+'s and some NFS servers' 1 s). The change
/// time is part of what an entry is valid for (a write, then the modification time put
/// back, changes it), not of this test: a copy that keeps modification times (`cp -a`,
/// `rsync -a`) is cached at once.
const RACY_NS: i64 = 2_000_000_000;

/// What a file's cached digest is valid for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileStat {
    size: u64,
    mtime_ns: i64,
    ctime_ns: i64,
    ino: u64,
    dev: u64,
}

impl FileStat {
    #[cfg(unix)]
    fn of(m: &std::fs::Metadata) -> Option<Self> {
        use std::os::unix::fs::MetadataExt;
        let ns = |s: i64, n: i64| s.checked_mul(1_000_000_000)?.checked_add(n);
        Some(Self {
            size: m.len(),
            mtime_ns: ns(m.mtime(), m.mtime_nsec())?,
            ctime_ns: ns(m.ctime(), m.ctime_nsec())?,
            ino: m.ino(),
            dev: m.dev(),
        })
    }
    #[cfg(not(unix))]
    fn of(_: &std::fs::Metadata) -> Option<Self> {
        None
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CachedDigest {
    stat: FileStat,
    sha256: String,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct DigestFile {
    format: u32,
    files: BTreeMap<String, CachedDigest>,
}

/// The digest cache of a run ([`DIGESTS`]).
#[derive(Debug, Default)]
struct Digests {
    /// The cache file; `None` when the run keeps no cache (a file of that name the run
    /// did not write is in the output folder, or writing it failed).
    path: Option<PathBuf>,
    files: BTreeMap<String, CachedDigest>,
    /// Digests of files checked unchanged in this run, by (device, inode).
    checked: HashMap<(u64, u64), (FileStat, [u8; 32])>,
    /// Keys looked up or stored in this run.
    used: HashSet<String>,
    /// Whether `files` differs from the cache file.
    changed: bool,
    /// Whether the entries of files that are gone were dropped.
    pruned: bool,
    /// Files (and their bytes) streamed through the hash in this run, and files whose
    /// digest came from the cache.
    files_read: u64,
    bytes_read: u64,
    files_cached: u64,
}

fn now_ns() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos().min(i64::MAX as u128) as i64)
        .unwrap_or(0)
}

fn parse_digest(hex: &str) -> Option<[u8; 32]> {
    if hex.len() != 64 {
        return None;
    }
    let mut out = [0u8; 32];
    for (i, b) in out.iter_mut().enumerate() {
        *b = u8::from_str_radix(hex.get(2 * i..2 * i + 2)?, 16).ok()?;
    }
    Some(out)
}

impl Digests {
    /// The cache of output folder `root`: read when the ledger lists it (`listed`),
    /// empty when it is not there yet; a file of its name the ledger does not list is the
    /// user's, and the run then keeps no cache. An entry whose file was modified at or
    /// after the cache file was written is dropped (git's racy rule).
    fn load(root: &Path, listed: bool) -> Self {
        let path = root.join(DIGESTS);
        let mut d = Self {
            path: Some(path.clone()),
            ..Self::default()
        };
        if !listed {
            if std::fs::symlink_metadata(&path).is_ok() {
                tracing::warn!(
                    path = %path.display(),
                    "not written by cloudcontrol ({LEDGER} does not list it): no digest cache \
                     is kept, every input is read again"
                );
                d.path = None;
            }
            return d;
        }
        let read = input::open_file(&path, input::Links::Refuse).and_then(|(f, meta)| {
            let written = FileStat::of(&meta).map_or(i64::MIN, |s| s.mtime_ns);
            let bytes = input::read_opened(&path, f, meta.len(), input::Cap::document())?;
            Ok((written, bytes))
        });
        match read {
            Ok((written, bytes)) => match serde_json::from_slice::<DigestFile>(&bytes) {
                Ok(f) if f.format == DIGESTS_FORMAT => {
                    d.files = f.files;
                    let before = d.files.len();
                    d.files.retain(|_, c| c.stat.mtime_ns < written);
                    d.changed = d.files.len() != before;
                }
                _ => {
                    tracing::warn!(path = %path.display(), "unreadable digest cache: read anew");
                    d.changed = true;
                }
            },
            Err(e) if matches!(&e, FormatError::Io { source, .. } if source.kind() == std::io::ErrorKind::NotFound) =>
                {}
            Err(e) => {
                tracing::warn!(error = %e, "unreadable digest cache: read anew");
                d.changed = true;
            }
        }
        d
    }

    /// The content SHA-256 of `file`: from the cache when its stat is the one it was
    /// hashed with, else streamed ([`input::sha256_checked`]) and cached when the file
    /// did not change while read and was last modified [`RACY_NS`] before.
    fn digest(&mut self, file: &input::Found) -> Result<[u8; 32], FormatError> {
        let stat = std::fs::metadata(&file.path)
            .ok()
            .and_then(|m| FileStat::of(&m));
        if let Some(st) = stat {
            if let Some((s, d)) = self.checked.get(&file.id) {
                if *s == st {
                    return Ok(*d);
                }
            }
        }
        let key = std::fs::canonicalize(&file.path)
            .ok()
            .and_then(|p| p.to_str().map(str::to_owned));
        if let (Some(k), Some(st)) = (&key, stat) {
            self.used.insert(k.clone());
            if let Some(c) = self.files.get(k).filter(|c| c.stat == st) {
                if let Some(d) = parse_digest(&c.sha256) {
                    self.checked.insert(file.id, (st, d));
                    self.files_cached += 1;
                    return Ok(d);
                }
            }
        }
        let started = now_ns();
        let (d, before, after) = input::sha256_checked(&file.path)?;
        self.files_read += 1;
        self.bytes_read += before.len();
        let Some(k) = key else { return Ok(d) };
        match (FileStat::of(&before), FileStat::of(&after)) {
            (Some(b), Some(a)) if b == a && b.mtime_ns < started.saturating_sub(RACY_NS) => {
                self.files.insert(
                    k,
                    CachedDigest {
                        stat: b,
                        sha256: hex(&d),
                    },
                );
                self.checked.insert(file.id, (b, d));
                self.changed = true;
            }
            _ => {
                if self.files.remove(&k).is_some() {
                    self.changed = true;
                }
            }
        }
        Ok(d)
    }

    /// The cache file's bytes: its entries of this run's files and of files that are
    /// still there.
    fn pruned_json(&mut self) -> Vec<u8> {
        if !self.pruned {
            let used = &self.used;
            self.files
                .retain(|k, _| used.contains(k) || std::fs::symlink_metadata(k).is_ok());
            self.pruned = true;
        }
        let file = DigestFile {
            format: DIGESTS_FORMAT,
            files: std::mem::take(&mut self.files),
        };
        let json = serde_json::to_vec(&file).expect("digest cache serialises");
        self.files = file.files;
        json
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

/// The marker file of an output folder a run made (or found empty and took): a run writes
/// only into a folder that holds it (formats/project/README.md, "The output folder").
pub const MARKER: &str = ".cloudcontrol-output";
/// Format of the marker and of the ledger.
const OUTPUT_FORMAT: u32 = 1;
const LEDGER: &str = "stages.json";

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Marker {
    /// [`OUTPUT_FORMAT`] of the cloudcontrol that made the folder.
    cloudcontrol_output: u32,
}

/// The ledger of an output folder (`stages.json`): what each stage wrote, and the
/// fingerprints that let a rerun skip it.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
struct Ledger {
    format: u32,
    stages: BTreeMap<String, Record>,
    /// Temporary stage folders (`.STAGE.part-PID-THREAD-N`) a run is writing, listed
    /// before they are made: those a killed run left are removed by the next.
    #[serde(default)]
    temporaries: Vec<String>,
    /// The names the run wrote beside the stage folders other than the marker and the
    /// ledger: the digest cache ([`DIGESTS`]), listed before it is first written.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    files: Vec<String>,
}

impl Default for Ledger {
    fn default() -> Self {
        Self {
            format: OUTPUT_FORMAT,
            stages: BTreeMap::new(),
            temporaries: Vec::new(),
            files: Vec::new(),
        }
    }
}

/// One stage in the ledger.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
struct Record {
    /// Fingerprint of the inputs the stage finished with; absent while its folder is being
    /// replaced (a run killed then redoes the stage).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    inputs: Option<String>,
    /// Fingerprint of the files in `written`.
    outputs: String,
    /// Every name the stage wrote in its folder, relative to it, `/`-separated, folders
    /// ending in `/`; while the folder is being replaced, the old and the new names. A
    /// redo removes these and nothing else.
    written: Vec<String>,
}

/// What an output folder is before a run takes it ([`check_output_folder`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OutputFolder {
    /// Not there yet: the run makes it.
    Missing,
    /// An empty folder: the run takes it.
    Empty,
    /// A folder a run made (its marker is there).
    Owned,
}

/// `path` made absolute with every link and `..` of its existing part resolved, the
/// missing rest appended lexically: what it names, to compare with other paths.
pub fn resolved_path(path: &Path) -> PathBuf {
    let abs = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let mut existing = abs.as_path();
    let mut rest = Vec::new();
    loop {
        if let Ok(c) = std::fs::canonicalize(existing) {
            let mut out = c;
            for part in rest.iter().rev() {
                match part {
                    std::path::Component::ParentDir => {
                        out.pop();
                    }
                    std::path::Component::CurDir => {}
                    c => out.push(c.as_os_str()),
                }
            }
            return out;
        }
        match (existing.parent(), existing.components().next_back()) {
            (Some(parent), Some(last)) => {
                rest.push(last);
                existing = parent;
            }
            _ => return abs,
        }
    }
}

fn refuse(path: &Path, message: impl Into<String>) -> StageError {
    StageError::Output {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// Checks, changing nothing, that a run may write into `root`: not `/`, the home folder
/// or a folder holding it, not a file, and either missing, empty or made by a run (its
/// [`MARKER`]); a folder of anything else is refused, naming what it holds.
pub fn check_output_folder(root: &Path) -> Result<OutputFolder, StageError> {
    let real = resolved_path(root);
    if real.parent().is_none() {
        return Err(refuse(
            root,
            "is the root folder: give a folder of its own for the outputs",
        ));
    }
    if let Some(home) = std::env::var_os("HOME").filter(|h| !h.is_empty()) {
        let home = resolved_path(Path::new(&home));
        if home.starts_with(&real) {
            return Err(refuse(
                root,
                format!(
                    "is the home folder {} or holds it: give a folder of its own for the outputs",
                    home.display()
                ),
            ));
        }
    }
    let meta = match std::fs::metadata(root) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            if std::fs::symlink_metadata(root).is_ok() {
                return Err(refuse(root, "is a link to nothing"));
            }
            return Ok(OutputFolder::Missing);
        }
        Err(e) => return Err(FormatError::io(root, e).into()),
    };
    if !meta.is_dir() {
        return Err(refuse(
            root,
            "exists and is not a folder: the output is a folder cloudcontrol makes",
        ));
    }
    let marker = root.join(MARKER);
    match std::fs::symlink_metadata(&marker) {
        Ok(m) if m.is_file() => {
            read_marker(&marker)?;
            return Ok(OutputFolder::Owned);
        }
        Ok(_) => return Err(refuse(&marker, "is not a file cloudcontrol wrote")),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        Err(e) => return Err(FormatError::io(&marker, e).into()),
    }
    let mut names = Vec::new();
    for e in std::fs::read_dir(root).map_err(|e| FormatError::io(root, e))? {
        let e = e.map_err(|e| FormatError::io(root, e))?;
        names.push(e.file_name().to_string_lossy().into_owned());
        if names.len() > 100 {
            break;
        }
    }
    if names.is_empty() {
        return Ok(OutputFolder::Empty);
    }
    names.sort();
    let shown = names.iter().take(3).cloned().collect::<Vec<_>>().join(", ");
    let more = if names.len() > 3 { ", …" } else { "" };
    Err(refuse(
        root,
        format!(
            "is a folder cloudcontrol did not make (no {MARKER} in it) and is not empty \
             ({shown}{more}): a run writes only into a new or empty folder, or one an earlier \
             run made; give another output"
        ),
    ))
}

fn read_marker(path: &Path) -> Result<(), StageError> {
    use std::io::Read;
    let mut text = Vec::new();
    std::fs::File::open(path)
        .and_then(|f| f.take(4096).read_to_end(&mut text))
        .map_err(|e| FormatError::io(path, e))?;
    match serde_json::from_slice::<Marker>(&text) {
        Ok(m) if m.cloudcontrol_output <= OUTPUT_FORMAT => Ok(()),
        Ok(m) => Err(refuse(
            path,
            format!(
                "the folder was made by a newer cloudcontrol (output format {}; this one \
                 writes {OUTPUT_FORMAT})",
                m.cloudcontrol_output
            ),
        )),
        Err(e) => Err(refuse(
            path,
            format!("is not a marker cloudcontrol wrote ({e})"),
        )),
    }
}

/// Every name below `dir` as a ledger lists them (relative, `/`-separated, folders ending
/// in `/`), sorted; links are names, not followed.
fn names_below(dir: &Path) -> Result<Vec<String>, FormatError> {
    let mut out = Vec::new();
    let mut stack = vec![(dir.to_path_buf(), String::new())];
    while let Some((d, prefix)) = stack.pop() {
        for e in std::fs::read_dir(&d).map_err(|e| FormatError::io(&d, e))? {
            let e = e.map_err(|e| FormatError::io(&d, e))?;
            let name = format!("{prefix}{}", e.file_name().to_string_lossy());
            let is_dir = e
                .file_type()
                .map_err(|x| FormatError::io(e.path(), x))?
                .is_dir();
            if is_dir {
                stack.push((e.path(), format!("{name}/")));
                out.push(format!("{name}/"));
            } else {
                out.push(name);
            }
        }
    }
    out.sort();
    Ok(out)
}

/// Fingerprint of the files a stage wrote (the output check of a skipped stage): each
/// file's name relative to the stage folder `dir` with its content's SHA-256.
fn written_fingerprint(
    dir: &Path,
    written: &[String],
    digests: &mut Digests,
) -> Result<String, FormatError> {
    let mut names: Vec<&String> = written.iter().filter(|w| !w.ends_with('/')).collect();
    names.sort();
    let mut h = Sha256::new();
    for w in names {
        for file in files_below(&dir.join(w))? {
            h.update(relative_name(dir, &file.path).as_bytes());
            h.update([0]);
            h.update(digests.digest(&file)?);
        }
    }
    Ok(hex(&h.finalize()))
}

/// Runs stages under one output folder.
pub struct Runner {
    root: PathBuf,
    /// The output folder's run lock (released on drop).
    _lock: crate::formats::Lock,
    ledger: Ledger,
    digests: Digests,
    /// Names of the stages skipped in this run (for logs and tests).
    pub skipped: Vec<String>,
    pub ran: Vec<String>,
}

impl Runner {
    /// Takes `root` as a run's output folder: checks it ([`check_output_folder`]), makes
    /// it with its marker or writes the marker into an empty one, takes its run lock
    /// (refused with [`StageError::Busy`] while another run holds it), and removes the
    /// temporary outputs a killed run left there.
    pub fn new(root: &Path) -> Result<Self, StageError> {
        let made = match check_output_folder(root)? {
            OutputFolder::Missing => Some(crate::formats::create_folders(root)?),
            _ => None,
        };
        let taken = Self::take(root);
        if let (Err(e), Some(m)) = (&taken, made) {
            // This call made the folder, and nothing but its marker can be in it — unless
            // another run took it meanwhile (busy), which is then that run's.
            if !matches!(e, StageError::Busy { .. }) {
                let _ = std::fs::remove_file(root.join(MARKER));
                m.undo(false);
            }
        }
        taken
    }

    fn take(root: &Path) -> Result<Self, StageError> {
        let lock = crate::formats::Lock::exclusive(root, false)
            .map_err(|e| FormatError::io(root, e))?
            .ok_or_else(|| StageError::Busy {
                path: root.to_path_buf(),
            })?;
        // Again under the lock: another run may have taken the folder meanwhile.
        match check_output_folder(root)? {
            OutputFolder::Owned => {}
            OutputFolder::Empty => {
                let json = serde_json::to_vec(&Marker {
                    cloudcontrol_output: OUTPUT_FORMAT,
                })
                .expect("marker serialises");
                write_bytes_atomically(&root.join(MARKER), &json)?;
            }
            OutputFolder::Missing => {
                return Err(FormatError::invalid(root, "disappeared while it was taken").into())
            }
        }
        let path = root.join(LEDGER);
        let ledger = match std::fs::read(&path) {
            Ok(b) => serde_json::from_slice::<Ledger>(&b)
                .ok()
                .filter(|l| l.format == OUTPUT_FORMAT)
                .ok_or_else(|| {
                    refuse(
                        &path,
                        "cannot be read as the ledger of this cloudcontrol: without it the run \
                         cannot tell what it wrote; give another output",
                    )
                })?,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ledger::default(),
            Err(e) => return Err(FormatError::io(&path, e).into()),
        };
        let digests = Digests::load(root, ledger.files.iter().any(|f| f == DIGESTS));
        let mut runner = Self {
            root: root.to_path_buf(),
            _lock: lock,
            ledger,
            digests,
            skipped: Vec::new(),
            ran: Vec::new(),
        };
        runner.remove_leftovers()?;
        Ok(runner)
    }

    /// The output folder of a stage.
    pub fn dir(&self, stage: &str) -> PathBuf {
        self.root.join(stage)
    }

    fn save(&self) -> Result<(), FormatError> {
        let json = serde_json::to_vec_pretty(&self.ledger).expect("ledger serialises");
        write_bytes_atomically(&self.root.join(LEDGER), &json)
    }

    /// Writes the digest cache when it changed, listing it in the ledger before it is
    /// first written. The cache only saves reading: a failure to write it is logged, and
    /// the run goes on without it.
    fn save_digests(&mut self) {
        let Some(path) = self.digests.path.clone() else {
            return;
        };
        if !self.digests.changed {
            return;
        }
        if !self.ledger.files.iter().any(|f| f == DIGESTS) {
            if std::fs::symlink_metadata(&path).is_ok() {
                tracing::warn!(path = %path.display(), "not written by cloudcontrol: no digest cache is kept");
                self.digests.path = None;
                return;
            }
            self.ledger.files.push(DIGESTS.into());
            if let Err(e) = self.save() {
                tracing::warn!(error = %e, "the digest cache is not kept");
                self.digests.path = None;
                return;
            }
        }
        let json = self.digests.pruned_json();
        match write_bytes_atomically(&path, &json) {
            Ok(()) => self.digests.changed = false,
            Err(e) => {
                tracing::warn!(error = %e, "the digest cache is not kept");
                self.digests.path = None;
            }
        }
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
    ///
    /// A stage is redone into a temporary folder, and its old folder replaced only when it
    /// holds nothing but names the ledger says the stage wrote: a file someone added there
    /// stops the redo before any work, named in the error, and is never removed.
    pub fn stage_keyed(
        &mut self,
        name: &str,
        inputs: &Inputs,
        work: impl FnOnce(&Path, &str) -> Result<(), WorkError>,
    ) -> Result<PathBuf, StageError> {
        let dir = self.dir(name);
        let fp = inputs.fingerprint(&mut self.digests);
        self.save_digests();
        let fp = fp?;
        if let Some(r) = self.ledger.stages.get(name) {
            let unchanged = r.inputs.as_deref() == Some(fp.as_str())
                && dir.is_dir()
                && written_fingerprint(&dir, &r.written, &mut self.digests)
                    .ok()
                    .as_ref()
                    == Some(&r.outputs);
            self.save_digests();
            if unchanged {
                tracing::info!(stage = name, "inputs unchanged, skipping");
                self.skipped.push(name.into());
                return Ok(dir);
            }
        }
        self.check_replaceable(name)?;
        let tmp = crate::formats::temporary_sibling(&dir);
        let tmp_name = tmp
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        // Listed before it is made, so that a killed run's is removed by the next.
        self.ledger.temporaries.push(tmp_name.clone());
        self.save()?;
        let result = std::fs::create_dir(&tmp)
            .map_err(|e| WorkError::from(FormatError::io(&tmp, e)))
            .and_then(|()| {
                tracing::info!(stage = name, "running");
                work(&tmp, &fp)
            });
        if let Err(source) = result {
            let _ = std::fs::remove_dir_all(&tmp);
            self.ledger.temporaries.retain(|t| *t != tmp_name);
            let _ = self.save();
            return Err(StageError::Failed {
                stage: name.into(),
                source: Box::new(source),
            });
        }
        let installed = self.install(name, &tmp, fp);
        self.ledger.temporaries.retain(|t| *t != tmp_name);
        if installed.is_err() {
            let _ = std::fs::remove_dir_all(&tmp);
        }
        let saved = self.save();
        installed?;
        saved?;
        self.ran.push(name.into());
        Ok(dir)
    }

    /// Puts a stage's finished temporary folder `tmp` in the place of its folder and
    /// records it in the ledger (saved by the caller).
    fn install(&mut self, name: &str, tmp: &Path, fp: String) -> Result<(), StageError> {
        let dir = self.dir(name);
        let written = names_below(tmp)?;
        // The old names and the new ones are the stage's while the folder is replaced.
        let mut both = written.clone();
        if let Some(old) = self.ledger.stages.get(name) {
            both.extend(old.written.iter().cloned());
            both.sort();
            both.dedup();
        }
        self.ledger.stages.insert(
            name.into(),
            Record {
                inputs: None,
                outputs: String::new(),
                written: both,
            },
        );
        self.save()?;
        // Again, now that the work is done: a file may have been added meanwhile.
        self.check_replaceable(name)?;
        self.remove_stage_folder(name)?;
        std::fs::rename(tmp, &dir).map_err(|e| FormatError::io(&dir, e))?;
        let outputs = written_fingerprint(&dir, &written, &mut self.digests);
        self.save_digests();
        let outputs = outputs?;
        // Later stages depend on this one: their fingerprints include its outputs, so
        // changing it invalidates them without any bookkeeping here.
        self.ledger.stages.insert(
            name.into(),
            Record {
                inputs: Some(fp),
                outputs,
                written,
            },
        );
        Ok(())
    }

    /// Refuses to redo a stage whose folder holds a name the stage did not write (or that
    /// the ledger does not list as a stage's at all), naming it.
    fn check_replaceable(&self, name: &str) -> Result<(), StageError> {
        let dir = self.dir(name);
        let meta = match std::fs::symlink_metadata(&dir) {
            Ok(m) => m,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
            Err(e) => return Err(FormatError::io(&dir, e).into()),
        };
        let Some(record) = self.ledger.stages.get(name).filter(|_| meta.is_dir()) else {
            return Err(refuse(
                &dir,
                format!(
                    "stage {name} must be written here, and this name was not written by \
                     cloudcontrol ({LEDGER} does not list it): move it out of the output \
                     folder and run again; cloudcontrol removes only what it wrote"
                ),
            ));
        };
        let own: std::collections::HashSet<&str> =
            record.written.iter().map(String::as_str).collect();
        let foreign: Vec<String> = names_below(&dir)?
            .into_iter()
            .filter(|n| !own.contains(n.as_str()))
            .collect();
        // A folder that holds a foreign name is named through that name.
        let Some(first) = foreign.iter().find(|n| {
            !(n.ends_with('/') && foreign.iter().any(|m| m != *n && m.starts_with(n.as_str())))
        }) else {
            return Ok(());
        };
        let others = match foreign.len() - 1 {
            0 => String::new(),
            n => format!(" (and {n} other name(s) it did not write)"),
        };
        Err(refuse(
            &dir.join(first.trim_end_matches('/')),
            format!(
                "stage {name} must be redone, and this was not written by cloudcontrol{others}: \
                 move it out of the output folder and run again; cloudcontrol removes only \
                 what it wrote"
            ),
        ))
    }

    /// Removes a stage's folder by the ledger's list: its files, then its folders (each
    /// must then be empty), then the folder itself.
    fn remove_stage_folder(&self, name: &str) -> Result<(), StageError> {
        let dir = self.dir(name);
        if !dir.exists() {
            return Ok(());
        }
        let written = self
            .ledger
            .stages
            .get(name)
            .map(|r| r.written.clone())
            .unwrap_or_default();
        let gone = |r: std::io::Result<()>, p: &Path| match r {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                Err(StageError::from(FormatError::io(p, e)))
            }
            _ => Ok(()),
        };
        for f in written.iter().filter(|w| !w.ends_with('/')) {
            let p = dir.join(f);
            gone(std::fs::remove_file(&p), &p)?;
        }
        // Deepest first.
        let mut folders: Vec<&String> = written.iter().filter(|w| w.ends_with('/')).collect();
        folders.sort_by_key(|w| std::cmp::Reverse(w.matches('/').count()));
        for f in folders
            .into_iter()
            .map(|f| dir.join(f))
            .chain([dir.clone()])
        {
            gone(std::fs::remove_dir(&f), &f).map_err(|_| {
                refuse(
                    &f,
                    "holds names cloudcontrol did not write; move them out of the output \
                     folder and run again",
                )
            })?;
        }
        Ok(())
    }

    /// Removes the temporary outputs of runs that ended without cleaning up (killed):
    /// under the run lock no other run can be writing them, and only names the product
    /// writes are touched ([`is_leftover`]).
    fn remove_leftovers(&mut self) -> Result<(), StageError> {
        let root = &self.root;
        for e in std::fs::read_dir(root).map_err(|e| FormatError::io(root, e))? {
            let e = e.map_err(|e| FormatError::io(root, e))?;
            let name = e.file_name().to_string_lossy().into_owned();
            if !is_leftover(&name, &self.ledger.temporaries) {
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
        if !self.ledger.temporaries.is_empty() {
            self.ledger.temporaries.clear();
            self.save()?;
        }
        Ok(())
    }
}

impl Drop for Runner {
    /// Logs what the run's fingerprints read: a restart whose inputs are unchanged reads
    /// none of them (their digests come from the cache).
    fn drop(&mut self) {
        let d = &self.digests;
        tracing::info!(
            files_read = d.files_read,
            bytes_read = d.bytes_read,
            files_cached = d.files_cached,
            "input digests"
        );
    }
}

/// Whether `name`, in an output folder, is a temporary output of a run: a temporary
/// ([`crate::formats::parse_temporary`]) of the ledger or the marker, or a temporary stage
/// folder the ledger lists.
fn is_leftover(name: &str, temporaries: &[String]) -> bool {
    let Some(t) = crate::formats::parse_temporary(name) else {
        return false;
    };
    (t.stem == "stages" && t.rest == "json")
        || (t.stem == MARKER && t.rest.is_empty())
        || (t.stem == DIGESTS_STEM && t.rest == "json")
        || temporaries.iter().any(|n| n == name)
}
