//! The one way an input is opened (formats/README.md, "Input files"): every file a user
//! names — a project file, a CSV, a camera, a photo, a LAS tile, a folder of them — is
//! read through these functions, so that none of them can hang a run, exhaust memory or
//! send a folder walk round in circles:
//!
//! - Only regular files are read. A FIFO, a device (`/dev/zero`), a socket or a folder
//!   where a file is expected is refused with an error naming the file and what it is.
//!   The type is checked on the path first (nothing is opened that is not a regular
//!   file: opening a FIFO waits for a writer, opening a device may act on it), then again
//!   on the opened descriptor, which is opened with `O_NONBLOCK` (a FIFO swapped in
//!   between cannot block the open) and must be the file that was checked; `O_NONBLOCK`
//!   is cleared before reading.
//! - Symbolic links are followed ([`Links::Follow`]) or refused ([`Links::Refuse`], the
//!   members of a DCP package). A link cycle is refused, naming the link.
//! - Text is read with a size cap ([`Cap`]), and line-by-line readers with a cap per
//!   line ([`lines`]); the caps are [`Limits`], configurable with
//!   `CLOUDCONTROL_INPUT_LIMITS` or [`set_limits`].
//! - A folder is walked ([`files_below`]) following links, with a cycle check on the
//!   folders' (device, inode) and bounds on depth and entries.
//! - A file is hashed by streaming it ([`sha256`]), never read whole.

use super::{FormatError, Result};
use sha2::{Digest, Sha256};
use std::fs::{File, Metadata};
use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::sync::{LazyLock, RwLock};

/// The environment variable that sets [`Limits`]: comma-separated `name=value` pairs,
/// values in bytes or counts with an optional binary suffix `K`, `M`, `G`
/// (`CLOUDCONTROL_INPUT_LIMITS="csv=1G,csv_line=4M"`). Names are those of
/// [`Limits::NAMES`].
pub const LIMITS_ENV: &str = "CLOUDCONTROL_INPUT_LIMITS";

/// Caps on what an input may hold (formats/README.md, "Input files"). Each bounds the
/// memory one file can make a reader take, far above what a real input of its kind holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    /// `project`: a project file (TOML). 1 MiB: a project of a hundred epochs is ~20 KB;
    /// the TOML parser takes ~40 bytes per byte of input.
    pub project_bytes: u64,
    /// `camera`: a camera file (JSON). 4 MiB: a film camera's certificate with its
    /// fiducials is ~5 KB, a frame camera < 1 KB.
    pub camera_bytes: u64,
    /// `csv`: a CSV file (POS, strips, control and check points, measurements). 256 MiB:
    /// ~3 million rows; the reader streams the file, only the records are kept.
    pub csv_bytes: u64,
    /// `csv_line`: one line (or quoted record) of a CSV file. 1 MiB: rows are < 1 KB.
    pub csv_line_bytes: u64,
    /// `csv_columns`: columns of a CSV header. 1024: our layouts have ≤ 16.
    pub csv_columns: u64,
    /// `document`: a JSON, XML or MessagePack file read whole other than a project or a
    /// camera (workflow files, BlocksExchange, LiDAR catalogues, side files, task files).
    /// 1 GiB: a BlocksExchange block of 10⁶ tie points is ~500 MB.
    pub document_bytes: u64,
    /// `line`: one line of another line-based text file (COLMAP text models, XYZ point
    /// files). 64 MiB: a COLMAP image line of 10⁶ keypoints is ~30 MB.
    pub line_bytes: u64,
    /// `folder_depth`: folders below a folder input. 64.
    pub folder_depth: u64,
    /// `folder_entries`: files and folders below a folder input. 10⁶: a photos folder
    /// of 10⁵ scans, a LiDAR folder of 10⁴ tiles, a DCP store of 10⁵ chips.
    pub folder_entries: u64,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            project_bytes: 1 << 20,
            camera_bytes: 4 << 20,
            csv_bytes: 256 << 20,
            csv_line_bytes: 1 << 20,
            csv_columns: 1024,
            document_bytes: 1 << 30,
            line_bytes: 64 << 20,
            folder_depth: 64,
            folder_entries: 1_000_000,
        }
    }
}

