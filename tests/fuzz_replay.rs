//! Replays every committed seed (fuzz/corpus/) and fixed crash reproducer
//! (fuzz/artifacts-fixed/) through its fuzz target's body on the stable toolchain, so the
//! fuzz glue keeps building and no input that once crashed a reader crashes it again,
//! without nightly or cargo-fuzz. The bodies are the fuzz crate's own source, compiled
//! here with the root crate's build (a build of the fuzz crate itself takes minutes).

#[allow(dead_code)] // helpers the corpus tools use
#[path = "../fuzz/src/lib.rs"]
mod cloudcontrol_fuzz;

use std::path::{Path, PathBuf};

fn inputs(sub: &str, target: &str) -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fuzz")
        .join(sub)
        .join(target);
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|d| d.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    files.sort();
    files
}

#[test]
fn every_input_replays_and_the_seeds_reach_the_readers() {
    for target in cloudcontrol_fuzz::TARGETS {
        let seeds = inputs("corpus", target);
        assert!(!seeds.is_empty(), "fuzz/corpus/{target} holds no seed");
        let mut read = Vec::new();
        for f in seeds.iter().chain(&inputs("artifacts-fixed", target)) {
            let data = std::fs::read(f).unwrap();
            // The entry libFuzzer runs, then the same body telling whether it read.
            let run: fn(&[u8]) = match *target {
                "colmap_bin" => cloudcontrol_fuzz::colmap_bin,
                "colmap_txt" => cloudcontrol_fuzz::colmap_txt,
                "blocks_exchange" => cloudcontrol_fuzz::blocks_exchange,
                "dcp_manifest" => cloudcontrol_fuzz::dcp_manifest,
                "dcp_package" => cloudcontrol_fuzz::dcp_package,
                "las" => cloudcontrol_fuzz::las,
                "ply_points" => cloudcontrol_fuzz::ply_points,
                "csv_points" => cloudcontrol_fuzz::csv_points,
                "odm_gcp" => cloudcontrol_fuzz::odm_gcp,
                "project_toml" => cloudcontrol_fuzz::project_toml,
                "camera_json" => cloudcontrol_fuzz::camera_json,
                "image_header" => cloudcontrol_fuzz::image_header,
                "fiducial_io" => cloudcontrol_fuzz::fiducial_io,
                "image_decode" => cloudcontrol_fuzz::image_decode,
                "task_files" => cloudcontrol_fuzz::task_files,
                "project_check" => cloudcontrol_fuzz::project_check,
                t => panic!("target {t} has no entry here"),
            };
            run(&data);
            if cloudcontrol_fuzz::reads(target, &data).unwrap() {
                read.push(f.file_name().unwrap().to_string_lossy().into_owned());
            }
        }
        eprintln!(
            "{target}: {} of {} seeds read: {read:?}",
            read.len(),
            seeds.len()
        );
        // A seed the reader refuses at once teaches the fuzzer nothing about the format.
        assert!(
            !read.is_empty(),
            "no seed of {target} is read by its reader"
        );
    }
}

/// `project_check` stands for `cloudcontrol run --check`: every seed and fixed reproducer,
/// laid out in a folder as the target lays it out, must be accepted by the CLI's check
/// exactly when the target accepts it (should the CLI check more than `Project::load`,
/// the target must follow).
#[test]
fn project_check_accepts_what_run_check_accepts() {
    let cli = env!("CARGO_BIN_EXE_cloudcontrol");
    let files: Vec<PathBuf> = inputs("corpus", "project_check")
        .into_iter()
        .chain(inputs("artifacts-fixed", "project_check"))
        .collect();
    let mut accepted = 0;
    for f in &files {
        let data = std::fs::read(f).unwrap();
        let parts = cloudcontrol_fuzz::members(&data, 3);
        let Some(toml) = parts[0] else { continue };
        let target = cloudcontrol_fuzz::reads("project_check", &data).unwrap();
        let dir = tempfile::tempdir().unwrap();
        cloudcontrol_fuzz::lay_out_project(
            dir.path(),
            parts[1].unwrap_or_default(),
            parts[2].unwrap_or_default(),
        );
        let project = dir.path().join("project.toml");
        std::fs::write(&project, toml).unwrap();
        let out = std::process::Command::new(cli)
            .args(["run", "--check"])
            .arg(&project)
            .output()
            .unwrap();
        assert_eq!(
            out.status.success(),
            target,
            "{}: run --check {} ({}), the target {}",
            f.display(),
            if out.status.success() {
                "accepts"
            } else {
                "refuses"
            },
            String::from_utf8_lossy(&out.stderr).trim(),
            if target { "accepts" } else { "refuses" },
        );
        accepted += target as usize;
    }
    assert!(accepted > 0, "no project_check seed is accepted");
}
