//! Deterministic synthetic aerial blocks with ground truth (`cloudcontrol synth`).
//!
//! [`generate`] writes a complete block — LiDAR tiles, surveyed checkpoints, a present-day
//! reference epoch, a digital archive epoch and a scanned-film epoch with a changed scene —
//! and keeps every true quantity apart under `truth/`. [`Scene`] is the in-memory world so
//! other modules' tests can build small blocks without writing files. Layout and file
//! formats: `formats/synth/README.md`.
//!
//! Determinism: every random draw comes from ChaCha streams seeded from the seed; per-pixel
//! noise is a hash of the pixel; parallel loops collect in index order; maps are BTreeMaps.

mod checkpoints;
mod epoch;
pub mod film;
pub mod flight;
pub mod lidar;
pub mod noise;
pub mod orthophoto;
pub mod project;
pub mod reading;
pub mod render;
pub mod scene;
pub mod surface_score;
pub mod truth;

pub use film::{Fiducial, FiducialShape, FilmCameraDef};
pub use render::{render, RayCaster};
pub use scene::{
    Building, Class, Roof, Scene, SurfacePoint, Target, TARGET_DISC_RADIUS, TARGET_SQUARE_HALF,
};

use crate::formats::{self, crs::Crs, FormatError};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use sha2::{Digest, Sha256};
use std::path::Path;
use std::time::Instant;

/// Block origin in EPSG:4547 (CGCS2000 / 3-degree Gauss-Krüger CM 114E).
pub const ORIGIN: [f64; 3] = [500_000.0, 4_400_000.0, 0.0];
pub const CRS_EPSG: u32 = 4547;

