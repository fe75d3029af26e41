//! Digital Control Photo packages: reusable control patches with orientation, object
//! coordinates and metadata, specified in `formats/dcp/README.md`.
//!
//! A package is a folder: `manifest.json` (versioned, self-describing) and `chips/` (PNG
//! image patches around each control point in each photo that sees it). Every chip is
//! listed with its SHA-256 in the manifest, so a package is verified on import and is
//! readable without this library.

use super::dcp_files::{read_member, MemberError, MAX_CHIP_BYTES, MAX_MANIFEST_BYTES};
use crate::formats::crs::Crs;
use crate::geometry::{Camera, Pose};
use image::DynamicImage;
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

pub const DCP_FORMAT: &str = "cloudcontrol-dcp";
pub const DCP_VERSION: u32 = 1;
const MANIFEST: &str = "manifest.json";

pub use super::plan_index::{point_in_polygon, DcpIndex, PlanIndex};

#[derive(Debug, thiserror::Error)]
pub enum DcpError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("DCP package {package}: {message}")]
    Invalid { package: PathBuf, message: String },
    #[error("DCP package {package}: chip {file}: {message}")]
    Chip {
        package: PathBuf,
        file: String,
        message: String,
    },
}

pub type Result<T> = std::result::Result<T, DcpError>;

fn invalid(package: &Path, message: impl Into<String>) -> DcpError {
    DcpError::Invalid {
        package: package.to_path_buf(),
        message: message.into(),
    }
}

/// Epoch the control was derived from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EpochInfo {
    pub name: String,
    /// Acquisition date (ISO 8601), when known.
    #[serde(default)]
    pub date: Option<String>,
}

/// Accuracy of the control points' object coordinates (1σ, m).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Accuracy {
    pub plan_m: f64,
    pub height_m: f64,
}

/// An oriented photo of the package.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DcpPhoto {
    pub id: u32,
    pub name: String,
    pub camera: Camera,
    /// World→camera rotation, row-major (x right, y down, z forward).
    pub rotation: [f64; 9],
    /// Projection centre in world coordinates of the package CRS.
    pub center: [f64; 3],
    #[serde(default)]
    pub date: Option<String>,
}

impl DcpPhoto {
    /// Exterior orientation in a block-local frame with the given origin.
    pub fn pose(&self, origin: &Vector3<f64>) -> Pose {
        Pose::new(
            Matrix3::from_row_slice(&self.rotation),
            Vector3::from(self.center) - origin,
        )
    }
}

/// Where a chip sits in its photo.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChipRef {
    /// Path relative to the package folder.
    pub file: String,
    /// Photo pixel of the chip's top-left corner (integer: chips are cut on the pixel grid).
    pub x0: u32,
    pub y0: u32,
    pub width: u32,
    pub height: u32,
}

/// One image measurement of a control point with its chip.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DcpMeasurement {
    pub photo: u32,
    /// Pixel position in the photo (design-overview convention).
    pub pixel: [f64; 2],
    pub chip: ChipRef,
}

/// Quality record of a cloud control point.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct PointQuality {
    /// Förstner interest value of the point in its best photo.
    #[serde(default)]
    pub interest: f64,
    /// LiDAR coplanarity λmin/Σλ of the supporting plane (0 = perfectly planar).
    #[serde(default)]
    pub coplanarity: f64,
    /// Land-cover class of the support (e.g. "ground").
    #[serde(default)]
    pub class: String,
}

/// A control point of the package.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DcpPoint {
    pub id: u64,
    #[serde(default)]
    pub name: String,
    /// World coordinates in the package CRS.
    pub xyz: [f64; 3],
    /// 1σ of x, y, z (m).
    pub sigma: [f64; 3],
    /// Unit normal of the supporting surface (LiDAR plane), used to align chips to a new
    /// photo's geometry through the ground plane.
    #[serde(default)]
    pub normal: Option<[f64; 3]>,
    #[serde(default)]
    pub quality: PointQuality,
    pub measurements: Vec<DcpMeasurement>,
}

