//! A [`Block`] from BlocksExchange XML: photogroups to cameras, photos to exterior
//! orientations (`M_ij` or Omega/Phi/Kappa), control and tie points to object points, in
//! the block's SRS.

use super::conventions::{camera_orientation_matrix, matrix_from_opk_degrees, HALF_PIXEL};
use super::xml::{XMeasurement, XPhoto, XPhotogroup, XRoot};
use crate::block::{Block, BlockCamera, ObjectPoint, Observation, Photo, PointKind};
use crate::formats::crs::{Crs, Transformer};
use crate::formats::{FormatError, Result};
use crate::geometry::{Brown, Camera, FrameCamera, Pose};
use nalgebra::{Matrix2, Matrix3, Vector2, Vector3};
use std::collections::HashMap;
use std::path::Path;

struct Group {
    camera: FrameCamera,
    o: Matrix3<f64>,
    /// mm per pixel, when the group has a metric sensor size.
    pixel_mm: Option<f64>,
}

/// Reads the first `<Block>` of a BlocksExchange file (`.xml`; `.xmlz` must be unzipped).
pub fn read(path: &Path) -> Result<Block> {
    let text = super::super::input::read_text(path, super::super::input::Cap::document())?;
    read_str(&text, path)
}

/// Parses BlocksExchange XML; `path` names the source in errors and resolves nothing.
pub fn read_str(text: &str, path: &Path) -> Result<Block> {
    let err = |m: String| FormatError::invalid(path, m);
    let root: XRoot = quick_xml::de::from_str(text)
        .map_err(|e| err(format!("not valid BlocksExchange XML: {e}")))?;
    let srs: HashMap<i64, String> = root
        .srs
        .iter()
        .flat_map(|l| l.srs.iter())
        .map(|s| (s.id, s.definition.clone()))
        .collect();
    let xb = root
        .blocks
        .first()
        .ok_or_else(|| err("BlocksExchange: no <Block> element".into()))?;
    if root.blocks.len() > 1 {
        tracing::warn!(path = %path.display(), blocks = root.blocks.len(), "only the first <Block> is read");
    }
    let srs_def = |id: Option<i64>, what: &str| -> Result<Option<String>> {
        match id {
            None => Ok(None),
            Some(i) => srs.get(&i).cloned().map(Some).ok_or_else(|| {
                err(format!(
                    "{what}: SRSId {i} is not defined in <SpatialReferenceSystems>"
                ))
            }),
        }
    };
    let block_crs = srs_def(xb.srs_id, "Block")?;
    if let Some(def) = &block_crs {
        Crs::parse(def).map_err(|e| err(format!("Block/SRSId: {e}")))?;
    }
    let mut block = Block::new();
    block.crs = block_crs.clone();

    // Photo poses first, in world coordinates; the origin is chosen from them afterwards.
    let mut groups: Vec<Group> = Vec::new();
    let mut photos: Vec<(Photo, Option<Vector3<f64>>)> = Vec::new();
    let empty = Vec::new();
    let pgs = xb
        .photogroups
        .as_ref()
        .map(|p| &p.photogroups)
        .unwrap_or(&empty);
    for (gi, pg) in pgs.iter().enumerate() {
        let gname = pg.name.clone().unwrap_or_else(|| format!("#{}", gi + 1));
        let what = format!("Photogroup {gname}");
        let group = read_photogroup(pg, &what).map_err(err)?;
        let camera_id = (gi + 1) as u32;
        for (pi, xp) in pg.photos.iter().enumerate() {
            let (photo, center) = read_photo(
                xp,
                camera_id,
                &group.o,
                &format!("{what}, Photo #{}", pi + 1),
            )
            .map_err(err)?;
            photos.push((photo, center));
        }
        block.cameras.insert(
            camera_id,
            BlockCamera {
                id: camera_id,
                name: gname,
                model: Camera::Frame(group.camera.clone()),
                free_params: Vec::new(),
                calibration_group: None,
            },
        );
        groups.push(group);
    }
    if let Some(bulk) = &xb.bulk_photos {
        if !bulk.photos.is_empty() {
            return Err(err(
                "BulkPhotos: photos without a photogroup have no camera; this reader needs \
                 <Photogroups> (CC estimates the camera from EXIF, which we cannot)"
                    .into(),
            ));
        }
    }

    let centers: Vec<Vector3<f64>> = photos.iter().filter_map(|(_, c)| *c).collect();
    if !centers.is_empty() {
        let mean = centers.iter().sum::<Vector3<f64>>() / centers.len() as f64;
        block.origin = [mean.x.round(), mean.y.round(), 0.0];
    }
    let origin = Vector3::from(block.origin);
    let mut group_of: HashMap<u32, usize> = HashMap::new();
    for (mut photo, center) in photos {
        if let Some(c) = center {
            photo.pose.center = c - origin;
        }
        group_of.insert(photo.id, (photo.camera - 1) as usize);
        let id = photo.id;
        if block.photos.insert(id, photo).is_some() {
            return Err(err(format!(
                "Photo Id {id} appears twice (Ids must be unique in the block)"
            )));
        }
    }

    let measurement = |m: &XMeasurement, what: &str| -> Result<Observation> {
        let pid = m
            .photo_id
            .ok_or_else(|| err(format!("{what}: Measurement without PhotoId")))?;
        let gi = *group_of.get(&pid).ok_or_else(|| {
            err(format!(
                "{what}: Measurement refers to unknown PhotoId {pid}"
            ))
        })?;
        let g = &groups[gi];
        let pixel = match (m.x, m.y, m.xmm, m.ymm) {
            (Some(x), Some(y), _, _) => [x + HALF_PIXEL, y + HALF_PIXEL],
            (_, _, Some(xmm), Some(ymm)) => {
                let ps = g.pixel_mm.ok_or_else(|| {
                    err(format!(
                        "{what}: Measurement in PhotoId {pid} is in mm (xmm/ymm) but its \
                         photogroup has no SensorSize/PixelSize"
                    ))
                })?;
                let o2 = g.o.fixed_view::<2, 2>(0, 0).into_owned();
                let d = o2 * Vector2::new(xmm, ymm) / ps;
                [g.camera.cx + d.x, g.camera.cy + d.y]
            }
            _ => {
                return Err(err(format!(
                    "{what}: Measurement in PhotoId {pid} has neither x/y nor xmm/ymm"
                )))
            }
        };
        if pixel.iter().any(|v| !v.is_finite()) {
            return Err(err(format!(
                "{what}: Measurement in PhotoId {pid} is not finite"
            )));
        }
        Ok(Observation {
            photo: pid,
            pixel,
            sigma_px: 1.0,
            provenance: m
                .kind
                .clone()
                .map(|k| format!("blocks-exchange {k}"))
                .unwrap_or_else(|| "blocks-exchange".into()),
        })
    };

    // Positions in another SRS are converted to the block's.
    let mut transformers: HashMap<i64, Transformer> = HashMap::new();
    let mut to_block = |p: Vector3<f64>, srs_id: Option<i64>, what: &str| -> Result<Vector3<f64>> {
        let Some(id) = srs_id.filter(|i| Some(*i) != xb.srs_id) else {
            return Ok(p);
        };
        let (Some(target), Some(def)) = (&block_crs, srs_def(Some(id), what)?) else {
            return Err(err(format!(
                "{what}: SRSId {id} differs from the block's, which has no SRS to convert to"
            )));
        };
        if let std::collections::hash_map::Entry::Vacant(slot) = transformers.entry(id) {
            let t = Transformer::new(
                &Crs::parse(&def).map_err(|e| err(format!("{what}: {e}")))?,
                &Crs::parse(target).map_err(|e| err(format!("Block: {e}")))?,
            )
            .map_err(|e| err(format!("{what}: {e}")))?;
            slot.insert(t);
        }
        let q = transformers[&id]
            .transform_point([p.x, p.y, p.z])
            .map_err(|e| err(format!("{what}: {e}")))?;
        Ok(Vector3::from(q))
    };

    // Control points first, then tie points, numbered from 1 in file order.
    let mut points: Vec<ObjectPoint> = Vec::new();
    let observations = |ms: &[XMeasurement], what: &str| -> Result<Vec<Observation>> {
        ms.iter().map(|m| measurement(m, what)).collect()
    };
    if let Some(cps) = &xb.control_points {
        for (i, cp) in cps.points.iter().enumerate() {
            let name = cp.name.clone().unwrap_or_else(|| format!("#{}", i + 1));
            let what = format!("ControlPoint {name}");
            let category = cp.category.as_deref().unwrap_or("Full");
            let pos = cp.position.as_ref();
            let get = |v: Option<f64>, axis: &str| {
                v.filter(|v| v.is_finite()).ok_or_else(|| {
                    err(format!(
                        "{what}: Position/{axis} is missing or not finite (Category {category})"
                    ))
                })
            };
            let h = cp.horizontal_accuracy.unwrap_or(0.01);
            let v = cp.vertical_accuracy.unwrap_or(0.01);
            let (xyz, sigma) = match category {
                "Full" => (
                    Vector3::new(
                        get(pos.and_then(|p| p.x), "x")?,
                        get(pos.and_then(|p| p.y), "y")?,
                        get(pos.and_then(|p| p.z), "z")?,
                    ),
                    [h, h, v],
                ),
                "Horizontal" => (
                    Vector3::new(
                        get(pos.and_then(|p| p.x), "x")?,
                        get(pos.and_then(|p| p.y), "y")?,
                        0.0,
                    ),
                    [h, h, f64::INFINITY],
                ),
                "Vertical" => (
                    Vector3::new(
                        pos.and_then(|p| p.x).unwrap_or(0.0),
                        pos.and_then(|p| p.y).unwrap_or(0.0),
                        get(pos.and_then(|p| p.z), "z")?,
                    ),
                    [f64::INFINITY, f64::INFINITY, v],
                ),
                other => {
                    return Err(err(format!(
                        "{what}: unknown Category {other:?} (Full, Horizontal or Vertical)"
                    )))
                }
            };
            let xyz = if category == "Full" {
                to_block(xyz, cp.srs_id.or(cps.srs_id), &what)?
            } else if cp
                .srs_id
                .or(cps.srs_id)
                .is_some_and(|i| Some(i) != xb.srs_id)
            {
                return Err(err(format!(
                    "{what}: a {category} control point in another SRS cannot be converted \
                     without all three coordinates"
                )));
            } else {
                xyz
            };
            let mut local = xyz - origin;
            if category == "Horizontal" {
                local.z = 0.0;
            }
            points.push(ObjectPoint {
                id: 0,
                name,
                kind: if cp.check_point == Some(true) {
                    PointKind::Check
                } else {
                    PointKind::Control
                },
                position: local,
                sigma: Some(sigma),
                color: [0; 3],
                observations: observations(&cp.measurements, &what)?,
            });
        }
    }
    if let Some(tps) = &xb.tie_points {
        for (i, tp) in tps.points.iter().enumerate() {
            let name = tp.name.clone().unwrap_or_default();
            let what = format!(
                "TiePoint {}",
                if name.is_empty() {
                    format!("#{}", i + 1)
                } else {
                    name.clone()
                }
            );
            let p = tp
                .position
                .as_ref()
                .and_then(|p| Some(Vector3::new(p.x?, p.y?, p.z?)))
                .filter(|p| p.iter().all(|v| v.is_finite()))
                .ok_or_else(|| {
                    err(format!(
                        "{what}: Position x/y/z is missing or not finite (tie points without \
                         a position are not supported)"
                    ))
                })?;
            let p = to_block(p, tp.srs_id.or(tps.srs_id), &what)?;
            let color = tp
                .color
                .as_ref()
                .map(|c| {
                    [c.red, c.green, c.blue].map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
                })
                .unwrap_or([0; 3]);
            points.push(ObjectPoint {
                id: 0,
                name,
                kind: PointKind::Tie,
                position: p - origin,
                sigma: None,
                color,
                observations: observations(&tp.measurements, &what)?,
            });
        }
    }
    for (k, mut p) in points.into_iter().enumerate() {
        p.id = k as u64 + 1;
        block.points.insert(p.id, p);
    }
    block
        .validate()
        .map_err(|e| err(format!("inconsistent block: {e}")))?;
    tracing::info!(path = %path.display(), photos = block.photos.len(), points = block.points.len(), "read BlocksExchange");
    Ok(block)
}

