//! Each epoch's own surface by dense matching, scored against the epoch's truth, over
//! synthetic blocks of several seeds (issue 55's acceptance table).
//!
//!     cargo bench --bench dense_epochs [-- --preset small --seeds 1,2,3,4,5
//!                                          --epochs film_1978 --prior dem|plane]
//!     cargo bench --bench dense_epochs -- --run RUN --block BLOCK   (a pipeline run's
//!                                          surfaces, from its adjusted orientations,
//!                                          and those orientations against the truth)
//!
//! Per block (generated once into target/dense-epochs/<preset>-<seed>/) and epoch, the
//! true orientation (`synth::reading::synth_truth_block`: the matching, pairing and
//! fusion alone, without the adjustment's errors) is matched within ± 25 m of the present
//! surface (`orthophoto/dem.tif`), in a child process of this bench so that its peak
//! memory (VmHWM) is the epoch's alone. Printed: pairs, time, peak memory, and the DSM
//! against the epoch's truth on cells ≥ 2 GSD from height edges (median and NMAD in GSD,
//! completeness over the stereo-covered cells), and in the cells that changed since the
//! present (NMAD against the epoch's truth and against the present's). The worst case of
//! each column is named at the end.

use cloudcontrol::adjust::resection::rotation_angle;
use cloudcontrol::change::{changed_areas, compare_dems, AreaOptions, ChangeOptions};
use cloudcontrol::dense::epoch::{epoch_dsm, DsmOptions};
use cloudcontrol::dense::products::DsmReport;
use cloudcontrol::formats::raster::read_dem;
use cloudcontrol::matching::oriented::Surface;
use cloudcontrol::matching::GreyImage;
use cloudcontrol::synth::reading::synth_truth_block;
use cloudcontrol::synth::surface_score::{score_surface, SurfaceScore};
use cloudcontrol::synth::{self, PosQuality, Preset, SynthConfig};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

const EPOCHS: [&str; 3] = ["reference_2024", "digital_2012", "film_1978"];

/// JSON has no NaN: serde_json writes it as null, read back here as NaN.
fn nan_from_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

#[derive(Serialize, Deserialize)]
struct Row {
    pairs: usize,
    gsd: f64,
    seconds: f64,
    cpu_seconds: f64,
    peak_mib: f64,
    #[serde(deserialize_with = "nan_from_null")]
    median_gsd: f64,
    #[serde(deserialize_with = "nan_from_null")]
    nmad_gsd: f64,
    #[serde(deserialize_with = "nan_from_null")]
    completeness: f64,
    cells: usize,
    #[serde(deserialize_with = "nan_from_null")]
    changed_nmad_gsd: f64,
    changed_cells: usize,
    #[serde(deserialize_with = "nan_from_null")]
    changed_nmad_vs_present_gsd: f64,
    /// Nuth & Kääb shift of the DSM to its truth (east, north, up; GSD): what the matching
    /// itself misplaces, with true orientations.
    shift_gsd: [f64; 3],
}

/// The Nuth & Kääb shift (GSD) of `dsm` to the truth of `epoch` in the block `dir`.
fn shift_to_truth(
    dir: &Path,
    epoch: &str,
    dsm: &cloudcontrol::geometry::Dem,
    gsd: f64,
) -> [f64; 3] {
    let (truth, _) = read_dem(&dir.join(format!("truth/epochs/{epoch}/dsm.tif"))).unwrap();
    match compare_dems(&truth, dsm, &Default::default(), &ChangeOptions::default()) {
        Ok(c) => c.report.nuth_kaab.shift_m.map(|v| v / gsd),
        Err(_) => [f64::NAN; 3],
    }
}

fn block_dir(preset: &str, seed: u64) -> PathBuf {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("target/dense-epochs")
        .join(format!("{preset}-{seed}"));
    if !dir.join("manifest.json").is_file() {
        let preset_v = match preset {
            "tiny" => Preset::Tiny,
            "small" => Preset::Small,
            "medium" => Preset::Medium,
            other => panic!("preset {other}: tiny, small or medium"),
        };
        let tmp = dir.with_extension("part");
        let _ = std::fs::remove_dir_all(&tmp);
        synth::generate(
            &SynthConfig {
                preset: preset_v,
                seed,
                change: 0.5,
                pos: PosQuality::Good,
                laz: false,
            },
            &tmp,
        )
        .expect("synthetic block");
        std::fs::rename(&tmp, &dir).unwrap();
    }
    dir
}