/// The manifest: everything but the chip pixels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    pub format: String,
    pub version: u32,
    /// `EPSG:n` or WKT.
    pub crs: String,
    pub epoch: EpochInfo,
    /// How the control was derived (e.g. "reference photos oriented against LiDAR").
    pub source: String,
    /// Ground pixel size of the photos (m).
    pub gsd_m: f64,
    pub accuracy: Accuracy,
    pub photos: Vec<DcpPhoto>,
    pub points: Vec<DcpPoint>,
    /// SHA-256 (hex) of every file of the package but the manifest, by relative path.
    pub files: BTreeMap<String, String>,
}

impl Manifest {
    pub fn new(crs: &str, epoch: EpochInfo, source: &str, gsd_m: f64, accuracy: Accuracy) -> Self {
        Self {
            format: DCP_FORMAT.into(),
            version: DCP_VERSION,
            crs: crs.into(),
            epoch,
            source: source.into(),
            gsd_m,
            accuracy,
            photos: Vec::new(),
            points: Vec::new(),
            files: BTreeMap::new(),
        }
    }
}

/// A package on disk, validated.
#[derive(Debug, Clone)]
pub struct DcpPackage {
    pub dir: PathBuf,
    pub manifest: Manifest,
}

fn sha256_hex(bytes: &[u8]) -> String {
    let d = Sha256::digest(bytes);
    d.iter().map(|b| format!("{b:02x}")).collect()
}

/// A listed file of the package (a chip), read only as a regular file inside it.
fn member(dir: &Path, file: &str) -> Result<Vec<u8>> {
    read_member(dir, file, MAX_CHIP_BYTES).map_err(|e| DcpError::Chip {
        package: dir.into(),
        file: file.into(),
        message: e.to_string(),
    })
}

/// The manifest's bytes, read only as a regular file inside the package.
fn manifest_bytes(dir: &Path) -> Result<Vec<u8>> {
    read_member(dir, MANIFEST, MAX_MANIFEST_BYTES).map_err(|e| match e {
        MemberError::Missing => invalid(dir, format!("has no {MANIFEST}: not a DCP package")),
        MemberError::Io(source) => DcpError::Io {
            path: dir.join(MANIFEST),
            source,
        },
        e => invalid(dir, format!("{MANIFEST} {e}")),
    })
}

/// The size (width, height) the manifest gives each chip file.
fn chip_sizes(m: &Manifest) -> BTreeMap<&str, (u32, u32)> {
    let ms = m.points.iter().flat_map(|p| &p.measurements);
    ms.map(|ms| (ms.chip.file.as_str(), (ms.chip.width, ms.chip.height)))
        .collect()
}

