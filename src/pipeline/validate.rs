//! Checking a project's inputs before any work: every epoch's photo folder, camera file
//! and POS or strip file (through [`EpochInput::build`], the one reader of an epoch), an
//! existing block's file, every photo's image size against its camera (headers only), the
//! checkpoint files, their CRS, and every checkpoint measurement's point and photo.
//! Every problem is collected, not only the first, so that one `run --check` lists all
//! that must be fixed before a run that may take hours; `run` makes the same check before
//! its first stage (formats/project/README.md, "What is checked before work starts").

use super::project::{Epoch, Project};
use crate::control::checkpoints::check_measured_points;
use crate::control::epoch::{json_key_line, EpochCamera, EpochError, EpochInput, PhotoInput};
use crate::formats::control_points::{read_all_checkpoint_measurements, read_points};
use crate::formats::crs::{Crs, Transformer};
use crate::formats::image_open::image_size;
use crate::formats::input::{read_text, Cap};
use crate::formats::pos::photo_key;
use crate::formats::FormatError;
use serde::Serialize;
use std::collections::{BTreeMap, BTreeSet};
use std::fmt;
use std::path::{Path, PathBuf};

/// One problem of an input: the file (and line, when the file has lines and the reader
/// knows it), the project key that names the file, and what is wrong.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Problem {
    pub file: PathBuf,
    pub line: Option<usize>,
    pub key: Option<String>,
    pub message: String,
}

impl fmt::Display for Problem {
    /// `file:line: message (key)`, or `file: message (key)` without a line.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file.display())?;
        if let Some(l) = self.line {
            write!(f, ":{l}")?;
        }
        write!(f, ": {}", self.message)?;
        if let Some(k) = &self.key {
            write!(f, " (key {k})")?;
        }
        Ok(())
    }
}

/// Every problem [`check_inputs`] found, in the order of the project file (epochs, then
/// the checkpoints); its message lists them one per line.
#[derive(Debug, Clone, thiserror::Error)]
#[error("{}", listing(.problems))]
pub struct InputProblems {
    pub problems: Vec<Problem>,
}

fn listing(problems: &[Problem]) -> String {
    let mut s = format!(
        "{} problem(s) in the project's inputs, found before any work (nothing was run):",
        problems.len()
    );
    for p in problems {
        s.push('\n');
        s.push_str(&p.to_string());
    }
    s
}

/// Reads and checks every input of every epoch and the checkpoint files, changing
/// nothing, and returns every problem found. The project itself (its keys, paths, CRS and
/// thresholds) is checked by [`Project::load`]; the output folder by
/// [`super::run::check_output`]; LiDAR tiles, the orthophoto and the DEM are read by the
/// stages that use them.
pub fn check_inputs(project: &Project) -> Result<(), InputProblems> {
    let mut problems = Vec::new();
    // Each epoch's photo keys, when its photo folder could be read.
    let mut photos: BTreeMap<String, Option<BTreeSet<String>>> = BTreeMap::new();
    for (key, e) in project.keyed_epochs() {
        let names = if e.block.is_some() {
            check_block_epoch(&key, e, &mut problems)
        } else {
            check_epoch(project, &key, e, &mut problems)
        };
        photos.insert(e.name.clone(), names);
    }
    check_checkpoints(project, &photos, &mut problems);
    if problems.is_empty() {
        Ok(())
    } else {
        Err(InputProblems { problems })
    }
}

/// A problem from a reader's error: its file and line where the error has them, else
/// `fallback`.
fn from_format(e: FormatError, key: &str, fallback: &Path) -> Problem {
    let key = Some(key.to_string());
    match e {
        FormatError::Csv {
            path,
            line,
            column,
            message,
        } => Problem {
            file: path,
            line: Some(line),
            key,
            message: match column {
                Some(c) => format!("column {c}: {message}"),
                None => message,
            },
        },
        FormatError::Io { ref path, .. }
        | FormatError::Invalid { ref path, .. }
        | FormatError::NotRegularFile { ref path, .. }
        | FormatError::TooLarge { ref path, .. } => Problem {
            file: path.clone(),
            line: None,
            key,
            message: e.detail(),
        },
        FormatError::Gdal { path, message } => Problem {
            file: path,
            line: None,
            key,
            message: format!("GDAL: {message}"),
        },
        e => Problem {
            file: fallback.to_path_buf(),
            line: None,
            key,
            message: e.to_string(),
        },
    }
}

