//! A [`Block`] as BlocksExchange 2.1 XML: cameras as photogroups (XRightYDown, pixels),
//! poses as `M_ij` rotations and world centres, control/check and tie points. Elements
//! are written in the order of real v3.x exports (formats/blocks-exchange/README.md).

use super::conventions::HALF_PIXEL;
use super::xml::{
    serialize_root, XBlock, XColor, XControlPoint, XControlPoints, XDims, XDistortion, XExif,
    XImagePoint, XMeasurement, XPhoto, XPhotogroup, XPhotogroups, XPose, XRoot, XRotation, XSrs,
    XSrsList, XTiePoint, XTiePoints, XXyz,
};
use crate::block::{Block, CameraId, Observation, PointKind};
use crate::formats::{frame_equivalent, write_bytes_atomically, FormatError, Result};
use nalgebra::Vector3;
use std::collections::BTreeMap;
use std::path::Path;

/// Options of the BlocksExchange writer.
#[derive(Debug, Clone, Default)]
pub struct WriteOptions {
    /// `<BaseImagePath>`: folder the photos' ImagePath are relative to.
    pub base_image_path: Option<String>,
    /// `<Block><Name>`.
    pub block_name: Option<String>,
    /// Physical pixel size (mm) of a camera's images, where known (a film scan's
    /// fiducial-frame image): its photogroup then states `FocalLength` and `SensorSize`
    /// in mm, as ContextCapture shows a metric camera, instead of `FocalLengthPixels`.
    pub pixel_mm: BTreeMap<CameraId, f64>,
}

fn xyz(v: Vector3<f64>) -> XXyz {
    XXyz {
        x: Some(v.x),
        y: Some(v.y),
        z: Some(v.z),
    }
}

fn pixel_measurement(o: &Observation) -> XMeasurement {
    XMeasurement {
        kind: None,
        photo_id: Some(o.photo),
        x: Some(o.pixel[0] - HALF_PIXEL),
        y: Some(o.pixel[1] - HALF_PIXEL),
        xmm: None,
        ymm: None,
    }
}