/// One epoch, in this (child) process: prints its row as JSON. `plane`: the prior is a
/// plane at the present surface's median height ± its relief instead of the surface
/// itself, so the whole of every pair is matched (the memory case of a film pair).
fn one(dir: &Path, epoch: &str, plane: bool) {
    let block = synth_truth_block(dir, epoch).unwrap();
    let (dem, _) = read_dem(&dir.join("orthophoto/dem.tif")).unwrap();
    let dem_prior = Surface::Dem {
        dem: &dem,
        origin: Vector3::from(block.origin),
        sigma_m: 1.0,
    };
    let prior = if plane {
        cloudcontrol::dense::epoch::plane_of(&dem_prior).unwrap()
    } else {
        dem_prior
    };
    let image = |p: &cloudcontrol::block::Photo| {
        GreyImage::load(p.image.as_ref().unwrap()).map_err(|e| e.to_string())
    };
    let (t0, c0) = (Instant::now(), cloudcontrol::dense::cpu_seconds());
    let out = epoch_dsm(
        &block,
        &image,
        &prior,
        None,
        &DsmOptions::default(),
        |k, n, r| {
            eprintln!(
                "  {epoch} pair {k}/{n}: {}×{} rectified, {:.2} matched, {:.1} s",
                r.rectified[0], r.rectified[1], r.matched, r.seconds
            )
        },
    )
    .unwrap();
    let gsd = out.ground_pixel;
    let (seconds, cpu) = (
        t0.elapsed().as_secs_f64(),
        cloudcontrol::dense::cpu_seconds() - c0,
    );
    let pairs: Vec<(u32, u32)> = out
        .pairs
        .iter()
        .map(|p| (p.pair.left, p.pair.right))
        .collect();
    let s: SurfaceScore = score_surface(dir, epoch, &out.surface.dsm, &block, &pairs, gsd).unwrap();
    let row = Row {
        pairs: out.pairs.len(),
        gsd,
        seconds,
        cpu_seconds: cpu,
        peak_mib: synth::peak_memory_mib(),
        median_gsd: s.median_gsd,
        nmad_gsd: s.nmad_gsd,
        completeness: s.completeness,
        cells: s.cells,
        changed_nmad_gsd: s.changed_nmad_gsd,
        changed_cells: s.changed_cells,
        changed_nmad_vs_present_gsd: s.changed_nmad_vs_present_gsd,
        shift_gsd: shift_to_truth(dir, epoch, &out.surface.dsm, gsd),
    };
    println!("ROW {}", serde_json::to_string(&row).unwrap());
}

/// The surfaces a pipeline run made (`RUN/surface-<epoch>/`, from its adjusted
/// orientations) scored against the truth of the synthetic block `BLOCK` it ran on.
fn score_run(run: &Path, block_dir: &Path) {
    println!(
        "pipeline run {}: each epoch's dsm.tif against its truth",
        run.display()
    );
    for epoch in EPOCHS {
        let sdir = run.join(format!("surface-{epoch}"));
        let Ok(report) = DsmReport::read(&sdir.join("dsm.json")) else {
            println!("{epoch:<15} no surface");
            continue;
        };
        let block =
            cloudcontrol::pipeline::epoch_files::load_block(&run.join(format!("epoch-{epoch}")))
                .unwrap();
        let (dsm, _) = read_dem(&sdir.join("dsm.tif")).unwrap();
        let pairs = report.pair_ids();
        let gsd = report.ground_pixel_m;
        let s = score_surface(block_dir, epoch, &dsm, &block, &pairs, gsd).unwrap();
        let shift = shift_to_truth(block_dir, epoch, &dsm, gsd);
        println!(
            "{epoch:<15} {:>3} pairs, {:>6.1} s: median {:+.3} GSD, NMAD {:.3} GSD, completeness {:.3}, changed NMAD {:.3} GSD ({} cells, {:.1} GSD from the present), shift to truth {:+.2} {:+.2} {:+.2} GSD",
            pairs.len(),
            report.seconds,
            s.median_gsd,
            s.nmad_gsd,
            s.completeness,
            s.changed_nmad_gsd,
            s.changed_cells,
            s.changed_nmad_vs_present_gsd,
            shift[0],
            shift[1],
            shift[2]
        );
        if let Some(o) = orientation_error(block_dir, epoch, &block) {
            println!(
                "{epoch:<15} orientation against the truth ({} photos): centres {:+.3} {:+.3} {:+.3} m on average, RMS {:.3} m, worst {:.3} m; rotation RMS {:.4}°, worst {:.4}°",
                o.photos, o.mean_m[0], o.mean_m[1], o.mean_m[2], o.rms_m, o.worst_m, o.rms_deg, o.worst_deg
            );
        }
    }
    for epoch in &EPOCHS[1..] {
        match changed_area_score(run, block_dir, epoch) {
            Some(a) => println!(
                "{epoch:<15} changed areas against today: changed buildings found {}/{} ({:.2}); all change objects {}/{} ({:.2}; of ≥ {} m²: {}/{}, {:.2}), precision {}/{} ({:.2})",
                a.buildings_found,
                a.buildings,
                a.buildings_found as f64 / a.buildings.max(1) as f64,
                a.found,
                a.objects,
                a.found as f64 / a.objects.max(1) as f64,
                2.0 * AreaOptions::default().min_area_m2,
                a.large_found,
                a.large,
                a.large_found as f64 / a.large.max(1) as f64,
                a.right,
                a.detected,
                a.right as f64 / a.detected.max(1) as f64
            ),
            None => println!("{epoch:<15} no change-{epoch}/changed_areas.geojson"),
        }
    }
}