impl Limits {
    /// The names of the limits in [`LIMITS_ENV`], in field order.
    pub const NAMES: [&'static str; 9] = [
        "project",
        "camera",
        "csv",
        "csv_line",
        "csv_columns",
        "document",
        "line",
        "folder_depth",
        "folder_entries",
    ];

    fn field(&mut self, name: &str) -> Option<&mut u64> {
        Some(match name {
            "project" => &mut self.project_bytes,
            "camera" => &mut self.camera_bytes,
            "csv" => &mut self.csv_bytes,
            "csv_line" => &mut self.csv_line_bytes,
            "csv_columns" => &mut self.csv_columns,
            "document" => &mut self.document_bytes,
            "line" => &mut self.line_bytes,
            "folder_depth" => &mut self.folder_depth,
            "folder_entries" => &mut self.folder_entries,
            _ => return None,
        })
    }

    /// These limits changed by a [`LIMITS_ENV`] value (`csv=1G,csv_line=4M`).
    pub fn parse(mut self, spec: &str) -> std::result::Result<Self, String> {
        for item in spec.split(',').map(str::trim).filter(|s| !s.is_empty()) {
            let (name, value) = item
                .split_once('=')
                .ok_or_else(|| format!("{item:?} is not name=value"))?;
            let name = name.trim();
            let value = parse_size(value.trim()).ok_or_else(|| {
                format!("{name}: {value:?} is not a positive number (with K, M or G)")
            })?;
            *self.field(name).ok_or_else(|| {
                format!(
                    "{name:?} is not a limit (one of {})",
                    Self::NAMES.join(", ")
                )
            })? = value;
        }
        Ok(self)
    }

    /// The defaults changed by [`LIMITS_ENV`]; a value that does not parse is reported
    /// in the log and the defaults are kept.
    pub fn from_env() -> Self {
        match std::env::var(LIMITS_ENV) {
            Ok(spec) => Self::default().parse(&spec).unwrap_or_else(|e| {
                tracing::warn!("{LIMITS_ENV}: {e}; the default input limits apply");
                Self::default()
            }),
            Err(_) => Self::default(),
        }
    }
}

fn parse_size(s: &str) -> Option<u64> {
    let (digits, shift) = match s.as_bytes().last()? {
        b'k' | b'K' => (&s[..s.len() - 1], 10),
        b'm' | b'M' => (&s[..s.len() - 1], 20),
        b'g' | b'G' => (&s[..s.len() - 1], 30),
        _ => (s, 0),
    };
    let v: u64 = digits.trim().parse().ok()?;
    (v > 0).then_some(v)?.checked_mul(1 << shift)
}

static LIMITS: LazyLock<RwLock<Limits>> = LazyLock::new(|| RwLock::new(Limits::from_env()));

/// The limits in force: [`LIMITS_ENV`] over the defaults, or what [`set_limits`] set.
pub fn limits() -> Limits {
    *LIMITS.read().unwrap_or_else(|e| e.into_inner())
}

/// Sets the limits for the whole process (callers of the library that do not use the
/// environment).
pub fn set_limits(l: Limits) {
    *LIMITS.write().unwrap_or_else(|e| e.into_inner()) = l;
}

/// A cap on the bytes of a file read whole: the limit and what it is for, named in the
/// error of a larger file.
#[derive(Debug, Clone, Copy)]
pub struct Cap {
    pub bytes: u64,
    /// What the file is ("CSV file"), in the message.
    pub what: &'static str,
    /// Its name in [`LIMITS_ENV`], when it is configurable.
    pub setting: Option<&'static str>,
}