fn finite(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// Chip file names may not leave the package (no absolute paths, no `..`).
fn safe_relative(file: &str) -> bool {
    let p = Path::new(file);
    !file.is_empty()
        && p.is_relative()
        && p.components()
            .all(|c| matches!(c, std::path::Component::Normal(_)))
}

impl DcpPackage {
    /// Checks the manifest's internal consistency (no file access).
    pub fn validate_manifest(m: &Manifest, package: &Path) -> Result<()> {
        if m.format != DCP_FORMAT {
            return Err(invalid(
                package,
                format!("format is {:?}, not {DCP_FORMAT:?}", m.format),
            ));
        }
        if m.version > DCP_VERSION {
            return Err(invalid(
                package,
                format!(
                    "package version {} is newer than this library reads ({DCP_VERSION})",
                    m.version
                ),
            ));
        }
        if m.version == 0 {
            return Err(invalid(package, "package version 0 does not exist"));
        }
        let crs_err =
            |e: crate::formats::FormatError| invalid(package, format!("{MANIFEST}: crs: {e}"));
        let crs = Crs::parse(&m.crs).map_err(crs_err)?;
        crs.require_projected(None).map_err(crs_err)?;
        if !(m.gsd_m.is_finite() && m.gsd_m > 0.0) {
            return Err(invalid(
                package,
                format!("gsd_m must be positive, got {}", m.gsd_m),
            ));
        }
        if !finite(&[m.accuracy.plan_m, m.accuracy.height_m]) {
            return Err(invalid(package, "accuracy is not finite"));
        }
        let mut photo_ids = BTreeSet::new();
        for p in &m.photos {
            if !photo_ids.insert(p.id) {
                return Err(invalid(package, format!("photo id {} appears twice", p.id)));
            }
            p.camera
                .validate()
                .map_err(|e| invalid(package, format!("photo {} ({}): {e}", p.id, p.name)))?;
            let pose = Pose::new(
                Matrix3::from_row_slice(&p.rotation),
                Vector3::from(p.center),
            );
            pose.validate(1e-6)
                .map_err(|e| invalid(package, format!("photo {} ({}): {e}", p.id, p.name)))?;
        }
        let mut point_ids = BTreeSet::new();
        let mut referenced = BTreeMap::new();
        for pt in &m.points {
            if !point_ids.insert(pt.id) {
                return Err(invalid(
                    package,
                    format!("point id {} appears twice", pt.id),
                ));
            }
            if !finite(&pt.xyz) || !finite(&pt.sigma) || pt.sigma.iter().any(|s| *s <= 0.0) {
                return Err(invalid(
                    package,
                    format!("point {}: coordinates or σ not finite and positive", pt.id),
                ));
            }
            if pt.measurements.is_empty() {
                return Err(invalid(
                    package,
                    format!("point {} has no measurement", pt.id),
                ));
            }
            for ms in &pt.measurements {
                if !photo_ids.contains(&ms.photo) {
                    return Err(invalid(
                        package,
                        format!("point {} is measured in unknown photo {}", pt.id, ms.photo),
                    ));
                }
                if !finite(&ms.pixel) {
                    return Err(invalid(
                        package,
                        format!("point {} in photo {}: pixel not finite", pt.id, ms.photo),
                    ));
                }
                let c = &ms.chip;
                if !safe_relative(&c.file) {
                    return Err(invalid(
                        package,
                        format!("chip path {:?} leaves the package", c.file),
                    ));
                }
                if !m.files.contains_key(&c.file) {
                    return Err(DcpError::Chip {
                        package: package.into(),
                        file: c.file.clone(),
                        message: "not listed with a checksum in the manifest".into(),
                    });
                }
                let inside = ms.pixel[0] >= c.x0 as f64
                    && ms.pixel[1] >= c.y0 as f64
                    && ms.pixel[0] <= (c.x0 + c.width) as f64
                    && ms.pixel[1] <= (c.y0 + c.height) as f64;
                if !inside || c.width == 0 || c.height == 0 {
                    return Err(DcpError::Chip {
                        package: package.into(),
                        file: c.file.clone(),
                        message: format!("does not contain its point's pixel {:?}", ms.pixel),
                    });
                }
                let size = (c.width, c.height);
                if let Some(other) = referenced
                    .insert(c.file.clone(), size)
                    .filter(|o| *o != size)
                {
                    return Err(DcpError::Chip {
                        package: package.into(),
                        file: c.file.clone(),
                        message: format!(
                            "is given two sizes, {}×{} and {}×{}",
                            other.0, other.1, size.0, size.1
                        ),
                    });
                }
            }
        }
        Ok(())
    }

    /// Opens and fully verifies a package: manifest schema and consistency, CRS, presence,
    /// checksum and type (a regular file inside the package: `dcp_files`) of every listed
    /// file, and each chip's size from its image header. Nothing is written.
    pub fn open(dir: &Path) -> Result<Self> {
        match std::fs::metadata(dir) {
            Err(source) => {
                return Err(DcpError::Io {
                    path: dir.to_path_buf(),
                    source,
                })
            }
            Ok(m) if !m.is_dir() => return Err(invalid(dir, "is not a folder")),
            Ok(_) => {}
        }
        let bytes = manifest_bytes(dir)?;
        let manifest: Manifest =
            serde_json::from_slice(&bytes).map_err(|e| invalid(dir, format!("{MANIFEST}: {e}")))?;
        Self::validate_manifest(&manifest, dir)?;
        let sizes = chip_sizes(&manifest);
        for (file, sum) in &manifest.files {
            if !safe_relative(file) {
                return Err(invalid(
                    dir,
                    format!("listed file {file:?} leaves the package"),
                ));
            }
            let data = member(dir, file)?;
            let actual = sha256_hex(&data);
            if !actual.eq_ignore_ascii_case(sum) {
                return Err(DcpError::Chip {
                    package: dir.into(),
                    file: file.clone(),
                    message: format!("checksum mismatch (manifest {sum}, file {actual}): the chip was changed or damaged"),
                });
            }
            if let Some(&(w, h)) = sizes.get(file.as_str()) {
                let chip_err = |message: String| DcpError::Chip {
                    package: dir.into(),
                    file: file.clone(),
                    message,
                };
                // The header only: the pixels are decoded when a chip is matched.
                let (iw, ih) = crate::formats::image_open::image_size_bytes(Path::new(file), &data)
                    .map_err(|e| chip_err(e.detail()))?;
                if (iw, ih) != (w, h) {
                    return Err(chip_err(format!(
                        "is {iw}×{ih} pixels, the manifest says {w}×{h}"
                    )));
                }
            }
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            manifest,
        })
    }

    /// Writes a package folder atomically: everything goes into a temporary sibling folder
    /// that replaces `dir` only when complete. Checksums are computed here.
    pub fn write(
        dir: &Path,
        manifest: Manifest,
        chips: &BTreeMap<String, DynamicImage>,
    ) -> Result<Self> {
        let encoded = chips
            .iter()
            .map(|(file, img)| {
                let png = encode_chip(img).map_err(|e| DcpError::Chip {
                    package: dir.into(),
                    file: file.clone(),
                    message: format!("cannot be encoded ({e})"),
                })?;
                Ok((file.clone(), png))
            })
            .collect::<Result<BTreeMap<_, _>>>()?;
        Self::write_encoded(dir, manifest, &encoded)
    }

    /// [`DcpPackage::write`] of chips already encoded as PNG ([`encode_chip`]): chips cut
    /// and encoded elsewhere (a task of a distributed run) give the same package.
    pub fn write_encoded(
        dir: &Path,
        mut manifest: Manifest,
        chips: &BTreeMap<String, Vec<u8>>,
    ) -> Result<Self> {
        let parent = dir
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        // Made here, removed again if the package cannot be written.
        let created = crate::formats::create_folders(parent).map_err(|e| match e {
            crate::formats::FormatError::Io { path, source } => DcpError::Io { path, source },
            e => invalid(parent, e.to_string()),
        })?;
        let named = match dir.file_name() {
            Some(n) => parent.join(n),
            None => parent.join("dcp"),
        };
        // A name of this call alone, made exclusively (formats::temporary_sibling).
        let tmp = crate::formats::temporary_sibling(&named);
        let result = (|| -> Result<()> {
            std::fs::create_dir(&tmp).map_err(|e| DcpError::Io {
                path: tmp.clone(),
                source: e,
            })?;
            manifest.files.clear();
            for (file, bytes) in chips {
                if !safe_relative(file) {
                    return Err(invalid(
                        dir,
                        format!("chip path {file:?} leaves the package"),
                    ));
                }
                let path = tmp.join(file);
                if let Some(p) = path.parent() {
                    std::fs::create_dir_all(p).map_err(|e| DcpError::Io {
                        path: p.into(),
                        source: e,
                    })?;
                }
                std::fs::write(&path, bytes).map_err(|e| DcpError::Io {
                    path: path.clone(),
                    source: e,
                })?;
                manifest.files.insert(file.clone(), sha256_hex(bytes));
            }
            Self::validate_manifest(&manifest, dir)?;
            let json =
                serde_json::to_vec_pretty(&manifest).map_err(|e| invalid(dir, e.to_string()))?;
            let mpath = tmp.join(MANIFEST);
            std::fs::write(&mpath, json).map_err(|e| DcpError::Io {
                path: mpath,
                source: e,
            })?;
            Ok(())
        })();
        if let Err(e) = result {
            let _ = std::fs::remove_dir_all(&tmp);
            created.undo(false);
            return Err(e);
        }
        // Swap in: move an old package aside first so a failure leaves it intact.
        let old = crate::formats::temporary_sibling(&named);
        let had_old = dir.exists();
        if had_old {
            std::fs::rename(dir, &old).map_err(|e| DcpError::Io {
                path: dir.into(),
                source: e,
            })?;
        }
        if let Err(e) = std::fs::rename(&tmp, dir) {
            if had_old {
                let _ = std::fs::rename(&old, dir);
            }
            let _ = std::fs::remove_dir_all(&tmp);
            return Err(DcpError::Io {
                path: dir.into(),
                source: e,
            });
        }
        if had_old {
            let _ = std::fs::remove_dir_all(&old);
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            manifest,
        })
    }

    /// Loads a chip, verifying its checksum and size again (the package may have changed
    /// on disk since it was opened).
    pub fn chip(&self, chip: &ChipRef) -> Result<DynamicImage> {
        let err = |message: String| DcpError::Chip {
            package: self.dir.clone(),
            file: chip.file.clone(),
            message,
        };
        let data = member(&self.dir, &chip.file)?;
        let want = self
            .manifest
            .files
            .get(&chip.file)
            .ok_or_else(|| err("not listed in the manifest".into()))?;
        if !sha256_hex(&data).eq_ignore_ascii_case(want) {
            return Err(err(
                "checksum mismatch: the chip was changed or damaged".into()
            ));
        }
        // Decoded within the image limits: a chip is a few hundred pixels, a crafted one
        // must not decompress to gigabytes.
        let img = crate::formats::image_open::decode_image_bytes(Path::new(&chip.file), &data)
            .map_err(|e| err(format!("cannot be decoded ({e})")))?;
        if img.width() != chip.width || img.height() != chip.height {
            return Err(err(format!(
                "is {}×{} pixels, the manifest says {}×{}",
                img.width(),
                img.height(),
                chip.width,
                chip.height
            )));
        }
        Ok(img)
    }

    /// Merges packages of one CRS into a new package at `dir`. Photo and point ids are
    /// renumbered so they stay unique; chips are copied under `chips/<n>/`; the accuracy is
    /// the worst of the inputs and the epoch names are joined.
    pub fn merge(packages: &[DcpPackage], dir: &Path) -> Result<Self> {
        let first = packages
            .first()
            .ok_or_else(|| invalid(dir, "nothing to merge"))?;
        let crs0 =
            Crs::parse(&first.manifest.crs).map_err(|e| invalid(&first.dir, e.to_string()))?;
        let mut m = Manifest::new(
            &first.manifest.crs,
            EpochInfo {
                name: packages
                    .iter()
                    .map(|p| p.manifest.epoch.name.as_str())
                    .collect::<Vec<_>>()
                    .join("+"),
                date: None,
            },
            &format!("merge of {} packages", packages.len()),
            packages
                .iter()
                .map(|p| p.manifest.gsd_m)
                .fold(0.0, f64::max),
            Accuracy {
                plan_m: packages
                    .iter()
                    .map(|p| p.manifest.accuracy.plan_m)
                    .fold(0.0, f64::max),
                height_m: packages
                    .iter()
                    .map(|p| p.manifest.accuracy.height_m)
                    .fold(0.0, f64::max),
            },
        );
        let mut chips = BTreeMap::new();
        let (mut next_photo, mut next_point) = (1u32, 1u64);
        for (k, pkg) in packages.iter().enumerate() {
            let crs =
                Crs::parse(&pkg.manifest.crs).map_err(|e| invalid(&pkg.dir, e.to_string()))?;
            if crs.label() != crs0.label() {
                return Err(invalid(
                    &pkg.dir,
                    format!(
                        "CRS {} differs from {} of {}",
                        crs.label(),
                        crs0.label(),
                        first.dir.display()
                    ),
                ));
            }
            let mut photo_map = BTreeMap::new();
            for p in &pkg.manifest.photos {
                photo_map.insert(p.id, next_photo);
                m.photos.push(DcpPhoto {
                    id: next_photo,
                    date: p.date.clone().or(pkg.manifest.epoch.date.clone()),
                    ..p.clone()
                });
                next_photo += 1;
            }
            for pt in &pkg.manifest.points {
                let mut q = pt.clone();
                q.id = next_point;
                next_point += 1;
                for ms in &mut q.measurements {
                    ms.photo = photo_map[&ms.photo];
                    let new_file =
                        format!("chips/{k}/{}", ms.chip.file.trim_start_matches("chips/"));
                    let img = pkg.chip(&ms.chip)?;
                    chips.insert(new_file.clone(), img);
                    ms.chip.file = new_file;
                }
                m.points.push(q);
            }
        }
        Self::write(dir, m, &chips)
    }

    /// Imports verified packages into a store folder (created when missing): each goes to
    /// `store/<its folder name>`. Every package is opened and fully verified first, and
    /// all must share the CRS of the packages already in the store; only then is anything
    /// written. Each copy is verified again while it is made, in a temporary sibling that
    /// is renamed into place, and the copies of a failed import are removed. A package that
    /// is already in the store with the same manifest is left as it is.
    ///
    /// Imports into one store, from threads of one process or from several processes,
    /// run one after the other: each holds the store's lock (`flock` on the folder) from
    /// reading what the store holds to its last copy.
    pub fn import(packages: &[PathBuf], store: &Path) -> Result<Vec<Self>> {
        if packages.is_empty() {
            return Err(invalid(store, "nothing to import"));
        }
        let mut opened = Vec::new();
        let mut names = BTreeMap::new();
        for p in packages {
            let pkg = Self::open(p)?;
            let name = folder_name(&pkg.dir)?;
            if let Some(other) = names.insert(name.clone(), p.clone()) {
                return Err(invalid(
                    p,
                    format!(
                        "has the folder name {name:?} of {} too: both cannot go into one store",
                        other.display()
                    ),
                ));
            }
            opened.push((pkg, name));
        }
        let created = crate::formats::create_folders(store).map_err(|e| match e {
            crate::formats::FormatError::Io { path, source } => DcpError::Io { path, source },
            e => invalid(store, e.detail()),
        })?;
        let locked = crate::formats::Lock::exclusive(store, true).map_err(|e| DcpError::Io {
            path: store.into(),
            source: e,
        });
        let result = locked.and_then(|_lock| Self::import_locked(opened, store));
        if result.is_err() {
            // Only a store this call made, and only while empty.
            created.undo(false);
        }
        result
    }

    /// [`DcpPackage::import`] of the opened packages, under the store's lock.
    fn import_locked(opened: Vec<(Self, String)>, store: &Path) -> Result<Vec<Self>> {
        // The first package sets the CRS of an empty store.
        let mut reference: Option<(String, PathBuf)> = store_crs(store)?;
        for (pkg, _) in &opened {
            let label = Crs::parse(&pkg.manifest.crs)
                .map_err(|e| invalid(&pkg.dir, e.to_string()))?
                .label();
            match &reference {
                Some((crs, from)) if *crs != label => {
                    return Err(invalid(
                        &pkg.dir,
                        format!(
                            "CRS {label} differs from {crs} of {}: a store holds one CRS",
                            from.display()
                        ),
                    ))
                }
                Some(_) => {}
                None => reference = Some((label, pkg.dir.clone())),
            }
        }
        let mut plan = Vec::new();
        for (pkg, name) in opened {
            let dest = store.join(&name);
            if dest.exists() {
                let same = manifest_bytes(&dest)
                    .ok()
                    .zip(manifest_bytes(&pkg.dir).ok())
                    .is_some_and(|(a, b)| a == b);
                if !same {
                    return Err(invalid(
                        &pkg.dir,
                        format!(
                            "{} already holds a different package of that name",
                            dest.display()
                        ),
                    ));
                }
            }
            plan.push((pkg, dest));
        }
        let mut done: Vec<PathBuf> = Vec::new();
        let mut out = Vec::new();
        for (pkg, dest) in plan {
            if dest.exists() {
                // Same manifest: re-verify what the store holds instead of copying.
                out.push(Self::open(&dest)?);
                continue;
            }
            match pkg.copy_verified(&dest) {
                Ok(p) => {
                    done.push(dest);
                    out.push(p);
                }
                Err(e) => {
                    for d in &done {
                        let _ = std::fs::remove_dir_all(d);
                    }
                    return Err(e);
                }
            }
        }
        Ok(out)
    }

    /// Copies the manifest and every listed file to `dest` through a temporary sibling,
    /// checking each file's checksum on the bytes written (the source may have changed
    /// since it was opened), then opens the copy.
    fn copy_verified(&self, dest: &Path) -> Result<Self> {
        folder_name(dest)?;
        // A name of this call alone, made exclusively (formats::temporary_sibling).
        let tmp = crate::formats::temporary_sibling(dest);
        let io = |path: &Path, e: std::io::Error| DcpError::Io {
            path: path.into(),
            source: e,
        };
        let result = (|| -> Result<Self> {
            std::fs::create_dir(&tmp).map_err(|e| io(&tmp, e))?;
            for (file, sum) in &self.manifest.files {
                let data = member(&self.dir, file)?;
                if !sha256_hex(&data).eq_ignore_ascii_case(sum) {
                    return Err(DcpError::Chip {
                        package: self.dir.clone(),
                        file: file.clone(),
                        message: "checksum mismatch: the chip changed while it was imported".into(),
                    });
                }
                let to = tmp.join(file);
                if let Some(p) = to.parent() {
                    std::fs::create_dir_all(p).map_err(|e| io(p, e))?;
                }
                std::fs::write(&to, &data).map_err(|e| io(&to, e))?;
            }
            // The manifest as opened, byte for byte, so the copy is the same package.
            let bytes = manifest_bytes(&self.dir)?;
            let parsed: Manifest = serde_json::from_slice(&bytes)
                .map_err(|e| invalid(&self.dir, format!("{MANIFEST}: {e}")))?;
            if parsed != self.manifest {
                return Err(invalid(
                    &self.dir,
                    format!("{MANIFEST} changed while the package was imported"),
                ));
            }
            std::fs::write(tmp.join(MANIFEST), &bytes).map_err(|e| io(&tmp, e))?;
            Self::open(&tmp)
        })();
        let copy = match result {
            Ok(c) => c,
            Err(e) => {
                let _ = std::fs::remove_dir_all(&tmp);
                return Err(e);
            }
        };
        if let Err(e) = std::fs::rename(&tmp, dest) {
            let _ = std::fs::remove_dir_all(&tmp);
            return Err(io(dest, e));
        }
        Ok(Self {
            dir: dest.to_path_buf(),
            manifest: copy.manifest,
        })
    }

    /// World coordinates of every point.
    pub fn points_xy(&self) -> impl Iterator<Item = (usize, [f64; 2])> + '_ {
        self.manifest
            .points
            .iter()
            .enumerate()
            .map(|(i, p)| (i, [p.xyz[0], p.xyz[1]]))
    }
}

