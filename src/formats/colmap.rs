//! COLMAP sparse models, text and binary, in the legacy 3-file layout (`cameras`,
//! `images`, `points3D`) and the COLMAP ≥ 3.12 / 4.x 5-file layout (`rigs`, `frames` too).
//!
//! Layouts and byte formats follow `colmap/src/colmap/scene/reconstruction_io_*.cc`
//! (see formats/colmap/README.md). COLMAP has no CRS: coordinates in the model are
//! block-local and the CRS, the block origin and the roles of control/check points travel
//! in a side file ([`SIDE_FILE`]) that COLMAP ignores.
//!
//! I/O streams through `BufReader`/`BufWriter`; a million-point model never exists as one
//! string. Every output file is written to a temporary sibling and renamed.

use super::{frame_equivalent, write_atomically, FormatError, Result};
use crate::block::{
    Block, BlockCamera, CameraId, ObjectPoint, Observation, Photo, PhotoId, PointId, PointKind,
};
use crate::geometry::{
    matrix_from_quaternion_wxyz, quaternion_wxyz_from_matrix, Brown, Camera, FrameCamera, Pose,
};
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

/// Side file with what COLMAP cannot hold: CRS, block origin, control/check points.
pub const SIDE_FILE: &str = "cloudcontrol_georef.json";

/// COLMAP's invalid `point3D_t` (2⁶⁴ − 1).
const INVALID_POINT3D: u64 = u64::MAX;

/// Observation σ given to COLMAP measurements, which carry none.
pub const DEFAULT_SIGMA_PX: f64 = 1.0;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    Text,
    Binary,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    /// `cameras`, `images`, `points3D` (COLMAP ≤ 3.11; read by every version).
    Legacy,
    /// Adds `rigs` and `frames` (one trivial rig per camera, one frame per image), as
    /// COLMAP 4.x writes.
    Rigs,
}

#[derive(Debug, Clone, Copy)]
pub struct WriteOptions {
    pub encoding: Encoding,
    pub layout: Layout,
}

impl Default for WriteOptions {
    fn default() -> Self {
        Self {
            encoding: Encoding::Binary,
            layout: Layout::Rigs,
        }
    }
}

/// COLMAP camera models that map onto [`FrameCamera`]: (id, name, number of parameters).
const MODELS: [(i32, &str, usize); 5] = [
    (0, "SIMPLE_PINHOLE", 3),
    (1, "PINHOLE", 4),
    (2, "SIMPLE_RADIAL", 4),
    (3, "RADIAL", 5),
    (4, "OPENCV", 8),
];
const FULL_OPENCV: (i32, &str, usize) = (6, "FULL_OPENCV", 12);

/// All COLMAP model names by id, to name unsupported ones in errors.
const ALL_MODEL_NAMES: [&str; 18] = [
    "SIMPLE_PINHOLE",
    "PINHOLE",
    "SIMPLE_RADIAL",
    "RADIAL",
    "OPENCV",
    "OPENCV_FISHEYE",
    "FULL_OPENCV",
    "FOV",
    "SIMPLE_RADIAL_FISHEYE",
    "RADIAL_FISHEYE",
    "THIN_PRISM_FISHEYE",
    "RAD_TAN_THIN_PRISM_FISHEYE",
    "SIMPLE_DIVISION",
    "DIVISION",
    "SIMPLE_FISHEYE",
    "FISHEYE",
    "EUCM",
    "EQUIRECTANGULAR",
];

fn model_by_name(name: &str) -> Option<(i32, usize)> {
    MODELS
        .iter()
        .chain(std::iter::once(&FULL_OPENCV))
        .find(|m| m.1 == name)
        .map(|m| (m.0, m.2))
        .or_else(|| {
            ALL_MODEL_NAMES
                .iter()
                .position(|n| *n == name)
                .map(|i| (i as i32, usize::MAX))
        })
}

fn model_name(id: i32) -> String {
    usize::try_from(id)
        .ok()
        .and_then(|i| ALL_MODEL_NAMES.get(i))
        .map(|s| s.to_string())
        .unwrap_or_else(|| format!("model id {id}"))
}

fn num_params(id: i32) -> Option<usize> {
    MODELS
        .iter()
        .chain(std::iter::once(&FULL_OPENCV))
        .find(|m| m.0 == id)
        .map(|m| m.2)
}

