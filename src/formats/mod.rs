//! Format adapters: coordinate reference systems (GDAL/PROJ), GeoTIFF rasters, and the
//! photogrammetric exchange formats. Readers and writers only; no photogrammetry here.

pub mod adjust_report;
pub mod blocks_exchange;
pub mod colmap;
pub mod control_points;
pub mod convert;
pub mod crs;
pub mod crs_input;
pub mod csv;
pub mod gdal;
pub mod image_open;
pub mod input;
pub mod odm_gcp;
pub mod ortho;
pub mod paths;
pub mod pos;
pub mod raster;
pub mod tiff_window;

use std::path::{Path, PathBuf};

/// Errors of the format adapters; each names the file (or CRS) and what was wrong.
#[derive(Debug, thiserror::Error)]
pub enum FormatError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
    /// A CSV row or header (formats/README.md, "CSV files"): 1-based line, column if known.
    #[error("{path}: line {line}{}: {message}", .column.as_ref().map(|c| format!(", column {c}")).unwrap_or_default())]
    Csv {
        path: PathBuf,
        line: usize,
        column: Option<String>,
        message: String,
    },
    #[error("coordinate reference system {crs:?}: {message}")]
    Crs { crs: String, message: String },
    /// A size or count in the file claims more than the file or a documented limit
    /// allows: refused before anything is allocated or decoded from it.
    #[error("{path}: {what}: {claimed} exceeds {limit}, {basis}")]
    TooLarge {
        path: PathBuf,
        what: String,
        claimed: u64,
        limit: u64,
        basis: String,
    },
    /// An input that is not a regular file (a FIFO, a device, a socket, a folder where a
    /// file is expected) or is reached through a symbolic link cycle: refused before
    /// anything is read from it ([`input`]).
    #[error("{path}: {message}")]
    NotRegularFile { path: PathBuf, message: String },
    #[error("{path}: GDAL: {message}")]
    Gdal { path: PathBuf, message: String },
    #[error(transparent)]
    Geometry(#[from] crate::geometry::GeometryError),
}

pub type Result<T> = std::result::Result<T, FormatError>;

impl FormatError {
    pub fn invalid(path: impl AsRef<Path>, message: impl Into<String>) -> Self {
        FormatError::Invalid {
            path: path.as_ref().to_path_buf(),
            message: message.into(),
        }
    }
    /// An error at `line` (1-based) and, if given, `column` of a CSV file.
    pub fn at(
        path: impl AsRef<Path>,
        line: usize,
        column: Option<String>,
        message: impl Into<String>,
    ) -> Self {
        FormatError::Csv {
            path: path.as_ref().to_path_buf(),
            line,
            column,
            message: message.into(),
        }
    }
    /// The message without the file name in front, for callers whose own error names
    /// the file.
    pub fn detail(&self) -> String {
        match self {
            FormatError::Io { source, .. } => source.to_string(),
            FormatError::Invalid { message, .. } => message.clone(),
            FormatError::NotRegularFile { message, .. } => message.clone(),
            FormatError::TooLarge {
                what,
                claimed,
                limit,
                basis,
                ..
            } => format!("{what}: {claimed} exceeds {limit}, {basis}"),
            FormatError::Csv {
                line,
                column,
                message,
                ..
            } => match column {
                Some(c) => format!("line {line}, column {c}: {message}"),
                None => format!("line {line}: {message}"),
            },
            e => e.to_string(),
        }
    }
    pub fn io(path: impl AsRef<Path>, source: std::io::Error) -> Self {
        FormatError::Io {
            path: path.as_ref().to_path_buf(),
            source,
        }
    }
    pub fn gdal(path: impl AsRef<Path>, e: gdal::GdalError) -> Self {
        FormatError::Gdal {
            path: path.as_ref().to_path_buf(),
            message: e.to_string(),
        }
    }
}

/// The token of a temporary name: `PID-THREAD-N`, unique per process, thread and call.
fn temporary_token() -> String {
    use std::sync::atomic::{AtomicU64, Ordering};
    static CALLS: AtomicU64 = AtomicU64::new(0);
    static THREADS: AtomicU64 = AtomicU64::new(0);
    thread_local! {
        static THREAD: u64 = THREADS.fetch_add(1, Ordering::Relaxed);
    }
    let thread = THREAD.with(|t| *t);
    let call = CALLS.fetch_add(1, Ordering::Relaxed);
    format!("{}-{thread}-{call}", std::process::id())
}

