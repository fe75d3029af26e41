//! ContextCapture / iTwin Capture Modeler BlocksExchange XML (read any version, write 2.1).
//!
//! Conventions (formats/blocks-exchange/README.md, design/formats-notes.md §1):
//! - `<Rotation>` is world→camera in the photogroup's `<CameraOrientation>` axes:
//!   our `R = O·M` (`O = I` for XRightYDown, `diag(1,−1,−1)` for XRightYUp).
//!   Omega/Phi/Kappa (degrees) give `M = R3(κ)·R2(φ)·R1(ω)`.
//! - `<Center>` is the projection centre.
//! - Pixel coordinates have their origin at the centre of the top-left pixel: ours are
//!   half a pixel larger.
//! - Brown tangential terms are swapped relative to OpenCV: `p1 = P2`, `p2 = P1`.
//! - `FocalLength`, `SensorSize` (largest sensor dimension), `PixelSize`, `xmm/ymm` in mm;
//!   `FocalLengthPixels` and `PrincipalPoint x/y` in pixels; `xmm/ymm` of a principal point
//!   from the sensor centre, of a measurement from the principal point, axes per
//!   CameraOrientation.
//!
//! Control point categories map onto σ: Horizontal has an infinite vertical σ (its height
//! is unknown and stored as 0), Vertical an infinite horizontal σ.

use super::crs::{Crs, Transformer};
use super::{frame_equivalent, write_bytes_atomically, FormatError, Result};
use crate::block::{Block, BlockCamera, ObjectPoint, Observation, Photo, PointKind};
use crate::geometry::{Brown, Camera, FrameCamera, Pose};
use nalgebra::{Matrix2, Matrix3, Vector2, Vector3};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

