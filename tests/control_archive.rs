//! Archive orientation from Digital Control Photos on synthetic blocks (issue 9 acceptance):
//! DCPs from the reference epoch's true orientation over the LiDAR ground, then the film
//! and digital archive epochs oriented from rough POS or strip end points, checked at the
//! surveyed checkpoints; the time series reference → digital → film; damaged packages.

use cloudcontrol::control::archive::{self, ArchiveOptions, DcpExportOptions, EpochInput};
use cloudcontrol::control::cloud::{CloudOptions, GroundSurface};
use cloudcontrol::control::dcp::{DcpPackage, EpochInfo};
use cloudcontrol::synth::{self, PosQuality, Preset, SynthConfig};
use std::path::{Path, PathBuf};
use std::time::Instant;

struct Setup {
    _tmp: tempfile::TempDir,
    dir: PathBuf,
    surface: GroundSurface,
    reference: DcpPackage,
}

fn lidar_tiles(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir.join("lidar"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "las" || e == "laz"))
        .collect();
    v.sort();
    v
}

fn export_opts(preset: Preset) -> DcpExportOptions {
    DcpExportOptions {
        cloud: CloudOptions {
            interval_px: match preset {
                Preset::Tiny => 60.0,
                _ => 120.0,
            },
            max_coplanarity: 0.02,
            ..CloudOptions::default()
        },
        chip_size: match preset {
            Preset::Tiny => 161,
            _ => 193,
        },
        ..DcpExportOptions::default()
    }
}

/// A synthetic block and the reference DCP package from the reference epoch's true
/// orientation over the LiDAR ground.
fn setup(preset: Preset, pos: PosQuality, seed: u64) -> Setup {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("block");
    synth::generate(
        &SynthConfig {
            preset,
            seed,
            change: 0.5,
            pos,
            laz: false,
        },
        &dir,
    )
    .unwrap();
    let surface = archive::lidar_surfaces(&lidar_tiles(&dir), synth::ORIGIN, 1.0).unwrap();
    let (block, images) = archive::synth_truth_block(&dir, "reference_2024").unwrap();
    let reference = archive::export_dcp(
        &block,
        &images,
        &surface,
        EpochInfo {
            name: "reference_2024".into(),
            date: Some("2024-05-29".into()),
        },
        &tmp.path().join("reference.dcp"),
        &export_opts(preset),
    )
    .unwrap();
    Setup {
        _tmp: tmp,
        dir,
        surface,
        reference,
    }
}

struct Outcome {
    oriented: f64,
    eval: archive::CheckpointEvaluation,
    result: archive::EpochResult,
}

fn orient(s: &Setup, epoch: &str, dcp: &[DcpPackage], opts: &ArchiveOptions) -> Outcome {
    let t = Instant::now();
    let input = EpochInput::from_synth_epoch(&s.dir, epoch).unwrap();
    let result = archive::orient_epoch(&input, dcp, &s.surface.ground, opts).unwrap();
    let meas =
        archive::read_checkpoint_images(&s.dir.join("truth/checkpoint_images.csv"), epoch).unwrap();
    let surveyed = archive::read_checkpoints(&s.dir.join("checkpoints.csv")).unwrap();
    println!(
        "{epoch}: {} DCP points",
        dcp.iter().map(|p| p.manifest.points.len()).sum::<usize>()
    );
    for p in &result.photos {
        println!(
            "  {} oriented={} matches={} σ={:.2} px predicted={} {:?} {:?}",
            p.name, p.oriented, p.control_matches, p.sigma_px, p.predicted, p.matching, p.reason
        );
        for r in &p.iterations {
            println!("    {r:?}");
        }
    }
    let eval =
        archive::evaluate_checkpoints(&result.block, &meas, &surveyed, result.gsd_m).unwrap();
    let oriented = result.oriented_fraction();
    println!(
        "{epoch}: oriented {:.0} % of {}, checkpoints {} — plan {:.3} m ({:.2} px), height {:.3} m ({:.2} px), max {:.3} m, gsd {:.3} m, {:.1} s (with evaluation {:.1} s)",
        100.0 * oriented,
        result.photos.len(),
        eval.count,
        eval.rmse_plan_m,
        eval.rmse_plan_px,
        eval.rmse_height_m,
        eval.rmse_height_px,
        eval.max_m,
        eval.gsd_m,
        result.time_s,
        t.elapsed().as_secs_f64()
    );
    if let Some(a) = &result.adjustment {
        println!(
            "  adjustment σ0 {:.2}, rmse {:.2} px, rejected {}, datum {}",
            a.sigma0, a.rmse_px, a.rejected.count, a.datum
        );
    }
    Outcome {
        oriented,
        eval,
        result,
    }
}

fn assert_accuracy(o: &Outcome, what: &str) {
    assert!(o.oriented >= 0.9, "{what}: oriented {:.2}", o.oriented);
    assert!(o.eval.count >= 3, "{what}: {} checkpoints", o.eval.count);
    assert!(
        o.eval.rmse_plan_px <= 1.0,
        "{what}: plan RMSE {:.2} px",
        o.eval.rmse_plan_px
    );
    assert!(
        o.eval.rmse_height_px <= 1.5,
        "{what}: height RMSE {:.2} px",
        o.eval.rmse_height_px
    );
}

#[test]
fn film_epoch_with_rough_pos_is_oriented_to_a_ground_pixel() {
    let s = setup(Preset::Small, PosQuality::Rough, 3);
    let o = orient(
        &s,
        "film_1978",
        std::slice::from_ref(&s.reference),
        &ArchiveOptions::default(),
    );
    assert_accuracy(&o, "film_1978, POS 10 m / 3°");
    // Refinement: every oriented photo was resected and predicted again.
    for p in o.result.photos.iter().filter(|p| p.oriented) {
        assert!(p.iterations.len() >= 2 && p.iterations[0].resected, "{p:?}");
        assert!(p.io_rmse_um.is_some_and(|r| r < 20.0), "{p:?}");
    }
}
