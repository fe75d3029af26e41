//! Paths as the user reads them: the folder a file's relative references are taken from,
//! and a path's lexical normal form for printing.

use std::path::{Component, Path, PathBuf};

/// The folder of `file`, for taking paths relative to it: `.` for a bare file name
/// (`rc10.json`), whose [`Path::parent`] is the empty path that names no folder (opening
/// or canonicalising it fails), and for a root or empty path.
pub fn folder_of(file: &Path) -> &Path {
    match file.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    }
}

/// `path` with `.` components dropped and each `..` taken against the component before
/// it, without asking the file system: `/data/block/../run/x` reads `/data/run/x`. For
/// printing only: where a component before a `..` is a symbolic link, the file system
/// resolves the `..` from the link's target, so a path to open is left as it is. A `..`
/// with nothing before it to remove is kept (`../a` stays, `/..` is `/`); the empty path
/// and `.` give `.`.
pub fn normalise(path: &Path) -> PathBuf {
    let mut out: Vec<Component> = Vec::new();
    for c in path.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => match out.last() {
                Some(Component::Normal(_)) => {
                    out.pop();
                }
                Some(Component::RootDir | Component::Prefix(_)) => {}
                _ => out.push(c),
            },
            c => out.push(c),
        }
    }
    if out.is_empty() {
        return PathBuf::from(".");
    }
    out.iter().collect()
}