/// A number of an input file as an error message shows it: in scientific notation when
/// far from 1 (`1e-300`, not three hundred zeros), as written otherwise.
pub fn number_in_message(v: f64) -> String {
    if v != 0.0 && v.is_finite() && !(1e-4..1e9).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

/// A temporary sibling of `path` to write into before an atomic rename, so that readers
/// never see a half-written output: `.STEM.part-PID-THREAD-N[.EXT]`, a name no other
/// process, thread or call of this one is given (formats/README.md, "Outputs"). The
/// extension is kept (GDAL picks drivers by it). Every temporary output of the product is
/// named by this function, and [`parse_temporary`] recognises exactly these names.
pub fn temporary_sibling(path: &Path) -> PathBuf {
    let stem = path
        .file_stem()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let token = temporary_token();
    let name = match path.extension() {
        Some(ext) => format!(".{stem}.part-{token}.{}", ext.to_string_lossy()),
        None => format!(".{stem}.part-{token}"),
    };
    path.with_file_name(name)
}

/// A name [`temporary_sibling`] made: `.STEM.part-PID-THREAD-N` followed by nothing or by
/// `.` and the rest (the destination's extension, or what a writer such as GDAL added to
/// the temporary's name).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TemporaryName<'a> {
    /// The destination's stem.
    pub stem: &'a str,
    /// `PID-THREAD-N`.
    pub token: &'a str,
    pub pid: u32,
    /// After the token, without its leading dot (empty when nothing follows).
    pub rest: &'a str,
}

/// The parts of a temporary name of the product, or `None` for any other name.
pub fn parse_temporary(name: &str) -> Option<TemporaryName<'_>> {
    let rest = name.strip_prefix('.')?;
    // The last `.part-` followed by a well-formed token: a stem may hold `.part-` itself.
    rest.rmatch_indices(".part-").find_map(|(i, m)| {
        let stem = &rest[..i];
        let tail = &rest[i + m.len()..];
        let (token, after) = match tail.find('.') {
            Some(j) => (&tail[..j], &tail[j + 1..]),
            None => (tail, ""),
        };
        let parts: Vec<&str> = token.split('-').collect();
        let digits =
            |p: &&str| !p.is_empty() && p.len() <= 20 && p.bytes().all(|b| b.is_ascii_digit());
        if stem.is_empty() || parts.len() != 3 || !parts.iter().all(digits) {
            return None;
        }
        if tail.len() > token.len() && after.is_empty() {
            return None; // a trailing dot: not a name the product writes
        }
        Some(TemporaryName {
            stem,
            token,
            pid: parts[0].parse().ok()?,
            rest: after,
        })
    })
}

