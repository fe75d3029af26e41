//! The products of a film epoch in fiducial-frame images: every oriented scan resampled
//! (`matching::fiducial::frame_image`) into `outputs-<epoch>/resampled/`, one scan at a
//! time, and the epoch's block rewritten for them — frame cameras instead of the scans'
//! film cameras, the frame images as the photos' images, every observation moved from
//! its scan into its frame. COLMAP, BlocksExchange and the orthophoto are then written
//! from that block, exactly (formats/workflow/README.md, "Resampled film scans").

use super::stages::WorkError;
use crate::block::{Block, BlockCamera, CameraId, PhotoId};
use crate::geometry::{Camera, FilmCamera, FrameCamera, InteriorOrientation};
use crate::matching::fiducial::{
    mean_scan_pixel_mm, write_frame_image, FiducialFrame, FrameImageReport,
};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Folder of the frame images in an epoch's products.
pub const RESAMPLED_DIR: &str = "resampled";

/// A film epoch moved into its frame images (made by [`to_frame_images`]).
#[derive(Debug, Clone)]
pub struct FilmFrames {
    /// The block with frame cameras (scans of one frame camera share it) and the frame
    /// images as its photos' images.
    pub block: Block,
    /// The frame's pixel size (mm) of each frame camera, for formats that state the
    /// focal length in mm (BlocksExchange `FocalLength` and `SensorSize`).
    pub pixel_mm: BTreeMap<CameraId, f64>,
    pub report: FramesReport,
}

/// `resampled/frames.json`: the frame and what was made of each scan.
#[derive(Debug, Clone, Serialize)]
pub struct FramesReport {
    /// Film format (mm) the frames are cropped to, from the camera definition.
    pub format_mm: [f64; 2],
    pub frame: FiducialFrame,
    /// `"given"` (the project's `outputs.film_pixel_um`) or `"mean scan pixel"`.
    pub pixel_source: String,
    /// Per photo id: the scan, the frame image (its file name in `resampled/`), the
    /// masked pixels and the resampling time.
    pub photos: BTreeMap<PhotoId, FrameImageReport>,
}

/// A film epoch's move into its frame images before any is made: the block for the frame
/// images ([`FilmFrames::block`]), and one job per scan, which can run anywhere.
#[derive(Debug, Clone)]
pub struct FramePlan {
    pub block: Block,
    pub pixel_mm: BTreeMap<CameraId, f64>,
    pub format_mm: [f64; 2],
    pub frame: FiducialFrame,
    pub pixel_source: String,
    /// In photo id order.
    pub jobs: Vec<FrameJob>,
}

/// One scan to resample into its frame image.
#[derive(Debug, Clone)]
pub struct FrameJob {
    pub photo: PhotoId,
    pub name: String,
    pub scan: PathBuf,
    pub interior: InteriorOrientation,
    /// The frame image to write.
    pub target: PathBuf,
}

/// Resamples every photo of `block` that has a film camera into `dir` (`<stem>.png`) and
/// returns the block for its frame images ([`plan_frames`], then each job).
pub fn to_frame_images(
    block: &Block,
    format_mm: [f64; 2],
    pixel_mm: Option<f64>,
    camera_name: &str,
    dir: &Path,
) -> Result<FilmFrames, WorkError> {
    let plan = plan_frames(block, format_mm, pixel_mm, camera_name, dir)?;
    let reports = plan
        .jobs
        .iter()
        .map(|j| j.resample(&plan.frame))
        .collect::<Result<Vec<_>, _>>()?;
    let report = plan.report(reports, dir);
    Ok(FilmFrames {
        block: plan.block,
        pixel_mm: plan.pixel_mm,
        report,
    })
}