/// A problem from an epoch's error, keyed by the file it names (`archive[0].camera`).
fn from_epoch(e: EpochError, key: &str, epoch: &Epoch) -> Problem {
    let file_key = |path: &Path| {
        let k = [
            ("camera", epoch.camera.as_deref()),
            ("pos", epoch.pos.as_deref()),
            ("strips", epoch.strips.as_deref()),
            ("photos", Some(epoch.photos.as_path())),
        ]
        .into_iter()
        .find(|(_, p)| *p == Some(path))
        .map(|(k, _)| k);
        match k {
            Some(k) => format!("{key}.{k}"),
            None if path.starts_with(&epoch.photos) => format!("{key}.photos"),
            None => key.to_string(),
        }
    };
    match e {
        EpochError::Input { path, message } => Problem {
            key: Some(file_key(&path)),
            file: path,
            line: None,
            message,
        },
        EpochError::Format(f) => {
            let path = match &f {
                FormatError::Csv { path, .. }
                | FormatError::Io { path, .. }
                | FormatError::Invalid { path, .. }
                | FormatError::NotRegularFile { path, .. }
                | FormatError::TooLarge { path, .. }
                | FormatError::Gdal { path, .. } => path.clone(),
                _ => epoch.photos.clone(),
            };
            from_format(f, &file_key(&path), &epoch.photos)
        }
        e => Problem {
            file: epoch
                .pos
                .clone()
                .or_else(|| epoch.strips.clone())
                .unwrap_or_else(|| epoch.photos.clone()),
            line: None,
            key: Some(key.to_string()),
            message: e.to_string(),
        },
    }
}

/// The photo keys of a folder, when it can be read (its problem is reported elsewhere).
fn folder_keys(photos: &[PhotoInput]) -> BTreeSet<String> {
    photos.iter().map(|p| p.name.clone()).collect()
}

/// An epoch to orient: its input built as the run builds it, then every photo's image
/// header against the camera. Returns the epoch's photo keys when its folder was read.
fn check_epoch(
    project: &Project,
    key: &str,
    e: &Epoch,
    problems: &mut Vec<Problem>,
) -> Option<BTreeSet<String>> {
    let input = match EpochInput::build(&e.spec(), &project.crs, [0.0; 3]) {
        Ok(i) => i,
        Err(err) => {
            problems.push(from_epoch(err, key, e));
            // The photo names still tell whether a checkpoint measurement names a photo.
            return PhotoInput::from_folder(&e.photos)
                .ok()
                .map(|p| folder_keys(&p));
        }
    };
    // A frame camera has one image size, every photo's header must give it. Film scans
    // differ from scan to scan (the fiducial interior orientation maps each). A photo
    // that cannot be read is the run's to report, as a photo it could not orient (the run
    // ends partial, naming it): one bad file does not stop an epoch.
    let mut other_size: BTreeMap<(u32, u32), Vec<&PhotoInput>> = BTreeMap::new();
    if let EpochCamera::Frame(f) = &input.camera {
        for p in &input.photos {
            if let Ok(size) = image_size(&p.image) {
                if size != (f.width, f.height) {
                    other_size.entry(size).or_default().push(p)
                }
            }
        }
    }
    let camera_size = match &input.camera {
        EpochCamera::Frame(f) => Some((f.width, f.height)),
        EpochCamera::Film(_) => None,
    };
    if let (Some((cw, ch)), Some(camera)) = (camera_size, e.camera.as_deref()) {
        let line = read_text(camera, Cap::camera())
            .ok()
            .and_then(|t| json_key_line(&t, "width"));
        for ((w, h), photos) in other_size {
            let more = match photos.len() {
                1 => String::new(),
                n => format!(" (and {} more photo(s) of the epoch)", n - 1),
            };
            problems.push(Problem {
                file: camera.to_path_buf(),
                line,
                key: Some(format!("{key}.camera")),
                message: format!(
                    "the camera is {cw}×{ch} px, and image {} is {w}×{h} px{more}: give \
                     the camera of these photos (epoch {})",
                    photos[0].image.display(),
                    e.name
                ),
            });
        }
    }
    Some(folder_keys(&input.photos))
}