#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    #[error("invalid synth configuration: {0}")]
    InvalidConfig(String),
    #[error(transparent)]
    Format(#[from] FormatError),
    #[error("LAS writer: {0}")]
    Las(String),
    #[error("{path}: image encoding failed: {message}")]
    Image { path: String, message: String },
    #[error(transparent)]
    Geometry(#[from] crate::geometry::GeometryError),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Preset {
    /// A few photos per epoch on a 120 m × 90 m area: for unit tests of other modules.
    Tiny,
    /// The demo block: ~300 m × 220 m, 18 reference photos.
    Small,
    /// ≈100 reference photos.
    Medium,
    /// ≈400 reference photos at 5 cm, ≥ 20 M LiDAR points.
    Large,
}

/// Quality of the approximate exterior orientation given with the archive epochs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PosQuality {
    /// Centre σ 1 m, attitude σ 0.5°.
    Good,
    /// Centre σ 10 m, attitude σ 3°.
    Rough,
    /// No POS: only each strip's first and last projection centre.
    None,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SynthConfig {
    pub preset: Preset,
    pub seed: u64,
    /// Fraction of the scene changed between the present and each archive epoch (0–1).
    pub change: f64,
    pub pos: PosQuality,
    /// Write LiDAR tiles as LAZ instead of LAS.
    pub laz: bool,
}

impl Default for SynthConfig {
    fn default() -> Self {
        Self {
            preset: Preset::Small,
            seed: 1,
            change: 0.5,
            pos: PosQuality::Rough,
            laz: false,
        }
    }
}

/// Sizes of a preset.
#[derive(Debug, Clone, Copy)]
pub(crate) struct PresetParams {
    pub area: [f64; 4],
    pub lidar_density: f64,
    pub tile_m: f64,
    pub frame_size: (u32, u32),
    pub frame_focal_px: f64,
    pub ref_gsd: f64,
    pub archive_gsd: f64,
    pub film_gsd: f64,
    pub film_scan_mm: f64,
    /// Least film flight: strips × photos per strip (a film frame covers kilometres, far
    /// more than the LiDAR area, so the block is planned by its layout, not the area).
    pub film_layout: (usize, usize),
}

impl Preset {
    pub(crate) fn params(self) -> PresetParams {
        let (area, density, tile, size, focal, ref_gsd) = match self {
            Preset::Tiny => (
                [-60.0, -45.0, 60.0, 45.0],
                6.0,
                100.0,
                (600, 400),
                720.0,
                0.15,
            ),
            Preset::Small => (
                [-150.0, -110.0, 150.0, 110.0],
                8.0,
                100.0,
                (1500, 1000),
                1800.0,
                0.1,
            ),
            Preset::Medium => (
                [-400.0, -300.0, 400.0, 300.0],
                8.0,
                250.0,
                (1500, 1000),
                1800.0,
                0.1,
            ),
            Preset::Large => (
                [-500.0, -850.0, 500.0, 850.0],
                14.0,
                500.0,
                (3000, 2000),
                3600.0,
                0.05,
            ),
        };
        // Film as archives hold it: a 153 mm camera scanned at 42 µm, 0.5 m ground pixel
        // (a 5.7k-pixel scan covering 2.7 km). The tiny preset keeps a coarse scan for
        // unit tests of other modules.
        let (archive_gsd, film_gsd, film_scan_mm) = match self {
            Preset::Tiny => (0.3, 0.6, 0.2),
            _ => (2.0 * f64::max(ref_gsd, 0.1), 0.5, 0.042),
        };
        let film_layout = match self {
            Preset::Tiny => (1, 2),
            Preset::Small => (2, 3),
            Preset::Medium => (4, 6),
            Preset::Large => (8, 10),
        };
        PresetParams {
            area,
            lidar_density: density,
            tile_m: tile,
            frame_size: size,
            frame_focal_px: focal,
            ref_gsd,
            archive_gsd,
            film_gsd,
            film_scan_mm,
            film_layout,
        }
    }
}

/// One file of the block with its size and SHA-256.
#[derive(Debug, Clone, Serialize)]
pub struct FileEntry {
    pub path: String,
    pub bytes: u64,
    pub sha256: String,
}

/// What a photo epoch contains (paths relative to the output folder).
#[derive(Debug, Clone, Serialize)]
pub struct EpochInfo {
    pub name: String,
    /// `frame` (digital) or `film` (scanned metric film).
    pub kind: String,
    pub date: String,
    pub gsd_m: f64,
    pub photos: Vec<String>,
    pub image_size: [u32; 2],
    pub images_dir: String,
    pub camera: String,
    /// `pos.csv`, or `strips.csv` when no POS is given.
    pub navigation: String,
    /// Change of the step from the next younger epoch (0 for the reference).
    pub scene_change: f64,
    pub truth_dir: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct LidarInfo {
    pub format: String,
    pub tiles: Vec<lidar::LidarTile>,
    pub points: u64,
    pub density_per_m2: f64,
    pub strips: usize,
}

/// Time and memory of a run (not part of the deterministic output: `run.json`).
#[derive(Debug, Clone, Default, Serialize)]
pub struct RunStats {
    pub stages: Vec<(String, f64)>,
    pub total_s: f64,
    /// Peak resident memory of the process (VmHWM), MiB.
    pub peak_memory_mib: f64,
    pub threads: usize,
}

/// `manifest.json`: everything a pipeline needs to find the inputs, plus the hash of each
/// file. Deterministic for a seed.
#[derive(Debug, Clone, Serialize)]
pub struct SynthManifest {
    pub format: String,
    pub generator: String,
    pub preset: Preset,
    pub seed: u64,
    pub change: f64,
    pub pos: PosQuality,
    pub crs: String,
    /// Block-local origin (world = local + origin).
    pub origin: [f64; 3],
    /// World bounds of the scene [xmin, ymin, xmax, ymax].
    pub area: [f64; 4],
    pub lidar: LidarInfo,
    pub checkpoints: String,
    pub checkpoint_count: usize,
    pub epochs: Vec<EpochInfo>,
    pub truth_dir: String,
    pub files: Vec<FileEntry>,
    #[serde(skip)]
    pub run: RunStats,
}

/// True when `dir` holds a finished block of `config` (the manifest is written last) with
/// its project file: the demo and the bench keep it instead of generating it again.
pub fn holds_block(dir: &Path, config: &SynthConfig) -> bool {
    let Ok(text) = std::fs::read_to_string(dir.join("manifest.json")) else {
        return false;
    };
    let Ok(m) = serde_json::from_str::<serde_json::Value>(&text) else {
        return false;
    };
    m["seed"].as_u64() == Some(config.seed)
        && serde_json::to_value(config.preset).ok().as_ref() == Some(&m["preset"])
        && serde_json::to_value(config.pos).ok().as_ref() == Some(&m["pos"])
        && m["change"].as_f64() == Some(config.change)
        && dir.join("project.toml").is_file()
}

/// Peak resident set size of this process in MiB (Linux; 0 elsewhere).
pub fn peak_memory_mib() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines().find(|l| l.starts_with("VmHWM:")).and_then(|l| {
                l.split_whitespace()
                    .nth(1)
                    .and_then(|v| v.parse::<f64>().ok())
            })
        })
        .map(|kb| kb / 1024.0)
        .unwrap_or(0.0)
}