/// The frame images of every photo of `block` that has a film camera, to be written into
/// `dir` (`<stem>.png`), and the block for them. `format_mm` is the camera definition's film
/// format; `pixel_mm` the frame's pixel size, by default [`mean_scan_pixel_mm`] of the
/// block's film photos. Frame cameras are named `camera_name`. Photos with frame cameras
/// pass unchanged.
pub fn plan_frames(
    block: &Block,
    format_mm: [f64; 2],
    pixel_mm: Option<f64>,
    camera_name: &str,
    dir: &Path,
) -> Result<FramePlan, WorkError> {
    let film_of = |c: &BlockCamera| match &c.model {
        Camera::Film(f) => Some(f.clone()),
        Camera::Frame(_) => None,
    };
    let films: BTreeMap<CameraId, FilmCamera> = block
        .cameras
        .values()
        .filter_map(|c| Some((c.id, film_of(c)?)))
        .collect();
    let used: Vec<&FilmCamera> = block
        .photos
        .values()
        .filter_map(|p| films.get(&p.camera))
        .collect();
    let (p, pixel_source) = match pixel_mm {
        Some(p) => (p, "given"),
        None => (
            mean_scan_pixel_mm(used.iter().map(|f| &f.interior)).ok_or_else(|| {
                WorkError::Inconsistent("no photo with a film camera to resample".into())
            })?,
            "mean scan pixel",
        ),
    };
    let frame =
        FiducialFrame::new(format_mm, p).map_err(|e| WorkError::Inconsistent(e.to_string()))?;

    // Frame cameras: scans of one calibration share one (the first camera id with it).
    let mut out = block.clone();
    let mut frame_cams: Vec<(CameraId, FrameCamera)> = Vec::new();
    let mut new_id: BTreeMap<CameraId, CameraId> = BTreeMap::new();
    for (&id, film) in &films {
        let fc = frame.frame_camera(film);
        let target = match frame_cams.iter().find(|(_, c)| *c == fc) {
            Some((k, _)) => *k,
            None => {
                frame_cams.push((id, fc));
                id
            }
        };
        new_id.insert(id, target);
    }
    for id in films.keys() {
        out.cameras.remove(id);
    }
    for (id, fc) in &frame_cams {
        out.cameras.insert(
            *id,
            BlockCamera {
                id: *id,
                name: camera_name.to_string(),
                model: Camera::Frame(fc.clone()),
                free_params: Vec::new(),
                calibration_group: None,
            },
        );
    }

    // Observations move from the scan into the frame; their σ scales with the pixel.
    let moved =
        |photo: PhotoId| -> Option<&FilmCamera> { films.get(&block.photos.get(&photo)?.camera) };
    for pt in out.points.values_mut() {
        for o in &mut pt.observations {
            if let Some(f) = moved(o.photo) {
                o.pixel = frame.scan_to_frame(&f.interior, o.pixel);
                o.sigma_px *= f.interior.mean_pixel_size_mm() / p;
            }
        }
    }
    for (photo, kps) in &mut out.keypoints {
        if let Some(f) = moved(*photo) {
            for k in kps.iter_mut() {
                *k = frame.scan_to_frame(&f.interior, *k);
            }
        }
    }

    // The scans, one at a time (each resampled with its rows in parallel): a scan of
    // 5714² px and its frame image are all that is in memory.
    // Each film photo's frame image: its target (the photo's image from here on) and
    // the job of making it.
    let mut jobs: Vec<FrameJob> = Vec::new();
    for ph in out.photos.values_mut() {
        let Some(film) = films.get(&ph.camera) else {
            continue;
        };
        let scan = ph.image.clone().ok_or_else(|| {
            WorkError::Inconsistent(format!("photo {} ({}): no scan file", ph.id, ph.name))
        })?;
        let stem = scan
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| ph.name.clone());
        let target = dir.join(format!("{stem}.png"));
        if jobs.iter().any(|j| j.target == target) {
            return Err(WorkError::Inconsistent(format!(
                "photo {} ({}): two scans named {stem} would write the same frame image",
                ph.id, ph.name
            )));
        }
        jobs.push(FrameJob {
            photo: ph.id,
            name: ph.name.clone(),
            scan,
            interior: film.interior.clone(),
            target: target.clone(),
        });
        ph.image = Some(target);
        ph.camera = new_id[&ph.camera];
    }
    let pixel_mm = frame_cams.iter().map(|(id, _)| (*id, p)).collect();
    Ok(FramePlan {
        block: out,
        pixel_mm,
        format_mm,
        frame,
        pixel_source: pixel_source.into(),
        jobs,
    })
}

impl FrameJob {
    /// Reads the scan, resamples it into its frame image and writes that (atomically).
    pub fn resample(&self, frame: &FiducialFrame) -> Result<FrameImageReport, WorkError> {
        if let Some(d) = self.target.parent() {
            std::fs::create_dir_all(d).map_err(|e| crate::formats::FormatError::io(d, e))?;
        }
        let mut rep =
            write_frame_image(&self.scan, &self.interior, frame, &self.target).map_err(|e| {
                WorkError::Inconsistent(format!("photo {} ({}): {e}", self.photo, self.name))
            })?;
        tracing::info!(
            photo = self.name,
            seconds = rep.seconds,
            masked = rep.masked_pixels,
            "scan resampled into its fiducial frame"
        );
        // The report names the frame image by its file name: the stage folder is renamed.
        rep.image = rep.image.file_name().map(Into::into).unwrap_or_default();
        Ok(rep)
    }
}

impl FramePlan {
    /// The report of the frame images, from each job's report in job order, to be written
    /// into `folder`: it names each scan relative to that folder, so that a project moved
    /// whole still finds them.
    pub fn report(
        &self,
        photos: impl IntoIterator<Item = FrameImageReport>,
        folder: &Path,
    ) -> FramesReport {
        let named = photos.into_iter().map(|mut r| {
            r.scan = crate::formats::paths::relative_to(&r.scan, folder);
            r
        });
        FramesReport {
            format_mm: self.format_mm,
            frame: self.frame,
            pixel_source: self.pixel_source.clone(),
            photos: self.jobs.iter().map(|j| j.photo).zip(named).collect(),
        }
    }
}