impl Cap {
    pub fn project() -> Self {
        Self::setting(limits().project_bytes, "project file", "project")
    }
    pub fn camera() -> Self {
        Self::setting(limits().camera_bytes, "camera file", "camera")
    }
    pub fn csv() -> Self {
        Self::setting(limits().csv_bytes, "CSV file", "csv")
    }
    /// One line (or quoted record) of a CSV file.
    pub fn csv_line() -> Self {
        Self::setting(limits().csv_line_bytes, "CSV line", "csv_line")
    }
    pub fn document() -> Self {
        Self::setting(limits().document_bytes, "document", "document")
    }
    /// One line of another line-based text file.
    pub fn line() -> Self {
        Self::setting(limits().line_bytes, "line", "line")
    }
    /// A cap that is not configurable (a CRS definition, a DCP member).
    pub const fn fixed(bytes: u64, what: &'static str) -> Self {
        Self {
            bytes,
            what,
            setting: None,
        }
    }
    const fn setting(bytes: u64, what: &'static str, name: &'static str) -> Self {
        Self {
            bytes,
            what,
            setting: Some(name),
        }
    }
    /// Why the limit is what it is, for [`FormatError::TooLarge`].
    pub fn basis(&self) -> String {
        match self.setting {
            Some(s) => format!(
                "the largest {} read (raise `{s}` in {LIMITS_ENV} to read more)",
                self.what
            ),
            None => format!("the largest {} read", self.what),
        }
    }
    fn too_large(&self, path: &Path, what: String, claimed: u64) -> FormatError {
        FormatError::TooLarge {
            path: path.to_path_buf(),
            what,
            claimed,
            limit: self.bytes,
            basis: self.basis(),
        }
    }
}

/// Whether symbolic links in a path are followed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Links {
    /// Followed (a link cycle is refused): the inputs a user names.
    Follow,
    /// The last component may not be a link: the members of a DCP package, which may
    /// come from anyone.
    Refuse,
}

/// What a file system object is, for messages: "a FIFO", "a device", ….
pub fn kind(m: &Metadata) -> &'static str {
    let t = m.file_type();
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_fifo() {
            return "a FIFO";
        }
        if t.is_char_device() || t.is_block_device() {
            return "a device";
        }
        if t.is_socket() {
            return "a socket";
        }
    }
    if t.is_symlink() {
        "a symbolic link"
    } else if t.is_dir() {
        "a folder"
    } else if t.is_file() {
        "a regular file"
    } else {
        "not a regular file"
    }
}

/// Whether two metadata are of one file (device and inode).
pub fn same_file(a: &Metadata, b: &Metadata) -> bool {
    file_id(a) == file_id(b)
}

/// The (device, inode) of a file.
#[cfg(unix)]
pub fn file_id(m: &Metadata) -> (u64, u64) {
    use std::os::unix::fs::MetadataExt;
    (m.dev(), m.ino())
}

#[cfg(not(unix))]
pub fn file_id(_: &Metadata) -> (u64, u64) {
    (0, 0)
}

fn not_regular(path: &Path, message: String) -> FormatError {
    FormatError::NotRegularFile {
        path: path.to_path_buf(),
        message,
    }
}

/// Whether an I/O error is "too many levels of symbolic links".
fn is_loop(e: &std::io::Error) -> bool {
    #[cfg(unix)]
    {
        e.raw_os_error() == Some(libc::ELOOP)
    }
    #[cfg(not(unix))]
    {
        let _ = e;
        false
    }
}

/// The error of a path whose metadata could not be read (following links).
fn stat_error(path: &Path, e: std::io::Error) -> FormatError {
    if is_loop(&e) {
        return not_regular(
            path,
            "is a symbolic link cycle (too many levels of symbolic links)".into(),
        );
    }
    if e.kind() == std::io::ErrorKind::NotFound {
        if let Ok(target) = std::fs::read_link(path) {
            return FormatError::io(
                path,
                std::io::Error::new(
                    std::io::ErrorKind::NotFound,
                    format!(
                        "is a symbolic link to {}, which does not exist",
                        target.display()
                    ),
                ),
            );
        }
    }
    FormatError::io(path, e)
}

/// "is a FIFO" or "links to /dev/zero, a character device".
fn describe(path: &Path, m: &Metadata) -> String {
    match std::fs::read_link(path) {
        Ok(target) => format!("links to {}, {}", target.display(), kind(m)),
        Err(_) => format!("is {}", kind(m)),
    }
}

