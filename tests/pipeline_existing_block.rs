//! An existing oriented block as the reference epoch (issue 20): the reference stage's own
//! BlocksExchange export read back as a production block, the archive epochs oriented from
//! its DCPs to the same accuracy as from the block the workflow oriented itself; the check
//! against the LiDAR finds a block moved by a known offset and, on request, takes it out;
//! the same block as a COLMAP model with its side file gives the same poses; project keys
//! that do not fit an existing block are refused, naming the key.

use cloudcontrol::block::Block;
use cloudcontrol::formats::{blocks_exchange, colmap, convert};
use cloudcontrol::pipeline::project::Project;
use cloudcontrol::pipeline::run::{run_project, RunError};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

mod common;
use common::{block_copy, epoch, exe, finished, px, without_surfaces};

/// The synthetic block's project with its reference replaced by `block` (a table body),
/// writing into `output`.
fn project_with_block(blk: &Path, block: &str, output: &str) -> PathBuf {
    let text = std::fs::read_to_string(blk.join("project.toml")).unwrap();
    let mut out = String::new();
    let mut in_reference = false;
    for line in text.lines() {
        if line.starts_with('[') {
            in_reference = line == "[reference]";
        }
        if line.starts_with("output =") {
            out.push_str(&format!("output = \"{output}\"\n"));
            continue;
        }
        // The block holds the reference's camera and orientations.
        if in_reference && (line.starts_with("camera =") || line.starts_with("pos =")) {
            continue;
        }
        out.push_str(line);
        out.push('\n');
        if line == "[reference]" {
            out.push_str(block);
            out.push('\n');
        }
    }
    let path = blk.join(format!("{output}.toml"));
    std::fs::write(&path, out).unwrap();
    path
}

fn report_of(run: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(run.join("report/report.json")).unwrap()).unwrap()
}

/// World projection centres by photo stem.
fn centres(block: &Block) -> std::collections::BTreeMap<String, [f64; 3]> {
    block
        .photos
        .values()
        .map(|p| {
            let key = cloudcontrol::formats::pos::photo_key(&p.name).to_string();
            (key, block.to_world(&p.pose.center).into())
        })
        .collect()
}

fn largest_difference(a: &Block, b: &Block) -> f64 {
    let (ca, cb) = (centres(a), centres(b));
    assert_eq!(ca.len(), cb.len());
    ca.iter()
        .map(|(k, p)| {
            let q = cb[k];
            ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
        })
        .fold(0.0, f64::max)
}

fn oriented_block(run: &Path, epoch: &str) -> Block {
    cloudcontrol::pipeline::epoch_files::load_block(&run.join(format!("epoch-{epoch}"))).unwrap()
}