/// Our frame camera from a COLMAP model's parameters.
fn camera_from_colmap(
    model: i32,
    width: u64,
    height: u64,
    p: &[f64],
) -> std::result::Result<FrameCamera, String> {
    let size = |v: u64, what: &str| {
        u32::try_from(v)
            .ok()
            .filter(|&v| v > 0)
            .ok_or_else(|| format!("{what} {v} is not a valid image size"))
    };
    let (width, height) = (size(width, "width")?, size(height, "height")?);
    if p.iter().any(|v| !v.is_finite()) {
        return Err("a parameter is not finite".into());
    }
    let d = |k1, k2, k3, p1, p2| Brown { k1, k2, k3, p1, p2 };
    let (fx, fy, cx, cy, distortion) = match model {
        0 => (p[0], p[0], p[1], p[2], Brown::default()),
        1 => (p[0], p[1], p[2], p[3], Brown::default()),
        2 => (p[0], p[0], p[1], p[2], d(p[3], 0.0, 0.0, 0.0, 0.0)),
        3 => (p[0], p[0], p[1], p[2], d(p[3], p[4], 0.0, 0.0, 0.0)),
        4 => (p[0], p[1], p[2], p[3], d(p[4], p[5], 0.0, p[6], p[7])),
        6 => {
            if p[9] != 0.0 || p[10] != 0.0 || p[11] != 0.0 {
                return Err(format!(
                    "FULL_OPENCV with rational radial terms k4..k6 = ({}, {}, {}) has no Brown \
                     equivalent; only k4 = k5 = k6 = 0 is supported",
                    p[9], p[10], p[11]
                ));
            }
            (p[0], p[1], p[2], p[3], d(p[4], p[5], p[8], p[6], p[7]))
        }
        _ => {
            return Err(format!(
                "camera model {} is not supported (supported: SIMPLE_PINHOLE, PINHOLE, \
                 SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV)",
                model_name(model)
            ))
        }
    };
    if fx <= 0.0 || fy <= 0.0 {
        return Err(format!(
            "focal length must be positive (fx = {fx}, fy = {fy})"
        ));
    }
    Ok(FrameCamera {
        width,
        height,
        fx,
        fy,
        cx,
        cy,
        distortion,
    })
}

/// The smallest COLMAP model that holds the camera exactly, and its parameters.
fn camera_to_colmap(c: &FrameCamera) -> (i32, &'static str, Vec<f64>) {
    let d = &c.distortion;
    let square = c.fx == c.fy;
    let tangential = d.p1 != 0.0 || d.p2 != 0.0;
    if d.is_zero() {
        if square {
            (0, "SIMPLE_PINHOLE", vec![c.fx, c.cx, c.cy])
        } else {
            (1, "PINHOLE", vec![c.fx, c.fy, c.cx, c.cy])
        }
    } else if square && !tangential && d.k3 == 0.0 && d.k2 == 0.0 {
        (2, "SIMPLE_RADIAL", vec![c.fx, c.cx, c.cy, d.k1])
    } else if square && !tangential && d.k3 == 0.0 {
        (3, "RADIAL", vec![c.fx, c.cx, c.cy, d.k1, d.k2])
    } else if d.k3 == 0.0 {
        (
            4,
            "OPENCV",
            vec![c.fx, c.fy, c.cx, c.cy, d.k1, d.k2, d.p1, d.p2],
        )
    } else {
        (
            6,
            "FULL_OPENCV",
            vec![
                c.fx, c.fy, c.cx, c.cy, d.k1, d.k2, d.p1, d.p2, d.k3, 0.0, 0.0, 0.0,
            ],
        )
    }
}

/// What the side file holds.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
struct SideFile {
    crs: Option<String>,
    origin: [f64; 3],
    /// Control and check points (tie points need no entry).
    #[serde(default)]
    points: Vec<SidePoint>,
    /// Photo metadata COLMAP has no field for.
    #[serde(default)]
    photos: Vec<SidePhoto>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct SidePoint {
    id: PointId,
    name: String,
    kind: PointKind,
    /// σ x, y, z (m); `null` for an unconstrained coordinate (σ = ∞, e.g. the height of a
    /// horizontal control point), which JSON cannot write as a number.
    sigma: Option<[Option<f64>; 3]>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct SidePhoto {
    id: PhotoId,
    date: Option<String>,
}

/// A parsed image record before its 2-D points are attached to object points.
struct Image {
    id: PhotoId,
    pose: Pose,
    camera: CameraId,
    name: String,
    points2d: Vec<([f64; 2], u64)>,
}

/// Sensor poses of one rig: camera id → `sensor_from_rig` (None for the reference sensor).
type RigSensors = HashMap<u32, Option<Pose>>;

fn pose_from_qt(q: [f64; 4], t: [f64; 3]) -> std::result::Result<Pose, String> {
    let n = (q.iter().map(|v| v * v).sum::<f64>()).sqrt();
    if !n.is_finite() || (n - 1.0).abs() > 1e-3 || t.iter().any(|v| !v.is_finite()) {
        return Err(format!(
            "pose is not a unit quaternion with a finite translation (|q| = {n})"
        ));
    }
    let r = matrix_from_quaternion_wxyz([q[0] / n, q[1] / n, q[2] / n, q[3] / n]);
    Ok(Pose::from_rotation_translation(r, Vector3::from(t)))
}

fn qt_from_pose(p: &Pose) -> ([f64; 4], [f64; 3]) {
    let t = p.translation();
    (quaternion_wxyz_from_matrix(&p.rotation), [t.x, t.y, t.z])
}

/// `a ∘ b` for cam_from_world style poses: x ↦ a(b(x)).
fn compose(a: &Pose, b: &Pose) -> Pose {
    let r: Matrix3<f64> = a.rotation * b.rotation;
    let t = a.rotation * b.translation() + a.translation();
    Pose::from_rotation_translation(r, t)
}

fn find_file(dir: &Path, stem: &str) -> Option<(PathBuf, Encoding)> {
    let bin = dir.join(format!("{stem}.bin"));
    if bin.is_file() {
        return Some((bin, Encoding::Binary));
    }
    let txt = dir.join(format!("{stem}.txt"));
    txt.is_file().then_some((txt, Encoding::Text))
}

fn open(path: &Path) -> Result<BufReader<File>> {
    File::open(path)
        .map(|f| BufReader::with_capacity(1 << 20, f))
        .map_err(|e| FormatError::io(path, e))
}

// ---------------------------------------------------------------------------------------
// Reading
// ---------------------------------------------------------------------------------------

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
        Encoding::Binary => read_cameras_bin(&cam_path)?,
        Encoding::Text => read_cameras_txt(&cam_path)?,
    };
    for (id, cam) in cameras {
        block.cameras.insert(
            id,
            BlockCamera {
                id,
                name: format!("camera {id}"),
                model: Camera::Frame(cam),
                free_params: Vec::new(),
            },
        );
    }