/// Metadata of `path`, which must be a regular file (links followed or refused).
fn regular_metadata(path: &Path, links: Links) -> Result<Metadata> {
    let m = match links {
        Links::Follow => std::fs::metadata(path),
        Links::Refuse => std::fs::symlink_metadata(path),
    }
    .map_err(|e| stat_error(path, e))?;
    if m.file_type().is_symlink() {
        let target = std::fs::read_link(path)
            .map(|t| format!(" (to {})", t.display()))
            .unwrap_or_default();
        return Err(not_regular(
            path,
            format!("is a symbolic link{target}, not a regular file"),
        ));
    }
    if !m.is_file() {
        return Err(not_regular(
            path,
            format!("{}, not a regular file", describe(path, &m)),
        ));
    }
    Ok(m)
}

/// Checks, without opening it, that `path` is a regular file (links followed) of at most
/// `cap` bytes when a cap is given; for the checks made before work starts.
pub fn check_file(path: &Path, cap: Option<Cap>) -> Result<Metadata> {
    let m = regular_metadata(path, Links::Follow)?;
    if let Some(cap) = cap {
        if m.len() > cap.bytes {
            return Err(cap.too_large(path, "size in bytes".into(), m.len()));
        }
    }
    Ok(m)
}

/// Checks, without reading any file, that `path` is a regular file, or a folder all of
/// whose entries below are regular files or folders ([`files_below`]).
pub fn check_tree(path: &Path) -> Result<()> {
    files_below(path).map(|_| ())
}

/// Opens a regular file for reading (links followed).
pub fn open(path: &Path) -> Result<File> {
    open_file(path, Links::Follow).map(|(f, _)| f)
}

/// Opens a regular file for reading and returns it with its metadata (taken on the open
/// descriptor).
pub fn open_file(path: &Path, links: Links) -> Result<(File, Metadata)> {
    let checked = regular_metadata(path, links)?;
    let file = open_nonblocking(path, links).map_err(|e| {
        if is_loop(&e) {
            match links {
                Links::Refuse => not_regular(path, "is a symbolic link, not a regular file".into()),
                Links::Follow => stat_error(path, e),
            }
        } else {
            FormatError::io(path, e)
        }
    })?;
    let opened = file.metadata().map_err(|e| FormatError::io(path, e))?;
    if !opened.is_file() || !same_file(&checked, &opened) {
        return Err(not_regular(
            path,
            format!(
                "changed while it was opened (now {}), not a regular file",
                kind(&opened)
            ),
        ));
    }
    clear_nonblocking(&file).map_err(|e| FormatError::io(path, e))?;
    Ok((file, opened))
}

#[cfg(unix)]
fn open_nonblocking(path: &Path, links: Links) -> std::io::Result<File> {
    use std::os::unix::fs::OpenOptionsExt;
    let mut flags = libc::O_NONBLOCK | libc::O_NOCTTY;
    if links == Links::Refuse {
        flags |= libc::O_NOFOLLOW;
    }
    std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(flags)
        .open(path)
}

#[cfg(not(unix))]
fn open_nonblocking(path: &Path, _: Links) -> std::io::Result<File> {
    File::open(path)
}

#[cfg(unix)]
fn clear_nonblocking(f: &File) -> std::io::Result<()> {
    use std::os::unix::io::AsRawFd;
    let fd = f.as_raw_fd();
    // SAFETY: fcntl on a descriptor `f` owns, for the lifetime of the call.
    let flags = unsafe { libc::fcntl(fd, libc::F_GETFL) };
    if flags < 0 {
        return Err(std::io::Error::last_os_error());
    }
    // SAFETY: as above.
    if unsafe { libc::fcntl(fd, libc::F_SETFL, flags & !libc::O_NONBLOCK) } < 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(())
}

#[cfg(not(unix))]
fn clear_nonblocking(_: &File) -> std::io::Result<()> {
    Ok(())
}

