//! `cloudcontrol run`: seed 000's five steps over every epoch of a project, as restartable
//! stages under the project's output folder:
//!
//! 1. `sources` — LiDAR catalogue (CRS, density, dates), cleaning (noise, strip offsets),
//!    evaluation of the LiDAR against the surveyed checkpoints;
//! 2. `epoch-<reference>` — the reference epoch oriented against the LiDAR alone
//!    ([`crate::control::reference`]), or an existing oriented block taken as it is and
//!    checked against the LiDAR ([`crate::control::existing`]);
//! 3. `dcp-<epoch>` — each oriented epoch exported as Digital Control Photos;
//! 4. `epoch-<archive>` — each archive epoch, newest first, oriented from the DCPs of all
//!    newer epochs ([`crate::control::archive::orient_epoch`]);
//! 5. `outputs-<epoch>` — COLMAP model, BlocksExchange XML, orthophoto and DEM GeoTIFFs;
//!    `report` — JSON and HTML.
//!
//! A stage's inputs are the files it reads (earlier stages' folders included) and its
//! parameters, so a rerun skips every stage whose inputs are unchanged and redoes the rest.

use super::epoch_files::{epoch_report, load_block, read_json, save_epoch, write_json};
use super::ground::{control_dem, ControlGround};
use super::project::{Epoch, OrthoSurface, Project, ProjectError};
use super::report::{self, EpochReport, IcpIteration, OrthoPreview, Warning, WarningKind};
use super::stages::{resolved_path, Inputs, OutputFolder, Runner, StageError, WorkError};
use super::tasks::dcp::cut_chips;
use super::tasks::lidar::{clean_sources, LidarPlan};
use super::tasks::outputs::{OutputTasks, OutputsPlan};
use super::tasks::reference::ReferenceTasks;
use super::tasks::surface::{SurfaceTaskPlan, SurfaceTasks};
use super::tasks::{open_packages, EpochContext, EpochPlan, EpochTasks, Task, TaskMode};
use crate::block::Block;
use crate::control::archive::{self, ArchiveContext, ArchiveOptions};
use crate::control::checkpoints::{self, CheckpointEvaluation, EvaluationError};
use crate::control::cloud::CloudOptions;
use crate::control::dcp::{Accuracy, DcpPackage, EpochInfo};
use crate::control::epoch::{block_origin, EpochInput, Navigation, PhotoInput};
use crate::control::existing::{self, ExistingOptions};
use crate::control::export::{self, DcpExportOptions};
use crate::control::ortho_source::{orthophoto_dcp, OrthoControlOptions, OrthoSource};
use crate::control::reference::{self, ReferenceOptions};
use crate::control::rounds::InMemory;
use crate::formats::control_points;
use crate::formats::crs::{Crs, Transformer};
use crate::lidar::{self, Catalogue, ScanOptions, TileStore};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error(transparent)]
    Project(#[from] ProjectError),
    #[error(transparent)]
    Stage(#[from] StageError),
    /// The project's inputs, checked before any stage ([`super::validate`]).
    #[error(transparent)]
    Inputs(#[from] super::validate::InputProblems),
    #[error("stopped after stage {0} as asked")]
    Stopped(String),
    /// A planning run ([`TaskMode::Plan`]) reached a stage whose per-photo tasks have not
    /// all run: run them (anywhere the output folder is shared), then run again.
    #[error("stage {stage}: {} task(s) to run first", tasks.len())]
    Pending { stage: String, tasks: Vec<Task> },
}

/// What the run reports while it works (the CLI draws progress from it).
#[derive(Debug, Clone)]
pub enum Event {
    Start {
        stage: String,
        index: usize,
        total: usize,
    },
    Done {
        stage: String,
        skipped: bool,
        seconds: f64,
    },
}

/// The outcome of a run.
#[derive(Debug, Clone)]
pub struct RunSummary {
    pub output: PathBuf,
    pub report: report::Report,
    pub ran: Vec<String>,
    pub skipped: Vec<String>,
    /// Product files per epoch (COLMAP folder, XML, GeoTIFFs, DCP package).
    pub products: BTreeMap<String, Vec<PathBuf>>,
    /// Wall time of each stage of this run (s; a skipped stage's is the check's).
    pub stage_seconds: Vec<(String, f64)>,
    /// The epochs that oriented fewer photos than they have, with why: a partial run
    /// ([`super::partial`]); empty when every photo was oriented.
    pub partial: Vec<super::partial::PartialEpoch>,
}

impl RunSummary {
    /// The machine-readable outcome (CLI `--json`, C ABI, Python): output folder, stages
    /// run and skipped, products per epoch, the partial epochs, and the report.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "output": self.output,
            "ran": self.ran,
            "skipped": self.skipped,
            "products": self.products,
            "stage_seconds": self.stage_seconds,
            "partial": self.partial,
            "report": self.report,
        })
    }
}

/// `sources/origin.json`: the block-local origin shared by every epoch.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
struct Origin {
    origin: [f64; 3],
}

/// `sources/selection.json`: the LiDAR tiles the block needs.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct TileSelection {
    /// World plan extent [x_min, y_min, x_max, y_max] the photos can see.
    pub footprint: [f64; 4],
    pub tiles_total: usize,
    /// Indices into the catalogue of the tiles intersecting the footprint.
    pub selected: Vec<usize>,
}