    let mut images = match img_enc {
        Encoding::Binary => read_images_bin(&img_path)?,
        Encoding::Text => read_images_txt(&img_path)?,
    };

    // COLMAP 4.x: the pose of record is the frame's rig_from_world composed with the
    // sensor's sensor_from_rig; the copy in `images` is ignored on read, as COLMAP does.
    if let (Some((rig_path, rig_enc)), Some((frm_path, frm_enc))) =
        (find_file(dir, "rigs"), find_file(dir, "frames"))
    {
        let rigs = match rig_enc {
            Encoding::Binary => read_rigs_bin(&rig_path)?,
            Encoding::Text => read_rigs_txt(&rig_path)?,
        };
        let frames = match frm_enc {
            Encoding::Binary => read_frames_bin(&frm_path)?,
            Encoding::Text => read_frames_txt(&frm_path)?,
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
        Encoding::Binary => read_points_bin(&pts_path, &mut sink)?,
        Encoding::Text => read_points_txt(&pts_path, &mut sink)?,
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

    let side = dir.join(SIDE_FILE);
    if side.is_file() {
        let s = std::fs::read_to_string(&side).map_err(|e| FormatError::io(&side, e))?;
        let sf: SideFile = serde_json::from_str(&s)
            .map_err(|e| FormatError::invalid(&side, format!("not a valid side file: {e}")))?;
        block.crs = sf.crs;
        block.origin = sf.origin;
        for sp in sf.points {
            let p = block.points.get_mut(&sp.id).ok_or_else(|| {
                FormatError::invalid(&side, format!("point {} is not in points3D", sp.id))
            })?;
            p.name = sp.name;
            p.kind = sp.kind;
            p.sigma = sp.sigma.map(|s| s.map(|v| v.unwrap_or(f64::INFINITY)));
        }
        for ph in sf.photos {
            if let Some(p) = block.photos.get_mut(&ph.id) {
                p.date = ph.date;
            }
        }
    }
    tracing::info!(
        dir = %dir.display(),
        cameras = block.cameras.len(),
        images = block.photos.len(),
        points = block.points.len(),
        "read COLMAP model"
    );
    Ok(block)
}

/// Binary reader that turns short reads into "truncated" errors naming the record.
struct Bin {
    r: BufReader<File>,
    path: PathBuf,
    buf: Vec<u8>,
    len: u64,
}

impl Bin {
    fn open(path: &Path) -> Result<Self> {
        let r = open(path)?;
        let len = r.get_ref().metadata().map(|m| m.len()).unwrap_or(u64::MAX);
        Ok(Self {
            r,
            path: path.to_path_buf(),
            buf: Vec::new(),
            len,
        })
    }
    /// `n` bytes in one read (whole arrays of fixed-size items), in a reused buffer.
    fn chunk(&mut self, n: usize, what: &dyn Fn() -> String) -> Result<&[u8]> {
        self.buf.resize(n, 0);
        if let Err(e) = self.r.read_exact(&mut self.buf) {
            return Err(self.fail(e, what));
        }
        Ok(&self.buf)
    }
    fn fail(&self, e: std::io::Error, what: &dyn Fn() -> String) -> FormatError {
        if e.kind() == std::io::ErrorKind::UnexpectedEof {
            FormatError::invalid(
                &self.path,
                format!("truncated: the file ends inside {}", what()),
            )
        } else {
            FormatError::io(&self.path, e)
        }
    }
    fn bytes<const N: usize>(&mut self, what: &dyn Fn() -> String) -> Result<[u8; N]> {
        let mut b = [0u8; N];
        match self.r.read_exact(&mut b) {
            Ok(()) => Ok(b),
            Err(e) => Err(self.fail(e, what)),
        }
    }
    fn u8(&mut self, what: &dyn Fn() -> String) -> Result<u8> {
        Ok(self.bytes::<1>(what)?[0])
    }
    fn u32(&mut self, what: &dyn Fn() -> String) -> Result<u32> {
        Ok(u32::from_le_bytes(self.bytes(what)?))
    }
    fn i32(&mut self, what: &dyn Fn() -> String) -> Result<i32> {
        Ok(i32::from_le_bytes(self.bytes(what)?))
    }
    fn u64(&mut self, what: &dyn Fn() -> String) -> Result<u64> {
        Ok(u64::from_le_bytes(self.bytes(what)?))
    }
    fn f64(&mut self, what: &dyn Fn() -> String) -> Result<f64> {
        Ok(f64::from_le_bytes(self.bytes(what)?))
    }
    fn f64s<const N: usize>(&mut self, what: &dyn Fn() -> String) -> Result<[f64; N]> {
        let mut out = [0.0; N];
        for v in out.iter_mut() {
            *v = self.f64(what)?;
        }
        Ok(out)
    }
    fn cstring(&mut self, what: &dyn Fn() -> String) -> Result<String> {
        let mut buf = Vec::new();
        match self.r.read_until(0, &mut buf) {
            Ok(_) if buf.last() == Some(&0) => {
                buf.pop();
                String::from_utf8(buf).map_err(|_| {
                    FormatError::invalid(&self.path, format!("{}: name is not UTF-8", what()))
                })
            }
            Ok(_) => Err(FormatError::invalid(
                &self.path,
                format!("truncated: the file ends inside {}", what()),
            )),
            Err(e) => Err(self.fail(e, what)),
        }
    }
    /// A count, refused when it could not fit in the rest of the file (corrupt header).
    fn count(&mut self, min_record: u64, what: &dyn Fn() -> String) -> Result<u64> {
        let n = self.u64(what)?;
        let len = self.len;
        if n.saturating_mul(min_record) > len {
            return Err(FormatError::invalid(
                &self.path,
                format!(
                    "{}: count {n} cannot fit in a file of {len} bytes (corrupt or truncated)",
                    what()
                ),
            ));
        }
        Ok(n)
    }
    fn expect_end(&mut self) -> Result<()> {
        let mut b = [0u8; 1];
        match self.r.read(&mut b) {
            Ok(0) => Ok(()),
            Ok(_) => Err(FormatError::invalid(
                &self.path,
                "trailing bytes after the last record",
            )),
            Err(e) => Err(FormatError::io(&self.path, e)),
        }
    }
}

fn read_cameras_bin(path: &Path) -> Result<BTreeMap<CameraId, FrameCamera>> {
    let mut b = Bin::open(path)?;
    let n = b.count(24, &|| "the camera count".into())?;
    let mut out = BTreeMap::new();
    for i in 0..n {
        let ctx = || format!("camera record {i}");
        let id = b.u32(&ctx)?;
        let model = b.i32(&ctx)?;
        let w = b.u64(&ctx)?;
        let h = b.u64(&ctx)?;
        let np = num_params(model).ok_or_else(|| {
            FormatError::invalid(
                path,
                format!(
                    "camera {id}: camera model {} is not supported (supported: SIMPLE_PINHOLE, \
                     PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV)",
                    model_name(model)
                ),
            )
        })?;
        let mut p = vec![0.0; np];
        for v in p.iter_mut() {
            *v = b.f64(&ctx)?;
        }
        let cam = camera_from_colmap(model, w, h, &p)
            .map_err(|m| FormatError::invalid(path, format!("camera {id}: {m}")))?;
        if out.insert(id, cam).is_some() {
            return Err(FormatError::invalid(
                path,
                format!("camera id {id} appears twice"),
            ));
        }
    }
    b.expect_end()?;
    Ok(out)
}

fn read_images_bin(path: &Path) -> Result<Vec<Image>> {
    let mut b = Bin::open(path)?;
    let n = b.count(64, &|| "the image count".into())?;
    let mut out = Vec::with_capacity(n as usize);
    for i in 0..n {
        let ctx = || format!("image record {i}");
        let id = b.u32(&ctx)?;
        let ctx = || format!("image {id}");
        let q = b.f64s::<4>(&ctx)?;
        let t = b.f64s::<3>(&ctx)?;
        let camera = b.u32(&ctx)?;
        let name = b.cstring(&ctx)?;
        let np = b.count(24, &ctx)?;
        let points2d = b
            .chunk(np as usize * 24, &ctx)?
            .chunks_exact(24)
            .map(|c| ([le_f64(&c[0..8]), le_f64(&c[8..16])], le_u64(&c[16..24])))
            .collect();
        let pose = pose_from_qt(q, t)
            .map_err(|m| FormatError::invalid(path, format!("image {id} ({name}): {m}")))?;
        out.push(Image {
            id,
            pose,
            camera,
            name,
            points2d,
        });
    }
    b.expect_end()?;
    Ok(out)
}

type PointSink<'a> =
    dyn FnMut(u64, [f64; 3], [u8; 3], &[(u32, u32)]) -> std::result::Result<(), String> + 'a;

fn read_points_bin(path: &Path, sink: &mut PointSink) -> Result<()> {
    let mut b = Bin::open(path)?;
    let n = b.count(43, &|| "the point count".into())?;
    let mut track = Vec::new();
    for i in 0..n {
        let ctx = || format!("point record {i}");
        // id, x y z, r g b, error, track length: one fixed 51-byte head.
        let h = b.chunk(51, &ctx)?;
        let id = le_u64(&h[0..8]);
        let xyz = [le_f64(&h[8..16]), le_f64(&h[16..24]), le_f64(&h[24..32])];
        let rgb = [h[32], h[33], h[34]];
        let len = le_u64(&h[43..51]);
        let ctx = || format!("point {id}");
        if len.saturating_mul(8) > b.len {
            return Err(FormatError::invalid(
                path,
                format!(
                    "point {id}: track length {len} cannot fit in the file (corrupt or truncated)"
                ),
            ));
        }
        track.clear();
        track.extend(
            b.chunk(len as usize * 8, &ctx)?
                .chunks_exact(8)
                .map(|c| (le_u32(&c[0..4]), le_u32(&c[4..8]))),
        );
        sink(id, xyz, rgb, &track).map_err(|m| FormatError::invalid(path, m))?;
    }
    b.expect_end()
}

#[inline]
fn le_f64(b: &[u8]) -> f64 {
    f64::from_le_bytes(b.try_into().expect("8 bytes"))
}
#[inline]
fn le_u64(b: &[u8]) -> u64 {
    u64::from_le_bytes(b.try_into().expect("8 bytes"))
}
#[inline]
fn le_u32(b: &[u8]) -> u32 {
    u32::from_le_bytes(b.try_into().expect("4 bytes"))
}

fn read_rigs_bin(path: &Path) -> Result<HashMap<u32, RigSensors>> {
    let mut b = Bin::open(path)?;
    let n = b.count(8, &|| "the rig count".into())?;
    let mut out = HashMap::new();
    for i in 0..n {
        let ctx = || format!("rig record {i}");
        let id = b.u32(&ctx)?;
        let ns = b.u32(&ctx)?;
        let mut sensors = RigSensors::new();
        if ns > 0 {
            let ty = b.i32(&ctx)?;
            let sid = b.u32(&ctx)?;
            if ty == 0 {
                sensors.insert(sid, None);
            }
            for _ in 1..ns {
                let ty = b.i32(&ctx)?;
                let sid = b.u32(&ctx)?;
                let has = b.u8(&ctx)?;
                let pose = if has != 0 {
                    let q = b.f64s::<4>(&ctx)?;
                    let t = b.f64s::<3>(&ctx)?;
                    Some(pose_from_qt(q, t).map_err(|m| {
                        FormatError::invalid(path, format!("rig {id}, sensor {sid}: {m}"))
                    })?)
                } else {
                    None
                };
                if ty == 0 {
                    sensors.insert(sid, pose);
                }
            }
        }
        out.insert(id, sensors);
    }
    b.expect_end()?;
    Ok(out)
}

type FrameRecord = (u32, u32, Pose, Vec<(i32, u32, u64)>);

fn read_frames_bin(path: &Path) -> Result<Vec<FrameRecord>> {
    let mut b = Bin::open(path)?;
    let n = b.count(68, &|| "the frame count".into())?;
    let mut out = Vec::with_capacity(n as usize);
    for i in 0..n {
        let ctx = || format!("frame record {i}");
        let id = b.u32(&ctx)?;
        let rig = b.u32(&ctx)?;
        let q = b.f64s::<4>(&ctx)?;
        let t = b.f64s::<3>(&ctx)?;
        let nd = b.u32(&ctx)?;
        let mut data = Vec::with_capacity(nd as usize);
        for _ in 0..nd {
            data.push((b.i32(&ctx)?, b.u32(&ctx)?, b.u64(&ctx)?));
        }
        let pose = pose_from_qt(q, t)
            .map_err(|m| FormatError::invalid(path, format!("frame {id}: {m}")))?;
        out.push((id, rig, pose, data));
    }
    b.expect_end()?;
    Ok(out)
}

/// Whitespace-token cursor over one text line, with errors naming file, line and field.
struct Tokens<'a> {
    it: std::str::SplitWhitespace<'a>,
    path: &'a Path,
    line: usize,
}

impl<'a> Tokens<'a> {
    fn new(s: &'a str, path: &'a Path, line: usize) -> Self {
        Self {
            it: s.split_whitespace(),
            path,
            line,
        }
    }
    fn err(&self, m: impl std::fmt::Display) -> FormatError {
        FormatError::invalid(self.path, format!("line {}: {m}", self.line))
    }
    fn next_str(&mut self, field: &str) -> Result<&'a str> {
        let (path, line) = (self.path, self.line);
        self.it.next().ok_or_else(|| {
            FormatError::invalid(path, format!("line {line}: field {field} is missing"))
        })
    }
    fn parse<T: std::str::FromStr>(&mut self, field: &str) -> Result<T> {
        let s = self.next_str(field)?;
        s.parse()
            .map_err(|_| self.err(format!("field {field} is not a valid number: {s:?}")))
    }
    fn f64s<const N: usize>(&mut self, field: &str) -> Result<[f64; N]> {
        let mut out = [0.0; N];
        for v in out.iter_mut() {
            *v = self.parse(field)?;
        }
        Ok(out)
    }
    fn rest_is_empty(&mut self) -> Result<()> {
        match self.it.next() {
            None => Ok(()),
            Some(s) => Err(self.err(format!("unexpected trailing field {s:?}"))),
        }
    }
}

