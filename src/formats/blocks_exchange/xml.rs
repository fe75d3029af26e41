//! The BlocksExchange XML schema, element names exactly as the format, and a document at
//! the XML level ([`Document`]) for files that do not make a complete block.

use crate::formats::{FormatError, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename = "BlocksExchange")]
pub(super) struct XRoot {
    #[serde(rename = "@version", default)]
    pub version: String,
    #[serde(
        rename = "SpatialReferenceSystems",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    pub srs: Option<XSrsList>,
    #[serde(
        rename = "BaseImagePath",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    pub base_image_path: Option<String>,
    #[serde(rename = "Block", default)]
    pub blocks: Vec<XBlock>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
pub(super) struct XSrsList {
    #[serde(rename = "SRS", default)]
    pub srs: Vec<XSrs>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
pub(super) struct XSrs {
    #[serde(rename = "Id")]
    pub id: i64,
    #[serde(rename = "Name", default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    #[serde(rename = "Definition")]
    pub definition: String,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
pub(super) struct XBlock {
    #[serde(rename = "Name", default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    #[serde(
        rename = "Description",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    pub description: Option<String>,
    #[serde(rename = "Type", default, skip_serializing_if = "Option::is_none")]
    pub kind: Option<String>,
    #[serde(rename = "SRSId", default, skip_serializing_if = "Option::is_none")]
    pub srs_id: Option<i64>,
    #[serde(
        rename = "Photogroups",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    pub photogroups: Option<XPhotogroups>,
    #[serde(
        rename = "BulkPhotos",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    pub bulk_photos: Option<XBulkPhotos>,
    #[serde(
        rename = "ControlPoints",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    pub control_points: Option<XControlPoints>,
    #[serde(rename = "TiePoints", default, skip_serializing_if = "Option::is_none")]
    pub tie_points: Option<XTiePoints>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
pub(super) struct XPhotogroups {
    #[serde(rename = "Photogroup", default)]
    pub photogroups: Vec<XPhotogroup>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
pub(super) struct XBulkPhotos {
    #[serde(rename = "Photo", default)]
    pub photos: Vec<XPhoto>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
pub(super) struct XDims {
    #[serde(rename = "Width")]
    pub width: u32,
    #[serde(rename = "Height")]
    pub height: u32,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
pub(super) struct XPhotogroup {
    #[serde(rename = "Name", default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    #[serde(
        rename = "ImageDimensions",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    pub image_dimensions: Option<XDims>,
    #[serde(
        rename = "CameraModelType",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    pub camera_model_type: Option<String>,
    /// Visible or Thermal (CC Orientations, real 3.x exports).
    #[serde(
        rename = "CameraModelBand",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    pub camera_model_band: Option<String>,
    // FocalLength before SensorSize, as real 3.x exports write them.
    #[serde(
        rename = "FocalLength",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    pub focal_length: Option<f64>,
    #[serde(
        rename = "SensorSize",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    pub sensor_size: Option<f64>,
    #[serde(rename = "PixelSize", default, skip_serializing_if = "Option::is_none")]
    pub pixel_size: Option<f64>,
    #[serde(
        rename = "FocalLengthPixels",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    pub focal_length_pixels: Option<f64>,
    #[serde(
        rename = "CameraOrientation",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    pub camera_orientation: Option<String>,
    #[serde(
        rename = "PrincipalPoint",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    pub principal_point: Option<XImagePoint>,
    #[serde(
        rename = "Distortion",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    pub distortion: Option<XDistortion>,
    #[serde(
        rename = "AspectRatio",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    pub aspect_ratio: Option<f64>,
    #[serde(rename = "Skew", default, skip_serializing_if = "Option::is_none")]
    pub skew: Option<f64>,
    #[serde(rename = "Photo", default)]
    pub photos: Vec<XPhoto>,
}

/// A 2-D point in pixels (`x`, `y`) or in mm (`xmm`, `ymm`).
#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
pub(super) struct XImagePoint {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub x: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub y: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub xmm: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ymm: Option<f64>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
pub(super) struct XDistortion {
    #[serde(rename = "K1", default)]
    pub k1: f64,
    #[serde(rename = "K2", default)]
    pub k2: f64,
    #[serde(rename = "K3", default)]
    pub k3: f64,
    #[serde(rename = "P1", default)]
    pub p1: f64,
    #[serde(rename = "P2", default)]
    pub p2: f64,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
pub(super) struct XPhoto {
    #[serde(rename = "Id")]
    pub id: Option<u32>,
    #[serde(rename = "ImagePath", default)]
    pub image_path: Option<String>,
    #[serde(rename = "MaskPath", default, skip_serializing_if = "Option::is_none")]
    pub mask_path: Option<String>,
    #[serde(rename = "Component", default, skip_serializing_if = "Option::is_none")]
    pub component: Option<i32>,
    #[serde(rename = "Pose", default, skip_serializing_if = "Option::is_none")]
    pub pose: Option<XPose>,
    #[serde(rename = "ExifData", default, skip_serializing_if = "Option::is_none")]
    pub exif: Option<XExif>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
pub(super) struct XExif {
    #[serde(
        rename = "DateTimeOriginal",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    pub date_time_original: Option<String>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
pub(super) struct XPose {
    #[serde(rename = "Rotation", default, skip_serializing_if = "Option::is_none")]
    pub rotation: Option<XRotation>,
    #[serde(rename = "Center", default, skip_serializing_if = "Option::is_none")]
    pub center: Option<XXyz>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
pub(super) struct XRotation {
    #[serde(rename = "M_00", default, skip_serializing_if = "Option::is_none")]
    pub m00: Option<f64>,
    #[serde(rename = "M_01", default, skip_serializing_if = "Option::is_none")]
    pub m01: Option<f64>,
    #[serde(rename = "M_02", default, skip_serializing_if = "Option::is_none")]
    pub m02: Option<f64>,
    #[serde(rename = "M_10", default, skip_serializing_if = "Option::is_none")]
    pub m10: Option<f64>,
    #[serde(rename = "M_11", default, skip_serializing_if = "Option::is_none")]
    pub m11: Option<f64>,
    #[serde(rename = "M_12", default, skip_serializing_if = "Option::is_none")]
    pub m12: Option<f64>,
    #[serde(rename = "M_20", default, skip_serializing_if = "Option::is_none")]
    pub m20: Option<f64>,
    #[serde(rename = "M_21", default, skip_serializing_if = "Option::is_none")]
    pub m21: Option<f64>,
    #[serde(rename = "M_22", default, skip_serializing_if = "Option::is_none")]
    pub m22: Option<f64>,
    #[serde(rename = "Omega", default, skip_serializing_if = "Option::is_none")]
    pub omega: Option<f64>,
    #[serde(rename = "Phi", default, skip_serializing_if = "Option::is_none")]
    pub phi: Option<f64>,
    #[serde(rename = "Kappa", default, skip_serializing_if = "Option::is_none")]
    pub kappa: Option<f64>,
    #[serde(rename = "Heading", default, skip_serializing_if = "Option::is_none")]
    pub heading: Option<f64>,
    #[serde(rename = "Yaw", default, skip_serializing_if = "Option::is_none")]
    pub yaw: Option<f64>,
    #[serde(rename = "Accurate", default, skip_serializing_if = "Option::is_none")]
    pub accurate: Option<bool>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
pub(super) struct XXyz {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub x: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub y: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub z: Option<f64>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
pub(super) struct XControlPoints {
    #[serde(rename = "SRSId", default, skip_serializing_if = "Option::is_none")]
    pub srs_id: Option<i64>,
    #[serde(rename = "ControlPoint", default)]
    pub points: Vec<XControlPoint>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
pub(super) struct XControlPoint {
    #[serde(rename = "Name", default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    #[serde(rename = "SRSId", default, skip_serializing_if = "Option::is_none")]
    pub srs_id: Option<i64>,
    #[serde(rename = "Category", default, skip_serializing_if = "Option::is_none")]
    pub category: Option<String>,
    #[serde(rename = "Position", default, skip_serializing_if = "Option::is_none")]
    pub position: Option<XXyz>,
    #[serde(
        rename = "CheckPoint",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    pub check_point: Option<bool>,
    #[serde(
        rename = "HorizontalAccuracy",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    pub horizontal_accuracy: Option<f64>,
    #[serde(
        rename = "VerticalAccuracy",
        default,
        skip_serializing_if = "Option::is_none"
    )]
    pub vertical_accuracy: Option<f64>,
    #[serde(rename = "Measurement", default)]
    pub measurements: Vec<XMeasurement>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
pub(super) struct XMeasurement {
    #[serde(rename = "Type", default, skip_serializing_if = "Option::is_none")]
    pub kind: Option<String>,
    #[serde(rename = "PhotoId")]
    pub photo_id: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub x: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub y: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub xmm: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ymm: Option<f64>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
pub(super) struct XTiePoints {
    #[serde(rename = "SRSId", default, skip_serializing_if = "Option::is_none")]
    pub srs_id: Option<i64>,
    #[serde(rename = "TiePoint", default)]
    pub points: Vec<XTiePoint>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
pub(super) struct XTiePoint {
    #[serde(rename = "Name", default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    #[serde(rename = "SRSId", default, skip_serializing_if = "Option::is_none")]
    pub srs_id: Option<i64>,
    #[serde(rename = "Position", default, skip_serializing_if = "Option::is_none")]
    pub position: Option<XXyz>,
    #[serde(rename = "Color", default, skip_serializing_if = "Option::is_none")]
    pub color: Option<XColor>,
    #[serde(rename = "Measurement", default)]
    pub measurements: Vec<XMeasurement>,
}

#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
pub(super) struct XColor {
    #[serde(rename = "Red")]
    pub red: f64,
    #[serde(rename = "Green")]
    pub green: f64,
    #[serde(rename = "Blue")]
    pub blue: f64,
}

pub(super) fn serialize_root(root: &XRoot) -> std::result::Result<String, String> {
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
pub struct Document(pub(super) XRoot);

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
