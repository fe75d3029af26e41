//! `cloudcontrol bench accuracy --no-surfaces` on the small preset, seeds 1–3 (issue 15: CI runs the
//! targets as assertions). Each epoch row must meet the targets (≥ 95 % of the photos
//! oriented; reference plan and height ≤ 1 GSD, or within 10 % of what the true
//! orientation scores; archive plan ≤ 1 GSD, height ≤ 1.5 GSD), except the rows listed in
//! `KNOWN_MISSES` with their measured cause: a ratchet, not an allowance — a known row
//! that starts to pass is reported so that it can leave the list.

mod common;
use common::{block_copy, exe, json_of};
use std::path::Path;
use std::process::Command;

/// (seed, epoch, why) of the rows that miss a target today. Seed 1's reference height
/// (1.31 GSD, the LiDAR 0.119 m low at the checkpoints) left the list when the strip
/// offsets took the strips' mean as their datum (0.66 GSD, LiDAR −0.034 m).
const KNOWN_MISSES: [(u64, &str, &str); 0] = [];

#[test]
fn small_preset_three_seeds_against_the_targets() {
    let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join("bench_accuracy");
    let _ = std::fs::remove_dir_all(&out);
    for seed in 1..=3 {
        block_copy(
            "small",
            seed,
            "rough",
            &out.join(format!("small-{seed}/block")),
        );
    }
    let v = json_of(
        &Command::new(exe())
            .args(["--json", "bench", "accuracy", "--preset", "small"])
            .args([
                "--seeds",
                "1..3",
                "--reuse-blocks",
                "--no-surfaces",
                "--out",
            ])
            .arg(&out)
            .output()
            .unwrap(),
    );
    let runs = v["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 3);
    // The orientation alone was run (the surfaces are pipeline_run's and dense_epoch's).
    assert_eq!(v["surfaces"], false);
    for seed in 1..=3 {
        let run = out.join(format!("small-{seed}/run"));
        let surfaces = std::fs::read_dir(&run)
            .unwrap()
            .filter(|e| {
                let n = e.as_ref().unwrap().file_name();
                let n = n.to_string_lossy();
                n.starts_with("surface-") || n.starts_with("change-")
            })
            .count();
        assert_eq!(surfaces, 0, "{}", run.display());
    }
    for r in runs {
        assert_eq!(r["completed"], true, "{r}");
        eprintln!(
            "seed {}: {:.0} s, peak RSS {:.0} MiB",
            r["seed"],
            r["seconds"].as_f64().unwrap(),
            r["peak_rss_mib"].as_f64().unwrap()
        );
    }
    let rows = v["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 9, "three epochs per seed");
    let mut unexpected = Vec::new();
    for r in rows {
        let seed = r["seed"].as_u64().unwrap();
        let epoch = r["epoch"].as_str().unwrap();
        let misses: Vec<&str> = r["misses"]
            .as_array()
            .unwrap()
            .iter()
            .map(|m| m.as_str().unwrap())
            .collect();
        eprintln!("seed {seed} {epoch}: {r}");
        // The scoring itself: the true orientation meets the targets at the same
        // checkpoints (their survey noise is half a reference ground pixel).
        for k in ["truth_plan_gsd", "truth_height_gsd"] {
            let t = r[k].as_f64().unwrap();
            assert!(t <= 1.0, "seed {seed} {epoch}: {k} {t:.2}");
        }
        let known = KNOWN_MISSES
            .iter()
            .find(|(s, e, _)| *s == seed && *e == epoch);
        match (misses.is_empty(), known) {
            (true, Some((_, _, why))) => {
                eprintln!("seed {seed} {epoch} now meets every target (was: {why})")
            }
            (false, None) => unexpected.push(format!("seed {seed} {epoch}: {misses:?}")),
            _ => {}
        }
    }
    assert!(unexpected.is_empty(), "targets missed: {unexpected:#?}");
}