/// Plan extent every photo of every epoch can see, from the navigation: the projection
/// centres' extent widened by each centre's height above the lowest LiDAR point times
/// `half_view` (tangent of the widest half field of view met in aerial cameras: 230 mm
/// film at 88 mm focal length reaches about 1.85 on the diagonal).
pub fn footprint(centres: &[[f64; 3]], ground_z: f64, half_view: f64) -> Option<[f64; 4]> {
    let mut fp = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for c in centres.iter().filter(|c| c.iter().all(|v| v.is_finite())) {
        let r = (c[2] - ground_z).abs() * half_view;
        fp = [
            fp[0].min(c[0] - r),
            fp[1].min(c[1] - r),
            fp[2].max(c[0] + r),
            fp[3].max(c[1] + r),
        ];
    }
    (fp[0] <= fp[2]).then_some(fp)
}

fn select_tiles(
    project: &Project,
    cat: &Catalogue,
) -> Result<([f64; 4], TileSelection), WorkError> {
    let mut centres = Vec::new();
    for e in project.epochs() {
        match &e.block {
            Some(b) => {
                let block = b.read()?;
                centres.extend(
                    block
                        .photos
                        .values()
                        .map(|p| -> [f64; 3] { block.to_world(&p.pose.center).into() }),
                );
            }
            None => {
                centres.extend(Navigation::load(e.pos.as_deref(), e.strips.as_deref())?.centres())
            }
        }
    }
    let fp = footprint(&centres, cat.bounds[2], 1.85).ok_or_else(|| {
        WorkError::Inconsistent("no projection centre in any POS or strip file".into())
    })?;
    let selected = cat.tiles_in(&lidar::Bbox::new(fp[0], fp[1], fp[2], fp[3]));
    if selected.is_empty() {
        return Err(WorkError::Inconsistent(format!(
            "no LiDAR tile lies under the photos (footprint {fp:?}, LiDAR bounds {:?}): wrong CRS or wrong tiles?",
            cat.bounds
        )));
    }
    Ok((
        fp,
        TileSelection {
            footprint: fp,
            tiles_total: cat.tiles.len(),
            selected,
        },
    ))
}

/// DCP export settings for an epoch: the same ground spacing of control points in every
/// epoch, and interest taken at roughly the film's scale (four reference pixels).
fn dcp_options(project: &Project, reference_gsd: f64, gsd: f64, epoch: &str) -> DcpExportOptions {
    let ratio = (gsd / reference_gsd).max(1.0);
    let t = &project.thresholds;
    DcpExportOptions {
        cloud: CloudOptions {
            interval_px: (t.control_interval_px / ratio).max(8.0),
            max_coplanarity: 0.02,
            ..CloudOptions::default()
        },
        chip_size: t.chip_size_px,
        source: format!("{epoch} oriented by cloudcontrol ({})", project.name),
        interest_level: (2 - ratio.log2().round() as i64).max(0) as usize,
        ..DcpExportOptions::default()
    }
}

pub(crate) fn archive_options(project: &Project, epoch: &Epoch) -> ArchiveOptions {
    let mut o = project.thresholds.archive_options();
    if let Some(sc) = &epoch.self_calibration {
        o.self_calibration = sc.clone();
        o.film_self_calibration = sc.clone();
    }
    o
}

/// Surveyed checkpoints converted to the project CRS, with the file of their image
/// measurements.
pub(crate) struct Checkpoints {
    pub(crate) surveyed: Vec<(String, [f64; 3])>,
    /// σ of each surveyed point (m): x, y, z, in the order of `surveyed`.
    pub(crate) sigma: Vec<[f64; 3]>,
    pub(crate) images: PathBuf,
}

pub(crate) fn read_checkpoints(project: &Project) -> Result<Option<Checkpoints>, WorkError> {
    let (Some(c), Some(i)) = (
        &project.control.checkpoints,
        &project.control.checkpoint_images,
    ) else {
        return Ok(None);
    };
    let points = control_points::read_points(c)?;
    let crs = Crs::parse(&project.crs)?;
    let source = match &project.control.checkpoints_crs {
        Some(d) => Crs::parse(d)?,
        None => crs.clone(),
    };
    let t = Transformer::new(&source, &crs)?;
    let surveyed: Vec<(String, [f64; 3])> = points
        .iter()
        .map(|p| Ok((p.id.clone(), t.transform_point(p.xyz)?)))
        .collect::<Result<_, crate::formats::FormatError>>()?;
    Ok(Some(Checkpoints {
        surveyed,
        sigma: points
            .iter()
            .map(|p| [p.sigma_xy, p.sigma_xy, p.sigma_z])
            .collect(),
        images: i.clone(),
    }))
}

/// The checkpoint evaluation of an epoch; too few rays is a result (NaN in the report),
/// a measurement in a photo the epoch does not have is an input error.
/// `left_out`: photos of the epoch the block does not hold.
pub(crate) fn evaluate(
    cps: &Option<Checkpoints>,
    block: &Block,
    epoch: &str,
    gsd_m: f64,
    left_out: &[&str],
) -> Result<Option<CheckpointEvaluation>, WorkError> {
    evaluate_noting(cps, block, epoch, gsd_m, left_out, &mut Vec::new())
}