/// Serialises a block as BlocksExchange 2.1 XML (XRightYDown, pixels, `M_ij` rotations).
pub fn to_string(block: &Block, opts: &WriteOptions) -> std::result::Result<String, String> {
    let origin = Vector3::from(block.origin);
    let mut group_index: BTreeMap<u32, usize> = BTreeMap::new();
    let mut groups = Vec::new();
    for (i, c) in block.cameras.values().enumerate() {
        group_index.insert(c.id, i);
        let f = frame_equivalent(&c.model).map_err(|m| format!("camera {}: {m}", c.id))?;
        let metric = opts
            .pixel_mm
            .get(&c.id)
            .copied()
            .filter(|p| p.is_finite() && *p > 0.0);
        groups.push(XPhotogroup {
            name: Some(if c.name.is_empty() {
                format!("camera {}", c.id)
            } else {
                c.name.clone()
            }),
            image_dimensions: Some(XDims {
                width: f.width,
                height: f.height,
            }),
            camera_model_type: Some("Perspective".into()),
            camera_model_band: Some("Visible".into()),
            focal_length: metric.map(|p| f.fx * p),
            sensor_size: metric.map(|p| f.width.max(f.height) as f64 * p),
            pixel_size: None,
            focal_length_pixels: metric.is_none().then_some(f.fx),
            camera_orientation: Some("XRightYDown".into()),
            principal_point: Some(XImagePoint {
                x: Some(f.cx - HALF_PIXEL),
                y: Some(f.cy - HALF_PIXEL),
                xmm: None,
                ymm: None,
            }),
            distortion: Some(XDistortion {
                k1: f.distortion.k1,
                k2: f.distortion.k2,
                k3: f.distortion.k3,
                p1: f.distortion.p2,
                p2: f.distortion.p1,
            }),
            aspect_ratio: Some(f.fy / f.fx),
            skew: Some(0.0),
            photos: Vec::new(),
        });
    }
    for p in block.photos.values() {
        let gi = *group_index
            .get(&p.camera)
            .ok_or_else(|| format!("photo {} refers to unknown camera {}", p.id, p.camera))?;
        if p.name.trim().is_empty() {
            return Err(format!("photo {}: image path is empty", p.id));
        }
        let r = &p.pose.rotation;
        groups[gi].photos.push(XPhoto {
            id: Some(p.id),
            image_path: Some(p.name.clone()),
            mask_path: None,
            component: Some(if p.is_oriented() { 1 } else { 0 }),
            pose: Some(XPose {
                rotation: Some(XRotation {
                    m00: Some(r[(0, 0)]),
                    m01: Some(r[(0, 1)]),
                    m02: Some(r[(0, 2)]),
                    m10: Some(r[(1, 0)]),
                    m11: Some(r[(1, 1)]),
                    m12: Some(r[(1, 2)]),
                    m20: Some(r[(2, 0)]),
                    m21: Some(r[(2, 1)]),
                    m22: Some(r[(2, 2)]),
                    ..Default::default()
                }),
                center: Some(xyz(p.pose.center + origin)),
            }),
            exif: p.date.as_ref().map(|d| XExif {
                date_time_original: Some(d.clone()),
            }),
        });
    }
    let mut cps = Vec::new();
    let mut tps = Vec::new();
    for p in block.points.values() {
        let world = p.position + origin;
        let measurements = p.observations.iter().map(pixel_measurement).collect();
        match p.kind {
            PointKind::Tie => tps.push(XTiePoint {
                name: (!p.name.is_empty()).then(|| p.name.clone()),
                srs_id: None,
                position: Some(xyz(world)),
                color: Some(XColor {
                    red: p.color[0] as f64 / 255.0,
                    green: p.color[1] as f64 / 255.0,
                    blue: p.color[2] as f64 / 255.0,
                }),
                measurements,
            }),
            PointKind::Control | PointKind::Check => {
                let s = p.sigma.unwrap_or([0.01; 3]);
                let (category, position, h, v) = if s[2].is_infinite() {
                    (
                        "Horizontal",
                        XXyz {
                            z: None,
                            ..xyz(world)
                        },
                        Some(s[0]),
                        None,
                    )
                } else if s[0].is_infinite() {
                    (
                        "Vertical",
                        XXyz {
                            x: None,
                            y: None,
                            z: Some(world.z),
                        },
                        None,
                        Some(s[2]),
                    )
                } else {
                    ("Full", xyz(world), Some(s[0]), Some(s[2]))
                };
                cps.push(XControlPoint {
                    name: Some(if p.name.is_empty() {
                        format!("point {}", p.id)
                    } else {
                        p.name.clone()
                    }),
                    srs_id: None,
                    category: Some(category.into()),
                    position: Some(position),
                    check_point: Some(p.kind == PointKind::Check),
                    horizontal_accuracy: h,
                    vertical_accuracy: v,
                    measurements,
                })
            }
        }
    }
    let root = XRoot {
        version: "2.1".into(),
        srs: block.crs.as_ref().map(|c| XSrsList {
            srs: vec![XSrs {
                id: 0,
                name: None,
                definition: c.clone(),
            }],
        }),
        base_image_path: opts.base_image_path.clone(),
        blocks: vec![XBlock {
            name: Some(
                opts.block_name
                    .clone()
                    .unwrap_or_else(|| "cloudcontrol".into()),
            ),
            description: None,
            kind: Some("Aerial".into()),
            srs_id: block.crs.as_ref().map(|_| 0),
            photogroups: Some(XPhotogroups {
                photogroups: groups,
            }),
            bulk_photos: None,
            control_points: (!cps.is_empty()).then_some(XControlPoints {
                srs_id: None,
                points: cps,
            }),
            tie_points: (!tps.is_empty()).then_some(XTiePoints {
                srs_id: None,
                points: tps,
            }),
        }],
    };
    serialize_root(&root)
}

/// Writes a block as BlocksExchange 2.1 XML, atomically.
pub fn write(path: &Path, block: &Block, opts: &WriteOptions) -> Result<()> {
    block
        .validate()
        .map_err(|e| FormatError::invalid(path, format!("block is inconsistent: {e}")))?;
    let s = to_string(block, opts).map_err(|m| FormatError::invalid(path, m))?;
    write_bytes_atomically(path, s.as_bytes())
}