/// An existing block given as the epoch: its file read, its photo folder read, and at
/// least one of its photos with an image there (as the run requires). Returns the photo
/// keys of the folder and of the block.
fn check_block_epoch(
    key: &str,
    e: &Epoch,
    problems: &mut Vec<Problem>,
) -> Option<BTreeSet<String>> {
    let b = e.block.as_ref()?;
    let folder = match PhotoInput::from_folder(&e.photos) {
        Ok(p) => Some(folder_keys(&p)),
        Err(err) => {
            problems.push(from_epoch(err, key, e));
            None
        }
    };
    let block_key = format!("{key}.block.path");
    let block = match b.read() {
        Ok(block) => block,
        Err(err) => {
            problems.push(from_format(err, &block_key, &b.path));
            return folder;
        }
    };
    let in_block: BTreeSet<String> = block
        .photos
        .values()
        .map(|p| photo_key(&p.name).to_string())
        .collect();
    let problem = |message: String| Problem {
        file: b.path.clone(),
        line: None,
        key: Some(block_key.clone()),
        message,
    };
    if in_block.is_empty() {
        problems.push(problem("the block holds no photo".into()));
    } else if let Some(f) = &folder {
        if in_block.is_disjoint(f) {
            problems.push(problem(format!(
                "none of the block's {} photos has an image in {} (photos are matched by \
                 file name or stem)",
                in_block.len(),
                e.photos.display()
            )));
        }
    }
    Some(
        folder
            .unwrap_or_default()
            .union(&in_block)
            .cloned()
            .collect(),
    )
}

/// The line of `control.checkpoints_crs` in the project file.
fn checkpoints_crs_line(project_file: &Path) -> Option<usize> {
    #[derive(serde::Deserialize)]
    struct Doc {
        control: Option<Control>,
    }
    #[derive(serde::Deserialize)]
    struct Control {
        checkpoints_crs: Option<toml::Spanned<toml::Value>>,
    }
    let text = read_text(project_file, Cap::project()).ok()?;
    let doc: Doc = toml::from_str(&text).ok()?;
    let start = doc.control?.checkpoints_crs?.span().start;
    Some(text.get(..start)?.matches('\n').count() + 1)
}

/// The surveyed checkpoints (read, their CRS known and convertible to the project's) and
/// the measurements (read; each of a surveyed point, in a photo of its epoch).
fn check_checkpoints(
    project: &Project,
    photos: &BTreeMap<String, Option<BTreeSet<String>>>,
    problems: &mut Vec<Problem>,
) {
    let c = &project.control;
    let Some(file) = &c.checkpoints else { return };
    let points = match read_points(file) {
        Ok(p) => Some(p),
        Err(e) => {
            problems.push(from_format(e, "control.checkpoints", file));
            None
        }
    };
    let project_file = project
        .file
        .clone()
        .unwrap_or_else(|| PathBuf::from("project"));
    let crs_problem = |message: String| Problem {
        file: project_file.clone(),
        line: checkpoints_crs_line(&project_file),
        key: Some("control.checkpoints_crs".into()),
        message,
    };
    let target = Crs::parse(&project.crs).ok();
    let source = match &c.checkpoints_crs {
        Some(d) => match Crs::parse(d) {
            Ok(s) => Some(s),
            Err(e) => {
                problems.push(crs_problem(format!("{e} (the CRS of {})", file.display())));
                None
            }
        },
        None => target.clone(),
    };
    if let (Some(points), Some(source), Some(target)) = (&points, &source, &target) {
        match Transformer::new(source, target) {
            Err(e) => problems.push(crs_problem(format!(
                "{e}: the checkpoints cannot be converted to the project CRS"
            ))),
            Ok(t) => {
                if let Some((p, e)) = points
                    .iter()
                    .find_map(|p| t.transform_point(p.xyz).err().map(|e| (p, e)))
                {
                    problems.push(Problem {
                        file: file.clone(),
                        line: None,
                        key: Some("control.checkpoints".into()),
                        message: format!(
                            "checkpoint {}: not convertible to the project CRS: {e}",
                            p.id
                        ),
                    });
                }
            }
        }
    }
    let Some(images) = &c.checkpoint_images else {
        return;
    };
    let key = "control.checkpoint_images";
    let rows = match read_all_checkpoint_measurements(images) {
        Ok(r) => r,
        Err(e) => {
            problems.push(from_format(e, key, images));
            return;
        }
    };
    let surveyed: Option<Vec<(String, [f64; 3])>> = points
        .as_ref()
        .map(|p| p.iter().map(|p| (p.id.clone(), p.xyz)).collect());
    for (epoch, m) in rows {
        if let Some(surveyed) = &surveyed {
            if let Err(e) = check_measured_points(images, std::slice::from_ref(&m), surveyed) {
                problems.push(from_format(e, key, images));
            }
        }
        // A row of an epoch the project does not have is another project's (one file
        // may serve several projects of a block); in an epoch of this one it must name
        // one of its photos.
        if let Some(Some(names)) = photos.get(&epoch) {
            if !names.contains(photo_key(&m.photo)) {
                problems.push(Problem {
                    file: images.clone(),
                    line: Some(m.line),
                    key: Some(key.into()),
                    message: format!(
                        "column photo: {:?} is not a photo of epoch {epoch} (photos are \
                         matched by file name or stem)",
                        m.photo
                    ),
                });
            }
        }
    }
}