/// How far a run's adjusted photos lie from their true exterior orientation: where a DSM
/// made from them departs from the one matched with the true orientation (`--seeds`
/// mode), this says whether the orientation is why.
struct OrientationError {
    photos: usize,
    mean_m: [f64; 3],
    rms_m: f64,
    worst_m: f64,
    rms_deg: f64,
    worst_deg: f64,
}

fn orientation_error(
    block_dir: &Path,
    epoch: &str,
    block: &cloudcontrol::block::Block,
) -> Option<OrientationError> {
    let truth = synth_truth_block(block_dir, epoch).ok()?;
    let true_pose: std::collections::BTreeMap<&str, _> = truth
        .photos
        .values()
        .map(|p| (p.name.as_str(), &p.pose))
        .collect();
    let (o, to) = (Vector3::from(block.origin), Vector3::from(truth.origin));
    let mut d = Vec::new();
    for ph in block.photos.values() {
        if ph.status != cloudcontrol::block::PhotoStatus::Oriented {
            continue;
        }
        let Some(t) = true_pose.get(ph.name.as_str()) else {
            continue;
        };
        let dc = (ph.pose.center + o) - (t.center + to);
        let angle = rotation_angle(&ph.pose.rotation, &t.rotation).to_degrees();
        d.push((dc, angle));
    }
    if d.is_empty() {
        return None;
    }
    let n = d.len() as f64;
    let mean: Vector3<f64> = d.iter().map(|(c, _)| c).sum::<Vector3<f64>>() / n;
    let metres: Vec<f64> = d.iter().map(|(c, _)| c.norm()).collect();
    let degrees: Vec<f64> = d.iter().map(|(_, a)| *a).collect();
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / n).sqrt();
    let worst = |v: &[f64]| v.iter().copied().fold(0.0, f64::max);
    Some(OrientationError {
        photos: d.len(),
        mean_m: mean.into(),
        rms_m: rms(&metres),
        worst_m: worst(&metres),
        rms_deg: rms(&degrees),
        worst_deg: worst(&degrees),
    })
}

