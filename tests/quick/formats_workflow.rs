//! The samples of formats/workflow/ (written by hand from its README) are read by the
//! library's own types: the document and the code say the same thing.

use cloudcontrol::block::{Block, PhotoFailure, PhotoId, PhotoStatus};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

fn sample(name: &str) -> Vec<u8> {
    std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("formats/workflow")
            .join(name),
    )
    .unwrap()
}

#[test]
fn workflow_samples_are_read_by_the_library() {
    let block: Block = serde_json::from_slice(&sample("block.json")).unwrap();
    block.validate().unwrap();
    assert_eq!(block.photos.len(), 2);
    let oriented: Vec<_> = block.photos.values().filter(|p| p.is_oriented()).collect();
    assert_eq!(oriented.len(), 1);
    // Rotations are written as rows: a world→camera rotation stays orthonormal, det +1.
    for p in block.photos.values() {
        let r = p.pose.rotation;
        assert!((r * r.transpose() - nalgebra::Matrix3::identity()).norm() < 1e-6);
        assert!((r.determinant() - 1.0).abs() < 1e-6);
    }
    let images: BTreeMap<PhotoId, PathBuf> =
        serde_json::from_slice(&sample("images.json")).unwrap();
    assert_eq!(
        images.keys().collect::<Vec<_>>(),
        block.photos.keys().collect::<Vec<_>>()
    );
    // result.json: the failed photo's reason is the block's status.
    let result: serde_json::Value = serde_json::from_slice(&sample("result.json")).unwrap();
    let failed = block
        .photos
        .values()
        .find_map(|p| match &p.status {
            PhotoStatus::Failed(f) => Some((p.name.clone(), f.clone())),
            _ => None,
        })
        .unwrap();
    let row = result["photos"]
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["name"] == failed.0)
        .unwrap();
    let reason: PhotoFailure = serde_json::from_value(row["reason"].clone()).unwrap();
    assert_eq!(reason, failed.1);
    let _: Option<cloudcontrol::adjust::AdjustReport> =
        serde_json::from_value(result["adjustment"].clone()).unwrap();
    let epoch: cloudcontrol::pipeline::report::EpochReport =
        serde_json::from_slice(&sample("epoch.json")).unwrap();
    assert_eq!(epoch.photos_total, 2);
    // Its tie statistics are those of the sample block (the only oriented photo sees the
    // six control points and overlaps no other oriented photo).
    let (ties, photos) = cloudcontrol::pipeline::tie_statistics::tie_statistics(&block);
    assert_eq!(epoch.ties, ties);
    for p in &epoch.photos {
        assert_eq!(p.ties, photos[&p.name], "{}", p.name);
    }
}

/// A task of a distributed run (formats/workflow/README.md, "Per-photo tasks"): the sample
/// is read by the library, names its result file as the README says, and a task naming a
/// folder without a plan is refused through the C ABI with the folder in the message.
#[test]
fn task_sample_is_read_and_a_task_without_its_plan_is_an_io_error() {
    use cloudcontrol::pipeline::tasks::{Task, TaskKind};
    let task: Task = serde_json::from_slice(&sample("task.json")).unwrap();
    assert_eq!(task.kind, TaskKind::Orient);
    assert_eq!(task.name(), "epoch-film_1978/orient/film_s02_001");
    assert_eq!(
        task.result(),
        Path::new("/data/run/tasks/epoch-film_1978/41530d51a57a95aa/orient-00003.msgpack")
    );
    let json = std::ffi::CString::new(String::from_utf8(sample("task.json")).unwrap()).unwrap();
    let mut out: *mut std::ffi::c_char = std::ptr::null_mut();
    // SAFETY: a NUL-terminated string and a valid out pointer.
    let status = unsafe { cloudcontrol::ffi::ccp_task_run(json.as_ptr(), &mut out) };
    assert_eq!(status, cloudcontrol::ffi::CcpStatus::Io);
    assert!(out.is_null());
    let msg = crate::common::last_error();
    assert!(
        msg.contains("epoch-film_1978/orient/film_s02_001") && msg.contains("plan.json"),
        "{msg}"
    );
    // Not a task at all: an invalid argument, not a crash.
    let bad = std::ffi::CString::new("{\"kind\": \"paint\"}").unwrap();
    let status = unsafe { cloudcontrol::ffi::ccp_task_run(bad.as_ptr(), &mut out) };
    assert_eq!(status, cloudcontrol::ffi::CcpStatus::InvalidArgument);
    // A LiDAR tile's task, with the item under the name the first task format gave it.
    let tile: Task = serde_json::from_str(
        r#"{"kind": "screen", "stage": "sources", "folder": "/data/run/tasks/sources/0123456789abcdef",
            "index": 12, "photo": "tile_0012.laz"}"#,
    )
    .unwrap();
    assert_eq!(tile.kind, TaskKind::Screen);
    assert_eq!(tile.name(), "sources/screen/tile_0012.laz");
    assert!(tile
        .result()
        .ends_with("sources/0123456789abcdef/screen-00012.msgpack"));
    // A task of an epoch's round: the round in its name (a Dask key) and result file.
    let round: Task = serde_json::from_str(
        r#"{"kind": "match", "stage": "epoch-film_1978", "folder": "/data/run/tasks/epoch-film_1978/41530d51a57a95aa",
            "index": 3, "item": "film_s02_001", "round": 2}"#,
    )
    .unwrap();
    assert_eq!((round.kind, round.round), (TaskKind::Match, Some(2)));
    assert_eq!(round.name(), "epoch-film_1978/match-2/film_s02_001");
    assert!(round
        .result()
        .ends_with("41530d51a57a95aa/match-002-00003.msgpack"));
}