/// Reads the rest of an opened file of `len` bytes (its size when opened), at most
/// `cap.bytes`: a larger file is refused from its size, a file that grows beyond the cap
/// while read is refused after `cap.bytes + 1` bytes.
pub fn read_opened(path: &Path, file: File, len: u64, cap: Cap) -> Result<Vec<u8>> {
    if len > cap.bytes {
        return Err(cap.too_large(path, "size in bytes".into(), len));
    }
    let mut data = Vec::with_capacity(len as usize);
    file.take(cap.bytes + 1)
        .read_to_end(&mut data)
        .map_err(|e| FormatError::io(path, e))?;
    if data.len() as u64 > cap.bytes {
        return Err(cap.too_large(
            path,
            "size in bytes (it grew while read)".into(),
            data.len() as u64,
        ));
    }
    Ok(data)
}

/// Reads a regular file of at most `cap.bytes` (links followed).
pub fn read_bytes(path: &Path, cap: Cap) -> Result<Vec<u8>> {
    let (file, meta) = open_file(path, Links::Follow)?;
    read_opened(path, file, meta.len(), cap)
}

/// [`read_bytes`] as UTF-8 text.
pub fn read_text(path: &Path, cap: Cap) -> Result<String> {
    String::from_utf8(read_bytes(path, cap)?).map_err(|e| {
        FormatError::invalid(
            path,
            format!(
                "is not UTF-8 text (byte {} is not valid UTF-8)",
                e.utf8_error().valid_up_to()
            ),
        )
    })
}

/// A regular file opened to be streamed, at most `cap.bytes` of it ([`open_capped`]).
pub struct Capped {
    file: File,
    read: u64,
    cap: Cap,
}

/// Opens a regular file (links followed) to be streamed: a file larger than `cap.bytes`
/// is refused from its size; one that grows beyond the cap while read fails with an I/O
/// error there, instead of being read in part.
pub fn open_capped(path: &Path, cap: Cap) -> Result<Capped> {
    let (file, meta) = open_file(path, Links::Follow)?;
    if meta.len() > cap.bytes {
        return Err(cap.too_large(path, "size in bytes".into(), meta.len()));
    }
    Ok(Capped { file, read: 0, cap })
}

impl Read for Capped {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        // One byte past the cap tells a file that grew.
        let room = (self.cap.bytes + 1 - self.read).min(buf.len() as u64) as usize;
        let n = self.file.read(&mut buf[..room])?;
        self.read += n as u64;
        if self.read > self.cap.bytes {
            return Err(std::io::Error::other(format!(
                "grew beyond {} bytes while it was read, {}",
                self.cap.bytes,
                self.cap.basis()
            )));
        }
        Ok(n)
    }
}

/// SHA-256 of a regular file's content, read in blocks (never whole).
pub fn sha256(path: &Path) -> Result<[u8; 32]> {
    sha256_checked(path).map(|(d, _, _)| d)
}

/// [`sha256`], with the file's metadata taken on the open descriptor before the first
/// read and after the last: a caller that keeps the digest for the file's (size, times,
/// inode) keeps it only when the two agree (the file did not change while it was read).
pub fn sha256_checked(path: &Path) -> Result<([u8; 32], Metadata, Metadata)> {
    let (mut f, before) = open_file(path, Links::Follow)?;
    let mut h = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = match f.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(FormatError::io(path, e)),
        };
        h.update(&buf[..n]);
    }
    let after = f.metadata().map_err(|e| FormatError::io(path, e))?;
    Ok((h.finalize().into(), before, after))
}

/// Lines of a text file, each at most a cap long (without its end): `\n` or `\r\n`
/// ends a line, as [`str::lines`]; a line longer than the cap is an error naming its
/// number, found after reading at most the cap, whatever the line's length.
pub struct Lines<R> {
    reader: R,
    path: PathBuf,
    cap: Cap,
    /// Lines returned so far.
    line: usize,
    buf: Vec<u8>,
    failed: bool,
}

/// The lines of a regular file (links followed), each at most `cap.bytes` long.
pub fn lines(path: &Path, cap: Cap) -> Result<Lines<BufReader<File>>> {
    let f = open(path)?;
    Ok(Lines::new(BufReader::with_capacity(1 << 16, f), path, cap))
}