// ---------------------------------------------------------------------------------------
// XML schema (element names exactly as the format)
// ---------------------------------------------------------------------------------------

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename = "BlocksExchange")]
struct XRoot {
    #[serde(rename = "@version", default)]
    version: String,
    #[serde(
        rename = "SpatialReferenceSystems",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    srs: Option<XSrsList>,
    #[serde(
        rename = "BaseImagePath",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    base_image_path: Option<String>,
    #[serde(rename = "Block", default)]
    blocks: Vec<XBlock>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
struct XSrsList {
    #[serde(rename = "SRS", default)]
    srs: Vec<XSrs>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
struct XSrs {
    #[serde(rename = "Id")]
    id: i64,
    #[serde(rename = "Name", default, skip_serializing_if = "Option::is_none")]
    name: Option<String>,
    #[serde(rename = "Definition")]
    definition: String,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
struct XBlock {
    #[serde(rename = "Name", default, skip_serializing_if = "Option::is_none")]
    name: Option<String>,
    #[serde(
        rename = "Description",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    description: Option<String>,
    #[serde(rename = "Type", default, skip_serializing_if = "Option::is_none")]
    kind: Option<String>,
    #[serde(rename = "SRSId", default, skip_serializing_if = "Option::is_none")]
    srs_id: Option<i64>,
    #[serde(
        rename = "Photogroups",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    photogroups: Option<XPhotogroups>,
    #[serde(
        rename = "BulkPhotos",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    bulk_photos: Option<XBulkPhotos>,
    #[serde(
        rename = "ControlPoints",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    control_points: Option<XControlPoints>,
    #[serde(rename = "TiePoints", default, skip_serializing_if = "Option::is_none")]
    tie_points: Option<XTiePoints>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
struct XPhotogroups {
    #[serde(rename = "Photogroup", default)]
    photogroups: Vec<XPhotogroup>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
struct XBulkPhotos {
    #[serde(rename = "Photo", default)]
    photos: Vec<XPhoto>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
struct XDims {
    #[serde(rename = "Width")]
    width: u32,
    #[serde(rename = "Height")]
    height: u32,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
struct XPhotogroup {
    #[serde(rename = "Name", default, skip_serializing_if = "Option::is_none")]
    name: Option<String>,
    #[serde(
        rename = "ImageDimensions",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    image_dimensions: Option<XDims>,
    #[serde(
        rename = "CameraModelType",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    camera_model_type: Option<String>,
    #[serde(
        rename = "SensorSize",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    sensor_size: Option<f64>,
    #[serde(rename = "PixelSize", default, skip_serializing_if = "Option::is_none")]
    pixel_size: Option<f64>,
    #[serde(
        rename = "FocalLength",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    focal_length: Option<f64>,
    #[serde(
        rename = "FocalLengthPixels",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    focal_length_pixels: Option<f64>,
    #[serde(
        rename = "CameraOrientation",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    camera_orientation: Option<String>,
    #[serde(
        rename = "PrincipalPoint",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    principal_point: Option<XImagePoint>,
    #[serde(
        rename = "Distortion",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    distortion: Option<XDistortion>,
    #[serde(
        rename = "AspectRatio",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    aspect_ratio: Option<f64>,
    #[serde(rename = "Skew", default, skip_serializing_if = "Option::is_none")]
    skew: Option<f64>,
    #[serde(rename = "Photo", default)]
    photos: Vec<XPhoto>,
}

/// A 2-D point in pixels (`x`, `y`) or in mm (`xmm`, `ymm`).
#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
struct XImagePoint {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    x: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    y: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    xmm: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    ymm: Option<f64>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
struct XDistortion {
    #[serde(rename = "K1", default)]
    k1: f64,
    #[serde(rename = "K2", default)]
    k2: f64,
    #[serde(rename = "K3", default)]
    k3: f64,
    #[serde(rename = "P1", default)]
    p1: f64,
    #[serde(rename = "P2", default)]
    p2: f64,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
struct XPhoto {
    #[serde(rename = "Id")]
    id: Option<u32>,
    #[serde(rename = "ImagePath", default)]
    image_path: Option<String>,
    #[serde(rename = "MaskPath", default, skip_serializing_if = "Option::is_none")]
    mask_path: Option<String>,
    #[serde(rename = "Component", default, skip_serializing_if = "Option::is_none")]
    component: Option<i32>,
    #[serde(rename = "Pose", default, skip_serializing_if = "Option::is_none")]
    pose: Option<XPose>,
    #[serde(rename = "ExifData", default, skip_serializing_if = "Option::is_none")]
    exif: Option<XExif>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
struct XExif {
    #[serde(
        rename = "DateTimeOriginal",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    date_time_original: Option<String>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
struct XPose {
    #[serde(rename = "Rotation", default, skip_serializing_if = "Option::is_none")]
    rotation: Option<XRotation>,
    #[serde(rename = "Center", default, skip_serializing_if = "Option::is_none")]
    center: Option<XXyz>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
struct XRotation {
    #[serde(rename = "M_00", default, skip_serializing_if = "Option::is_none")]
    m00: Option<f64>,
    #[serde(rename = "M_01", default, skip_serializing_if = "Option::is_none")]
    m01: Option<f64>,
    #[serde(rename = "M_02", default, skip_serializing_if = "Option::is_none")]
    m02: Option<f64>,
    #[serde(rename = "M_10", default, skip_serializing_if = "Option::is_none")]
    m10: Option<f64>,
    #[serde(rename = "M_11", default, skip_serializing_if = "Option::is_none")]
    m11: Option<f64>,
    #[serde(rename = "M_12", default, skip_serializing_if = "Option::is_none")]
    m12: Option<f64>,
    #[serde(rename = "M_20", default, skip_serializing_if = "Option::is_none")]
    m20: Option<f64>,
    #[serde(rename = "M_21", default, skip_serializing_if = "Option::is_none")]
    m21: Option<f64>,
    #[serde(rename = "M_22", default, skip_serializing_if = "Option::is_none")]
    m22: Option<f64>,
    #[serde(rename = "Omega", default, skip_serializing_if = "Option::is_none")]
    omega: Option<f64>,
    #[serde(rename = "Phi", default, skip_serializing_if = "Option::is_none")]
    phi: Option<f64>,
    #[serde(rename = "Kappa", default, skip_serializing_if = "Option::is_none")]
    kappa: Option<f64>,
    #[serde(rename = "Heading", default, skip_serializing_if = "Option::is_none")]
    heading: Option<f64>,
    #[serde(rename = "Yaw", default, skip_serializing_if = "Option::is_none")]
    yaw: Option<f64>,
    #[serde(rename = "Accurate", default, skip_serializing_if = "Option::is_none")]
    accurate: Option<bool>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
struct XXyz {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    x: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    y: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    z: Option<f64>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
struct XControlPoints {
    #[serde(rename = "SRSId", default, skip_serializing_if = "Option::is_none")]
    srs_id: Option<i64>,
    #[serde(rename = "ControlPoint", default)]
    points: Vec<XControlPoint>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
struct XControlPoint {
    #[serde(rename = "Name", default, skip_serializing_if = "Option::is_none")]
    name: Option<String>,
    #[serde(rename = "SRSId", default, skip_serializing_if = "Option::is_none")]
    srs_id: Option<i64>,
    #[serde(rename = "Category", default, skip_serializing_if = "Option::is_none")]
    category: Option<String>,
    #[serde(rename = "Position", default, skip_serializing_if = "Option::is_none")]
    position: Option<XXyz>,
    #[serde(
        rename = "CheckPoint",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    check_point: Option<bool>,
    #[serde(
        rename = "HorizontalAccuracy",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    horizontal_accuracy: Option<f64>,
    #[serde(
        rename = "VerticalAccuracy",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    vertical_accuracy: Option<f64>,
    #[serde(rename = "Measurement", default)]
    measurements: Vec<XMeasurement>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
struct XMeasurement {
    #[serde(rename = "Type", default, skip_serializing_if = "Option::is_none")]
    kind: Option<String>,
    #[serde(rename = "PhotoId")]
    photo_id: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    x: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    y: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    xmm: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    ymm: Option<f64>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
struct XTiePoints {
    #[serde(rename = "SRSId", default, skip_serializing_if = "Option::is_none")]
    srs_id: Option<i64>,
    #[serde(rename = "TiePoint", default)]
    points: Vec<XTiePoint>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
struct XTiePoint {
    #[serde(rename = "Name", default, skip_serializing_if = "Option::is_none")]
    name: Option<String>,
    #[serde(rename = "SRSId", default, skip_serializing_if = "Option::is_none")]
    srs_id: Option<i64>,
    #[serde(rename = "Position", default, skip_serializing_if = "Option::is_none")]
    position: Option<XXyz>,
    #[serde(rename = "Color", default, skip_serializing_if = "Option::is_none")]
    color: Option<XColor>,
    #[serde(rename = "Measurement", default)]
    measurements: Vec<XMeasurement>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
struct XColor {
    #[serde(rename = "Red")]
    red: f64,
    #[serde(rename = "Green")]
    green: f64,
    #[serde(rename = "Blue")]
    blue: f64,
}

// ---------------------------------------------------------------------------------------
// Conventions
// ---------------------------------------------------------------------------------------

/// `O` of a CameraOrientation: rows map its axes onto ours (x right, y down, z forward).
pub fn camera_orientation_matrix(name: &str) -> Option<Matrix3<f64>> {
    let m = |a: [f64; 9]| Matrix3::from_row_slice(&a);
    Some(match name {
        "XRightYDown" => Matrix3::identity(),
        "XRightYUp" => m([1., 0., 0., 0., -1., 0., 0., 0., -1.]),
        "XLeftYDown" => m([-1., 0., 0., 0., 1., 0., 0., 0., -1.]),
        "XLeftYUp" => m([-1., 0., 0., 0., -1., 0., 0., 0., 1.]),
        "XDownYRight" => m([0., 1., 0., 1., 0., 0., 0., 0., -1.]),
        "XDownYLeft" => m([0., -1., 0., 1., 0., 0., 0., 0., 1.]),
        "XUpYLeft" => m([0., -1., 0., -1., 0., 0., 0., 0., -1.]),
        "XUpYRight" => m([0., 1., 0., -1., 0., 0., 0., 0., 1.]),
        _ => return None,
    })
}

/// BlocksExchange's Omega/Phi/Kappa (degrees): `M = R3(κ)·R2(φ)·R1(ω)` with passive
/// elementary rotations.
pub fn matrix_from_opk_degrees(omega: f64, phi: f64, kappa: f64) -> Matrix3<f64> {
    let (so, co) = omega.to_radians().sin_cos();
    let (sp, cp) = phi.to_radians().sin_cos();
    let (sk, ck) = kappa.to_radians().sin_cos();
    let r1 = Matrix3::new(1.0, 0.0, 0.0, 0.0, co, so, 0.0, -so, co);
    let r2 = Matrix3::new(cp, 0.0, -sp, 0.0, 1.0, 0.0, sp, 0.0, cp);
    let r3 = Matrix3::new(ck, sk, 0.0, -sk, ck, 0.0, 0.0, 0.0, 1.0);
    r3 * r2 * r1
}

/// Offset between BlocksExchange pixel coordinates (origin at the top-left pixel's centre)
/// and ours (origin at its corner).
const HALF_PIXEL: f64 = 0.5;

/// Options of the BlocksExchange writer.
#[derive(Debug, Clone, Default)]
pub struct WriteOptions {
    /// `<BaseImagePath>`: folder the photos' ImagePath are relative to.
    pub base_image_path: Option<String>,
    /// `<Block><Name>`.
    pub block_name: Option<String>,
}

// ---------------------------------------------------------------------------------------
// Reading
// ---------------------------------------------------------------------------------------

struct Group {
    camera: FrameCamera,
    o: Matrix3<f64>,
    /// mm per pixel, when the group has a metric sensor size.
    pixel_mm: Option<f64>,
}

/// Reads the first `<Block>` of a BlocksExchange file (`.xml`; `.xmlz` must be unzipped).
pub fn read(path: &Path) -> Result<Block> {
    let text = std::fs::read_to_string(path).map_err(|e| FormatError::io(path, e))?;
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

    let mut next_id = 1u64;
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
            let observations = cp
                .measurements
                .iter()
                .map(|m| measurement(m, &what))
                .collect::<Result<Vec<_>>>()?;
            block.points.insert(
                next_id,
                ObjectPoint {
                    id: next_id,
                    name,
                    kind: if cp.check_point == Some(true) {
                        PointKind::Check
                    } else {
                        PointKind::Control
                    },
                    position: local,
                    sigma: Some(sigma),
                    color: [0; 3],
                    observations,
                },
            );
            next_id += 1;
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
            let observations = tp
                .measurements
                .iter()
                .map(|m| measurement(m, &what))
                .collect::<Result<Vec<_>>>()?;
            block.points.insert(
                next_id,
                ObjectPoint {
                    id: next_id,
                    name,
                    kind: PointKind::Tie,
                    position: p - origin,
                    sigma: None,
                    color,
                    observations,
                },
            );
            next_id += 1;
        }
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

// ---------------------------------------------------------------------------------------
// Writing
// ---------------------------------------------------------------------------------------

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
            sensor_size: None,
            pixel_size: None,
            focal_length: None,
            focal_length_pixels: Some(f.fx),
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

fn serialize_root(root: &XRoot) -> std::result::Result<String, String> {
    let mut body = String::new();
    let mut ser = quick_xml::se::Serializer::new(&mut body);
    ser.indent(' ', 2);
    root.serialize(ser).map_err(|e| e.to_string())?;
    Ok(format!(
        "<?xml version=\"1.0\" encoding=\"utf-8\"?>\n{body}\n"
    ))
}

/// A BlocksExchange document at the XML level (the elements this module knows), for
/// files that do not make a complete block, e.g. `BulkPhotos` without cameras.
#[derive(Debug, PartialEq)]
pub struct Document(XRoot);

impl Document {
    pub fn parse(text: &str, path: &Path) -> Result<Self> {
        quick_xml::de::from_str(text)
            .map(Document)
            .map_err(|e| FormatError::invalid(path, format!("not valid BlocksExchange XML: {e}")))
    }
    pub fn to_xml(&self) -> std::result::Result<String, String> {
        serialize_root(&self.0)
    }
    pub fn version(&self) -> &str {
        &self.0.version
    }
    /// Number of photos over all blocks, photogroups and bulk photos.
    pub fn num_photos(&self) -> usize {
        self.0
            .blocks
            .iter()
            .map(|b| {
                b.photogroups
                    .iter()
                    .flat_map(|p| p.photogroups.iter())
                    .map(|g| g.photos.len())
                    .sum::<usize>()
                    + b.bulk_photos.as_ref().map_or(0, |p| p.photos.len())
            })
            .sum()
    }
}

/// Writes a block as BlocksExchange 2.1 XML, atomically.
pub fn write(path: &Path, block: &Block, opts: &WriteOptions) -> Result<()> {
    block
        .validate()
        .map_err(|e| FormatError::invalid(path, format!("block is inconsistent: {e}")))?;
    let s = to_string(block, opts).map_err(|m| FormatError::invalid(path, m))?;
    write_bytes_atomically(path, s.as_bytes())
}