/// Data lines of a COLMAP text file (comments and blank lines skipped) with 1-based
/// line numbers; `keep_empty` keeps blank lines (an image's empty POINTS2D line).
fn text_lines(
    path: &Path,
    keep_empty: bool,
) -> Result<impl Iterator<Item = Result<(usize, String)>>> {
    let r = open(path)?;
    let p = path.to_path_buf();
    Ok(r.lines().enumerate().filter_map(move |(i, l)| match l {
        Err(e) => Some(Err(FormatError::io(&p, e))),
        Ok(l) => {
            let t = l.trim_start();
            if t.starts_with('#') || (!keep_empty && t.trim().is_empty()) {
                None
            } else {
                Some(Ok((i + 1, l)))
            }
        }
    }))
}

fn read_cameras_txt(path: &Path) -> Result<BTreeMap<CameraId, FrameCamera>> {
    let mut out = BTreeMap::new();
    for line in text_lines(path, false)? {
        let (no, l) = line?;
        let mut t = Tokens::new(&l, path, no);
        let id: u32 = t.parse("CAMERA_ID")?;
        let name = t.next_str("MODEL")?;
        let (model, np) = model_by_name(name)
            .ok_or_else(|| t.err(format!("camera {id}: unknown camera model {name:?}")))?;
        if np == usize::MAX {
            return Err(t.err(format!(
                "camera {id}: camera model {name} is not supported (supported: SIMPLE_PINHOLE, \
                 PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV)"
            )));
        }
        let w: u64 = t.parse("WIDTH")?;
        let h: u64 = t.parse("HEIGHT")?;
        let mut p = vec![0.0; np];
        for v in p.iter_mut() {
            *v = t.parse("PARAMS")?;
        }
        t.rest_is_empty()?;
        let cam =
            camera_from_colmap(model, w, h, &p).map_err(|m| t.err(format!("camera {id}: {m}")))?;
        if out.insert(id, cam).is_some() {
            return Err(t.err(format!("camera id {id} appears twice")));
        }
    }
    Ok(out)
}

