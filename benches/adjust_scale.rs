//! The adjustment at archive scale (issue 54): a synthetic aerial block of up to tens of
//! thousands of photos adjusted by `cloudcontrol adjust` as a user runs it, its time,
//! peak memory (per observation) and report size.
//!
//!     cargo bench --bench adjust_scale [-- --photos 20000 --obs-per-photo 1000
//!                                         --dir target/adjust-scale --keep]
//!
//! The block is the benches' (benches/adjust_pycolmap.py): nadir photos 6000 × 4000 px,
//! f = 5000 px, 1000 m above a sinusoidal terrain (±60 m), 60 % forward and 30 % side
//! overlap, √(n/4) strips flown both ways, 0.5 px image noise, no control (free network),
//! a start perturbed by 0.3° in attitude, 3 m in the centres and 1 m in the points. It is
//! made by `adjust::synthetic` (the Python generator of the pycolmap bench took 41 min
//! for 3,200 photos), written as a binary COLMAP model, and adjusted in a child process
//! under GNU time so that the peak is the adjustment's alone. No peer runs here: pycolmap
//! had not finished a 3,200-photo block in 600 s (benches/adjust_pycolmap.py compares up
//! to that size), and COLMAP's global adjustment runs out of 64 GB at about 20,000
//! images (colmap#2616).
//!
//! Printed: photos, points, observations, generation time; the adjustment's wall time,
//! peak resident memory, bytes per observation above 1 GiB, report.json size, σ0,
//! iterations and rounds, the reduced camera system's size, ordering and fill-in; and the
//! adjusted centres against the truth after a 7-parameter similarity (the free network's
//! datum is arbitrary).

use cloudcontrol::adjust::synthetic::{generate, SyntheticOptions};
use cloudcontrol::formats::colmap::{self, WriteOptions};
use cloudcontrol::geometry::Similarity;
use nalgebra::Vector3;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

struct Args {
    photos: usize,
    obs_per_photo: usize,
    dir: PathBuf,
    keep: bool,
    /// Only write the start model there (the child process).
    write_model: Option<PathBuf>,
}