impl<R: BufRead> Lines<R> {
    /// The lines of `reader`; `path` names it in errors.
    pub fn new(reader: R, path: &Path, cap: Cap) -> Self {
        Self {
            reader,
            path: path.to_path_buf(),
            cap,
            line: 0,
            buf: Vec::new(),
            failed: false,
        }
    }

    /// The file the lines are read from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The next line's bytes (without its end) and 1-based number, or `None` at the end.
    pub fn next_bytes(&mut self) -> Option<Result<(usize, &[u8])>> {
        if self.failed {
            return None;
        }
        self.buf.clear();
        let mut any = false;
        loop {
            let avail = match self.reader.fill_buf() {
                Ok(a) => a,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) => {
                    self.failed = true;
                    return Some(Err(FormatError::io(&self.path, e)));
                }
            };
            if avail.is_empty() {
                if !any {
                    return None;
                }
                break;
            }
            any = true;
            let end = avail.iter().position(|&b| b == b'\n');
            let take = end.unwrap_or(avail.len());
            if (self.buf.len() + take) as u64 > self.cap.bytes {
                self.failed = true;
                let read = (self.buf.len() + take) as u64;
                return Some(Err(self.cap.too_large(
                    &self.path,
                    format!("line {}, bytes read before its end", self.line + 1),
                    read,
                )));
            }
            self.buf.extend_from_slice(&avail[..take]);
            let used = take + usize::from(end.is_some());
            self.reader.consume(used);
            if end.is_some() {
                break;
            }
        }
        self.line += 1;
        if self.buf.last() == Some(&b'\r') {
            self.buf.pop();
        }
        Some(Ok((self.line, &self.buf)))
    }
}

impl<R: BufRead> Iterator for Lines<R> {
    /// A line as text and its 1-based number.
    type Item = Result<(usize, String)>;

    fn next(&mut self) -> Option<Self::Item> {
        let path = self.path.clone();
        Some(self.next_bytes()?.and_then(|(n, b)| {
            String::from_utf8(b.to_vec())
                .map(|s| (n, s))
                .map_err(|_| FormatError::at(&path, n, None, "is not UTF-8 text"))
        }))
    }
}

/// A regular file below a folder input ([`files_below`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Found {
    /// The path as reached from the input (through links, not resolved).
    pub path: PathBuf,
    /// (device, inode): one file reached by two paths is one file.
    pub id: (u64, u64),
    pub len: u64,
}

/// Every regular file of an input, sorted by path: the file itself, or every file below a
/// folder. Links are followed; a link cycle, a folder reached twice, anything that is
/// neither a regular file nor a folder, and more than [`Limits::folder_depth`] levels or
/// [`Limits::folder_entries`] entries are refused, naming the entry. Nothing is opened.
pub fn files_below(path: &Path) -> Result<Vec<Found>> {
    let m = std::fs::metadata(path).map_err(|e| stat_error(path, e))?;
    if m.is_file() {
        return Ok(vec![Found {
            path: path.to_path_buf(),
            id: file_id(&m),
            len: m.len(),
        }]);
    }
    if !m.is_dir() {
        return Err(not_regular(
            path,
            format!(
                "{}, neither a regular file nor a folder",
                describe(path, &m)
            ),
        ));
    }
    let l = limits();
    let mut walk = Walk {
        limits: l,
        entries: 0,
        ancestors: vec![(file_id(&m), path.to_path_buf())],
        visited: std::collections::HashMap::from([(file_id(&m), path.to_path_buf())]),
        out: Vec::new(),
    };
    walk.folder(path)?;
    let mut out = walk.out;
    out.sort_by(|a, b| a.path.cmp(&b.path));
    Ok(out)
}

struct Walk {
    limits: Limits,
    entries: u64,
    /// The folders from the input down to the one being read.
    ancestors: Vec<((u64, u64), PathBuf)>,
    /// Every folder entered, with the path it was entered by.
    visited: std::collections::HashMap<(u64, u64), PathBuf>,
    out: Vec<Found>,
}