/// The folder name of a package (`a.dcp` for `./a.dcp/` or `a.dcp/.`).
fn folder_name(dir: &Path) -> Result<String> {
    let named = dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .filter(|n| n != "." && n != "..");
    let name = match named {
        Some(n) => n,
        None => std::fs::canonicalize(dir)
            .ok()
            .and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
            .ok_or_else(|| invalid(dir, "has no folder name"))?,
    };
    if name.starts_with('.') {
        // Hidden names are the store's temporary folders.
        return Err(invalid(dir, "a package folder name may not start with '.'"));
    }
    Ok(name)
}

/// The CRS of the packages already in a store (label, package), from their manifests;
/// `None` for a missing or empty store. A store whose packages disagree is refused.
fn store_crs(store: &Path) -> Result<Option<(String, PathBuf)>> {
    if !store.exists() {
        return Ok(None);
    }
    if !store.is_dir() {
        return Err(invalid(store, "the store is not a folder"));
    }
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(store)
        .map_err(|e| DcpError::Io {
            path: store.into(),
            source: e,
        })?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.join(MANIFEST).is_file()
                && !p
                    .file_name()
                    .is_some_and(|n| n.to_string_lossy().starts_with('.'))
        })
        .collect();
    dirs.sort();
    let mut found: Option<(String, PathBuf)> = None;
    for d in dirs {
        let bytes = manifest_bytes(&d)?;
        let m: Manifest = serde_json::from_slice(&bytes)
            .map_err(|e| invalid(&d, format!("stored {MANIFEST}: {e}")))?;
        let label = Crs::parse(&m.crs)
            .map_err(|e| invalid(&d, e.to_string()))?
            .label();
        match &found {
            Some((crs, first)) if *crs != label => {
                return Err(invalid(
                    &d,
                    format!(
                        "the store mixes CRS {label} and {crs} (of {})",
                        first.display()
                    ),
                ))
            }
            Some(_) => {}
            None => found = Some((label, d)),
        }
    }
    Ok(found)
}

/// A chip as a package stores it: PNG (lossless, 8 or 16 bits grey).
pub fn encode_chip(img: &DynamicImage) -> std::result::Result<Vec<u8>, image::ImageError> {
    let mut buf = std::io::Cursor::new(Vec::new());
    img.write_to(&mut buf, image::ImageFormat::Png)?;
    Ok(buf.into_inner())
}
