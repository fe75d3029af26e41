//! A [`Block`] as a COLMAP model folder: the POINTS2D layout of every image, the frame
//! cameras, COLMAP's ERROR column, each model file in the chosen encoding, and the side
//! file.

use super::records::{qt_from_pose, Cameras, ImageRow, Points2d, PointsTable};
use super::{binary, side_file, text, Encoding, Layout, WriteOptions, INVALID_POINT3D};
use crate::block::{Block, CameraId, ObjectPoint, PhotoId};
use crate::formats::{create_folders, frame_equivalent, write_atomically, FormatError, Result};
use crate::geometry::Camera;
use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

/// Where each observation sits in its image's POINTS2D list, in point iteration order.
struct Layout2d {
    /// Per photo: (pixel, point id) in POINTS2D order (observations, then free keypoints).
    per_photo: BTreeMap<PhotoId, Points2d>,
    /// Flat over all observations of all points in `block.points` order: the POINT2D_IDX.
    idx: Vec<u32>,
}

fn layout_2d(block: &Block) -> Result<Layout2d> {
    let mut per_photo: BTreeMap<PhotoId, Points2d> =
        block.photos.keys().map(|&k| (k, Vec::new())).collect();
    let mut idx = Vec::with_capacity(block.num_observations());
    for p in block.points.values() {
        if p.id == INVALID_POINT3D {
            return Err(FormatError::invalid(
                "block",
                format!("point id {} is COLMAP's invalid id", p.id),
            ));
        }
        for o in &p.observations {
            let list = per_photo.get_mut(&o.photo).ok_or_else(|| {
                FormatError::invalid(
                    "block",
                    format!("point {} is observed in unknown photo {}", p.id, o.photo),
                )
            })?;
            idx.push(list.len() as u32);
            list.push((o.pixel, p.id));
        }
    }
    for (photo, kps) in &block.keypoints {
        if let Some(list) = per_photo.get_mut(photo) {
            list.extend(kps.iter().map(|&xy| (xy, INVALID_POINT3D)));
        }
    }
    Ok(Layout2d { per_photo, idx })
}

/// Frame cameras of the block (film cameras converted when their scan is an exact scale).
fn colmap_cameras(block: &Block) -> Result<Cameras> {
    block
        .cameras
        .values()
        .map(|c| {
            frame_equivalent(&c.model)
                .map(|f| (c.id, f))
                .map_err(|m| FormatError::invalid("block", format!("camera {}: {m}", c.id)))
        })
        .collect()
}

/// Mean reprojection error of a point over its observations (COLMAP's ERROR column).
fn mean_error(p: &ObjectPoint, block: &Block, models: &BTreeMap<CameraId, Camera>) -> f64 {
    let mut sum = 0.0;
    let mut n = 0usize;
    for o in &p.observations {
        let Some(ph) = block.photos.get(&o.photo) else {
            continue;
        };
        let Some(cam) = models.get(&ph.camera) else {
            continue;
        };
        if let Ok(px) = cam.project(&ph.pose.to_camera(&p.position)) {
            sum += ((px.x - o.pixel[0]).powi(2) + (px.y - o.pixel[1]).powi(2)).sqrt();
            n += 1;
        }
    }
    if n == 0 {
        -1.0
    } else {
        sum / n as f64
    }
}

/// Writes one model file atomically through a buffered writer; I/O errors name `path`.
/// Like every output, it is renamed into place without an fsync: the rename keeps a
/// crashed run from leaving a half-written file, and an fsync per file cost 2.5–4.5 ms
/// each (15 ms of a 50-photo adjustment's 0.2 s, the COLMAP files alone having them).
fn write_file(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<File>) -> std::io::Result<()>,
) -> Result<()> {
    write_atomically(path, |tmp| {
        let mut w = File::create(tmp)
            .map(|f| BufWriter::with_capacity(1 << 20, f))
            .map_err(|e| FormatError::io(tmp, e))?;
        write(&mut w).map_err(|e| FormatError::io(path, e))?;
        w.into_inner()
            .map(drop)
            .map_err(|e| FormatError::io(path, e.into_error()))
    })
}

