//! An epoch to orient, as a user specifies it (photos folder, camera file, POS or strip
//! file, scan pixel size) and as the workflow holds it ([`EpochInput`]), with the one
//! builder between the two ([`EpochInput::build`]) that `cloudcontrol run`, `cloudcontrol
//! orient` and the C ABI all call; the one rule for the block origin; the approximate
//! orientation of every photo with its covariance; and the one error type of epoch work.

use super::dcp::DcpError;
use super::strips;
use crate::adjust::AdjustError;
use crate::block::PosPrior;
use crate::formats::pos::{self, PosRecord, StripEnds};
use crate::formats::FormatError;
use crate::geometry::{matrix_from_opk, Camera, Dem, FrameCamera};
use crate::matching::CameraDefinition;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Errors of epoch work; each names the input (file, epoch, photo, package).
#[derive(Debug, thiserror::Error)]
pub enum EpochError {
    #[error("{path}: {message}")]
    Input { path: PathBuf, message: String },
    #[error("epoch {epoch}: {message}")]
    Epoch { epoch: String, message: String },
    #[error(transparent)]
    Format(#[from] FormatError),
    #[error(transparent)]
    Dcp(#[from] DcpError),
    /// LiDAR tiles (the error names the file).
    #[error(transparent)]
    Lidar(#[from] crate::lidar::LidarError),
    /// An oriented block given in memory (the caller names its file).
    #[error("oriented block: {0}")]
    Block(String),
    #[error("epoch {epoch}: archive block adjustment: {source}")]
    Adjust { epoch: String, source: AdjustError },
}

pub(crate) fn input_err(path: &Path, message: impl Into<String>) -> EpochError {
    EpochError::Input {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// The camera of an epoch: a calibrated (or nominal) digital frame camera, or a film
/// camera's calibration certificate whose interior orientation is found per scan.
#[derive(Debug, Clone)]
pub enum EpochCamera {
    Frame(FrameCamera),
    Film(CameraDefinition),
}

impl EpochCamera {
    /// Reads a camera file (formats/cameras/): a film certificate when it lists
    /// fiducials, else a frame camera (`{"kind": "frame", …}`).
    pub fn load(path: &Path) -> Result<Self, EpochError> {
        let text = crate::formats::input::read_text(path, crate::formats::input::Cap::camera())
            .map_err(|e| input_err(path, e.detail()))?;
        let json: serde_json::Value = serde_json::from_str(&text)
            .map_err(|e| FormatError::at(path, e.line(), None, format!("not JSON: {e}")))?;
        if json.get("fiducials").is_some() {
            let dir = crate::formats::paths::folder_of(path);
            return CameraDefinition::from_json(json, dir)
                .map(Self::Film)
                .map_err(|e| input_err(path, e));
        }
        let keys: Vec<String> = match json.as_object() {
            Some(o) if o.get("kind").and_then(|k| k.as_str()) == Some("frame") => {
                o.keys().cloned().collect()
            }
            _ => Vec::new(),
        };
        let decoded = serde_json::from_value::<Camera>(json).map_err(|e| {
            // The decoded value has no positions: a missing key is blamed on a key of the
            // file no frame camera has (`"fxx"` for `"fx"`), on its line.
            let odd = keys.iter().find(|k| !FRAME_KEYS.contains(&k.as_str()));
            match odd.and_then(|k| json_key_line(&text, k).map(|l| (k, l))) {
                Some((k, line)) if e.to_string().starts_with("missing field") => FormatError::at(
                    path,
                    line,
                    None,
                    format!("{e}; the file has {k:?}, which no frame camera has (misspelt?)"),
                )
                .into(),
                _ => input_err(path, e.to_string()),
            }
        })?;
        match decoded {
            Camera::Frame(f) => {
                Camera::Frame(f.clone())
                    .validate()
                    .map_err(|e| input_err(path, e.to_string()))?;
                Ok(Self::Frame(f))
            }
            Camera::Film(_) => Err(input_err(
                path,
                "a film camera needs its calibration certificate (fiducials), not a scan camera",
            )),
        }
    }
}

/// The keys of a frame camera file (formats/cameras/).
const FRAME_KEYS: [&str; 8] = [
    "kind",
    "width",
    "height",
    "fx",
    "fy",
    "cx",
    "cy",
    "distortion",
];

/// The 1-based line of the first `"key":` in a JSON text: where an error about the key
/// points the reader (a decoded `serde_json::Value` keeps no positions).
pub(crate) fn json_key_line(text: &str, key: &str) -> Option<usize> {
    let quoted = format!("\"{key}\"");
    let mut from = 0;
    while let Some(i) = text[from..].find(&quoted) {
        let at = from + i;
        let after = text[at + quoted.len()..].trim_start();
        if after.starts_with(':') {
            return Some(text[..at].matches('\n').count() + 1);
        }
        from = at + quoted.len();
    }
    None
}

/// A photo of an epoch: its name (the image file's stem) and image file.
#[derive(Debug, Clone, PartialEq)]
pub struct PhotoInput {
    pub name: String,
    pub image: PathBuf,
}

impl PhotoInput {
    /// Every image file (PNG, TIFF, JPEG) of a folder, sorted by name; the photo name is
    /// the file stem. An empty folder is an error naming it.
    pub fn from_folder(dir: &Path) -> Result<Vec<Self>, EpochError> {
        let mut v: Vec<Self> = std::fs::read_dir(dir)
            .map_err(|e| input_err(dir, e.to_string()))?
            .filter_map(|d| d.ok().map(|d| d.path()))
            .filter(|p| {
                p.extension().and_then(|x| x.to_str()).is_some_and(|x| {
                    matches!(
                        x.to_ascii_lowercase().as_str(),
                        "png" | "tif" | "tiff" | "jpg" | "jpeg"
                    )
                })
            })
            .map(|p| Self {
                name: p
                    .file_stem()
                    .unwrap_or_default()
                    .to_string_lossy()
                    .into_owned(),
                image: p,
            })
            .collect();
        v.sort_by(|a, b| a.name.cmp(&b.name));
        if v.is_empty() {
            return Err(input_err(dir, "no photo (PNG, TIFF or JPEG) in the folder"));
        }
        Ok(v)
    }
}

/// Approximate exterior orientation: a POS (world coordinates, angles with σ), or strips
/// given by their end points only (world coordinates).
#[derive(Debug, Clone, PartialEq)]
pub enum Navigation {
    Pos(Vec<PosRecord>),
    Strips(Vec<StripEnds>),
}

impl Navigation {
    /// Reads the POS file or the strip file (formats/pos/).
    pub fn load(pos: Option<&Path>, strips: Option<&Path>) -> Result<Self, EpochError> {
        Ok(match (pos, strips) {
            (Some(p), None) => Self::Pos(pos::read_pos(p)?),
            (None, Some(s)) => Self::Strips(pos::read_strips(s)?),
            _ => {
                return Err(EpochError::Block(
                    "give exactly one of a POS file or a strip file".into(),
                ))
            }
        })
    }

    /// World projection centres the navigation states (a strip's ends only).
    pub fn centres(&self) -> Vec<[f64; 3]> {
        match self {
            Self::Pos(r) => r.iter().map(|r| r.center).collect(),
            Self::Strips(s) => s.iter().flat_map(|s| [s.first, s.last]).collect(),
        }
    }

    /// Names of the photos it lists, in file order.
    fn names(&self) -> Vec<&str> {
        match self {
            Self::Pos(r) => r.iter().map(|r| r.name.as_str()).collect(),
            Self::Strips(s) => s
                .iter()
                .flat_map(|s| s.photos.iter().map(String::as_str))
                .collect(),
        }
    }
}

/// An epoch as a user specifies it: what `[[archive]]` in a project file, the `orient`
/// command's options and the C ABI give.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpochSpec {
    pub name: String,
    /// Acquisition date (ISO 8601), when known.
    pub date: Option<String>,
    /// Folder of the photos (PNG, TIFF, JPEG).
    pub photos: PathBuf,
    /// Camera file (formats/cameras/).
    pub camera: PathBuf,
    /// POS file or strip file (exactly one; formats/pos/).
    pub pos: Option<PathBuf>,
    pub strips: Option<PathBuf>,
    /// Film: scan pixel size (µm); estimated from the format and the scan size if absent.
    pub scan_pixel_um: Option<f64>,
}

/// One epoch to orient.
#[derive(Debug, Clone)]
pub struct EpochInput {
    pub name: String,
    pub date: Option<String>,
    /// CRS of the navigation (must be the DCP packages' CRS).
    pub crs: String,
    /// World coordinates of the block-local origin used for the numerics and the DEM.
    pub origin: [f64; 3],
    pub camera: EpochCamera,
    pub photos: Vec<PhotoInput>,
    pub navigation: Navigation,
    /// Film: the scan pixel size (µm) given by the user.
    pub scan_pixel_um: Option<f64>,
}

impl EpochInput {
    /// The one way from an epoch's specification to its input: photos of the folder,
    /// camera file, navigation file; every photo named in the navigation must be a photo
    /// of the folder (by file name or stem), and every photo of the folder must have its
    /// row in the navigation.
    pub fn build(spec: &EpochSpec, crs: &str, origin: [f64; 3]) -> Result<Self, EpochError> {
        let photos = PhotoInput::from_folder(&spec.photos)?;
        let camera = EpochCamera::load(&spec.camera)?;
        let nav_file = spec.pos.as_deref().or(spec.strips.as_deref());
        let navigation =
            Navigation::load(spec.pos.as_deref(), spec.strips.as_deref()).map_err(|e| match e {
                EpochError::Block(m) => EpochError::Epoch {
                    epoch: spec.name.clone(),
                    message: m,
                },
                e => e,
            })?;
        let nav_file = nav_file.unwrap_or(Path::new(""));
        let known: std::collections::BTreeSet<&str> =
            photos.iter().map(|p| p.name.as_str()).collect();
        if let Some(n) = navigation
            .names()
            .into_iter()
            .find(|n| !known.contains(pos::photo_key(n)))
        {
            return Err(input_err(
                nav_file,
                format!(
                    "photo {n:?} is not in {} (photos are matched by file name or stem)",
                    spec.photos.display()
                ),
            ));
        }
        // A photo without a row would be left out of the epoch without its
        // approximate orientation: refused here, before any work, naming it (a photo not to
        // orient is moved out of the folder; formats/pos/README.md).
        let listed: std::collections::BTreeSet<&str> =
            navigation.names().into_iter().map(pos::photo_key).collect();
        if let Some(p) = photos.iter().find(|p| !listed.contains(p.name.as_str())) {
            return Err(input_err(
                nav_file,
                format!(
                    "photo {} ({}) has no row: every photo of the folder needs its {} (add \
                     the row, or move the photo out of {})",
                    p.name,
                    p.image.display(),
                    if spec.pos.is_some() {
                        "POS row"
                    } else {
                        "strip row"
                    },
                    spec.photos.display()
                ),
            ));
        }
        if let Some(px) = spec.scan_pixel_um {
            crate::matching::fiducial::check_scan_pixel_um(px).map_err(|message| {
                EpochError::Epoch {
                    epoch: spec.name.clone(),
                    message,
                }
            })?;
        }
        Ok(Self {
            name: spec.name.clone(),
            date: spec.date.clone(),
            crs: crs.to_string(),
            origin,
            camera,
            photos,
            navigation,
            scan_pixel_um: spec.scan_pixel_um,
        })
    }

    /// Photos with no navigation record (they cannot be oriented; the report names them).
    pub fn unnavigated(&self) -> Vec<&str> {
        let names: std::collections::BTreeSet<&str> = self
            .navigation
            .names()
            .into_iter()
            .map(pos::photo_key)
            .collect();
        self.photos
            .iter()
            .map(|p| p.name.as_str())
            .filter(|n| !names.contains(n))
            .collect()
    }
}

/// The one rule for the block-local origin: the south-west corner of the area rounded
/// down to a kilometre, height 0 — local coordinates stay small and the origin reads well.
pub fn block_origin(points: impl IntoIterator<Item = [f64; 2]>) -> [f64; 3] {
    let (mut x, mut y) = (f64::INFINITY, f64::INFINITY);
    for p in points {
        if p[0].is_finite() && p[1].is_finite() {
            x = x.min(p[0]);
            y = y.min(p[1]);
        }
    }
    if !x.is_finite() {
        return [0.0; 3];
    }
    [
        (x / 1000.0).floor() * 1000.0,
        (y / 1000.0).floor() * 1000.0,
        0.0,
    ]
}

/// How the approximate orientations are stated when the navigation does not say.
#[derive(Debug, Clone)]
pub struct NavigationSigma {
    /// Centre σ (m) of strip end points (flight index) and attitude σ of strip photos.
    pub strip_end_m: f64,
    pub strip_attitude_deg: f64,
    /// POS without σ columns.
    pub pos_center_m: f64,
    pub pos_attitude_deg: f64,
    /// Replace the POS σ (centre m, attitude rad), e.g. to study EO groups.
    pub pos_override: Option<(f64, f64)>,
}

impl Default for NavigationSigma {
    fn default() -> Self {
        Self {
            strip_end_m: 10.0,
            strip_attitude_deg: 3.0,
            pos_center_m: 10.0,
            pos_attitude_deg: 3.0,
            pos_override: None,
        }
    }
}

/// Approximate orientation (block-local) with its σ per photo name of the epoch.
pub fn approximate_orientations(
    input: &EpochInput,
    dem: &Dem,
    sigma: &NavigationSigma,
) -> Result<BTreeMap<String, PosPrior>, EpochError> {
    let origin = Vector3::from(input.origin);
    let mut out = BTreeMap::new();
    match &input.navigation {
        Navigation::Pos(recs) => {
            for r in recs {
                let (sc, sa) = sigma.pos_override.unwrap_or((
                    r.sigma_xyz.unwrap_or(sigma.pos_center_m),
                    r.sigma_angle.unwrap_or(sigma.pos_attitude_deg.to_radians()),
                ));
                out.insert(
                    pos::photo_key(&r.name).to_string(),
                    PosPrior {
                        center: Vector3::from(r.center) - origin,
                        center_sigma: [sc; 3],
                        rotation: Some(matrix_from_opk(r.opk[0], r.opk[1], r.opk[2])),
                        rotation_sigma_rad: sa,
                    },
                );
            }
        }
        Navigation::Strips(ss) => {
            let (z0, z1) = dem.z_range();
            let ground = 0.5 * (z0 + z1);
            let att = sigma.strip_attitude_deg.to_radians();
            for s in ss {
                let local = StripEnds {
                    first: (Vector3::from(s.first) - origin).into(),
                    last: (Vector3::from(s.last) - origin).into(),
                    ..s.clone()
                };
                let list = strips::interpolate_strip(&local, 0.05, att).map_err(|e| {
                    EpochError::Epoch {
                        epoch: input.name.clone(),
                        message: e.to_string(),
                    }
                })?;
                for (name, (pose, prior)) in s.photos.iter().zip(list) {
                    // The flying height above ground fixes the scale of the prediction; the
                    // end points' heights are as uncertain as their positions.
                    let h = (pose.center.z - ground).abs();
                    let sc = prior.center_sigma[0].max(sigma.strip_end_m);
                    out.insert(
                        pos::photo_key(name).to_string(),
                        PosPrior {
                            center: pose.center,
                            center_sigma: [sc, sc, sigma.strip_end_m.max(0.01 * h)],
                            rotation: Some(pose.rotation),
                            rotation_sigma_rad: att,
                        },
                    );
                }
            }
        }
    }
    Ok(out)
}