fn args() -> Args {
    let mut a = Args {
        photos: 20_000,
        obs_per_photo: 1000,
        dir: PathBuf::from("target/adjust-scale"),
        keep: false,
        write_model: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(k) = it.next() {
        let mut value = || it.next().unwrap_or_else(|| panic!("{k} needs a value"));
        match k.as_str() {
            "--photos" => a.photos = value().parse().expect("--photos: a count"),
            "--obs-per-photo" => a.obs_per_photo = value().parse().expect("a count"),
            "--dir" => a.dir = PathBuf::from(value()),
            "--keep" => a.keep = true,
            "--write-model" => a.write_model = Some(PathBuf::from(value())),
            // cargo bench passes --bench to every bench binary.
            "--bench" => {}
            other => panic!("unknown argument {other}"),
        }
    }
    a
}

/// The benches' block layout for `photos` photos, with `tie_points` points.
fn options(photos: usize, tie_points: usize) -> SyntheticOptions {
    let strips = ((photos as f64 / 4.0).sqrt().round() as usize).max(2);
    SyntheticOptions {
        strips,
        photos_per_strip: photos.div_ceil(strips),
        tie_points,
        control_grid: (0, 0),
        check_points: 0,
        seed: 1,
        ..Default::default()
    }
}

fn observations(b: &cloudcontrol::block::Block) -> usize {
    b.points.values().map(|p| p.observations.len()).sum()
}

/// Resident peak (KiB) and wall time (s) of `cmd` under GNU time.
fn run_measured(cmd: &mut Command, dir: &Path) -> (f64, u64) {
    let times = dir.join("time.txt");
    let prog = cmd.get_program().to_owned();
    let args: Vec<_> = cmd.get_args().map(|a| a.to_owned()).collect();
    let status = Command::new("/usr/bin/time")
        .arg("-f")
        .arg("%e %M")
        .arg("-o")
        .arg(&times)
        .arg(prog)
        .args(args)
        .status()
        .expect("/usr/bin/time runs (GNU time: apt-get install time)");
    assert!(status.success(), "the adjustment failed: {status}");
    let text = std::fs::read_to_string(&times).expect("GNU time's output");
    let last = text.lines().last().expect("a line");
    let mut f = last.split_whitespace();
    let wall: f64 = f.next().and_then(|s| s.parse().ok()).expect("wall time");
    let kib: u64 = f.next().and_then(|s| s.parse().ok()).expect("peak");
    (wall, kib)
}

/// Writes the start block of `photos` photos (`obs_per_photo` observations a photo) as a
/// binary COLMAP model into `dir`; prints its size.
fn write_block(photos: usize, obs_per_photo: usize, dir: &Path) {
    // Mean rays per point of this layout from a pilot block (edges see fewer), so that the
    // block has the asked observations per photo.
    let pilot = generate(&options(photos.min(400), 20_000));
    let rays = observations(&pilot.truth) as f64 / pilot.truth.points.len() as f64;
    drop(pilot);
    let o = options(photos, 0);
    let n_photos = o.strips * o.photos_per_strip;
    let tie_points = (n_photos as f64 * obs_per_photo as f64 / rays).round() as usize;
    let t = Instant::now();
    let block = generate(&SyntheticOptions {
        tie_points,
        ..o.clone()
    });
    let t_gen = t.elapsed().as_secs_f64();
    let n_obs = observations(&block.start);
    println!(
        "block: {} photos ({} strips), {} points, {} observations ({:.0} a photo, {rays:.2} rays a point), generated in {t_gen:.0} s",
        block.start.photos.len(),
        o.strips,
        block.start.points.len(),
        n_obs,
        n_obs as f64 / n_photos as f64
    );
    let t = Instant::now();
    colmap::write(dir, &block.start, &WriteOptions::default()).expect("start model");
    std::fs::write(dir.with_extension("observations"), n_obs.to_string()).expect("count");
    println!("start model written in {:.0} s", t.elapsed().as_secs_f64());
}

fn main() {
    let a = args();
    std::fs::create_dir_all(&a.dir).expect("bench directory");
    let o = options(a.photos, 0);
    let n_photos = o.strips * o.photos_per_strip;
    let start_dir = a.dir.join(format!("start-{n_photos}"));
    if let Some(dir) = &a.write_model {
        write_block(a.photos, a.obs_per_photo, dir);
        return;
    }
    // The block is made in a child process: the allocator keeps a freed block's pages
    // (7.2 GiB resident at 20,000 photos after the block was dropped), which would sit
    // beside the adjustment's own peak.
    let status = Command::new(std::env::current_exe().expect("this bench"))
        .args(["--photos", &a.photos.to_string()])
        .args(["--obs-per-photo", &a.obs_per_photo.to_string()])
        .arg("--write-model")
        .arg(&start_dir)
        .status()
        .expect("the block's writer runs");
    assert!(status.success(), "writing the block failed: {status}");
    // The photos are drawn before anything else: a block without tie points has the same
    // true poses.
    let truth: Vec<(cloudcontrol::block::PhotoId, Vector3<f64>)> = generate(&o)
        .truth
        .photos
        .values()
        .map(|p| (p.id, p.pose.center))
        .collect();
    let n_obs: usize = std::fs::read_to_string(start_dir.with_extension("observations"))
        .ok()
        .and_then(|t| t.trim().parse().ok())
        .expect("the writer's observation count");

    let out = a.dir.join(format!("adjusted-{n_photos}"));
    let report = a.dir.join(format!("report-{n_photos}.json"));
    let bin = Path::new(env!("CARGO_BIN_EXE_cloudcontrol"));
    let (wall, kib) = run_measured(
        Command::new(bin)
            .arg("-q")
            .arg("adjust")
            .arg("--model")
            .arg(&start_dir)
            .arg("--out")
            .arg(&out)
            .arg("--report")
            .arg(&report),
        &a.dir,
    );
    let rep: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&report).expect("report.json")).expect("JSON");
    let report_mb = std::fs::metadata(&report).map(|m| m.len()).unwrap_or(0) as f64 / 1e6;
    let peak = kib as f64 * 1024.0;
    let above = match peak - (1u64 << 30) as f64 {
        a if a > 0.0 => format!("{:.0} B an observation above 1 GiB", a / n_obs as f64),
        _ => "within 1 GiB".into(),
    };
    println!(
        "adjust: {wall:.0} s wall ({:.0} s in the solver), peak {:.2} GiB = {:.0} B an observation, {above} (limit 1 GiB + 300 B); report.json {report_mb:.2} MB (limit 10)",
        rep["time_s"].as_f64().unwrap_or(f64::NAN),
        peak / (1u64 << 30) as f64,
        peak / n_obs as f64,
    );
    println!(
        "σ0 {:.4}, RMS {:.3} px, {} iterations, {} rounds, converged {}, rejected {}",
        rep["sigma0"].as_f64().unwrap_or(f64::NAN),
        rep["rmse_px"].as_f64().unwrap_or(f64::NAN),
        rep["iterations"],
        rep["rounds"],
        rep["converged"],
        rep["rejected"]["count"],
    );
    if let Some(r) = rep.get("reduced_system").filter(|r| !r.is_null()) {
        println!(
            "reduced camera system: {} unknowns, {} ordering, {} non-zeros in its upper triangle, {} in the factor (fill-in ×{:.2})",
            r["unknowns"],
            r["ordering"].as_str().unwrap_or("?"),
            r["nonzeros"],
            r["factor_nonzeros"],
            r["factor_nonzeros"].as_f64().unwrap_or(f64::NAN) / r["nonzeros"].as_f64().unwrap_or(f64::NAN)
        );
    }

    // The free network's datum (a photo and a coordinate held at their perturbed values)
    // is arbitrary: the centres are compared after the similarity that best maps them
    // onto the truth.
    let adjusted = colmap::read(&out).expect("adjusted model");
    let (src, dst): (Vec<_>, Vec<_>) = truth
        .iter()
        .filter_map(|(id, c)| adjusted.photos.get(id).map(|p| (p.pose.center, *c)))
        .unzip();
    let s = Similarity::estimate(&src, &dst, None, true).expect("similarity");
    let rms = (src
        .iter()
        .zip(&dst)
        .map(|(m, t)| (s.apply(m) - t).norm_squared())
        .sum::<f64>()
        / src.len() as f64)
        .sqrt();
    println!(
        "centres against the truth after a similarity: RMS {:.1} mm over {} photos",
        rms * 1e3,
        src.len()
    );
    if !a.keep {
        for d in [&start_dir, &out] {
            let _ = std::fs::remove_dir_all(d);
        }
        let _ = std::fs::remove_file(start_dir.with_extension("observations"));
    }
}