fn read_photogroup(pg: &XPhotogroup, what: &str) -> std::result::Result<Group, String> {
    let dims = pg
        .image_dimensions
        .as_ref()
        .ok_or_else(|| format!("{what}: ImageDimensions is missing"))?;
    let (w, h) = (dims.width, dims.height);
    if w == 0 || h == 0 {
        return Err(format!("{what}: ImageDimensions {w}×{h} is empty"));
    }
    match pg.camera_model_type.as_deref().unwrap_or("Perspective") {
        "Perspective" => {}
        other => {
            return Err(format!(
                "{what}: CameraModelType {other} is not supported (only Perspective)"
            ))
        }
    }
    let co = pg.camera_orientation.as_deref().unwrap_or("XRightYDown");
    let o = camera_orientation_matrix(co)
        .ok_or_else(|| format!("{what}: unknown CameraOrientation {co:?}"))?;
    let pixel_mm = pg
        .pixel_size
        .or_else(|| pg.sensor_size.map(|s| s / w.max(h) as f64));
    if let Some(ps) = pixel_mm {
        if !(ps.is_finite() && ps > 0.0) {
            return Err(format!("{what}: SensorSize/PixelSize {ps} is not positive"));
        }
    }
    let f = match (pg.focal_length_pixels, pg.focal_length, pixel_mm) {
        (Some(f), _, _) => f,
        (None, Some(fmm), Some(ps)) => fmm / ps,
        (None, Some(_), None) => {
            return Err(format!(
                "{what}: FocalLength in mm needs SensorSize or PixelSize to convert to pixels"
            ))
        }
        (None, None, _) => {
            return Err(format!(
            "{what}: no focal length (FocalLengthPixels, or FocalLength with SensorSize/PixelSize)"
        ))
        }
    };
    if !(f.is_finite() && f > 0.0) {
        return Err(format!("{what}: focal length {f} px is not positive"));
    }
    if pg.skew.is_some_and(|s| s != 0.0) {
        return Err(format!(
            "{what}: Skew {} is not representable by our camera model",
            pg.skew.unwrap_or_default()
        ));
    }
    let aspect = pg.aspect_ratio.unwrap_or(1.0);
    let centre = Vector2::new((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
    let o2: Matrix2<f64> = o.fixed_view::<2, 2>(0, 0).into_owned();
    let pp_cc = match &pg.principal_point {
        None => centre,
        Some(pp) => match (pp.x, pp.y, pp.xmm, pp.ymm) {
            (Some(x), Some(y), _, _) => Vector2::new(x, y),
            (_, _, Some(xmm), Some(ymm)) => {
                let ps = pixel_mm.ok_or_else(|| {
                    format!("{what}: PrincipalPoint in mm needs SensorSize or PixelSize")
                })?;
                centre + o2 * Vector2::new(xmm, ymm) / ps
            }
            _ => {
                return Err(format!(
                    "{what}: PrincipalPoint has neither x/y nor xmm/ymm"
                ))
            }
        },
    };
    let d = pg.distortion.as_ref();
    let distortion = Brown {
        k1: d.map_or(0.0, |d| d.k1),
        k2: d.map_or(0.0, |d| d.k2),
        k3: d.map_or(0.0, |d| d.k3),
        p1: d.map_or(0.0, |d| d.p2),
        p2: d.map_or(0.0, |d| d.p1),
    };
    let camera = FrameCamera {
        width: w,
        height: h,
        fx: f,
        fy: f * aspect,
        cx: pp_cc.x + HALF_PIXEL,
        cy: pp_cc.y + HALF_PIXEL,
        distortion,
    };
    Camera::Frame(camera.clone())
        .validate()
        .map_err(|e| format!("{what}: {e}"))?;
    Ok(Group {
        camera,
        o,
        pixel_mm,
    })
}

fn read_photo(
    xp: &XPhoto,
    camera: u32,
    o: &Matrix3<f64>,
    what: &str,
) -> std::result::Result<(Photo, Option<Vector3<f64>>), String> {
    let id = xp.id.ok_or_else(|| format!("{what}: Id is missing"))?;
    let what = format!("Photo Id {id}");
    let name = xp
        .image_path
        .clone()
        .filter(|p| !p.trim().is_empty())
        .ok_or_else(|| format!("{what}: ImagePath is missing"))?;
    let mut rotation = None;
    let mut center = None;
    if let Some(pose) = &xp.pose {
        if let Some(r) = &pose.rotation {
            let m = match (
                [
                    r.m00, r.m01, r.m02, r.m10, r.m11, r.m12, r.m20, r.m21, r.m22,
                ],
                (r.omega, r.phi, r.kappa),
            ) {
                (
                    [Some(a), Some(b), Some(c), Some(d), Some(e), Some(f), Some(g), Some(h), Some(i)],
                    _,
                ) => Matrix3::new(a, b, c, d, e, f, g, h, i),
                (_, (Some(om), Some(ph), Some(ka))) => matrix_from_opk_degrees(om, ph, ka),
                _ if r.heading.is_some() || r.yaw.is_some() => {
                    return Err(format!(
                        "{what}: Heading/Pitch/Roll and Yaw/Pitch/Roll rotations are not \
                         supported (their composition is not verified); export M_ij or \
                         Omega/Phi/Kappa"
                    ))
                }
                _ => {
                    return Err(format!(
                        "{what}: Rotation has neither all of M_00..M_22 nor Omega/Phi/Kappa"
                    ))
                }
            };
            let r = o * m;
            let pose = Pose::new(r, Vector3::zeros());
            pose.validate(1e-6)
                .map_err(|e| format!("{what}: Rotation: {e}"))?;
            rotation = Some(r);
        }
        if let Some(c) = &pose.center {
            let v = match (c.x, c.y, c.z) {
                (Some(x), Some(y), Some(z)) if x.is_finite() && y.is_finite() && z.is_finite() => {
                    Vector3::new(x, y, z)
                }
                _ => return Err(format!("{what}: Center needs finite x, y and z")),
            };
            center = Some(v);
        }
    }
    let oriented = rotation.is_some() && center.is_some() && xp.component != Some(0);
    let mut photo = Photo::new(
        id,
        name,
        camera,
        Pose::new(rotation.unwrap_or_else(Matrix3::identity), Vector3::zeros()),
    );
    if oriented {
        photo.status = crate::block::PhotoStatus::Oriented;
    }
    photo.date = xp.exif.as_ref().and_then(|e| e.date_time_original.clone());
    Ok((photo, center))
}
