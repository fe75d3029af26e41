//! The reference epoch oriented with the LiDAR only (issue 9 acceptance): POS-guided tie
//! points, adjustment, point-to-plane ICP and the bundle adjustment with LiDAR planes on
//! the small synthetic block; checkpoints (never used in the solution) within a ground
//! pixel in plan and height, and projection centres close to the truth.

use cloudcontrol::control::checkpoints::evaluate_checkpoints;
use cloudcontrol::control::reference::{self, ReferenceOptions};
use cloudcontrol::control::EpochInput;
use cloudcontrol::lidar::PlaneOptions;
use cloudcontrol::synth::reading::synth_truth_block;
use std::path::{Path, PathBuf};

mod common;
use common::{block_copy, synth_checkpoints};

fn lidar_tiles(dir: &Path) -> Vec<PathBuf> {
    cloudcontrol::lidar::catalogue::expand_inputs(&[dir.join("lidar")]).unwrap()
}

#[test]
fn reference_epoch_oriented_with_lidar_only_is_within_a_ground_pixel() {
    let root = Path::new(env!("CARGO_TARGET_TMPDIR")).join("control_reference");
    let _ = std::fs::remove_dir_all(&root);
    let dir = root.join("block");
    block_copy("small", 7, "rough", &dir);
    let tiles = lidar_tiles(&dir);
    let input = EpochInput::from_synth_epoch(&dir, "reference_2024").unwrap();
    let surface = cloudcontrol::lidar::lidar_surfaces(&tiles, input.origin, 1.0, None).unwrap();
    let index =
        reference::lidar_plane_index(&tiles, input.origin, &[2, 6], PlaneOptions::default())
            .unwrap();
    let t = std::time::Instant::now();
    let (result, rep) = reference::orient_reference(
        &input,
        &index,
        &surface.ground,
        &ReferenceOptions::default(),
    )
    .unwrap();
    let adj = result.adjustment.as_ref().unwrap();
    if let Some(i) = &rep.icp {
        for it in &i.iterations {
            eprintln!("  ICP {it:?}");
        }
    }
    eprintln!("  calibration {:?}", adj.calibration);
    for (w, a) in [("pos", &rep.pos_adjustment), ("final", adj)] {
        eprintln!(
            "  {w}: σ0 {:.3} rmse {:.3} px, obs {}, points {}, redundancy {}, rejected {}, rounds {}, iterations {}, converged {}",
            a.sigma0, a.rmse_px, a.observations, a.points, a.redundancy, a.rejected.count, a.rounds, a.iterations, a.converged
        );
    }
    eprintln!(
        "reference AT: {:.1} s, {} tie points, {} plane constraints, σ0 {:.3}, RMSE {:.3} px, datum {}, ICP {:?}",
        t.elapsed().as_secs_f64(),
        rep.ties.points_added,
        rep.plane_constraints,
        adj.sigma0,
        adj.rmse_px,
        adj.datum,
        rep.icp.as_ref().map(|i| (i.scale, i.rotation_deg, i.translation_m, i.rmse_m, i.degenerate_directions, i.iterations.len())),
    );
    assert!(
        result.photos.iter().all(|p| p.oriented),
        "every photo oriented"
    );
    assert!(
        adj.datum.contains("lidar"),
        "LiDAR planes hold the datum: {}",
        adj.datum
    );
    // The strips hang together by ties, not by the POS alone: the pairs of 15 % overlap
    // or more (the cross-strip pairs among them) are verified by their relative
    // orientation. With 256 interest points per photo, 25 of this block's 34 were (small
    // seeds 1–10: 74 %); with 1,024, 32 (95 %).
    let wide: Vec<_> = rep
        .ties
        .pairs
        .iter()
        .filter(|p| p.overlap >= 0.15)
        .collect();
    let verified = wide.iter().filter(|p| p.skipped.is_none()).count();
    eprintln!(
        "pairs of >= 15 % overlap: {verified} of {} verified",
        wide.len()
    );
    assert!(
        verified as f64 >= 0.9 * wide.len() as f64,
        "{verified} of {} pairs of >= 15 % overlap verified",
        wide.len()
    );

    let (measured, surveyed) = synth_checkpoints(&dir, "reference_2024");
    let ev = evaluate_checkpoints(&result.block, &measured, &surveyed, result.gsd_m).unwrap();
    eprintln!(
        "checkpoints: {} at GSD {:.3} m: plan {:.3} m ({:.2} px), height {:.3} m ({:.2} px), max {:.3} m",
        ev.count, ev.gsd_m, ev.rmse_plan_m, ev.rmse_plan_px, ev.rmse_height_m, ev.rmse_height_px, ev.max_m
    );
    assert!(ev.count >= 5, "{} checkpoints", ev.count);
    assert!(ev.rmse_plan_px <= 1.0, "plan {:.2} px", ev.rmse_plan_px);
    assert!(
        ev.rmse_height_px <= 1.0,
        "height {:.2} px",
        ev.rmse_height_px
    );

    // Projection centres against the truth.
    let truth = synth_truth_block(&dir, "reference_2024").unwrap();
    let floor = evaluate_checkpoints(&truth, &measured, &surveyed, result.gsd_m).unwrap();
    eprintln!(
        "true orientation at the same checkpoints (survey noise): plan {:.3} m, height {:.3} m",
        floor.rmse_plan_m, floor.rmse_height_m
    );
    let mut worst: f64 = 0.0;
    for p in result.block.photos.values() {
        let t = truth.photos.values().find(|q| q.name == p.name).unwrap();
        let d = p.pose.center - t.pose.center;
        eprintln!("  {} centre error {:.3} {:.3} {:.3}", p.name, d.x, d.y, d.z);
        worst = worst.max(d.norm());
    }
    eprintln!("largest projection-centre error {worst:.3} m");
    assert!(worst < 0.15, "centre error {worst:.3} m");

    // One photo without a single tie point (a blank frame, as a scanner or a camera fault
    // leaves) must not stop the epoch: it is reported with its count, the rest is
    // oriented as before.
    let mut blank_input = input.clone();
    let k = 1;
    let (w, h) = image::image_dimensions(&input.photos[k].image).unwrap();
    let blank = root.join("blank.png");
    image::GrayImage::from_pixel(w, h, image::Luma([128u8]))
        .save(&blank)
        .unwrap();
    blank_input.photos[k].image = blank;
    let (result2, _) = reference::orient_reference(
        &blank_input,
        &index,
        &surface.ground,
        &ReferenceOptions::default(),
    )
    .expect("one blank photo does not stop the reference epoch");
    let lost = &result2.photos[result2
        .photos
        .iter()
        .position(|p| p.name == input.photos[k].name)
        .unwrap()];
    assert!(!lost.oriented);
    assert!(
        matches!(
            lost.reason,
            Some(cloudcontrol::block::PhotoFailure::LostSupport { points: 0, .. })
        ),
        "{:?}",
        lost.reason
    );
    let others = result2.photos.iter().filter(|p| p.oriented).count();
    assert_eq!(others, input.photos.len() - 1);
    let ev2 = evaluate_checkpoints(&result2.block, &measured, &surveyed, result2.gsd_m).unwrap();
    eprintln!(
        "with photo {} blank: plan {:.2} px, height {:.2} px ({} checkpoints)",
        input.photos[k].name, ev2.rmse_plan_px, ev2.rmse_height_px, ev2.count
    );
    // The other photos as without the blank one (its neighbours lose the ties they
    // shared with it, so not to the millimetre), and the checkpoints they still see.
    let mut moved: f64 = 0.0;
    for p in result2.block.photos.values().filter(|p| p.is_oriented()) {
        let q = result
            .block
            .photos
            .values()
            .find(|q| q.name == p.name)
            .unwrap();
        moved = moved.max((p.pose.center - q.pose.center).norm());
    }
    eprintln!("largest centre change of the other photos {moved:.3} m");
    assert!(moved < 0.05, "centres moved by up to {moved:.3} m");
    assert!(
        ev2.rmse_plan_px <= 1.1 && ev2.rmse_height_px <= 1.0,
        "plan {:.2} px, height {:.2} px",
        ev2.rmse_plan_px,
        ev2.rmse_height_px
    );
}
