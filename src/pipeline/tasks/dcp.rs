//! The DCP export of an epoch (`dcp-<epoch>` stage) as tasks: `chips`, one photo's chips
//! cut and PNG-encoded. The selection of the control points before and the package
//! written from the chips after are the stage's global parts.

use super::{
    bad_task_file, has_item, read_result, write_result, ContextCache, StageTasks, Task, TaskData,
    TaskKind, TaskMode, TaskSummary,
};
use crate::block::Block;
use crate::control::cloud::{CutChip, ExportPlan, PhotoChips};
use crate::control::epoch::input_err;
use crate::control::export::cut_photo_chips;
use crate::pipeline::stages::WorkError;
use serde::{Deserialize, Serialize};
use serde_bytes::ByteBuf;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What every `chips` task of a DCP stage shares (`plan.json`): per photo of the export
/// plan, its image and the chips wanted from it; the chip side.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct DcpPlan {
    pub photos: Vec<(PathBuf, PhotoChips)>,
    pub chip_size: u32,
}

/// A `chips` task's result: the photo's chips (PNG bytes), or why its image could not
/// give them.
#[derive(Serialize, Deserialize)]
struct ChipsResult {
    photo: String,
    chips: Result<Vec<CutChip<ByteBuf>>, String>,
}

has_item!(ChipsResult => photo);

impl TaskData for ChipsResult {
    fn check(&self) -> Result<(), String> {
        // What each chip is of is checked against the plan where it is at hand
        // ([`check_chips`]).
        for c in self.chips.iter().flatten() {
            crate::control::task_checks::finite("chip pixel", &c.meas.pixel)?;
        }
        Ok(())
    }
}

/// A photo's chips against what the plan wanted of it: each chip one of its wanted
/// measurements, with the file name, photo, pixel and size the export gives it (a chip's
/// file is written into the package under that name).
fn check_chips(job: &PhotoChips, chip_size: u32, chips: &[CutChip<ByteBuf>]) -> Result<(), String> {
    for c in chips {
        let Some(&(_, _, id, pixel)) = job
            .wanted
            .iter()
            .find(|w| (w.0, w.1) == (c.point, c.measurement))
        else {
            return Err(format!(
                "a chip of point {} measurement {}, which photo {} was not asked for",
                c.point, c.measurement, job.photo
            ));
        };
        let file = format!("chips/{id}_{}.png", job.photo);
        let m = &c.meas;
        if c.file != file
            || m.chip.file != file
            || m.photo != job.photo
            || m.pixel != pixel
            || (m.chip.width, m.chip.height) != (chip_size, chip_size)
        {
            return Err(format!(
                "chip {:?} of point {} measurement {} is not the chip {file} the plan asked for",
                c.file, c.point, c.measurement
            ));
        }
    }
    Ok(())
}

/// A `chips` result file read as the stage reads it ([`super::read_task_file`]).
pub(super) fn read_result_file(path: &Path) -> Result<(), WorkError> {
    super::read_msgpack::<ChipsResult>(path).map(drop)
}

/// Every photo's chips of `plan` (in its photo order), from the `chips` tasks of stage
/// `stage` under output folder `output` (inputs fingerprint `key`): run here, or returned
/// as pending. A photo whose image cannot be read fails the export, naming the photo.
pub(crate) fn cut_chips(
    (output, stage, key): (&Path, &str, &str),
    block: &Block,
    plan: &ExportPlan,
    chip_size: u32,
    mode: TaskMode,
    package: &Path,
) -> Result<Vec<Vec<CutChip<Vec<u8>>>>, WorkError> {
    let mut photos = Vec::with_capacity(plan.photos.len());
    let mut names = Vec::with_capacity(plan.photos.len());
    for job in &plan.photos {
        let p = block.photos.get(&job.photo);
        let image = p
            .and_then(|p| p.image.clone())
            .ok_or_else(|| input_err(package, format!("no image for photo {}", job.photo)))?;
        names.push(p.map(|p| p.name.clone()).unwrap_or_default());
        photos.push((image, job.clone()));
    }
    let dcp = DcpPlan { photos, chip_size };
    let st = StageTasks::new(output, stage, key, &dcp)?;
    let tasks = st.tasks(TaskKind::Chips, names.iter().map(String::as_str), None);
    st.ensure(&tasks, mode, |t| execute(t, &dcp))?;
    let mut cuts = Vec::with_capacity(tasks.len());
    for (t, (_, job)) in tasks.iter().zip(&dcp.photos) {
        let r: ChipsResult = read_result(t)?;
        let chips = r
            .chips
            .map_err(|e| input_err(package, format!("photo {}: {e}", r.photo)))?;
        check_chips(job, chip_size, &chips).map_err(|e| bad_task_file(&t.result(), e))?;
        cuts.push(
            chips
                .into_iter()
                .map(|c| convert(c, ByteBuf::into_vec))
                .collect(),
        );
    }
    st.clear();
    Ok(cuts)
}

/// A chip with its bytes in another container.
fn convert<T, U>(c: CutChip<T>, f: impl FnOnce(T) -> U) -> CutChip<U> {
    let Ok(c) = c.map(|b| Ok::<_, std::convert::Infallible>(f(b)));
    c
}

fn execute(task: &Task, plan: &DcpPlan) -> Result<TaskSummary, WorkError> {
    let t0 = Instant::now();
    let (image, job) = plan.photos.get(task.index).ok_or_else(|| {
        WorkError::Inconsistent(format!(
            "task {}: the export plan has {} photos",
            task.name(),
            plan.photos.len()
        ))
    })?;
    let chips = cut_photo_chips(image, job, plan.chip_size)
        .map(|v| v.into_iter().map(|c| convert(c, ByteBuf::from)).collect());
    let reason = chips.as_ref().err().cloned();
    write_result(
        task,
        &ChipsResult {
            photo: task.item.clone(),
            chips,
        },
    )?;
    Ok(TaskSummary {
        ok: reason.is_none(),
        reason,
        ..TaskSummary::done(task, t0)
    })
}

static CONTEXT: ContextCache<DcpPlan> = ContextCache::new();

/// Runs one `chips` task (see [`super::run_task`]).
pub(super) fn run_task(task: &Task) -> Result<TaskSummary, WorkError> {
    let plan = CONTEXT.get(task, |p: DcpPlan, _| Ok(p))?;
    execute(task, &plan)
}