fn read_images_txt(path: &Path) -> Result<Vec<Image>> {
    let mut out = Vec::new();
    let mut lines = text_lines(path, true)?;
    while let Some(line) = lines.next() {
        let (no, l) = line?;
        if l.trim().is_empty() {
            continue;
        }
        let mut t = Tokens::new(&l, path, no);
        let id: u32 = t.parse("IMAGE_ID")?;
        let q = t.f64s::<4>("QW QX QY QZ")?;
        let tr = t.f64s::<3>("TX TY TZ")?;
        let camera: u32 = t.parse("CAMERA_ID")?;
        let name = t.next_str("NAME")?.to_string();
        t.rest_is_empty()?;
        let pose = pose_from_qt(q, tr).map_err(|m| t.err(format!("image {id} ({name}): {m}")))?;
        let mut points2d = Vec::new();
        match lines.next() {
            None => {
                return Err(FormatError::invalid(
                    path,
                    format!("truncated: image {id} ({name}) has no POINTS2D line"),
                ))
            }
            Some(pl) => {
                let (no2, pl) = pl?;
                let mut t2 = Tokens::new(&pl, path, no2);
                while let Some(x) = t2.it.next() {
                    let x: f64 = x.parse().map_err(|_| {
                        t2.err(format!("image {id}: POINTS2D X is not a number: {x:?}"))
                    })?;
                    let y: f64 = t2.parse("POINTS2D Y")?;
                    let pid: i64 = t2.parse("POINTS2D POINT3D_ID")?;
                    let pid = if pid < 0 { INVALID_POINT3D } else { pid as u64 };
                    points2d.push(([x, y], pid));
                }
            }
        }
        out.push(Image {
            id,
            pose,
            camera,
            name,
            points2d,
        });
    }
    Ok(out)
}