/// An advisory lock (`flock`) on an open file or folder, held until it is dropped; the
/// system releases it when the process ends, killed or not. Locks of one process conflict
/// too (each open file description holds its own), so threads serialise on it as
/// processes do.
#[derive(Debug)]
pub struct Lock(#[allow(dead_code)] std::fs::File);

impl Lock {
    /// Locks `path` (a file or a folder) exclusively; `wait` false returns `Ok(None)` at
    /// once when another holds the lock, `wait` true waits for it.
    pub fn exclusive(path: &Path, wait: bool) -> std::io::Result<Option<Lock>> {
        let f = std::fs::File::open(path)?;
        Ok(flock(&f, wait)?.then_some(Lock(f)))
    }
}

/// `flock(LOCK_EX)` on `f`: whether it was taken (`false`: held elsewhere and `wait` false).
fn flock(f: &std::fs::File, wait: bool) -> std::io::Result<bool> {
    #[cfg(unix)]
    {
        use std::os::unix::io::AsRawFd;
        let op = libc::LOCK_EX | if wait { 0 } else { libc::LOCK_NB };
        loop {
            // SAFETY: flock on a descriptor `f` owns for the duration of the call.
            if unsafe { libc::flock(f.as_raw_fd(), op) } == 0 {
                return Ok(true);
            }
            let e = std::io::Error::last_os_error();
            match e.raw_os_error() {
                Some(libc::EINTR) => continue,
                Some(libc::EWOULDBLOCK) => return Ok(false),
                _ => return Err(e),
            }
        }
    }
    #[cfg(not(unix))]
    {
        let _ = (f, wait);
        Ok(true)
    }
}

/// Folders created by [`create_folders`], removed again by [`CreatedFolders::undo`] when
/// the output that needed them failed, so that a failed command leaves no empty output
/// folder behind.
#[derive(Debug, Default)]
pub struct CreatedFolders(Vec<PathBuf>);

/// Creates `dir` and its missing ancestors, remembering those this call made: a folder
/// another thread or process made meanwhile is not this call's to remove.
pub fn create_folders(dir: &Path) -> Result<CreatedFolders> {
    let mut missing = Vec::new();
    let mut d = Some(dir);
    while let Some(p) =
        d.filter(|p| !p.as_os_str().is_empty() && std::fs::symlink_metadata(p).is_err())
    {
        missing.push(p.to_path_buf());
        d = p.parent();
    }
    let mut made = Vec::new();
    // Outermost first.
    for p in missing.iter().rev() {
        match std::fs::create_dir(p) {
            Ok(()) => made.push(p.clone()),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists && p.is_dir() => {}
            Err(e) => {
                made.reverse();
                CreatedFolders(made).undo(false);
                return Err(FormatError::io(p, e));
            }
        }
    }
    if !dir.is_dir() {
        // An existing name that is not a folder (or a link to none).
        made.reverse();
        CreatedFolders(made).undo(false);
        return Err(FormatError::invalid(dir, "exists and is not a folder"));
    }
    made.reverse();
    Ok(CreatedFolders(made))
}

impl CreatedFolders {
    /// Removes the created folders, innermost first; with `contents`, the outermost one
    /// is removed with whatever it holds (everything in it was written by the failed
    /// output, as it did not exist before), else only folders that are empty.
    pub fn undo(self, contents: bool) {
        if contents {
            if let Some(top) = self.0.last() {
                let _ = std::fs::remove_dir_all(top);
            }
            return;
        }
        for d in &self.0 {
            let _ = std::fs::remove_dir(d);
        }
    }
}

/// A temporary file reserved for one atomic write: created exclusively (`create_new`)
/// under a [`temporary_sibling`] name and locked while the write runs, so that
/// [`remove_dead_temporaries`] can tell a live writer's file from a killed one's. Removed
/// on drop (a failed or panicking write) unless it was renamed into place.
struct Reserved {
    path: PathBuf,
    _file: std::fs::File,
    renamed: bool,
}

impl Reserved {
    fn new(dest: &Path) -> Result<Self> {
        loop {
            let path = temporary_sibling(dest);
            match std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(&path)
            {
                Ok(file) => {
                    // A new file nobody else has opened: the lock is free.
                    flock(&file, false).map_err(|e| FormatError::io(&path, e))?;
                    return Ok(Self {
                        path,
                        _file: file,
                        renamed: false,
                    });
                }
                // A name left by a killed process of the same id: take the next.
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
                Err(e) => return Err(FormatError::io(dest, e)),
            }
        }
    }
}

impl Drop for Reserved {
    fn drop(&mut self) {
        if !self.renamed {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

/// Writes a file atomically: the closure writes into a temporary sibling (reserved for
/// this call alone, [`temporary_sibling`]) which is renamed over `path` only when it
/// succeeded; on failure, or a panic in the closure, the temporary file is removed, and so
/// are the folders created for it. Concurrent writes of one `path` from several threads or
/// processes each write their own temporary file; the last rename wins, whole.
pub fn write_atomically<T>(path: &Path, write: impl FnOnce(&Path) -> Result<T>) -> Result<T> {
    struct Folders(Option<CreatedFolders>);
    impl Drop for Folders {
        fn drop(&mut self) {
            if let Some(c) = self.0.take() {
                c.undo(false);
            }
        }
    }
    let mut created = Folders(match path.parent().filter(|d| !d.as_os_str().is_empty()) {
        Some(dir) => Some(create_folders(dir)?),
        None => None,
    });
    let mut tmp = Reserved::new(path)?;
    let v = write(&tmp.path)?;
    std::fs::rename(&tmp.path, path).map_err(|e| FormatError::io(path, e))?;
    tmp.renamed = true;
    created.0 = None;
    Ok(v)
}

/// Removes the temporary files a killed writer of `path` left beside it
/// ([`write_atomically`]'s, and what a writer added to their names): only names
/// [`parse_temporary`] recognises, with the stem of `path`, whose writer is gone — its
/// temporary file no longer locked, or no longer there (a file GDAL left beside a
/// temporary already renamed). A live writer's files, in this process or another, are
/// left alone. Returns the names removed.
pub fn remove_dead_temporaries(path: &Path) -> Result<Vec<PathBuf>> {
    let dir = match path.parent().filter(|d| !d.as_os_str().is_empty()) {
        Some(d) => d,
        None => Path::new("."),
    };
    let stem = path
        .file_stem()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().into_owned())
        .unwrap_or_default();
    let entries = match std::fs::read_dir(dir) {
        Ok(r) => r,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(FormatError::io(dir, e)),
    };
    // Temporary names of this destination, by token: (path, what follows the token).
    let mut groups: std::collections::BTreeMap<String, Vec<(PathBuf, String)>> = Default::default();
    for e in entries {
        let e = e.map_err(|e| FormatError::io(dir, e))?;
        let name = e.file_name().to_string_lossy().into_owned();
        let Some(t) = parse_temporary(&name) else {
            continue;
        };
        // Regular files only: the writers make no folders, links or anything else.
        if t.stem != stem || !e.file_type().is_ok_and(|k| k.is_file()) {
            continue;
        }
        groups
            .entry(t.token.to_string())
            .or_default()
            .push((e.path(), t.rest.to_string()));
    }
    let mut removed = Vec::new();
    for files in groups.into_values() {
        // Dead when the reserved file (the destination's extension after the token) is
        // gone, or when its lock can be taken.
        let dead = match files.iter().find(|(_, rest)| *rest == ext) {
            Some((main, _)) => match std::fs::File::open(main) {
                Ok(f) => flock(&f, false).unwrap_or(false),
                Err(e) => e.kind() == std::io::ErrorKind::NotFound,
            },
            None => true,
        };
        if !dead {
            continue;
        }
        for (f, _) in files {
            match std::fs::remove_file(&f) {
                Ok(()) => {
                    tracing::info!(path = %f.display(), "removed the temporary file of a killed writer");
                    removed.push(f);
                }
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(e) => return Err(FormatError::io(&f, e)),
            }
        }
    }
    Ok(removed)
}

/// Writes bytes atomically (text formats, JSON reports).
pub fn write_bytes_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomically(path, |tmp| {
        std::fs::write(tmp, bytes).map_err(|e| FormatError::io(path, e))
    })
}

/// The pixel-unit frame camera equivalent to a camera, for formats that only know frame
/// cameras (COLMAP, BlocksExchange in pixels). A film camera converts exactly when its
/// scan interior orientation is a pure scale with y up (axis-aligned scan, no shear);
/// any other scan needs resampling first (`matching::fiducial::frame_image`, which the
/// run's products do), which is refused here rather than approximated.
pub fn frame_equivalent(
    camera: &crate::geometry::Camera,
) -> std::result::Result<crate::geometry::FrameCamera, String> {
    use crate::geometry::{Camera, FrameCamera};
    match camera {
        Camera::Frame(f) => Ok(f.clone()),
        Camera::Film(c) => {
            let a = &c.interior.pixel_to_mm;
            let scale = a[(0, 0)].abs().max(a[(1, 1)].abs());
            let tol = 1e-12 * scale;
            if a[(0, 1)].abs() > tol
                || a[(1, 0)].abs() > tol
                || a[(2, 0)] != 0.0
                || a[(2, 1)] != 0.0
                || a[(2, 2)] != 1.0
                || a[(0, 0)] <= 0.0
                || a[(1, 1)] >= 0.0
            {
                return Err(
                    "film camera whose scan interior orientation is not an axis-aligned scale \
                     (x right, y up) has no exact frame-camera equivalent; resample the scan \
                     into its fiducial frame first (the products of `cloudcontrol run` do)"
                        .into(),
                );
            }
            let (sx, sy) = (a[(0, 0)], -a[(1, 1)]);
            Ok(FrameCamera {
                width: c.width,
                height: c.height,
                fx: c.focal_mm / sx,
                fy: c.focal_mm / sy,
                cx: (c.principal_point_mm[0] - a[(0, 2)]) / sx,
                cy: (a[(1, 2)] - c.principal_point_mm[1]) / sy,
                distortion: c.distortion,
            })
        }
    }
}
