//! Reading the members of a DCP package (its manifest and chips), which travel between
//! organisations: a member is read only when it is a regular file inside the package
//! folder — no symbolic link at any level (a link may point out of the package, to
//! `/dev/zero`, to a FIFO), no device, FIFO, socket or folder — and no larger than its
//! limit. The type is checked on the path's metadata before anything is opened (opening a
//! FIFO for reading would wait for a writer), then again on the open file, which is opened
//! without following links and without blocking, so a member swapped between the check
//! and the open is refused too.

use std::fs::{File, Metadata};
use std::io::Read;
use std::path::{Component, Path};

/// Largest chip file read (a 193 × 193 16-bit PNG chip is ~75 KB; 64 MiB holds a
/// 4096 × 4096 16-bit chip uncompressed).
pub const MAX_CHIP_BYTES: u64 = 64 << 20;

/// Largest manifest read (~1 M measurements).
pub const MAX_MANIFEST_BYTES: u64 = 256 << 20;

/// Why a member could not be read.
#[derive(Debug)]
pub enum MemberError {
    /// The member does not exist.
    Missing,
    /// The member is not a regular file inside the package, or too large.
    Refused(String),
    Io(std::io::Error),
}

impl std::fmt::Display for MemberError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            MemberError::Missing => write!(f, "does not exist"),
            MemberError::Refused(m) => write!(f, "{m}"),
            MemberError::Io(e) => write!(f, "cannot be read ({e})"),
        }
    }
}

fn kind(m: &Metadata) -> &'static str {
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

/// Reads `package/relative` (relative: normal components only, checked by the caller)
/// when it is a regular file of at most `limit` bytes inside the package.
pub fn read_member(package: &Path, relative: &str, limit: u64) -> Result<Vec<u8>, MemberError> {
    let refuse = |m: String| MemberError::Refused(m);
    let parts: Vec<_> = Path::new(relative).components().collect();
    let mut path = package.to_path_buf();
    let mut meta = None;
    for (i, c) in parts.iter().enumerate() {
        let Component::Normal(name) = c else {
            return Err(refuse("leaves the package".into()));
        };
        path.push(name);
        let m = match std::fs::symlink_metadata(&path) {
            Ok(m) => m,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Err(MemberError::Missing),
            Err(e) => return Err(MemberError::Io(e)),
        };
        let last = i + 1 == parts.len();
        let within = Path::new(relative)
            .components()
            .take(i + 1)
            .collect::<std::path::PathBuf>();
        if m.file_type().is_symlink() {
            let target = std::fs::read_link(&path)
                .map(|t| format!(" (to {})", t.display()))
                .unwrap_or_default();
            return Err(refuse(if last {
                format!("is a symbolic link{target}; package members must be regular files inside the package")
            } else {
                format!(
                    "lies in {}, a symbolic link{target}; package members must be regular files inside the package",
                    within.display()
                )
            }));
        }
        if !last && !m.is_dir() {
            return Err(refuse(format!(
                "lies in {}, which is {}, not a folder",
                within.display(),
                kind(&m)
            )));
        }
        if last {
            meta = Some(m);
        }
    }
    let Some(meta) = meta else {
        return Err(refuse("is an empty path".into()));
    };
    if !meta.is_file() {
        return Err(refuse(format!(
            "is {}; package members must be regular files",
            kind(&meta)
        )));
    }
    if meta.len() > limit {
        return Err(refuse(format!(
            "is {} bytes, more than {limit}, the largest such member read",
            meta.len()
        )));
    }
    let file = open_no_follow(&path).map_err(|e| match e.kind() {
        std::io::ErrorKind::NotFound => MemberError::Missing,
        _ => MemberError::Io(e),
    })?;
    let opened = file.metadata().map_err(MemberError::Io)?;
    if !opened.is_file() || !same_file(&meta, &opened) {
        return Err(refuse(format!(
            "changed while it was opened (now {})",
            kind(&opened)
        )));
    }
    let mut data = Vec::with_capacity(opened.len().min(limit) as usize);
    file.take(limit + 1)
        .read_to_end(&mut data)
        .map_err(MemberError::Io)?;
    if data.len() as u64 > limit {
        return Err(refuse(format!(
            "grew beyond {limit} bytes, the largest such member read"
        )));
    }
    Ok(data)
}

#[cfg(unix)]
fn open_no_follow(path: &Path) -> std::io::Result<File> {
    use std::os::unix::fs::OpenOptionsExt;
    // O_NONBLOCK: a FIFO swapped in after the type check does not block the open; reads of
    // a regular file are not affected by it.
    std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK)
        .open(path)
}

#[cfg(not(unix))]
fn open_no_follow(path: &Path) -> std::io::Result<File> {
    File::open(path)
}

#[cfg(unix)]
fn same_file(a: &Metadata, b: &Metadata) -> bool {
    use std::os::unix::fs::MetadataExt;
    a.dev() == b.dev() && a.ino() == b.ino()
}

#[cfg(not(unix))]
fn same_file(_: &Metadata, _: &Metadata) -> bool {
    true
}