#[test]
fn an_existing_block_controls_the_archive_epochs_as_our_own_reference_does() {
    let tmp = tempfile::tempdir().unwrap();
    let blk = tmp.path().join("block");
    block_copy("small", 1, "rough", &blk);
    without_surfaces(&blk.join("project.toml"));
    // Today's workflow: the reference oriented against the LiDAR.
    let o = Command::new(exe())
        .arg("run")
        .arg(blk.join("project.toml"))
        .output()
        .unwrap();
    assert!(finished(&o), "{}", String::from_utf8_lossy(&o.stderr));
    let run = tmp.path().join("run");
    let ours = report_of(&run);
    let xml = run.join("outputs-reference_2024/blocks_exchange.xml");
    let from_xml = blocks_exchange::read(&xml).unwrap();

    // The same block read back as an existing one, checked against the LiDAR.
    let project = project_with_block(
        &blk,
        &format!("block = {{ path = \"{}\" }}", xml.display()),
        "run_bx",
    );
    let o = Command::new(exe())
        .args(["run", "--json"])
        .arg(&project)
        .output()
        .unwrap();
    assert!(finished(&o), "{}", String::from_utf8_lossy(&o.stderr));
    let run_bx = blk.join("run_bx");
    let theirs = report_of(&run_bx);
    let existing: Value = serde_json::from_slice(
        &std::fs::read(run_bx.join("epoch-reference_2024/existing.json")).unwrap(),
    )
    .unwrap();
    eprintln!("existing block: {existing:#}");
    assert_eq!(existing["photos_with_image"], existing["photos_in_block"]);
    assert_eq!(existing["images_not_in_block"].as_array().unwrap().len(), 0);
    assert!(existing["tie_points"].as_u64().unwrap() > 100);
    // The block is the LiDAR-oriented one: the check finds it where the LiDAR is, within
    // the reference orientation's accuracy target (1 GSD on each axis). Seed 1's block
    // lies 0.06 m (0.6 GSD) east of the LiDAR by this check: its reference orientation
    // scores 0.66 GSD in height at the checkpoints, within the same target.
    let gsd = epoch(&ours, "reference_2024")["gsd_m"].as_f64().unwrap();
    let off = &existing["lidar"]["mean_offset_m"];
    let own: Vec<f64> = (0..3).map(|i| off[i].as_f64().unwrap()).collect();
    assert!(
        own.iter().all(|v| v.abs() <= gsd),
        "offset of our own block from the LiDAR {own:?}, GSD {gsd}"
    );
    assert_eq!(existing["lidar"]["applied"], false);
    // Its poses are those of the XML, every photo oriented.
    assert!(largest_difference(&oriented_block(&run_bx, "reference_2024"), &from_xml) < 1e-6);

    for name in ["reference_2024", "digital_2012", "film_1978"] {
        let (a, b) = (epoch(&ours, name), epoch(&theirs, name));
        let row = |e: &Value| {
            (
                e["photos_oriented"].as_u64().unwrap(),
                px(e, "check_rmse_plan_m"),
                px(e, "check_rmse_height_m"),
            )
        };
        let ((na, pa, ha), (nb, pb, hb)) = (row(a), row(b));
        eprintln!(
            "{name}: ours {na} oriented, plan {pa:.3}, height {ha:.3} GSD; \
             from the existing block {nb} oriented, plan {pb:.3}, height {hb:.3} GSD"
        );
        assert_eq!(b["photos_total"], a["photos_total"], "{name}");
        assert!(
            nb >= na,
            "{name}: {nb} oriented from the existing block, {na} ours"
        );
        // The same accuracy: within a tenth of a ground pixel of today's workflow.
        assert!(pb <= pa + 0.1 && hb <= ha + 0.1, "{name}");
    }

    // The same block 1.5 m east, 2 m south and 0.8 m up (a datum slip): the check finds
    // the slip (to 5 cm, on top of the block's own offset above) and, asked to, takes the
    // whole offset out, which puts the block where the unmoved one's check put it.
    let mut moved = from_xml.clone();
    let shift = [1.5, -2.0, 0.8];
    for (o, s) in moved.origin.iter_mut().zip(shift) {
        *o += s;
    }
    let moved_xml = blk.join("moved.xml");
    blocks_exchange::write(&moved_xml, &moved, &Default::default()).unwrap();
    let project = project_with_block(
        &blk,
        &format!(
            "block = {{ path = \"{}\", apply_lidar_offset = true }}",
            moved_xml.display()
        ),
        "run_moved",
    );
    let p = Project::load(&project).unwrap();
    match run_project(&p, &mut |_| {}, Some("epoch-reference_2024")) {
        Err(RunError::Stopped(_)) => {}
        other => panic!("{other:?}"),
    }
    let run_moved = blk.join("run_moved");
    let existing: Value = serde_json::from_slice(
        &std::fs::read(run_moved.join("epoch-reference_2024/existing.json")).unwrap(),
    )
    .unwrap();
    let off = &existing["lidar"]["mean_offset_m"];
    eprintln!("moved block: offset found {off}, shift {shift:?}");
    for (i, s) in shift.iter().enumerate() {
        let v = off[i].as_f64().unwrap();
        assert!(
            (v - own[i] + s).abs() < 0.05,
            "axis {i}: offset {v}, shift {s}, own offset {}",
            own[i]
        );
    }
    assert_eq!(existing["lidar"]["applied"], true);
    assert_eq!(existing["lidar"]["icp"]["converged"], true);
    assert_eq!(existing["lidar"]["icp"]["degenerate_directions"], 0);
    let back = largest_difference(&oriented_block(&run_moved, "reference_2024"), &from_xml);
    let own_norm = own.iter().map(|v| v * v).sum::<f64>().sqrt();
    assert!(
        back < own_norm + 0.05,
        "moved block brought back to {back} m of the XML's (own offset {own_norm} m)"
    );

    // The block as a COLMAP model (its side file holds the CRS and origin) gives the same
    // poses as the XML.
    let model = blk.join("colmap_model");
    convert::write_block(
        &model,
        &from_xml,
        Some(convert::BlockFormat::Colmap),
        &Default::default(),
    )
    .unwrap();
    let project = project_with_block(
        &blk,
        &format!(
            "block = {{ path = \"{}\", format = \"colmap\", lidar_check = false }}",
            model.display()
        ),
        "run_colmap",
    );
    let p = Project::load(&project).unwrap();
    assert!(matches!(
        run_project(&p, &mut |_| {}, Some("epoch-reference_2024")),
        Err(RunError::Stopped(_))
    ));
    let from_colmap = oriented_block(&blk.join("run_colmap"), "reference_2024");
    assert!(largest_difference(&from_colmap, &from_xml) < 1e-6);
    assert!(colmap::read(&model).is_ok());
}

