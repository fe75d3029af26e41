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