fn read_points_txt(path: &Path, sink: &mut PointSink) -> Result<()> {
    let mut track = Vec::new();
    for line in text_lines(path, false)? {
        let (no, l) = line?;
        let mut t = Tokens::new(&l, path, no);
        let id: u64 = t.parse("POINT3D_ID")?;
        let xyz = t.f64s::<3>("X Y Z")?;
        let rgb = [t.parse("R")?, t.parse("G")?, t.parse("B")?];
        let _error: f64 = t.parse("ERROR")?;
        track.clear();
        while let Some(s) = t.it.next() {
            let im: u32 = s
                .parse()
                .map_err(|_| t.err(format!("point {id}: TRACK IMAGE_ID is not valid: {s:?}")))?;
            let idx: u32 = t.parse("TRACK POINT2D_IDX")?;
            track.push((im, idx));
        }
        sink(id, xyz, rgb, &track).map_err(|m| t.err(m))?;
    }
    Ok(())
}

fn sensor_type(s: &str) -> i32 {
    match s {
        "CAMERA" => 0,
        "IMU" => 1,
        _ => -1,
    }
}

fn read_rigs_txt(path: &Path) -> Result<HashMap<u32, RigSensors>> {
    let mut out = HashMap::new();
    for line in text_lines(path, false)? {
        let (no, l) = line?;
        let mut t = Tokens::new(&l, path, no);
        let id: u32 = t.parse("RIG_ID")?;
        let ns: u32 = t.parse("NUM_SENSORS")?;
        let mut sensors = RigSensors::new();
        if ns > 0 {
            let ty = sensor_type(t.next_str("REF_SENSOR_TYPE")?);
            let sid: u32 = t.parse("REF_SENSOR_ID")?;
            if ty == 0 {
                sensors.insert(sid, None);
            }
            for _ in 1..ns {
                let ty = sensor_type(t.next_str("SENSOR_TYPE")?);
                let sid: u32 = t.parse("SENSOR_ID")?;
                let has: u32 = t.parse("HAS_POSE")?;
                let pose = if has != 0 {
                    let q = t.f64s::<4>("QW QX QY QZ")?;
                    let tr = t.f64s::<3>("TX TY TZ")?;
                    Some(pose_from_qt(q, tr).map_err(|m| t.err(format!("rig {id}: {m}")))?)
                } else {
                    None
                };
                if ty == 0 {
                    sensors.insert(sid, pose);
                }
            }
        }
        out.insert(id, sensors);
    }
    Ok(out)
}