/// The changed areas the run's `change-<epoch>` stage found against the present, scored
/// against the synthetic truth: the cells of the LiDAR grid that the epoch's surface
/// covers (dh has a value: a change outside the epoch's photos cannot be found) where its
/// true surface stands 2 m or more from the present's, as 4-connected objects of at least
/// 25 m². An object is found when half its cells lie in a detected area; a detected area
/// is right when half its cells are true change. The recall is of the changed
/// buildings (`truth/epochs/<epoch>/buildings.csv`: standing in the epoch or today, not
/// both), each found when half its footprint's covered cells are detected (buildings whose
/// footprint the epoch's surface covers less than half are not counted); the change
/// objects count trees as well (removed, or grown since), whose crowns match poorly.
fn changed_area_score(run: &Path, block_dir: &Path, epoch: &str) -> Option<AreaScore> {
    let dir = run.join(format!("change-{epoch}"));
    let (dh, _) = read_dem(&dir.join("dh.tif")).ok()?;
    let geo: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("changed_areas.geojson")).ok()?).ok()?;
    let (then, _) = read_dem(&block_dir.join(format!("truth/epochs/{epoch}/dsm.tif"))).ok()?;
    let (now, _) = read_dem(&block_dir.join(format!("truth/epochs/{}/dsm.tif", EPOCHS[0]))).ok()?;
    let n = dh.data.len();
    let centre = |i: usize| {
        dh.transform
            .pixel_to_world((i % dh.width) as f64 + 0.5, (i / dh.width) as f64 + 0.5)
    };
    // True change on the dh grid; detected cells: inside a detected polygon's outer ring.
    let truth: Vec<f64> = (0..n)
        .map(|i| {
            let (x, y) = centre(i);
            match (then.height_at(x, y), now.height_at(x, y)) {
                (Some(a), Some(b)) if (a - b).abs() >= 2.0 && dh.data[i].is_finite() => 10.0,
                _ => 0.0,
            }
        })
        .collect();
    let grid = |data: &[f64]| {
        cloudcontrol::geometry::Dem::new(
            dh.width,
            dh.height,
            dh.transform,
            data.iter().map(|&v| v as f32).collect(),
        )
        .unwrap()
    };
    let objects = changed_areas(
        &truth,
        &grid(&truth),
        (0.0, 0.0),
        None,
        &AreaOptions {
            k_nmad: 0.0,
            min_dh_m: 1.0,
            min_area_m2: 25.0,
        },
    )
    .ok()?;
    let rings: Vec<Vec<[f64; 2]>> = geo["features"]
        .as_array()?
        .iter()
        .filter_map(|f| serde_json::from_value(f["geometry"]["coordinates"][0].clone()).ok())
        .collect();
    let inside = |ring: &[[f64; 2]], (x, y): (f64, f64)| {
        let mut odd = false;
        for w in ring.windows(2) {
            let ([x0, y0], [x1, y1]) = (w[0], w[1]);
            if (y0 > y) != (y1 > y) && x < x0 + (y - y0) * (x1 - x0) / (y1 - y0) {
                odd = !odd;
            }
        }
        odd
    };
    let detected: Vec<bool> = (0..n)
        .map(|i| rings.iter().any(|r| inside(r, centre(i))))
        .collect();
    // Found objects, all and those of at least twice the least area: the edge cells of a
    // change are the least certain (a fused DSM's pairs disagree there), so an object near
    // the least area keeps a detected core below it.
    let found_of = |least: f64| {
        let mut n_found = 0;
        let mut n_all = 0;
        for o in objects.iter().filter(|o| o.area_m2 >= least) {
            let ring = &o.rings[0];
            let cells: Vec<usize> = (0..n).filter(|&i| inside(ring, centre(i))).collect();
            n_all += 1;
            n_found +=
                usize::from(2 * cells.iter().filter(|&&i| detected[i]).count() >= cells.len());
        }
        (n_found, n_all)
    };
    let (found, _) = found_of(0.0);
    let large = found_of(2.0 * AreaOptions::default().min_area_m2);
    let right = rings
        .iter()
        .filter(|ring| {
            let cells: Vec<usize> = (0..n).filter(|&i| inside(ring, centre(i))).collect();
            2 * cells.iter().filter(|&&i| truth[i] > 0.0).count() >= cells.len()
        })
        .count();
    // Changed buildings: standing in one of the two epochs only.
    let read = |e: &str| {
        cloudcontrol::synth::truth::read_buildings(
            &block_dir.join(format!("truth/epochs/{e}/buildings.csv")),
        )
        .ok()
    };
    let (then_b, now_b) = (read(epoch)?, read(EPOCHS[0])?);
    let ids = |v: &[cloudcontrol::synth::truth::TrueBuilding]| {
        v.iter()
            .map(|b| b.id)
            .collect::<std::collections::BTreeSet<_>>()
    };
    let (then_ids, now_ids) = (ids(&then_b), ids(&now_b));
    let (mut buildings, mut buildings_found) = (0, 0);
    for b in then_b
        .iter()
        .filter(|b| !now_ids.contains(&b.id))
        .chain(now_b.iter().filter(|b| !then_ids.contains(&b.id)))
    {
        let cells: Vec<usize> = (0..n)
            .filter(|&i| {
                let (x, y) = centre(i);
                b.contains(x, y)
            })
            .collect();
        let covered: Vec<usize> = cells
            .iter()
            .copied()
            .filter(|&i| dh.data[i].is_finite())
            .collect();
        if cells.is_empty() || 2 * covered.len() < cells.len() {
            continue;
        }
        buildings += 1;
        buildings_found +=
            usize::from(2 * covered.iter().filter(|&&i| detected[i]).count() >= covered.len());
    }
    Some(AreaScore {
        buildings,
        buildings_found,
        found,
        objects: objects.len(),
        large_found: large.0,
        large: large.1,
        right,
        detected: rings.len(),
    })
}