/// Writes the block as a COLMAP model folder, plus the side file.
pub fn write(dir: &Path, block: &Block, opts: &WriteOptions) -> Result<()> {
    block
        .validate()
        .map_err(|e| FormatError::invalid(dir, format!("block is inconsistent: {e}")))?;
    let cams = colmap_cameras(block).map_err(|e| match e {
        FormatError::Invalid { message, .. } => FormatError::invalid(dir, message),
        e => e,
    })?;
    let models: BTreeMap<CameraId, Camera> = cams
        .iter()
        .map(|(&k, c)| (k, Camera::Frame(c.clone())))
        .collect();
    let l2d = layout_2d(block).map_err(|e| match e {
        FormatError::Invalid { message, .. } => FormatError::invalid(dir, message),
        e => e,
    })?;
    let text = opts.encoding == Encoding::Text;
    if text {
        if let Some(p) = block
            .photos
            .values()
            .find(|p| p.name.chars().any(char::is_whitespace) || p.name.is_empty())
        {
            return Err(FormatError::invalid(
                dir,
                format!(
                    "photo {} has the name {:?}, which COLMAP's text format cannot hold \
                     (empty or with whitespace); write binary instead",
                    p.id, p.name
                ),
            ));
        }
    }
    // Everything is checked: only now is the folder made (and removed again, with what
    // was written into it, if writing fails).
    let created = create_folders(dir)?;
    let result = write_model(dir, block, opts, &cams, &models, &l2d);
    if result.is_err() {
        created.undo(true);
    }
    result
}

fn write_model(
    dir: &Path,
    block: &Block,
    opts: &WriteOptions,
    cams: &Cameras,
    models: &BTreeMap<CameraId, Camera>,
    l2d: &Layout2d,
) -> Result<()> {
    let text = opts.encoding == Encoding::Text;
    let ext = if text { "txt" } else { "bin" };
    let file = |stem: &str| dir.join(format!("{stem}.{ext}"));

    write_file(&file("cameras"), |w| match opts.encoding {
        Encoding::Text => text::write_cameras(w, cams),
        Encoding::Binary => binary::write_cameras(w, cams),
    })?;
    let images: Vec<ImageRow> = block
        .photos
        .iter()
        .map(|(id, ph)| {
            let (q, t) = qt_from_pose(&ph.pose);
            ImageRow {
                id: *id,
                q,
                t,
                camera: ph.camera,
                name: &ph.name,
                points2d: &l2d.per_photo[id],
            }
        })
        .collect();
    write_file(&file("images"), |w| match opts.encoding {
        Encoding::Text => text::write_images(w, &images),
        Encoding::Binary => binary::write_images(w, &images),
    })?;
    // COLMAP's ERROR column: recomputed from the block, in parallel (deterministic: one
    // value per point, collected in order).
    let points: Vec<&ObjectPoint> = block.points.values().collect();
    let errors: Vec<f64> = {
        use rayon::prelude::*;
        points
            .par_iter()
            .map(|p| mean_error(p, block, models))
            .collect()
    };
    let table = PointsTable {
        points,
        errors,
        idx: &l2d.idx,
    };
    write_file(&file("points3D"), |w| match opts.encoding {
        Encoding::Text => text::write_points(w, &table),
        Encoding::Binary => binary::write_points(w, &table),
    })?;

    let stale = |stem: &str| {
        // A leftover rigs/frames of another layout or encoding would override our images.
        for e in ["bin", "txt"] {
            let p = dir.join(format!("{stem}.{e}"));
            if p.exists() && (opts.layout == Layout::Legacy || e != ext) {
                std::fs::remove_file(&p).map_err(|e| FormatError::io(&p, e))?;
            }
        }
        Ok::<(), FormatError>(())
    };
    stale("rigs")?;
    stale("frames")?;
    for stem in ["cameras", "images", "points3D"] {
        let other = dir.join(format!("{stem}.{}", if text { "bin" } else { "txt" }));
        if text && other.exists() {
            // COLMAP prefers .bin; a stale binary would shadow the text model we wrote.
            std::fs::remove_file(&other).map_err(|e| FormatError::io(&other, e))?;
        }
    }
    // One trivial rig per camera (the camera its only, reference sensor) and one frame per
    // photo in its camera's rig: rig_from_world = cam_from_world.
    if opts.layout == Layout::Rigs {
        write_file(&file("rigs"), |w| match opts.encoding {
            Encoding::Text => text::write_rigs(w, cams),
            Encoding::Binary => binary::write_rigs(w, cams),
        })?;
        write_file(&file("frames"), |w| match opts.encoding {
            Encoding::Text => text::write_frames(w, &images),
            Encoding::Binary => binary::write_frames(w, &images),
        })?;
    }
    side_file::write(dir, block)?;
    tracing::info!(
        dir = %dir.display(),
        images = block.photos.len(),
        points = block.points.len(),
        "wrote COLMAP model"
    );
    Ok(())
}