fn read_frames_txt(path: &Path) -> Result<Vec<FrameRecord>> {
    let mut out = Vec::new();
    for line in text_lines(path, false)? {
        let (no, l) = line?;
        let mut t = Tokens::new(&l, path, no);
        let id: u32 = t.parse("FRAME_ID")?;
        let rig: u32 = t.parse("RIG_ID")?;
        let q = t.f64s::<4>("QW QX QY QZ")?;
        let tr = t.f64s::<3>("TX TY TZ")?;
        let nd: u32 = t.parse("NUM_DATA_IDS")?;
        let mut data = Vec::with_capacity(nd as usize);
        for _ in 0..nd {
            let ty = sensor_type(t.next_str("SENSOR_TYPE")?);
            data.push((ty, t.parse("SENSOR_ID")?, t.parse("DATA_ID")?));
        }
        let pose = pose_from_qt(q, tr).map_err(|m| t.err(format!("frame {id}: {m}")))?;
        out.push((id, rig, pose, data));
    }
    Ok(out)
}

// ---------------------------------------------------------------------------------------
// Writing
// ---------------------------------------------------------------------------------------

/// Where each observation sits in its image's POINTS2D list, in point iteration order.
struct Layout2d {
    /// Per photo: (pixel, point id) in POINTS2D order (observations, then free keypoints).
    per_photo: BTreeMap<PhotoId, Vec<([f64; 2], u64)>>,
    /// Flat over all observations of all points in `block.points` order: the POINT2D_IDX.
    idx: Vec<u32>,
}

