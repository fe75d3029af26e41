//! The `small` preset (the demo's data) once: its size, its budget (< 75 s on 2 cores,
//! measured as process CPU time / 2 so a busy machine does not fail it) and the accuracy of
//! its rendered checkpoints in the reference epoch.

use cloudcontrol::formats;
use cloudcontrol::synth::{self, PosQuality, Preset, SynthConfig};

fn cpu_seconds() -> f64 {
    // SAFETY: getrusage only writes into the struct we pass.
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) };
    let t = |v: libc::timeval| v.tv_sec as f64 + v.tv_usec as f64 * 1e-6;
    t(u.ru_utime) + t(u.ru_stime)
}

#[test]
fn small_preset_meets_its_budget_and_sizes() {
    let dir = tempfile::tempdir().unwrap();
    let cpu0 = cpu_seconds();
    let m = synth::generate(
        &SynthConfig {
            preset: Preset::Small,
            seed: 1,
            change: 0.5,
            pos: PosQuality::None,
            laz: true,
        },
        dir.path(),
    )
    .unwrap();
    let cpu = cpu_seconds() - cpu0;
    eprintln!(
        "small preset: wall {:.1} s, CPU {:.1} s (= {:.1} s on 2 cores), peak {:.0} MiB, {} LiDAR points ({:.1}/m²), {} checkpoints, photos {:?}",
        m.run.total_s,
        cpu,
        cpu / 2.0,
        m.run.peak_memory_mib,
        m.lidar.points,
        m.lidar.density_per_m2,
        m.checkpoint_count,
        m.epochs.iter().map(|e| (e.name.as_str(), e.photos.len())).collect::<Vec<_>>()
    );
    // The budget is the demo's (issue 15: under 3 minutes), which is this synthesis plus
    // `run` on it. The synthesis measured 108–122.5 CPU s on the 2-core machines of
    // November 2026's first weeks, then 160–172 on slower ones (165 in CI, failing this
    // 150); since the film's frame is no longer rendered, pixels start from their row
    // neighbours and more of the reference's rays take the terrain's single root,
    // 114–136 CPU s there.
    assert!(cpu / 2.0 < 75.0, "small preset needs {cpu:.1} CPU s");
    assert!((6.0..=10.0).contains(&m.lidar.density_per_m2));
    assert!(m.lidar.tiles.iter().all(|t| t.path.ends_with(".laz")));
    assert!(m.checkpoint_count >= 8);
    let reference = &m.epochs[0];
    assert!(
        (12..=20).contains(&reference.photos.len()),
        "{}",
        reference.photos.len()
    );
    assert_eq!(reference.gsd_m, 0.1);
    assert_eq!(m.epochs[2].kind, "film");
    assert_eq!(m.epochs[2].gsd_m, 0.5);
    // No POS: each archive epoch gets strip ends only, in the documented strips CSV
    // (formats/pos/): every photo by image file name, flown with image up along track.
    let film = &m.epochs[2];
    let strips = formats::pos::read_strips(&dir.path().join(&film.navigation)).unwrap();
    let listed: Vec<String> = strips.iter().flat_map(|s| s.photos.clone()).collect();
    let files: Vec<String> = film.photos.iter().map(|p| format!("{p}.png")).collect();
    assert_eq!(listed, files);
    assert!(strips
        .iter()
        .all(|s| s.flight_axis == formats::pos::FlightAxis::MinusY));
    assert!(listed
        .iter()
        .all(|p| dir.path().join(&film.images_dir).join(p).is_file()));
    // The reference epoch's POS names the same image files.
    let reference_pos = formats::pos::read_pos(&dir.path().join(&reference.navigation)).unwrap();
    assert_eq!(
        reference_pos
            .iter()
            .map(|r| r.name.clone())
            .collect::<Vec<_>>(),
        reference
            .photos
            .iter()
            .map(|p| format!("{p}.png"))
            .collect::<Vec<_>>()
    );
    assert!(dir.path().join("run.json").exists());
    // Truth is apart from the inputs.
    for e in &m.epochs {
        assert!(e.truth_dir.starts_with("truth/"));
        assert!(!dir.path().join(&e.images_dir).join("../eo.csv").exists());
    }
}

/// The large preset's LiDAR size (≥ 20 M points) without rendering; ~1 GB and tens of
/// seconds, so run on demand: `cargo test --release --test synth_small -- --ignored`.
#[test]
#[ignore]
fn large_preset_has_at_least_20_million_lidar_points() {
    let config = SynthConfig {
        preset: Preset::Large,
        seed: 1,
        change: 0.5,
        pos: PosQuality::Rough,
        laz: false,
    };
    let scene = synth::Scene::generate(config.seed, synth::scene_extent(config.preset));
    let (_, points) = synth::simulate_lidar(&config, &scene);
    eprintln!("large preset LiDAR: {} points", points.len());
    assert!(points.len() >= 20_000_000, "{}", points.len());
}