/// Keys that do not fit an existing block are refused before any work, naming the key.
#[test]
fn project_keys_of_an_existing_block_are_checked() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    std::fs::create_dir_all(d.join("lidar")).unwrap();
    std::fs::create_dir_all(d.join("photos")).unwrap();
    std::fs::write(d.join("block.xml"), "<BlocksExchange/>").unwrap();
    std::fs::write(d.join("cam.json"), "{}").unwrap();
    std::fs::write(d.join("pos.csv"), "").unwrap();
    let load = |reference: &str, archive: &str| {
        let text = format!(
            "name = \"t\"\ncrs = \"EPSG:32611\"\noutput = \"run\"\n[control]\nlidar = [\"lidar\"]\n\
             [reference]\nname = \"r\"\ndate = \"2020\"\nphotos = \"photos\"\n{reference}\n{archive}"
        );
        let p = d.join("p.toml");
        std::fs::write(&p, text).unwrap();
        Project::load(&p).map(|_| ()).map_err(|e| e.to_string())
    };
    let archive = "[[archive]]\nname = \"a\"\ndate = \"1990\"\nphotos = \"photos\"\ncamera = \"cam.json\"\npos = \"pos.csv\"";
    assert!(load("block = { path = \"block.xml\" }", archive).is_ok());
    let e = load(
        "block = { path = \"block.xml\" }\ncamera = \"cam.json\"",
        archive,
    )
    .unwrap_err();
    assert!(
        e.contains("reference.camera") && e.contains("given with block"),
        "{e}"
    );
    let e = load(
        "block = { path = \"block.xml\", format = \"ply\" }",
        archive,
    )
    .unwrap_err();
    assert!(
        e.contains("reference.block.format") && e.contains("ply"),
        "{e}"
    );
    let e = load("block = { path = \"nowhere.xml\" }", archive).unwrap_err();
    assert!(
        e.contains("reference.block.path") && e.contains("nowhere.xml"),
        "{e}"
    );
    let e = load(
        "block = { path = \"block.xml\", lidar_check = false, apply_lidar_offset = true }",
        archive,
    )
    .unwrap_err();
    assert!(e.contains("apply_lidar_offset"), "{e}");
    let e = load(
        "block = { path = \"block.xml\" }",
        &format!("{archive}\nblock = {{ path = \"block.xml\" }}"),
    )
    .unwrap_err();
    assert!(
        e.contains("archive[0].block") && e.contains("only the reference"),
        "{e}"
    );
    // Without a block the camera is still required.
    let e = load("pos = \"pos.csv\"", archive).unwrap_err();
    assert!(
        e.contains("reference.camera") && e.contains("missing"),
        "{e}"
    );
}