impl Walk {
    fn folder(&mut self, dir: &Path) -> Result<()> {
        let mut names = Vec::new();
        for e in std::fs::read_dir(dir).map_err(|e| FormatError::io(dir, e))? {
            let e = e.map_err(|e| FormatError::io(dir, e))?;
            self.entries += 1;
            if self.entries > self.limits.folder_entries {
                let top = &self.ancestors[0].1;
                return Err(FormatError::TooLarge {
                    path: top.clone(),
                    what: "files and folders below it".into(),
                    claimed: self.entries,
                    limit: self.limits.folder_entries,
                    basis: format!(
                        "the most entries a folder input may hold (raise `folder_entries` in {LIMITS_ENV})"
                    ),
                });
            }
            names.push(e.path());
        }
        names.sort();
        for path in names {
            let m = std::fs::metadata(&path).map_err(|e| stat_error(&path, e))?;
            if m.is_file() {
                self.out.push(Found {
                    path,
                    id: file_id(&m),
                    len: m.len(),
                });
            } else if m.is_dir() {
                let id = file_id(&m);
                if let Some((_, above)) = self.ancestors.iter().find(|(a, _)| *a == id) {
                    return Err(not_regular(
                        &path,
                        format!(
                            "links back to {}, a folder that holds it: a symbolic link cycle",
                            above.display()
                        ),
                    ));
                }
                if let Some(first) = self.visited.get(&id) {
                    return Err(not_regular(
                        &path,
                        format!(
                            "is the folder {} again (reached twice through symbolic links)",
                            first.display()
                        ),
                    ));
                }
                let depth = self.ancestors.len() as u64;
                if depth > self.limits.folder_depth {
                    return Err(FormatError::TooLarge {
                        path,
                        what: "folder depth below the input".into(),
                        claimed: depth,
                        limit: self.limits.folder_depth,
                        basis: format!(
                            "the deepest folder input walked (raise `folder_depth` in {LIMITS_ENV})"
                        ),
                    });
                }
                self.visited.insert(id, path.clone());
                self.ancestors.push((id, path.clone()));
                self.folder(&path)?;
                self.ancestors.pop();
            } else {
                return Err(not_regular(
                    &path,
                    format!(
                        "{}, neither a regular file nor a folder",
                        describe(&path, &m)
                    ),
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_and_limits_parse() {
        assert_eq!(parse_size("12"), Some(12));
        assert_eq!(parse_size("4K"), Some(4096));
        assert_eq!(parse_size("2g"), Some(2 << 30));
        assert_eq!(parse_size("0"), None);
        assert_eq!(parse_size("x"), None);
        let l = Limits::default().parse("csv=1G, csv_line=4M").unwrap();
        assert_eq!(l.csv_bytes, 1 << 30);
        assert_eq!(l.csv_line_bytes, 4 << 20);
        assert_eq!(l.project_bytes, Limits::default().project_bytes);
        assert!(Limits::default().parse("nope=1").is_err());
        assert!(Limits::default().parse("csv").is_err());
        let mut d = Limits::default();
        for n in Limits::NAMES {
            assert!(d.field(n).is_some(), "{n}");
        }
    }

    #[test]
    fn lines_are_capped() {
        let text = b"ab\r\ncd\n\nlong line\n";
        let mut l = Lines::new(&text[..], Path::new("t"), Cap::fixed(4, "line"));
        assert_eq!(l.next_bytes().unwrap().unwrap(), (1, &b"ab"[..]));
        assert_eq!(l.next_bytes().unwrap().unwrap(), (2, &b"cd"[..]));
        assert_eq!(l.next_bytes().unwrap().unwrap(), (3, &b""[..]));
        let e = l.next_bytes().unwrap().unwrap_err().to_string();
        assert!(e.contains("line 4"), "{e}");
        assert!(l.next_bytes().is_none());
        let mut l = Lines::new(&b"x"[..], Path::new("t"), Cap::fixed(4, "line"));
        assert_eq!(l.next_bytes().unwrap().unwrap(), (1, &b"x"[..]));
        assert!(l.next_bytes().is_none());
    }
}
