//! The LiDAR tiles of the `sources` stage as tasks: `screen` (a tile's noise points and
//! its share of the strip sample, [`screen_tile`]) for every tile, then the one global
//! step, the strip offsets from all samples (written once to `strip_offsets.msgpack`), then
//! `clean` (the tile rewritten, [`rewrite_tile`]) for every tile. A cleaned tile is
//! written into the task folder (`lidar/<file name>`) and moved into the stage folder
//! when every tile is done.

use super::{
    bad_task_file, has_item, not_of, read_msgpack, read_result, write_msgpack, write_result,
    StageTasks, Task, TaskData, TaskKind, TaskMode, TaskSummary,
};
use crate::control::task_checks as c;
use crate::formats::FormatError;
use crate::lidar::catalogue::TileEntry;
use crate::lidar::clean::{
    rewrite_tile, screen_tile, strip_offsets, CleanOptions, CleanReport, StripOffsetReport,
    TileCleanReport, TileScreen,
};
use crate::pipeline::stages::WorkError;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What every tile task of the stage shares (`plan.json`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LidarPlan {
    /// The tiles to clean (the catalogue's entries of the tiles under the photos), in
    /// order: a task's index is its tile's here.
    pub tiles: Vec<TileEntry>,
    /// Every `stride`-th usable point of a tile enters the strip sample.
    pub stride: usize,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct ScreenResult {
    tile: String,
    screen: TileScreen,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct CleanResult {
    tile: String,
    report: TileCleanReport,
}

has_item!(ScreenResult => tile, CleanResult => tile);

/// Largest strip offset a task file may give (m): strips are matched where their points
/// lie within metres of each other's planes, so an offset of more is no offset found
/// (formats/workflow/README.md, "Tasks").
pub const MAX_STRIP_OFFSET_M: f64 = 100.0;

impl TaskData for ScreenResult {
    fn check(&self) -> Result<(), String> {
        let s = &self.screen;
        if let Some(w) = s.noise.windows(2).find(|w| w[0] >= w[1]) {
            return Err(format!(
                "noise point indices are not ascending ({} before {})",
                w[0], w[1]
            ));
        }
        if s.sample_src.len() != s.sample_xyz.len() {
            return Err(format!(
                "{} strip ids for {} sample points",
                s.sample_src.len(),
                s.sample_xyz.len()
            ));
        }
        for p in &s.sample_xyz {
            c::finite("sample point", p)?;
        }
        if let Some(o) = &s.outliers {
            c::at_most("outliers removed", o.removed, o.points)?;
            for (what, v) in [
                ("outliers n_sigma", o.n_sigma),
                ("outliers mean_distance_m", o.mean_distance_m),
                ("outliers std_distance_m", o.std_distance_m),
                ("outliers threshold_m", o.threshold_m),
            ] {
                c::sigma(what, v)?;
            }
        }
        Ok(())
    }
}

impl TaskData for CleanResult {
    fn check(&self) -> Result<(), String> {
        let r = &self.report;
        c::at_most("noise points", r.noise as usize, r.points as usize)?;
        c::at_most("points written", r.written as usize, r.points as usize)
    }
}

impl TaskData for Option<StripOffsetReport> {
    fn check(&self) -> Result<(), String> {
        let Some(r) = self else { return Ok(()) };
        let mut seen = std::collections::BTreeSet::new();
        for s in &r.strips {
            if !seen.insert(s.source_id) {
                return Err(format!("strip {} has two offsets", s.source_id));
            }
            c::finite(&format!("strip {} offset_m", s.source_id), &s.offset_m)?;
            if let Some(v) = s.offset_m.iter().find(|v| v.abs() > MAX_STRIP_OFFSET_M) {
                return Err(format!(
                    "strip {} offset_m {v} is beyond {MAX_STRIP_OFFSET_M} m",
                    s.source_id
                ));
            }
            for v in s.sigma_m {
                c::sigma(&format!("strip {} sigma_m", s.source_id), v)?;
            }
        }
        for p in &r.pairs {
            for (what, v) in [
                ("median_distance_m", p.median_distance_m),
                ("rms_after_m", p.rms_after_m),
            ] {
                if v.is_infinite() {
                    return Err(format!("strip pair {}–{} {what} = {v}", p.a, p.b));
                }
            }
        }
        c::sigma("sigma0_m", r.sigma0_m)
    }
}

/// A tile's screen against the tile it is of: its noise indices are points of the tile.
fn check_screen(task: &Task, tile: &TileEntry, screen: &TileScreen) -> Result<(), WorkError> {
    match screen.noise.last() {
        Some(&i) if i >= tile.point_count => Err(bad_task_file(
            &task.result(),
            format!(
                "noise point {i} of tile {}, which has {} points",
                task.item, tile.point_count
            ),
        )),
        _ => Ok(()),
    }
}

const OFFSETS: &str = "strip_offsets.msgpack";
const CLEANED: &str = "lidar";

fn tile_name(t: &TileEntry) -> String {
    t.file
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// Cleans the plan's tiles into `lidar_dir` through the stage's tasks (run here, or
/// returned as pending in `mode` Plan), and returns the cleaning report.
pub(crate) fn clean_sources(
    output: &Path,
    stage: &str,
    key: &str,
    plan: &LidarPlan,
    lidar_dir: &Path,
    mode: TaskMode,
) -> Result<CleanReport, WorkError> {
    let opts = CleanOptions::default();
    let st = StageTasks::new(output, stage, key, plan)?;
    let names: Vec<String> = plan.tiles.iter().map(tile_name).collect();
    let screens = st.tasks(TaskKind::Screen, names.iter().map(String::as_str), None);
    st.ensure(&screens, mode, |t| execute(t, plan))?;
    let screened = screens
        .iter()
        .zip(&plan.tiles)
        .map(|(t, tile)| {
            let r = read_result::<ScreenResult>(t)?;
            check_screen(t, tile, &r.screen)?;
            Ok(r.screen)
        })
        .collect::<Result<Vec<_>, WorkError>>()?;
    let offsets_file = st.folder().join(OFFSETS);
    if !offsets_file.is_file() {
        let offsets = strip_offsets(&screened, &opts)?;
        write_msgpack(&offsets_file, &offsets)?;
    }
    let offsets = read_offsets(&offsets_file)?;
    let cleans = st.tasks(TaskKind::Clean, names.iter().map(String::as_str), None);
    // A result whose tile has gone (moved by a stage that did not finish) is run again.
    for t in &cleans {
        if t.result().is_file() && !cleaned_file(t).is_file() {
            let _ = std::fs::remove_file(t.result());
        }
    }
    st.ensure(&cleans, mode, |t| execute(t, plan))?;
    let mut tiles = Vec::with_capacity(cleans.len());
    for (t, s) in cleans.iter().zip(screened) {
        let mut r = read_result::<CleanResult>(t)?.report;
        let to = lidar_dir.join(&t.item);
        let from = cleaned_file(t);
        std::fs::rename(&from, &to).map_err(|e| FormatError::io(&from, e))?;
        r.output = to;
        r.outliers = s.outliers;
        tiles.push(r);
    }
    st.clear();
    Ok(CleanReport {
        strip_offsets: offsets,
        tiles,
    })
}

/// The strip offsets the stage found (`strip_offsets.msgpack`).
pub(super) fn read_offsets(path: &Path) -> Result<Option<StripOffsetReport>, WorkError> {
    read_msgpack(path)
}

/// A `screen` or `clean` result file read as the stage reads it ([`super::read_task_file`]).
pub(super) fn read_result_file(kind: TaskKind, path: &Path) -> Result<(), WorkError> {
    match kind {
        TaskKind::Screen => read_msgpack::<ScreenResult>(path).map(drop),
        _ => read_msgpack::<CleanResult>(path).map(drop),
    }
}

fn cleaned_file(task: &Task) -> PathBuf {
    task.folder.join(CLEANED).join(&task.item)
}

fn execute(task: &Task, plan: &LidarPlan) -> Result<TaskSummary, WorkError> {
    let t0 = Instant::now();
    let tile = plan
        .tiles
        .get(task.index)
        .filter(|t| tile_name(t) == task.item)
        .ok_or_else(|| {
            WorkError::Inconsistent(format!(
                "task {}: tile {} is not tile {} of the plan",
                task.name(),
                task.item,
                task.index
            ))
        })?;
    let opts = CleanOptions::default();
    match task.kind {
        TaskKind::Screen => {
            let screen = screen_tile(&tile.file, plan.stride, &opts)?;
            write_result(
                task,
                &ScreenResult {
                    tile: task.item.clone(),
                    screen,
                },
            )?;
        }
        TaskKind::Clean => {
            let screen_task = Task {
                kind: TaskKind::Screen,
                ..task.clone()
            };
            let own: ScreenResult = read_result(&screen_task)?;
            check_screen(&screen_task, tile, &own.screen)?;
            let offsets = read_offsets(&task.folder.join(OFFSETS))?;
            let out = cleaned_file(task);
            if let Some(dir) = out.parent() {
                std::fs::create_dir_all(dir).map_err(|e| FormatError::io(dir, e))?;
            }
            let report = rewrite_tile(tile, &out, &own.screen.noise, offsets.as_ref(), &opts)?;
            write_result(
                task,
                &CleanResult {
                    tile: task.item.clone(),
                    report,
                },
            )?;
        }
        _ => return Err(not_of(task, "the LiDAR tiles")),
    }
    Ok(TaskSummary::done(task, t0))
}

/// Runs one task of the `sources` stage (see [`super::run_task`]).
pub(super) fn run_task(task: &Task) -> Result<TaskSummary, WorkError> {
    let plan: LidarPlan = crate::pipeline::epoch_files::read_json(&task.folder.join("plan.json"))?;
    execute(task, &plan)
}
