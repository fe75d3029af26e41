//! A [`Block`] from a COLMAP model folder: cameras, images (posed through their frame and
//! rig in the 5-file layout), 3-D points with their tracks, and the side file.

use super::records::compose;
use super::{binary, side_file, text, Encoding, DEFAULT_SIGMA_PX, INVALID_POINT3D};
use crate::block::{Block, BlockCamera, ObjectPoint, Observation, Photo, PhotoId, PointKind};
use crate::formats::{FormatError, Result};
use crate::geometry::{Camera, Pose};
use nalgebra::Vector3;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// The file `stem.bin` or `stem.txt` of the model, binary first as COLMAP reads.
fn find_file(dir: &Path, stem: &str) -> Option<(PathBuf, Encoding)> {
    let bin = dir.join(format!("{stem}.bin"));
    if bin.is_file() {
        return Some((bin, Encoding::Binary));
    }
    let txt = dir.join(format!("{stem}.txt"));
    txt.is_file().then_some((txt, Encoding::Text))
}

/// Reads a COLMAP model folder (binary preferred over text when both exist, as COLMAP
/// does), with its side file when present.
pub fn read(dir: &Path) -> Result<Block> {
    if !dir.is_dir() {
        return Err(FormatError::invalid(dir, "is not a COLMAP model folder"));
    }
    let need = |stem: &str| {
        find_file(dir, stem).ok_or_else(|| {
            FormatError::invalid(
                dir,
                format!("COLMAP model is missing {stem}.bin / {stem}.txt"),
            )
        })
    };
    let (cam_path, cam_enc) = need("cameras")?;
    let (img_path, img_enc) = need("images")?;
    let (pts_path, pts_enc) = need("points3D")?;
    let mut block = Block::new();

    let cameras = match cam_enc {
        Encoding::Binary => binary::read_cameras(&cam_path)?,
        Encoding::Text => text::read_cameras(&cam_path)?,
    };
    for (id, cam) in cameras {
        block.cameras.insert(
            id,
            BlockCamera {
                id,
                name: format!("camera {id}"),
                model: Camera::Frame(cam),
                free_params: Vec::new(),
                calibration_group: None,
            },
        );
    }

    let mut images = match img_enc {
        Encoding::Binary => binary::read_images(&img_path)?,
        Encoding::Text => text::read_images(&img_path)?,
    };

    // COLMAP 4.x: the pose of record is the frame's rig_from_world composed with the
    // sensor's sensor_from_rig; the copy in `images` is ignored on read, as COLMAP does.
    if let (Some((rig_path, rig_enc)), Some((frm_path, frm_enc))) =
        (find_file(dir, "rigs"), find_file(dir, "frames"))
    {
        let rigs = match rig_enc {
            Encoding::Binary => binary::read_rigs(&rig_path)?,
            Encoding::Text => text::read_rigs(&rig_path)?,
        };
        let frames = match frm_enc {
            Encoding::Binary => binary::read_frames(&frm_path)?,
            Encoding::Text => text::read_frames(&frm_path)?,
        };
        let mut posed: HashMap<PhotoId, Pose> = HashMap::new();
        for (frame_id, rig_id, rig_from_world, data) in frames {
            let rig = rigs.get(&rig_id).ok_or_else(|| {
                FormatError::invalid(
                    &frm_path,
                    format!("frame {frame_id} refers to unknown rig {rig_id}"),
                )
            })?;
            for (sensor_type, sensor_id, data_id) in data {
                if sensor_type != 0 {
                    continue;
                }
                let sensor_from_rig = rig.get(&sensor_id).ok_or_else(|| {
                    FormatError::invalid(
                        &frm_path,
                        format!("frame {frame_id}: camera {sensor_id} is not in rig {rig_id}"),
                    )
                })?;
                let pose = match sensor_from_rig {
                    None => rig_from_world,
                    Some(s) => compose(s, &rig_from_world),
                };
                posed.insert(data_id as PhotoId, pose);
            }
        }
        for im in images.iter_mut() {
            im.pose = *posed.get(&im.id).ok_or_else(|| {
                FormatError::invalid(
                    &frm_path,
                    format!("image {} ({}) belongs to no frame", im.id, im.name),
                )
            })?;
        }
    }

    let mut index: HashMap<PhotoId, usize> = HashMap::with_capacity(images.len());
    for (i, im) in images.iter().enumerate() {
        if !block.cameras.contains_key(&im.camera) {
            return Err(FormatError::invalid(
                &img_path,
                format!(
                    "image {} ({}) refers to unknown camera {}",
                    im.id, im.name, im.camera
                ),
            ));
        }
        if index.insert(im.id, i).is_some() {
            return Err(FormatError::invalid(
                &img_path,
                format!("image id {} appears twice", im.id),
            ));
        }
    }

    let mut points: Vec<ObjectPoint> = Vec::new();
    let mut sink = |id: u64,
                    xyz: [f64; 3],
                    rgb: [u8; 3],
                    track: &[(u32, u32)]|
     -> std::result::Result<(), String> {
        let mut observations = Vec::with_capacity(track.len());
        for &(image_id, idx) in track {
            let im = index
                .get(&image_id)
                .map(|&i| &images[i])
                .ok_or_else(|| format!("point {id}: track refers to unknown image {image_id}"))?;
            let (xy, _) = im.points2d.get(idx as usize).ok_or_else(|| {
                format!(
                    "point {id}: track refers to 2-D point {idx} of image {image_id}, which has {}",
                    im.points2d.len()
                )
            })?;
            observations.push(Observation {
                photo: image_id,
                pixel: *xy,
                sigma_px: DEFAULT_SIGMA_PX,
                provenance: String::new(),
            });
        }
        if xyz.iter().any(|v| !v.is_finite()) {
            return Err(format!("point {id}: position is not finite"));
        }
        points.push(ObjectPoint {
            id,
            name: String::new(),
            kind: PointKind::Tie,
            position: Vector3::from(xyz),
            sigma: None,
            color: rgb,
            observations,
        });
        Ok(())
    };
    match pts_enc {
        Encoding::Binary => binary::read_points(&pts_path, &mut sink)?,
        Encoding::Text => text::read_points(&pts_path, &mut sink)?,
    }
    // Bulk-building the map from sorted ids is linear; files are usually sorted already.
    points.sort_by_key(|p| p.id);
    if let Some(w) = points.windows(2).find(|w| w[0].id == w[1].id) {
        return Err(FormatError::invalid(
            &pts_path,
            format!("point id {} appears twice", w[0].id),
        ));
    }
    block.points = points.into_iter().map(|p| (p.id, p)).collect();

    for im in images {
        let free: Vec<[f64; 2]> = im
            .points2d
            .iter()
            .filter(|(_, p)| *p == INVALID_POINT3D)
            .map(|(xy, _)| *xy)
            .collect();
        if !free.is_empty() {
            block.keypoints.insert(im.id, free);
        }
        block.photos.insert(
            im.id,
            Photo::new(im.id, im.name, im.camera, im.pose).oriented(),
        );
    }

    side_file::apply(dir, &mut block)?;
    tracing::info!(
        dir = %dir.display(),
        cameras = block.cameras.len(),
        images = block.photos.len(),
        points = block.points.len(),
        "read COLMAP model"
    );
    Ok(block)
}
