//! Paths a product writes for its inputs (formats/workflow, `images.json`): relative to
//! the file's folder, resolved from there again, through links as the file system
//! resolves them.

use cloudcontrol::formats::paths::{relative_to, resolve_from};
use std::path::Path;

#[test]
fn an_input_is_named_relative_to_the_folder_and_found_from_there() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().canonicalize().unwrap();
    let photo = root.join("epochs/d/images/p1.png");
    let stage = root.join("run/epoch-d");
    std::fs::create_dir_all(photo.parent().unwrap()).unwrap();
    std::fs::create_dir_all(&stage).unwrap();
    std::fs::write(&photo, b"x").unwrap();
    let rel = relative_to(&photo, &stage);
    assert_eq!(rel, Path::new("../../epochs/d/images/p1.png"));
    assert_eq!(
        resolve_from(&stage, &rel).canonicalize().unwrap(),
        photo.canonicalize().unwrap()
    );
    // Below the folder, and the folder itself.
    assert_eq!(relative_to(&stage.join("a/b"), &stage), Path::new("a/b"));
    assert_eq!(relative_to(&stage, &stage), Path::new("."));
    // An absolute path read back is taken as it is.
    assert_eq!(resolve_from(&stage, &photo), photo);
    // Not there yet: lexically, `..` taken against the component before it.
    let later = root.join("run/x/../outputs/o.tif");
    assert_eq!(relative_to(&later, &stage), Path::new("../outputs/o.tif"));
}

#[cfg(unix)]
#[test]
fn a_folder_reached_through_a_link_names_the_input_from_its_real_place() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().canonicalize().unwrap();
    // The run folder lives on another disk and is linked into the project.
    let real_run = root.join("disk2/run");
    let project = root.join("project");
    std::fs::create_dir_all(&real_run).unwrap();
    std::fs::create_dir_all(project.join("images")).unwrap();
    std::fs::write(project.join("images/p.png"), b"x").unwrap();
    std::os::unix::fs::symlink(&real_run, project.join("run")).unwrap();
    let stage = project.join("run");
    let rel = relative_to(&project.join("images/p.png"), &stage);
    // Opened from the link, `..` leaves the link's target, not the project.
    assert!(resolve_from(&stage, &rel).is_file(), "{}", rel.display());
    assert_eq!(rel, Path::new("../../project/images/p.png"));
}