/// Changed areas scored against the truth.
struct AreaScore {
    /// Changed buildings, and those found.
    buildings: usize,
    buildings_found: usize,
    found: usize,
    objects: usize,
    /// Found among the objects of at least twice the least area.
    large_found: usize,
    large: usize,
    right: usize,
    detected: usize,
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let arg = |k: &str| {
        args.iter()
            .position(|a| a == k)
            .and_then(|i| args.get(i + 1).cloned())
    };
    if let (Some(run), Some(block)) = (arg("--run"), arg("--block")) {
        score_run(Path::new(&run), Path::new(&block));
        return;
    }
    let plane = arg("--prior").is_some_and(|p| p == "plane");
    if let (Some(dir), Some(epoch)) = (arg("--one-dir"), arg("--one-epoch")) {
        one(Path::new(&dir), &epoch, plane);
        return;
    }
    let epochs: Vec<String> = arg("--epochs")
        .map(|e| e.split(',').map(str::to_string).collect())
        .unwrap_or_else(|| EPOCHS.map(str::to_string).to_vec());
    let preset = arg("--preset").unwrap_or("small".into());
    let seeds: Vec<u64> = arg("--seeds")
        .unwrap_or("1,2,3,4,5".into())
        .split(',')
        .map(|s| s.parse().unwrap())
        .collect();
    println!(
        "dense matching per epoch, {preset} preset, true orientation, prior: {} ± 25 m",
        if plane {
            "plane at the present surface's median height, ± its relief"
        } else {
            "present surface"
        }
    );
    println!(
        "{:<6} {:<15} {:>5} {:>6} {:>7} {:>7} {:>8} {:>8} {:>7} {:>7} {:>8} {:>8} {:>7} {:>6} {:>6} {:>6}",
        "seed",
        "epoch",
        "pairs",
        "GSD m",
        "wall s",
        "cpu s",
        "peak MiB",
        "median",
        "NMAD",
        "compl",
        "chg NMAD",
        "vs now",
        "chg n",
        "dE",
        "dN",
        "dZ"
    );
    let mut worst: Vec<(String, f64, String)> = Vec::new();
    let mut note = |what: &str, v: f64, at: String, higher_is_worse: bool| {
        if v.is_nan() {
            return;
        }
        let e = worst.iter_mut().find(|w| w.0 == what);
        match e {
            Some(w) if (higher_is_worse && v > w.1) || (!higher_is_worse && v < w.1) => {
                w.1 = v;
                w.2 = at;
            }
            Some(_) => {}
            None => worst.push((what.to_string(), v, at)),
        }
    };
    for seed in seeds {
        let dir = block_dir(&preset, seed);
        for epoch in &epochs {
            let epoch = epoch.as_str();
            let out = std::process::Command::new(std::env::current_exe().unwrap())
                .args(["--one-dir", dir.to_str().unwrap(), "--one-epoch", epoch])
                .args(["--prior", if plane { "plane" } else { "dem" }])
                .stderr(std::process::Stdio::inherit())
                .output()
                .unwrap();
            let text = String::from_utf8_lossy(&out.stdout);
            let Some(json) = text.lines().find_map(|l| l.strip_prefix("ROW ")) else {
                println!("{seed:<6} {epoch:<15} FAILED ({})", out.status);
                continue;
            };
            let r: Row = serde_json::from_str(json).unwrap();
            println!(
                "{:<6} {:<15} {:>5} {:>6.3} {:>7.1} {:>7.1} {:>8.0} {:>+8.3} {:>7.3} {:>7.3} {:>8.3} {:>8.3} {:>7} {:>+6.2} {:>+6.2} {:>+6.2}",
                seed, epoch, r.pairs, r.gsd, r.seconds, r.cpu_seconds, r.peak_mib, r.median_gsd,
                r.nmad_gsd, r.completeness, r.changed_nmad_gsd, r.changed_nmad_vs_present_gsd,
                r.changed_cells, r.shift_gsd[0], r.shift_gsd[1], r.shift_gsd[2]
            );
            let at = format!("seed {seed} {epoch}");
            note("|median| GSD", r.median_gsd.abs(), at.clone(), true);
            note("NMAD GSD", r.nmad_gsd, at.clone(), true);
            note("completeness", r.completeness, at.clone(), false);
            note("changed NMAD GSD", r.changed_nmad_gsd, at.clone(), true);
            note(
                "plan shift GSD",
                r.shift_gsd[0].hypot(r.shift_gsd[1]),
                at.clone(),
                true,
            );
            note("peak MiB", r.peak_mib, at.clone(), true);
            note("wall s", r.seconds, at, true);
        }
    }
    println!("worst:");
    for (what, v, at) in worst {
        println!("  {what:<18} {v:>9.3}  ({at})");
    }
}
