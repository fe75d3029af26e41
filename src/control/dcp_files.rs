//! Reading the members of a DCP package (its manifest and chips), which travel between
//! organisations: a member is read only when it is a regular file inside the package
//! folder — no symbolic link at any level (a link may point out of the package, to
//! `/dev/zero`, to a FIFO), no device, FIFO, socket or folder — and no larger than its
//! limit. The folders on the way are checked here; the member itself is opened by the one
//! opener of inputs ([`crate::formats::input`]) without following links: its type is
//! checked on the path before it is opened, then again on the open file, which is opened
//! without blocking, so a member swapped between the check and the open is refused too.

use crate::formats::input::{self, Cap, Links};
use crate::formats::FormatError;
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
                input::kind(&m)
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
            input::kind(&meta)
        )));
    }
    if meta.len() > limit {
        return Err(refuse(format!(
            "is {} bytes, more than {limit}, the largest such member read",
            meta.len()
        )));
    }
    let (file, opened) = input::open_file(&path, Links::Refuse).map_err(|e| match e {
        FormatError::Io { source, .. } if source.kind() == std::io::ErrorKind::NotFound => {
            MemberError::Missing
        }
        FormatError::Io { source, .. } => MemberError::Io(source),
        e => refuse(e.detail()),
    })?;
    if !input::same_file(&meta, &opened) {
        return Err(refuse(format!(
            "changed while it was opened (now {})",
            input::kind(&opened)
        )));
    }
    input::read_opened(&path, file, opened.len(), Cap::fixed(limit, "such member")).map_err(|e| {
        match e {
            FormatError::Io { source, .. } => MemberError::Io(source),
            FormatError::TooLarge { claimed, .. } => refuse(format!(
                "is {claimed} bytes, more than {limit}, the largest such member read"
            )),
            e => refuse(e.detail()),
        }
    })
}