/// [`evaluate`], the reason the checkpoints were not evaluated added to `notes` (the
/// epoch's warnings in the report).
fn evaluate_noting(
    cps: &Option<Checkpoints>,
    block: &Block,
    epoch: &str,
    gsd_m: f64,
    left_out: &[&str],
    notes: &mut Vec<Warning>,
) -> Result<Option<CheckpointEvaluation>, WorkError> {
    let Some(c) = cps else { return Ok(None) };
    let mut meas = control_points::read_checkpoint_measurements(&c.images, epoch)?;
    // A photo of the epoch that the block cannot hold (a scan that could not be read has
    // no interior orientation, so no camera) is not oriented: its measurements are left
    // out as any unoriented photo's, not taken for a misnamed photo.
    meas.retain(|m| {
        let key = crate::formats::pos::photo_key(&m.photo);
        !left_out
            .iter()
            .any(|n| crate::formats::pos::photo_key(n) == key)
    });
    if meas.is_empty() {
        notes.push(Warning::new(
            WarningKind::Checkpoints,
            "no checkpoint is measured in the epoch's photos (checkpoint_images): its accuracy is not checked",
        ));
        return Ok(None);
    }
    // An epoch that oriented no photo has no ground pixel either: a result, not an error
    // that would stop the run (the tiny preset's film epoch ended the run this way).
    if !block
        .photos
        .values()
        .any(|p| p.status == crate::block::PhotoStatus::Oriented)
    {
        tracing::warn!(epoch, "checkpoints not evaluated: no photo oriented");
        notes.push(Warning::new(
            WarningKind::Checkpoints,
            "checkpoints not evaluated: no photo oriented",
        ));
        return Ok(None);
    }
    match checkpoints::evaluate_checkpoints(block, &meas, &c.surveyed, gsd_m) {
        Ok(e) => Ok(Some(e)),
        Err(EvaluationError::TooFewRays) => {
            tracing::warn!(epoch, "checkpoints not evaluated: too few rays");
            notes.push(Warning::new(
                WarningKind::Checkpoints,
                "checkpoints not evaluated: no checkpoint is measured in two oriented photos",
            ));
            Ok(None)
        }
        Err(e) => Err(WorkError::Inconsistent(format!(
            "{}: epoch {epoch}: {e}",
            c.images.display()
        ))),
    }
}

/// What controlled an epoch, in words for the report.
fn control_of(
    project: &Project,
    e: &Epoch,
    is_reference: bool,
    dcp_dirs: &[PathBuf],
) -> Vec<String> {
    if let Some(b) = &e.block {
        let check = if b.lidar_check {
            if b.apply_lidar_offset {
                ", moved onto the LiDAR"
            } else {
                ", checked against the LiDAR"
            }
        } else {
            ""
        };
        return vec![format!("existing block {}{check}", b.path.display())];
    }
    if is_reference {
        return vec!["LiDAR (tie points by ICP and plane constraints)".into()];
    }
    dcp_dirs
        .iter()
        .map(|d| {
            let name = d.file_name().map(|n| n.to_string_lossy().into_owned());
            match name.as_deref().and_then(|n| n.strip_prefix("dcp-")) {
                Some("orthophoto") => format!(
                    "DCPs of the orthophoto {} with the DEM {}",
                    project
                        .control
                        .orthophoto
                        .as_deref()
                        .unwrap_or(Path::new(""))
                        .display(),
                    project
                        .control
                        .dem
                        .as_deref()
                        .unwrap_or(Path::new(""))
                        .display()
                ),
                Some(epoch) => format!("DCPs of epoch {epoch}"),
                None => d.display().to_string(),
            }
        })
        .collect()
}

/// The report's rows of an ICP onto the LiDAR.
fn icp_rows(iterations: &[lidar::IcpIteration]) -> Vec<IcpIteration> {
    iterations
        .iter()
        .map(|it| IcpIteration {
            iteration: it.iteration,
            rmse_m: it.rmse_m,
            inliers: it.correspondences,
        })
        .collect()
}

/// The reference adjustment tests its gross errors by Baarda's data snooping (its tie
/// points are many and precise; `reject_k` is the archive adjustments' k·σ0).
pub(crate) fn reference_options(project: &Project, epoch: &Epoch) -> ReferenceOptions {
    let mut o = ReferenceOptions::default();
    o.adjust.lidar_datum_sigma_m = Some([project.control.lidar_datum_sigma_m; 3]);
    if let Some(sc) = &epoch.self_calibration {
        o.self_calibration = sc.clone();
    }
    o
}

/// Runs a project. `stop_after` ends the run (as a kill would) once that stage finished;
/// tests use it to prove that a rerun completes. Per-photo tasks run in this process.
pub fn run_project(
    project: &Project,
    on_event: &mut dyn FnMut(&Event),
    stop_after: Option<&str>,
) -> Result<RunSummary, RunError> {
    run_project_with(project, on_event, stop_after, TaskMode::InProcess)
}

/// [`run_project`], its per-photo tasks run here or, with [`TaskMode::Plan`], left to the
/// caller: the run then ends at the first stage with unfinished tasks with
/// [`RunError::Pending`], and a run after they finished goes on from there.
pub fn run_project_with(
    project: &Project,
    on_event: &mut dyn FnMut(&Event),
    stop_after: Option<&str>,
    tasks: TaskMode,
) -> Result<RunSummary, RunError> {
    run_stages(project, on_event, stop_after, tasks).map_err(|e| match e {
        RunError::Stage(StageError::Failed { stage, source }) => match *source {
            WorkError::Pending(tasks) => RunError::Pending { stage, tasks },
            source => RunError::Stage(StageError::Failed {
                stage,
                source: Box::new(source),
            }),
        },
        e => e,
    })
}

/// Every input path of the project with its key (`control.lidar[0]`, `archive[1].pos`).
fn input_paths(project: &Project) -> Vec<(String, &Path)> {
    let c = &project.control;
    let mut out: Vec<(String, &Path)> = c
        .lidar
        .iter()
        .enumerate()
        .map(|(i, l)| (format!("control.lidar[{i}]"), l.as_path()))
        .collect();
    for (key, p) in [
        ("control.orthophoto", &c.orthophoto),
        ("control.dem", &c.dem),
        ("control.checkpoints", &c.checkpoints),
        ("control.checkpoint_images", &c.checkpoint_images),
    ] {
        if let Some(p) = p {
            out.push((key.into(), p));
        }
    }
    for (key, e) in project.keyed_epochs() {
        out.push((format!("{key}.photos"), &e.photos));
        for (k, p) in [
            ("camera", &e.camera),
            ("pos", &e.pos),
            ("strips", &e.strips),
        ] {
            if let Some(p) = p {
                out.push((format!("{key}.{k}"), p));
            }
        }
        if let Some(b) = &e.block {
            out.push((format!("{key}.block.path"), &b.path));
        }
    }
    out
}

