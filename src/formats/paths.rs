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

/// `path` as a file in `folder` names it: relative to that folder, so that a project
/// moved or copied whole (inputs and run folder together) still finds what its products
/// name. Taken between the two paths as the file system resolves them (links followed),
/// since a reader opens `folder/../x` from the folder's real place; lexically between
/// the absolute paths where either does not exist yet. Absolute when the two share no
/// root (another drive).
pub fn relative_to(path: &Path, folder: &Path) -> PathBuf {
    let real = |p: &Path| {
        std::fs::canonicalize(p)
            .or_else(|_| std::path::absolute(p).map(|a| normalise(&a)))
            .unwrap_or_else(|_| p.to_path_buf())
    };
    let (to, from) = (real(path), real(folder));
    let (tc, fc): (Vec<Component>, Vec<Component>) =
        (to.components().collect(), from.components().collect());
    let common = tc.iter().zip(&fc).take_while(|(a, b)| a == b).count();
    let rooted = |c: &Component| matches!(c, Component::Prefix(_) | Component::RootDir);
    if common == 0 || !tc[..common].iter().any(rooted) {
        return to;
    }
    let mut out = PathBuf::new();
    for _ in common..fc.len() {
        out.push("..");
    }
    for c in &tc[common..] {
        out.push(c.as_os_str());
    }
    if out.as_os_str().is_empty() {
        out.push(".");
    }
    out
}

/// A path read from a file in `folder` ([`relative_to`]'s counterpart): a relative one is
/// taken from that folder, an absolute one as it is.
pub fn resolve_from(folder: &Path, path: &Path) -> PathBuf {
    if path.is_relative() {
        folder.join(path)
    } else {
        path.to_path_buf()
    }
}