fn layout_2d(block: &Block) -> Result<Layout2d> {
    let mut per_photo: BTreeMap<PhotoId, Vec<([f64; 2], u64)>> =
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
fn colmap_cameras(block: &Block) -> Result<BTreeMap<CameraId, FrameCamera>> {
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
    std::fs::create_dir_all(dir).map_err(|e| FormatError::io(dir, e))?;
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
    let ext = if text { "txt" } else { "bin" };
    let file = |stem: &str| dir.join(format!("{stem}.{ext}"));
    let writer = |tmp: &Path| -> Result<BufWriter<File>> {
        File::create(tmp)
            .map(|f| BufWriter::with_capacity(1 << 20, f))
            .map_err(|e| FormatError::io(tmp, e))
    };
    macro_rules! w {
        ($path:expr, $w:expr, $($arg:tt)*) => {
            write!($w, $($arg)*).map_err(|e| FormatError::io($path, e))?
        };
    }
    macro_rules! b {
        ($path:expr, $w:expr, $v:expr) => {
            $w.write_all(&$v.to_le_bytes())
                .map_err(|e| FormatError::io($path, e))?
        };
    }
    let finish = |path: &Path, w: BufWriter<File>| -> Result<()> {
        let f = w
            .into_inner()
            .map_err(|e| FormatError::io(path, e.into_error()))?;
        f.sync_all().map_err(|e| FormatError::io(path, e))
    };

    // cameras
    let path = file("cameras");
    write_atomically(&path, |tmp| {
        let mut w = writer(tmp)?;
        if text {
            w!(&path, w, "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n# Number of cameras: {}\n", cams.len());
        } else {
            b!(&path, w, cams.len() as u64);
        }
        for (&id, c) in &cams {
            let (model, name, params) = camera_to_colmap(c);
            if text {
                w!(&path, w, "{id} {name} {} {}", c.width, c.height);
                for p in &params {
                    w!(&path, w, " {p}");
                }
                w!(&path, w, "\n");
            } else {
                b!(&path, w, id);
                b!(&path, w, model);
                b!(&path, w, c.width as u64);
                b!(&path, w, c.height as u64);
                for p in &params {
                    b!(&path, w, p);
                }
            }
        }
        finish(&path, w)
    })?;

    // images
    let path = file("images");
    write_atomically(&path, |tmp| {
        let mut w = writer(tmp)?;
        if text {
            w!(&path, w, "# Image list with two lines of data per image:\n#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n#   POINTS2D[] as (X, Y, POINT3D_ID)\n# Number of images: {}\n", block.photos.len());
        } else {
            b!(&path, w, block.photos.len() as u64);
        }
        for (id, ph) in &block.photos {
            let (q, t) = qt_from_pose(&ph.pose);
            let pts = &l2d.per_photo[id];
            if text {
                w!(
                    &path,
                    w,
                    "{id} {} {} {} {} {} {} {} {} {}\n",
                    q[0],
                    q[1],
                    q[2],
                    q[3],
                    t[0],
                    t[1],
                    t[2],
                    ph.camera,
                    ph.name
                );
                for (k, (xy, pid)) in pts.iter().enumerate() {
                    let sep = if k == 0 { "" } else { " " };
                    if *pid == INVALID_POINT3D {
                        w!(&path, w, "{sep}{} {} -1", xy[0], xy[1]);
                    } else {
                        w!(&path, w, "{sep}{} {} {pid}", xy[0], xy[1]);
                    }
                }
                w!(&path, w, "\n");
            } else {
                b!(&path, w, *id);
                for v in q.iter().chain(t.iter()) {
                    b!(&path, w, v);
                }
                b!(&path, w, ph.camera);
                w.write_all(ph.name.as_bytes())
                    .and_then(|_| w.write_all(&[0]))
                    .map_err(|e| FormatError::io(&path, e))?;
                b!(&path, w, pts.len() as u64);
                let mut rec: Vec<u8> = Vec::with_capacity(pts.len() * 24);
                for (xy, pid) in pts {
                    rec.extend_from_slice(&xy[0].to_le_bytes());
                    rec.extend_from_slice(&xy[1].to_le_bytes());
                    rec.extend_from_slice(&pid.to_le_bytes());
                }
                w.write_all(&rec).map_err(|e| FormatError::io(&path, e))?;
            }
        }
        finish(&path, w)
    })?;

    // points3D
    let path = file("points3D");
    // COLMAP's ERROR column: recomputed from the block, in parallel (deterministic: one
    // value per point, collected in order).
    let all: Vec<&ObjectPoint> = block.points.values().collect();
    let errors: Vec<f64> = {
        use rayon::prelude::*;
        all.par_iter()
            .map(|p| mean_error(p, block, &models))
            .collect()
    };
    write_atomically(&path, |tmp| {
        let mut w = writer(tmp)?;
        if text {
            w!(&path, w, "# 3D point list with one line of data per point:\n#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n# Number of points: {}\n", block.points.len());
        } else {
            b!(&path, w, block.points.len() as u64);
        }
        let mut k = 0usize;
        let mut rec: Vec<u8> = Vec::with_capacity(256);
        for (p, err) in all.iter().zip(&errors) {
            let (id, x) = (p.id, &p.position);
            if text {
                w!(
                    &path,
                    w,
                    "{id} {} {} {} {} {} {} {err}",
                    x.x,
                    x.y,
                    x.z,
                    p.color[0],
                    p.color[1],
                    p.color[2]
                );
                for o in &p.observations {
                    w!(&path, w, " {} {}", o.photo, l2d.idx[k]);
                    k += 1;
                }
                w!(&path, w, "\n");
            } else {
                rec.clear();
                rec.extend_from_slice(&id.to_le_bytes());
                for v in [x.x, x.y, x.z] {
                    rec.extend_from_slice(&v.to_le_bytes());
                }
                rec.extend_from_slice(&p.color);
                rec.extend_from_slice(&err.to_le_bytes());
                rec.extend_from_slice(&(p.observations.len() as u64).to_le_bytes());
                for o in &p.observations {
                    rec.extend_from_slice(&o.photo.to_le_bytes());
                    rec.extend_from_slice(&l2d.idx[k].to_le_bytes());
                    k += 1;
                }
                w.write_all(&rec).map_err(|e| FormatError::io(&path, e))?;
            }
        }
        finish(&path, w)
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
    if opts.layout == Layout::Rigs {
        let path = file("rigs");
        write_atomically(&path, |tmp| {
            let mut w = writer(tmp)?;
            if text {
                w!(&path, w, "# Rig calib list with one line of data per calib:\n#   RIG_ID, NUM_SENSORS, REF_SENSOR_TYPE, REF_SENSOR_ID, SENSORS[] as (SENSOR_TYPE, SENSOR_ID, HAS_POSE, [QW, QX, QY, QZ, TX, TY, TZ])\n# Number of rigs: {}\n", cams.len());
            } else {
                b!(&path, w, cams.len() as u64);
            }
            for &id in cams.keys() {
                if text {
                    w!(&path, w, "{id} 1 CAMERA {id}\n");
                } else {
                    b!(&path, w, id);
                    b!(&path, w, 1u32);
                    b!(&path, w, 0i32);
                    b!(&path, w, id);
                }
            }
            finish(&path, w)
        })?;
        let path = file("frames");
        write_atomically(&path, |tmp| {
            let mut w = writer(tmp)?;
            if text {
                w!(&path, w, "# Frame list with one line of data per frame:\n#   FRAME_ID, RIG_ID, RIG_FROM_WORLD[QW, QX, QY, QZ, TX, TY, TZ], NUM_DATA_IDS, DATA_IDS[] as (SENSOR_TYPE, SENSOR_ID, DATA_ID)\n# Number of frames: {}\n", block.photos.len());
            } else {
                b!(&path, w, block.photos.len() as u64);
            }
            for (id, ph) in &block.photos {
                let (q, t) = qt_from_pose(&ph.pose);
                if text {
                    w!(
                        &path,
                        w,
                        "{id} {} {} {} {} {} {} {} {} 1 CAMERA {} {id}\n",
                        ph.camera,
                        q[0],
                        q[1],
                        q[2],
                        q[3],
                        t[0],
                        t[1],
                        t[2],
                        ph.camera
                    );
                } else {
                    b!(&path, w, *id);
                    b!(&path, w, ph.camera);
                    for v in q.iter().chain(t.iter()) {
                        b!(&path, w, v);
                    }
                    b!(&path, w, 1u32);
                    b!(&path, w, 0i32);
                    b!(&path, w, ph.camera);
                    b!(&path, w, *id as u64);
                }
            }
            finish(&path, w)
        })?;
    }

    let side = SideFile {
        crs: block.crs.clone(),
        origin: block.origin,
        points: block
            .points
            .values()
            .filter(|p| p.kind != PointKind::Tie || !p.name.is_empty() || p.sigma.is_some())
            .map(|p| SidePoint {
                id: p.id,
                name: p.name.clone(),
                kind: p.kind,
                sigma: p.sigma.map(|s| s.map(|v| v.is_finite().then_some(v))),
            })
            .collect(),
        photos: block
            .photos
            .values()
            .filter(|p| p.date.is_some())
            .map(|p| SidePhoto {
                id: p.id,
                date: p.date.clone(),
            })
            .collect(),
    };
    let json = serde_json::to_vec_pretty(&side).expect("side file serialises");
    super::write_bytes_atomically(&dir.join(SIDE_FILE), &json)?;
    tracing::info!(
        dir = %dir.display(),
        images = block.photos.len(),
        points = block.points.len(),
        "wrote COLMAP model"
    );
    Ok(())
}