fn sub_seed(seed: u64, stream: u64) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(stream);
    rng
}

/// The preset's scene extent (block-local [xmin, ymin, xmax, ymax]).
pub fn scene_extent(preset: Preset) -> [f64; 4] {
    preset.params().area
}

/// The LiDAR strips and points (block-local) that [`generate`] writes for `config`, with
/// `scene` = `Scene::generate(config.seed, scene_extent(config.preset))`.
pub fn simulate_lidar(
    config: &SynthConfig,
    scene: &Scene,
) -> (Vec<lidar::LidarStrip>, Vec<lidar::LidarPoint>) {
    let p = config.preset.params();
    let mut rng = sub_seed(config.seed, 1);
    lidar::simulate(scene, p.area, p.lidar_density, &mut rng)
}

/// Renders one 8-bit grey photo of `scene` (noise-free apart from sensor noise seeded by
/// `seed`), for tests that need an image of a known world without writing a block. The
/// height-bound grid covers the photo's footprint.
pub fn render_photo(
    scene: &Scene,
    camera: &crate::geometry::Camera,
    pose: &crate::geometry::Pose,
    seed: u64,
) -> Result<Vec<u8>, SynthError> {
    let (w, h) = camera.image_size();
    let (zlo, zhi) = scene.terrain_bounds();
    let top = scene.object_top().max(zhi) + 1.0;
    let mut bbox = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for (c, r) in [
        (0.0, 0.0),
        (w as f64, 0.0),
        (0.0, h as f64),
        (w as f64, h as f64),
    ] {
        let d = pose.direction_to_world(&camera.unproject([c, r])?);
        if d.z >= -1e-6 {
            return Err(SynthError::InvalidConfig(
                "the photo sees the horizon; render_photo needs a downward-looking camera".into(),
            ));
        }
        for z in [zlo - 5.0, top] {
            let t = (z - pose.center.z) / d.z;
            let (x, y) = (pose.center.x + t * d.x, pose.center.y + t * d.y);
            bbox = [
                bbox[0].min(x),
                bbox[1].min(y),
                bbox[2].max(x),
                bbox[3].max(y),
            ];
        }
    }
    let caster = RayCaster::new(
        scene,
        [bbox[0] - 5.0, bbox[1] - 5.0, bbox[2] + 5.0, bbox[3] + 5.0],
        1.0,
    );
    let radiance = render(&caster, camera, pose, 1, 0.4, &|_, _| true);
    Ok(film::finish_digital(&radiance, w, h, seed, 1.0, 8.0, 1.5))
}