/// Checks, changing nothing, that a run may write the project's `output`: the checks of
/// [`stages::check_output_folder`] (not `/`, the home folder or a file; missing, empty
/// or made by a run), and no input of the project is the output folder, lies in it or
/// holds it (a run's outputs would become its inputs, or sit among them). `run --check`
/// and every run make it before anything else.
pub fn check_output(project: &Project) -> Result<OutputFolder, RunError> {
    let out = &project.output;
    let state = super::stages::check_output_folder(out)?;
    let real = resolved_path(out);
    for (key, p) in input_paths(project) {
        let input = resolved_path(p);
        let how = if input == real {
            "is"
        } else if real.starts_with(&input) {
            "lies inside"
        } else if input.starts_with(&real) {
            "holds"
        } else {
            continue;
        };
        return Err(StageError::Output {
            path: out.clone(),
            message: format!(
                "output {how} the input {key} ({}): a run's outputs and the project's inputs \
                 must not share a folder; give an output of its own",
                p.display()
            ),
        }
        .into());
    }
    Ok(state)
}

fn run_stages(
    project: &Project,
    on_event: &mut dyn FnMut(&Event),
    stop_after: Option<&str>,
    task_mode: TaskMode,
) -> Result<RunSummary, RunError> {
    let out = &project.output;
    check_output(project)?;
    let mut runner = Runner::new(out)?;
    // Every input of every epoch and the checkpoint files, read and checked before the
    // first stage (a misspelt camera key, a photo without its POS row, a measurement of
    // an unknown checkpoint), all problems at once: not one by one after hours of work.
    // After the lock, so that a run held by another is told so first.
    super::validate::check_inputs(project)?;
    let epochs: Vec<&Epoch> = project.epochs().collect();
    let has_reference = project.reference.is_some();
    let o = &project.outputs;
    let want_outputs = o.colmap || o.blocks_exchange || o.orthophoto || o.dem;
    // Sources; the orthophoto's DCP; each epoch, and the DCP of each but the oldest; each
    // epoch's surface and change; the control's surfaces; each epoch's products; the
    // report.
    let n = epochs.len();
    let total = 1
        + usize::from(project.control.orthophoto.is_some())
        + n
        + n.saturating_sub(1)
        + n * (usize::from(o.dsm) + usize::from(o.dsm && o.change) + usize::from(want_outputs))
        + usize::from(o.dem)
        + 1;
    let mut index = 0;
    let mut products: BTreeMap<String, Vec<PathBuf>> = BTreeMap::new();
    let mut stage_seconds = Vec::new();

    // Each stage: announce, run (or skip), announce, maybe stop.
    macro_rules! stage {
        ($name:expr, $inputs:expr, $work:expr) => {
            stage!(@run stage, $name, $inputs, $work)
        };
        (keyed $name:expr, $inputs:expr, $work:expr) => {
            stage!(@run stage_keyed, $name, $inputs, $work)
        };
        (@run $method:ident, $name:expr, $inputs:expr, $work:expr) => {{
            let name: String = $name;
            index += 1;
            on_event(&Event::Start {
                stage: name.clone(),
                index,
                total,
            });
            let t = Instant::now();
            let skipped_before = runner.skipped.len();
            let dir = runner.$method(&name, &$inputs, $work)?;
            stage_seconds.push((name.clone(), t.elapsed().as_secs_f64()));
            on_event(&Event::Done {
                stage: name.clone(),
                skipped: runner.skipped.len() > skipped_before,
                seconds: t.elapsed().as_secs_f64(),
            });
            if stop_after == Some(name.as_str()) {
                return Err(RunError::Stopped(name));
            }
            dir
        }};
    }

    // 1. Control sources.
    let mut src_inputs = Inputs::new().param("crs", &project.crs);
    for l in &project.control.lidar {
        src_inputs = src_inputs.file(l);
    }
    let with_lidar = !project.control.lidar.is_empty();
    if !with_lidar {
        // The DEM then gives the origin.
        if let Some(d) = &project.control.dem {
            src_inputs = src_inputs
                .file(d)
                .param("dem_crs", &project.control.dem_crs);
        }
    }
    if let Some(c) = &project.control.checkpoints {
        src_inputs = src_inputs.file(c);
    }
    // The navigation decides which tiles the block needs.
    for e in project.epochs() {
        for f in [&e.pos, &e.strips].into_iter().flatten() {
            src_inputs = src_inputs.file(f);
        }
        if let Some(b) = &e.block {
            src_inputs = src_inputs.file(&b.path);
        }
    }
    let checkpoints = read_checkpoints(project).map_err(|source| StageError::Failed {
        stage: "sources".into(),
        source: Box::new(source),
    })?;
    let sources = stage!(keyed "sources".to_string(), src_inputs, |dir: &Path, key: &str| {
        if !with_lidar {
            // The block origin: the one rule, over the DEM.
            let dem = control_dem(project)?;
            let (x0, y0, x1, y1) = dem.extent();
            let origin = block_origin([[x0, y0], [x1, y1]]);
            return Ok(write_json(&dir.join("origin.json"), &Origin { origin })?);
        }
        // Tiles without a CRS are in the project's (a warning in the catalogue says so);
        // tiles with one must match it horizontally (the scan refuses them otherwise).
        let scan = ScanOptions {
            assume_crs: Some(project.crs.clone()),
        };
        let cat = Catalogue::scan(&project.control.lidar, &scan)?;
        cat.save(&dir.join("catalogue.json"))?;
        // Only the tiles under the photos are cleaned and used: the rest of a national
        // dataset never enters memory.
        let (footprint, selection) = select_tiles(project, &cat)?;
        write_json(&dir.join("selection.json"), &selection)?;
        let cat = Catalogue {
            tiles: selection
                .selected
                .iter()
                .map(|&i| cat.tiles[i].clone())
                .collect(),
            ..cat
        };
        tracing::info!(
            selected = cat.tiles.len(),
            of = selection.tiles_total,
            ?footprint,
            "LiDAR tiles under the photos"
        );
        let lidar_dir = dir.join("lidar");
        std::fs::create_dir_all(&lidar_dir)
            .map_err(|x| crate::formats::FormatError::io(&lidar_dir, x))?;
        // Per tile, as tasks (a Dask worker's, or this process's threads).
        let plan = LidarPlan {
            stride: lidar::clean::sample_stride(&cat, &lidar::clean::CleanOptions::default()),
            tiles: cat.tiles.clone(),
        };
        let mut clean = clean_sources(out, "sources", key, &plan, &lidar_dir, task_mode)?;
        // The stage is written in a temporary folder that is renamed when it is done: the
        // report names the cleaned tiles inside the stage folder, not where they were made,
        // and the input tiles relative to it (a project moved whole).
        for t in &mut clean.tiles {
            if let Ok(rel) = t.output.strip_prefix(dir) {
                t.output = rel.to_path_buf();
            }
            t.file = crate::formats::paths::relative_to(&t.file, dir);
        }
        write_json(&dir.join("clean.json"), &clean)?;
        if let Some(cps) = &checkpoints {
            let cleaned = Catalogue::scan(std::slice::from_ref(&lidar_dir), &scan)?;
            let mut store = TileStore::new(cleaned, 50_000_000);
            let rep = lidar::eval::evaluate_checkpoints_store(
                &mut store,
                &cps.surveyed,
                Some(&[2]),
                &lidar::CheckpointOptions::default(),
            )?;
            write_json(&dir.join("lidar_checkpoints.json"), &rep)?;
            let txt = dir.join("lidar_checkpoints.txt");
            std::fs::write(&txt, rep.to_text())
                .map_err(|x| crate::formats::FormatError::io(&txt, x))?;
        }
        // The block origin: the one rule, over the LiDAR under the photos.
        // (the selected tiles' own bounds: the catalogue's are those of every tile given)
        let origin = block_origin(cat.tiles.iter().map(|t| [t.bounds[0], t.bounds[1]]));
        Ok(write_json(&dir.join("origin.json"), &Origin { origin })?)
    });
    let origin = read_json::<Origin>(&sources.join("origin.json"))
        .map_err(|e| StageError::Failed {
            stage: "sources".into(),
            source: Box::new(e.into()),
        })?
        .origin;
    let lidar = ControlGround::new(project, &sources, origin);
    let cp_inputs = |i: Inputs| match &project.control.checkpoint_images {
        Some(p) => i.file(p),
        None => i,
    };

    // 2–4. Epochs in time order, each from the DCPs of the epochs before it (and of the
    // orthophoto with its DEM, the first package when given).
    let mut epoch_dirs: Vec<PathBuf> = Vec::new();
    let mut dcp_dirs: Vec<PathBuf> = Vec::new();
    let mut reference_gsd = f64::NAN;
    if let (Some(ortho), Some(dem)) = (&project.control.orthophoto, &project.control.dem) {
        let c = &project.control;
        let inputs = Inputs::new()
            .file(&sources)
            .file(ortho)
            .file(dem)
            .param("crs", &project.crs)
            .param("orthophoto_crs", &c.orthophoto_crs)
            .param("orthophoto_date", &c.orthophoto_date)
            .param("orthophoto_sigma_m", &c.orthophoto_sigma_m)
            .param("dem_crs", &c.dem_crs)
            .param("dem_sigma_m", &c.dem_sigma_m)
            .param("thresholds", &project.thresholds);
        let ddir = stage!("dcp-orthophoto".to_string(), inputs, |dir: &Path| {
            let src = OrthoSource {
                orthophoto: ortho,
                orthophoto_crs: c.orthophoto_crs.as_deref(),
                dem,
                dem_crs: c.dem_crs.as_deref(),
                epoch: EpochInfo {
                    name: "orthophoto".into(),
                    date: c.orthophoto_date.clone(),
                },
            };
            let opts = OrthoControlOptions {
                interval_px: project.thresholds.control_interval_px,
                chip_size: project.thresholds.chip_size_px,
                plan_sigma_m: c.orthophoto_sigma_m,
                dem_sigma_m: c.dem_sigma_m,
                ..OrthoControlOptions::default()
            };
            let (_, rep) = orthophoto_dcp(&src, &project.crs, &dir.join("package"), &opts)?;
            Ok(write_json(&dir.join("orthophoto.json"), &rep)?)
        });
        let pkg = DcpPackage::open(&ddir.join("package")).map_err(|e| StageError::Failed {
            stage: "dcp-orthophoto".into(),
            source: Box::new(e.into()),
        })?;
        // Without a reference epoch, the orthophoto's pixel is the scale archive epochs'
        // DCPs are taken relative to.
        if !has_reference {
            reference_gsd = pkg.manifest.gsd_m;
        }
        products
            .entry("orthophoto".into())
            .or_default()
            .push(ddir.join("package"));
        dcp_dirs.push(ddir);
    }
    for (k, e) in epochs.iter().enumerate() {
        // Every log line of the epoch's stages names it; at ERROR level, so that every
        // filter that lets a line through keeps its epoch (an INFO span is off at the
        // default WARN level).
        let _epoch = tracing::error_span!("epoch", name = %e.name).entered();
        let mut inputs = Inputs::new()
            .file(&sources)
            .file(&e.photos)
            .param("thresholds", &project.thresholds)
            .param("date", &e.date)
            .param("scan_pixel_um", &e.scan_pixel_mm())
            .param("self_calibration", &e.self_calibration);
        if let Some(c) = &e.camera {
            inputs = inputs.file(c);
        }
        if let Some(b) = &e.block {
            // The block's path enters as the file (hashed by its name and content), not as
            // a parameter: an absolute path there made a copied project redo the epoch.
            inputs = inputs
                .file(&b.path)
                .param("block_format", &b.format)
                .param("block_lidar_check", &b.lidar_check)
                .param("block_apply_lidar_offset", &b.apply_lidar_offset);
        }
        if k == 0 && has_reference {
            inputs = inputs.param("lidar_datum_sigma_m", &project.control.lidar_datum_sigma_m);
        }
        if let Some(p) = &e.pos {
            inputs = inputs.file(p);
        }
        if let Some(s) = &e.strips {
            inputs = inputs.file(s);
        }
        for d in &dcp_dirs {
            inputs = inputs.file(d);
        }
        let inputs = cp_inputs(inputs);
        let is_reference = has_reference && k == 0;
        let stage_name = format!("epoch-{}", e.name);
        let edir = stage!(keyed stage_name.clone(), inputs, |dir: &Path, key: &str| {
            let mut notes = Vec::new();
            let (mut result, icp) = if let Some(b) = &e.block {
                // An existing oriented block: taken as it is, checked against the LiDAR.
                let block = b.read()?;
                let photos = PhotoInput::from_folder(&e.photos)?;
                let opts = ExistingOptions {
                    lidar_check: b
                        .lidar_check
                        .then(|| ExistingOptions::default().lidar_check)
                        .flatten(),
                    apply_offset: b.apply_lidar_offset,
                };
                let planes = if b.lidar_check {
                    Some(lidar.planes()?)
                } else {
                    None
                };
                let (r, rep) = existing::existing_epoch(
                    &e.name,
                    Some(&e.date),
                    &b.path,
                    block,
                    &photos,
                    &project.crs,
                    origin,
                    planes,
                    &lidar.surface()?.ground,
                    &opts,
                )?;
                write_json(&dir.join("existing.json"), &rep)?;
                notes.extend(report::gather::existing_warnings(&rep));
                let icp = rep
                    .lidar
                    .as_ref()
                    .map(|c| icp_rows(&c.icp.iterations))
                    .unwrap_or_default();
                (r, icp)
            } else if is_reference {
                let input = EpochInput::build(&e.spec(), &project.crs, origin)?;
                let (planes, ground) = (lidar.planes()?, &lidar.surface()?.ground);
                let opts = reference_options(project, e);
                // The tie matching of its photo pairs: on this process's threads, or as
                // tasks of the stage for a planning run.
                let (r, rep) = match task_mode {
                    TaskMode::InProcess => {
                        reference::orient_reference(&input, planes, ground, &opts)?
                    }
                    TaskMode::Plan => {
                        let plan = EpochPlan {
                            project: project.clone(),
                            epoch: e.name.clone(),
                            sources: sources.clone(),
                            packages: Vec::new(),
                            origin,
                        };
                        let tasks = ReferenceTasks::new(out, &stage_name, key, &plan)?;
                        let r = reference::orient_reference_with(
                            &input, planes, ground, &opts, &tasks,
                        )?;
                        tasks.clear();
                        r
                    }
                };
                write_json(&dir.join("reference.json"), &rep)?;
                let icp = rep
                    .icp
                    .as_ref()
                    .map(|i| icp_rows(&i.iterations))
                    .unwrap_or_default();
                (r, icp)
            } else {
                let t0 = Instant::now();
                // The DCPs of every newer epoch, combined: the previous epoch's are the
                // closest in time and appearance, the reference's the most accurate.
                let plan = EpochPlan {
                    project: project.clone(),
                    epoch: e.name.clone(),
                    sources: sources.clone(),
                    packages: dcp_dirs.clone(),
                    origin,
                };
                let tasks = EpochTasks::new(out, &stage_name, key, &plan)?;
                let ctx = EpochContext {
                    input: EpochInput::build(&e.spec(), &project.crs, origin)?,
                    opts: archive_options(project, e),
                    surface: lidar.surface_arc()?.clone(),
                    packages: open_packages(&dcp_dirs)?,
                    plan,
                };
                let dem = &ctx.surface.ground;
                let archive = ArchiveContext::new(&ctx.input, &ctx.packages, dem, &ctx.opts)?;
                let first = tasks.first_pass(&ctx, &archive, task_mode)?;
                // The global passes' rounds: on this process's threads, or as tasks of
                // the stage for a planning run.
                let r = match task_mode {
                    TaskMode::InProcess => archive::finish_epoch(
                        &ctx.input, &archive, dem, &ctx.opts, first, t0, &InMemory,
                    )?,
                    TaskMode::Plan => {
                        let majority = first.scans.as_ref().and_then(|s| s.majority);
                        let rounds = tasks.rounds(&ctx, task_mode, majority);
                        archive::finish_epoch(
                            &ctx.input, &archive, dem, &ctx.opts, first, t0, &rounds,
                        )?
                    }
                };
                tasks.clear();
                (r, Vec::new())
            };
            let left_out: Vec<&str> = result
                .photos
                .iter()
                .map(|p| p.name.as_str())
                .filter(|n| !result.block.photos.values().any(|p| p.name == *n))
                .collect();
            let eval = evaluate_noting(
                &checkpoints,
                &result.block,
                &e.name,
                result.gsd_m,
                &left_out,
                &mut notes,
            )?;
            let surveyed = checkpoints.as_ref().map_or(&[][..], |c| &c.surveyed[..]);
            let mut rep = epoch_report(&result, &e.date, &eval, surveyed, icp);
            rep.control = control_of(project, e, is_reference, &dcp_dirs);
            rep.warnings.extend(notes);
            Ok(save_epoch(dir, &mut result, &rep, &eval)?)
        });
        let rep: EpochReport =
            read_json(&edir.join("epoch.json")).map_err(|x| StageError::Failed {
                stage: format!("epoch-{}", e.name),
                source: Box::new(x.into()),
            })?;
        if is_reference {
            reference_gsd = rep.gsd_m;
        }
        epoch_dirs.push(edir.clone());
        // The oldest epoch has no older one to control.
        if k + 1 == epochs.len() {
            break;
        }
        let dcp_stage = format!("dcp-{}", e.name);
        let ddir = stage!(
            keyed dcp_stage.clone(),
            Inputs::new()
                .file(&sources)
                .file(&edir)
                .param("thresholds", &project.thresholds),
            |dir: &Path, key: &str| {
                let block = load_block(&edir)?;
                // A control point is measured in two oriented photos at least: an epoch
                // with fewer gives no package, and the older epochs take the DCPs of the
                // other newer ones (one epoch does not stop the walk back in time).
                let oriented = block.photos.values().filter(|p| p.is_oriented()).count();
                if oriented < 2 {
                    tracing::warn!(
                        epoch = e.name,
                        oriented,
                        "no DCP package: fewer than two oriented photos"
                    );
                    return Ok(write_json(
                        &dir.join("skipped.json"),
                        &serde_json::json!({
                            "reason": format!("{oriented} oriented photo(s); a control point needs two")
                        }),
                    )?);
                }
                let mut opts = dcp_options(project, reference_gsd, rep.gsd_m, &e.name);
                // The package's stated accuracy: what the checkpoints showed, never
                // better than half a ground pixel.
                let floor = 0.5 * rep.gsd_m;
                opts.accuracy = Accuracy {
                    plan_m: if rep.check_rmse_plan_m.is_finite() {
                        rep.check_rmse_plan_m.max(floor)
                    } else {
                        rep.gsd_m
                    },
                    height_m: if rep.check_rmse_height_m.is_finite() {
                        rep.check_rmse_height_m.max(floor)
                    } else {
                        rep.gsd_m
                    },
                };
                let info = EpochInfo {
                    name: e.name.clone(),
                    date: Some(e.date.clone()),
                };
                let package = dir.join("package");
                let surface = lidar.surface()?;
                // The photos' chips: on this process's threads, or as tasks of the stage
                // for a planning run.
                match task_mode {
                    TaskMode::InProcess => {
                        export::export_dcp(&block, surface, info, &package, &opts)?;
                    }
                    TaskMode::Plan => {
                        export::export_dcp_with(
                            &block,
                            surface,
                            info,
                            &package,
                            &opts,
                            |plan, size| {
                                cut_chips(
                                    (out, &dcp_stage, key),
                                    &block,
                                    plan,
                                    size,
                                    task_mode,
                                    &package,
                                )
                            },
                        )?;
                    }
                }
                Ok(())
            }
        );
        if ddir.join("package").is_dir() {
            products
                .entry(e.name.clone())
                .or_default()
                .push(ddir.join("package"));
            dcp_dirs.push(ddir);
        }
    }

    // 5. Each epoch's own surface, searched around the control's surface model (before
    // the products: an orthophoto may be rectified onto it).
    let mut surface_dirs: Vec<Option<PathBuf>> = vec![None; epochs.len()];
    if o.dsm {
        let crs = Crs::parse(&project.crs).map_err(|e| StageError::Failed {
            stage: "surface".into(),
            source: Box::new(e.into()),
        })?;
        let prior = if with_lidar {
            "lidar_surface"
        } else {
            "control_dem"
        };
        for (k, e) in epochs.iter().enumerate() {
            let _epoch = tracing::error_span!("epoch", name = %e.name).entered();
            let edir = epoch_dirs[k].clone();
            let options = crate::dense::epoch::DsmOptions {
                grid_base_m: o.grid_base_m,
                ..Default::default()
            };
            let sdir = stage!(
                keyed format!("surface-{}", e.name),
                Inputs::new()
                    .file(&sources)
                    .file(&edir)
                    .param("dsm", &options)
                    .param("dsm_points", &o.dsm_points),
                |dir: &Path, key: &str| {
                    let stage = format!("surface-{}", e.name);
                    let plan = SurfaceTaskPlan {
                        project: project.clone(),
                        epoch: e.name.clone(),
                        sources: sources.clone(),
                        epoch_dir: edir.clone(),
                        origin: lidar.origin,
                        options: options.clone(),
                    };
                    let tasks = SurfaceTasks::new(out, &stage, key, &plan)?;
                    super::surface::write_epoch_surface(
                        &plan,
                        prior,
                        &crs,
                        dir,
                        (&tasks, task_mode),
                    )
                }
            );
            let dsm = sdir.join(crate::dense::products::DSM_FILE);
            surface_dirs[k] = Some(sdir.clone());
            if dsm.exists() {
                products.entry(e.name.clone()).or_default().push(dsm);
            }
        }
    }

    // 5b. Each epoch's surface against the control's (today) and the next younger epoch's.
    if o.dsm && o.change {
        let crs = Crs::parse(&project.crs).map_err(|e| StageError::Failed {
            stage: "change".into(),
            source: Box::new(e.into()),
        })?;
        let against = if with_lidar {
            "lidar_surface"
        } else {
            "control_dem"
        };
        let options = crate::change::ChangeOptions::default();
        for (k, e) in epochs.iter().enumerate() {
            let _epoch = tracing::error_span!("epoch", name = %e.name).entered();
            let Some(sdir) = surface_dirs[k].clone() else {
                continue;
            };
            let younger = k
                .checked_sub(1)
                .and_then(|j| Some((epochs[j].name.clone(), surface_dirs[j].clone()?)));
            let cdir = stage!(
                format!("change-{}", e.name),
                Inputs::new()
                    .file(&sources)
                    .file(&sdir)
                    .file_if(younger.as_ref().map(|y| y.1.as_path()))
                    .param("change", &options),
                |dir: &Path| {
                    super::change::write_epoch_change(
                        &e.name,
                        &sdir,
                        younger.as_ref().map(|(n, d)| (n.as_str(), d.as_path())),
                        (lidar.surface()?, against),
                        lidar.origin,
                        &crs,
                        &options,
                        dir,
                    )
                }
            );
            let dh = cdir.join(crate::change::compare::DH_FILE);
            if dh.exists() {
                products.entry(e.name.clone()).or_default().push(dh);
            }
        }
    }

    // 6. The control's surfaces, once for all epochs, then the products per epoch.
    if o.dem {
        let cdir = stage!(
            super::products::CONTROL_PRODUCTS.to_string(),
            Inputs::new()
                .file(&sources)
                .param("grid_base_m", &o.grid_base_m),
            |dir: &Path| super::products::write_control_surfaces(project, &lidar, dir)
        );
        let files = products
            .entry(super::products::CONTROL_PRODUCTS.to_string())
            .or_default();
        for f in super::products::CONTROL_FILES {
            if cdir.join(f).exists() {
                files.push(cdir.join(f));
            }
        }
    }
    let mut ortho_preview: Option<OrthoPreview> = None;
    if want_outputs {
        for (k, e) in epochs.iter().enumerate() {
            let _epoch = tracing::error_span!("epoch", name = %e.name).entered();
            let edir = epoch_dirs[k].clone();
            // The epoch's own surface, when its orthophoto is rectified onto it.
            let surface_dir = surface_dirs[k]
                .clone()
                .filter(|_| project.outputs.ortho_surface == OrthoSurface::Dsm);
            // The camera definition gives a film epoch's format (its frame images).
            let odir = stage!(
                keyed format!("outputs-{}", e.name),
                cp_inputs(
                    match &e.camera {
                        Some(c) => Inputs::new().file(c),
                        None => Inputs::new(),
                    }
                    .file(&sources)
                    .file(&edir)
                    .file_if(surface_dir.as_deref())
                    .param("outputs", &project.outputs)
                ),
                |dir: &Path, key: &str| {
                    let stage = format!("outputs-{}", e.name);
                    let plan = OutputsPlan {
                        project: project.clone(),
                        epoch: e.name.clone(),
                        sources: sources.clone(),
                        epoch_dir: edir.clone(),
                        origin: lidar.origin,
                        surface_dir: surface_dir.clone(),
                    };
                    let tasks = OutputTasks::new(out, &stage, key, &plan)?;
                    super::products::write_products(
                        project,
                        e,
                        checkpoints.as_ref(),
                        (&lidar, surface_dir.as_deref()),
                        lidar.origin,
                        &edir,
                        dir,
                        (&tasks, task_mode),
                    )
                }
            );
            let files = products.entry(e.name.clone()).or_default();
            for f in super::products::PRODUCT_FILES {
                if odir.join(f).exists() {
                    files.push(odir.join(f));
                }
            }
            if k == 0 && has_reference && odir.join("preview.png").exists() {
                let png = std::fs::read(odir.join("preview.png")).unwrap_or_default();
                let extent: Option<[f64; 4]> = read_json(&odir.join("preview.json")).ok();
                if let Some(extent) = extent {
                    ortho_preview = Some(OrthoPreview { png, extent });
                }
            }
        }
    }

    // Report.
    let folders = report::gather::RunFolders {
        sources: sources.clone(),
        epochs: epochs
            .iter()
            .zip(&epoch_dirs)
            .map(|(e, d)| report::gather::EpochFolders {
                name: e.name.clone(),
                epoch: d.clone(),
                dcp: runner.dir(&format!("dcp-{}", e.name)),
                outputs: runner.dir(&format!("outputs-{}", e.name)),
                change: runner.dir(&format!("change-{}", e.name)),
            })
            .collect(),
    };
    let rinputs = report::gather::report_inputs(project, &folders);
    let preview = ortho_preview.clone();
    let rdir = stage!("report".to_string(), rinputs, |dir: &Path| {
        let rep = report::gather::make_report(project, &folders, preview)?;
        if project.outputs.html_report {
            Ok(report::write(&rep, dir)?)
        } else {
            Ok(write_json(&dir.join("report.json"), &rep)?)
        }
    });
    let mut report: report::Report =
        read_json(&rdir.join("report.json")).map_err(|x| StageError::Failed {
            stage: "report".into(),
            source: Box::new(x.into()),
        })?;
    report.ortho = ortho_preview;
    Ok(RunSummary {
        output: out.clone(),
        report,
        ran: runner.ran.clone(),
        skipped: runner.skipped.clone(),
        products,
        stage_seconds,
        partial: super::partial::partial_epochs(&epoch_dirs).map_err(|x| StageError::Failed {
            stage: "report".into(),
            source: Box::new(x.into()),
        })?,
    })
}