/// The buildings of `scene` as `truth/epochs/<epoch>/buildings.csv` ([`truth::read_buildings`]):
/// which ones changed between two epochs is what the change detection is scored on.
fn write_buildings(scene: &Scene, origin: [f64; 3], path: &Path) -> Result<(), SynthError> {
    use std::fmt::Write;
    let mut csv = format!("{}\n", truth::BUILDINGS_HEADER);
    for b in &scene.buildings {
        let _ = writeln!(
            csv,
            "{},{:.3},{:.3},{:.3},{:.3},{:.6},{:.3},{:.3}",
            b.id,
            b.center[0] + origin[0],
            b.center[1] + origin[1],
            b.half[0],
            b.half[1],
            b.angle,
            b.base + origin[2],
            b.eave
        );
    }
    formats::write_bytes_atomically(path, csv.as_bytes())?;
    Ok(())
}

/// Generates a complete synthetic block into `out_dir`.
pub fn generate(config: &SynthConfig, out_dir: &Path) -> Result<SynthManifest, SynthError> {
    let start = Instant::now();
    if !(0.0..=1.0).contains(&config.change) || !config.change.is_finite() {
        return Err(SynthError::InvalidConfig(format!(
            "change must be a fraction in [0, 1], got {}",
            config.change
        )));
    }
    std::fs::create_dir_all(out_dir).map_err(|e| FormatError::io(out_dir, e))?;
    let p = config.preset.params();
    let mut stats = RunStats {
        threads: rayon::current_num_threads(),
        ..Default::default()
    };
    let mut lap = Instant::now();
    let mut stage = |stats: &mut RunStats, name: &str| {
        stats
            .stages
            .push((name.to_string(), lap.elapsed().as_secs_f64()));
        tracing::info!(
            stage = name,
            seconds = lap.elapsed().as_secs_f64(),
            "synth stage done"
        );
        lap = Instant::now();
    };

    let scene = Scene::generate(config.seed, p.area);
    let crs = Crs::from_epsg(CRS_EPSG)?;
    let wkt = crs.to_wkt()?;
    stage(&mut stats, "scene");

    // LiDAR of the present scene.
    let (strips, points) = simulate_lidar(config, &scene);
    let tiles = lidar::write_tiles(
        &points,
        ORIGIN,
        p.tile_m,
        &wkt,
        config.laz,
        &out_dir.join("lidar"),
        "lidar",
    )?;
    let area_m2 = (p.area[2] - p.area[0]) * (p.area[3] - p.area[1]);
    let lidar_info = LidarInfo {
        format: if config.laz { "laz" } else { "las" }.into(),
        points: points.len() as u64,
        density_per_m2: points.len() as f64 / area_m2,
        strips: strips.len(),
        tiles,
    };
    drop(points);
    checkpoints::write_lidar_truth(&strips, out_dir)?;
    stage(&mut stats, "lidar");

    let mut rng = sub_seed(config.seed, 2);
    checkpoints::write_checkpoints(&scene, out_dir, &mut rng)?;
    stage(&mut stats, "checkpoints");

    // The same present as an orthophoto with its surface model: the control of
    // `project_orthophoto.toml`, for owners without LiDAR or a reference flight.
    orthophoto::write(
        &scene,
        p.area,
        ORIGIN,
        p.archive_gsd,
        &crs,
        config.seed ^ 0x0127_0F07,
        &out_dir.join("orthophoto"),
    )?;
    stage(&mut stats, "orthophoto");

    let mut epochs = Vec::new();
    let mut cp_rows = Vec::new();
    let specs = epoch::specs(config, &p);
    // Epochs from the youngest back: each one's world is the younger one's, changed.
    let mut epoch_scene = scene.clone();
    for (k, spec) in specs.iter().enumerate() {
        if spec.change > 0.0 {
            epoch_scene = epoch_scene.changed(spec.change, 0xE90C + k as u64);
        }
        let mut rng = sub_seed(config.seed, 10 + k as u64);
        let (info, rows) =
            epoch::generate_epoch(spec, &epoch_scene, config, &p, out_dir, &mut rng)?;
        // The surface as it was in this epoch, at its ground pixel, over the block.
        orthophoto::write_surface(
            &epoch_scene,
            p.area,
            ORIGIN,
            spec.gsd,
            &crs,
            &out_dir.join(&info.truth_dir).join("dsm.tif"),
        )?;
        write_buildings(
            &epoch_scene,
            ORIGIN,
            &out_dir.join(&info.truth_dir).join("buildings.csv"),
        )?;
        epochs.push(info);
        cp_rows.extend(rows);
        stage(&mut stats, &spec.name);
    }
    checkpoints::write_image_truth(&cp_rows, out_dir)?;
    let project = project::project_toml(config.preset, &format!("EPSG:{CRS_EPSG}"), &epochs);
    formats::write_bytes_atomically(&out_dir.join("project.toml"), project.as_bytes())?;
    let project =
        project::orthophoto_project_toml(config.preset, &format!("EPSG:{CRS_EPSG}"), &epochs);
    formats::write_bytes_atomically(&out_dir.join("project_orthophoto.toml"), project.as_bytes())?;

    let mut manifest = SynthManifest {
        format: "cloudcontrol-synth/1".into(),
        generator: format!("cloudcontrol {}", crate::VERSION),
        preset: config.preset,
        seed: config.seed,
        change: config.change,
        pos: config.pos,
        crs: format!("EPSG:{CRS_EPSG}"),
        origin: ORIGIN,
        area: [
            p.area[0] + ORIGIN[0],
            p.area[1] + ORIGIN[1],
            p.area[2] + ORIGIN[0],
            p.area[3] + ORIGIN[1],
        ],
        lidar: lidar_info,
        checkpoints: "checkpoints.csv".into(),
        checkpoint_count: scene.targets.len(),
        epochs,
        truth_dir: "truth".into(),
        files: Vec::new(),
        run: RunStats::default(),
    };
    manifest.files = hash_tree(out_dir)?;
    let json = serde_json::to_vec_pretty(&manifest).expect("manifest serialises");
    formats::write_bytes_atomically(&out_dir.join("manifest.json"), &json)?;
    stage(&mut stats, "manifest");
    stats.total_s = start.elapsed().as_secs_f64();
    stats.peak_memory_mib = peak_memory_mib();
    let run = serde_json::json!({
        "preset": config.preset,
        "seed": config.seed,
        "stages_s": stats.stages.iter().map(|(n, t)| serde_json::json!({"stage": n, "seconds": t})).collect::<Vec<_>>(),
        "total_s": stats.total_s,
        "peak_memory_mib": stats.peak_memory_mib,
        "threads": stats.threads,
    });
    formats::write_bytes_atomically(
        &out_dir.join("run.json"),
        &serde_json::to_vec_pretty(&run).expect("run stats serialise"),
    )?;
    manifest.run = stats;
    Ok(manifest)
}

/// Every file under `dir` except `manifest.json` and `run.json`, sorted, with its SHA-256.
pub fn hash_tree(dir: &Path) -> Result<Vec<FileEntry>, SynthError> {
    let mut files = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).map_err(|e| FormatError::io(&d, e))? {
            let entry = entry.map_err(|e| FormatError::io(&d, e))?;
            let path = entry.path();
            if path.is_dir() {
                stack.push(path);
            } else {
                let rel = path
                    .strip_prefix(dir)
                    .unwrap_or(&path)
                    .to_string_lossy()
                    .replace('\\', "/");
                if rel == "manifest.json" || rel == "run.json" || rel.contains(".part-") {
                    continue;
                }
                let bytes = std::fs::read(&path).map_err(|e| FormatError::io(&path, e))?;
                files.push(FileEntry {
                    path: rel,
                    bytes: bytes.len() as u64,
                    sha256: format!("{:x}", Sha256::digest(&bytes)),
                });
            }
        }
    }
    files.sort_by(|a, b| a.path.cmp(&b.path));
    Ok(files)
}
