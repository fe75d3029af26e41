//! Cloud control points (seed 000 §2.2 (4), seed 001 §4): from a reference block oriented
//! against the LiDAR, pick points that are well textured (interest operator), lie on
//! planar, stable ground (LiDAR coplanarity and class), and are spread evenly over every
//! photo; give them object coordinates from the LiDAR plane and image coordinates in every
//! reference photo that sees them; then cut the chips of a DCP package.

use super::dcp::{
    Accuracy, ChipRef, DcpMeasurement, DcpPhoto, DcpPoint, EpochInfo, Manifest, PointQuality,
};
use crate::block::{Block, PhotoId};
use crate::geometry::{self, Dem, Result as GResult};
use image::DynamicImage;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// A local plane of the control surface (LiDAR) around a ground position.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfacePlane {
    /// A point on the plane (block-local).
    pub point: Vector3<f64>,
    pub normal: Vector3<f64>,
    /// λmin/Σλ of the neighbourhood: 0 for a perfect plane, 1/3 for isotropic scatter.
    pub coplanarity: f64,
    /// Ground (stable) or not: roofs and trees change between epochs (seed 001 §4).
    pub stable: bool,
}

/// The control surface: local planes of the LiDAR. Implemented by the LiDAR index; a DEM
/// serves for tests and for surfaces without classification.
pub trait ControlSurface {
    fn plane_near(&self, x: f64, y: f64) -> Option<SurfacePlane>;
}

impl ControlSurface for Dem {
    /// PCA of a 5×5 patch of DEM samples within ±2 m, as a LiDAR neighbourhood would be.
    fn plane_near(&self, x: f64, y: f64) -> Option<SurfacePlane> {
        let step = 1.0;
        let mut pts = Vec::with_capacity(25);
        for i in -2..=2 {
            for j in -2..=2 {
                let (px, py) = (x + i as f64 * step, y + j as f64 * step);
                pts.push(Vector3::new(px, py, self.height_at(px, py)?));
            }
        }
        let mean = pts.iter().sum::<Vector3<f64>>() / pts.len() as f64;
        let cov = pts
            .iter()
            .map(|p| (p - mean) * (p - mean).transpose())
            .sum::<nalgebra::Matrix3<f64>>()
            / pts.len() as f64;
        let eig = nalgebra::SymmetricEigen::new(cov);
        let (imin, _) = eig
            .eigenvalues
            .iter()
            .enumerate()
            .min_by(|a, b| a.1.total_cmp(b.1))?;
        let mut n: Vector3<f64> = eig.eigenvectors.column(imin).into_owned();
        if n.z < 0.0 {
            n = -n;
        }
        let sum: f64 = eig.eigenvalues.iter().map(|v| v.max(0.0)).sum();
        Some(SurfacePlane {
            point: Vector3::new(x, y, self.height_at(x, y)?),
            normal: n,
            coplanarity: if sum > 0.0 {
                eig.eigenvalues[imin].max(0.0) / sum
            } else {
                0.0
            },
            stable: true,
        })
    }
}

pub use crate::lidar::GroundSurface;

// The LiDAR as a control surface: planes from the ground DEM (class 2), stability from
// the surface model of all returns. Where the surface model stands above the ground
// (roofs, canopy) or no ground return exists nearby, the point is not stable: those are
// the places that change between epochs or whose height is not the LiDAR ground's.
impl ControlSurface for GroundSurface {
    fn plane_near(&self, x: f64, y: f64) -> Option<SurfacePlane> {
        let mut plane = self.ground.plane_near(x, y)?;
        let r = self.radius_m;
        let bare = [(0.0, 0.0), (r, 0.0), (-r, 0.0), (0.0, r), (0.0, -r)]
            .iter()
            .all(|(dx, dy)| {
                match (
                    self.ground.height_at(x + dx, y + dy),
                    self.surface.height_at(x + dx, y + dy),
                ) {
                    (Some(g), Some(s)) => s - g <= self.max_above_ground_m,
                    _ => false,
                }
            });
        plane.stable = bare;
        Some(plane)
    }
}

#[derive(Debug, Clone)]
pub struct CloudOptions {
    /// Grid spacing of control points in each photo (px): one point per cell at most.
    pub interval_px: f64,
    /// Largest accepted coplanarity of the LiDAR neighbourhood.
    pub max_coplanarity: f64,
    /// Least number of reference photos that must see a point.
    pub min_photos: usize,
    /// Border (px) kept free so that chips fit inside the photo.
    pub border_px: f64,
    /// Ray–plane iterations (the plane is re-fitted where the ray meets it).
    pub iterations: usize,
}

impl Default for CloudOptions {
    fn default() -> Self {
        Self {
            interval_px: 250.0,
            max_coplanarity: 0.01,
            min_photos: 2,
            border_px: 32.0,
            iterations: 5,
        }
    }
}

/// A selected cloud control point.
#[derive(Debug, Clone, PartialEq)]
pub struct CloudPoint {
    /// Block-local object coordinates from the LiDAR plane.
    pub position: Vector3<f64>,
    pub normal: Vector3<f64>,
    pub interest: f64,
    pub coplanarity: f64,
    /// Photo where the point was picked, then every photo that sees it, with pixels.
    pub measurements: Vec<(PhotoId, [f64; 2])>,
}

/// Intersects a photo ray with the control surface: ray → plane near the current ground
/// estimate → new estimate, until it settles (planes vary slowly on good control).
fn ray_to_surface(
    block: &Block,
    photo: PhotoId,
    pixel: [f64; 2],
    surface: &dyn ControlSurface,
    opts: &CloudOptions,
) -> GResult<Option<(Vector3<f64>, SurfacePlane)>> {
    let p = &block.photos[&photo];
    let cam = &block.cameras[&p.camera].model;
    let ray = geometry::back_project(cam, &p.pose, pixel)?;
    // Start from the nadir height under the projection centre.
    let Some(start) = surface.plane_near(p.pose.center.x, p.pose.center.y) else {
        return Ok(None);
    };
    let mut t = (start.point.z - ray.origin.z) / ray.direction.z;
    let mut last = None;
    for _ in 0..opts.iterations.max(1) {
        if t.is_nan() || t <= 0.0 {
            return Ok(None);
        }
        let x = ray.at(t);
        let Some(plane) = surface.plane_near(x.x, x.y) else {
            return Ok(None);
        };
        let den = plane.normal.dot(&ray.direction);
        if den.abs() < 1e-6 {
            return Ok(None);
        }
        let t_new = plane.normal.dot(&(plane.point - ray.origin)) / den;
        let converged = (t_new - t).abs() < 1e-4;
        t = t_new;
        last = Some(plane);
        if converged {
            break;
        }
    }
    Ok(last.map(|pl| (ray.at(t), pl)))
}

/// An interest point: pixel and interest value.
pub type Candidate = ([f64; 2], f64);

/// Selects cloud control points. `interest` holds, per photo, candidate pixels with their
/// interest values (e.g. Förstner points); the strongest acceptable candidate of each grid
/// cell wins. Points found again from another photo (within half a cell on the ground) are
/// merged, so each ground point appears once.
pub fn select(
    block: &Block,
    surface: &dyn ControlSurface,
    interest: &BTreeMap<PhotoId, Vec<Candidate>>,
    opts: &CloudOptions,
) -> GResult<Vec<CloudPoint>> {
    let mut points: Vec<CloudPoint> = Vec::new();
    for (&pid, candidates) in interest {
        let Some(photo) = block.photos.get(&pid) else {
            continue;
        };
        let cam = &block.cameras[&photo.camera].model;
        let (w, h) = cam.image_size();
        let gsd = photo.pose.center.z.abs().max(1.0) / cam.focal_px();
        let mut by_cell: BTreeMap<(i64, i64), Vec<Candidate>> = BTreeMap::new();
        for &(px, v) in candidates {
            let inside = px[0] >= opts.border_px
                && px[1] >= opts.border_px
                && px[0] <= w as f64 - opts.border_px
                && px[1] <= h as f64 - opts.border_px;
            if inside {
                let key = (
                    (px[0] / opts.interval_px) as i64,
                    (px[1] / opts.interval_px) as i64,
                );
                by_cell.entry(key).or_default().push((px, v));
            }
        }
        // Within each cell, the strongest candidates first, until one is on good ground.
        for (_, mut cands) in by_cell {
            cands.sort_by(|a, b| b.1.total_cmp(&a.1));
            for (px, v) in cands.into_iter().take(5) {
                let Some((x, plane)) = ray_to_surface(block, pid, px, surface, opts)? else {
                    continue;
                };
                if !plane.stable || plane.coplanarity > opts.max_coplanarity {
                    continue;
                }
                let dup = points
                    .iter()
                    .any(|q| (q.position - x).xy().norm() < 0.5 * opts.interval_px * gsd);
                if dup {
                    break;
                }
                let measurements = visible_in(block, &x, opts.border_px);
                if measurements.len() >= opts.min_photos {
                    points.push(CloudPoint {
                        position: x,
                        normal: plane.normal,
                        interest: v,
                        coplanarity: plane.coplanarity,
                        measurements,
                    });
                    break;
                }
            }
        }
    }
    Ok(points)
}

/// Photos whose frame (less a border) contains the projection of `x`, with the pixels.
pub fn visible_in(block: &Block, x: &Vector3<f64>, border: f64) -> Vec<(PhotoId, [f64; 2])> {
    block
        .photos
        .values()
        .filter_map(|p| {
            let cam = &block.cameras.get(&p.camera)?.model;
            let (w, h) = cam.image_size();
            let px = geometry::project(cam, &p.pose, x).ok()?.pixel;
            (px.x >= border
                && px.y >= border
                && px.x <= w as f64 - border
                && px.y <= h as f64 - border)
                .then_some((p.id, [px.x, px.y]))
        })
        .collect()
}

/// Metadata of an exported package.
#[derive(Debug, Clone)]
pub struct ExportInfo {
    pub crs: String,
    pub epoch: EpochInfo,
    pub source: String,
    pub gsd_m: f64,
    pub accuracy: Accuracy,
    /// Chip side (px, odd).
    pub chip_size: u32,
}

/// One image measurement of a cloud control point (no chip).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PointMeasurement {
    pub photo: PhotoId,
    /// Name of the photo, so a listing is readable without the block.
    pub name: String,
    /// Pixel position in the photo (design-overview convention).
    pub pixel: [f64; 2],
}

/// A cloud control point in world coordinates with its image measurements: what a DCP
/// package holds of it, chips aside. Ids and names are the package's.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControlPointRecord {
    pub id: u64,
    pub name: String,
    /// World coordinates (block-local + origin).
    pub xyz: [f64; 3],
    /// 1σ of x, y, z (m).
    pub sigma: [f64; 3],
    /// Unit normal of the supporting LiDAR plane.
    pub normal: [f64; 3],
    pub quality: PointQuality,
    pub measurements: Vec<PointMeasurement>,
}

/// World records of selected points, numbered as their package will number them.
pub fn records(
    block: &Block,
    points: &[CloudPoint],
    accuracy: &Accuracy,
) -> Vec<ControlPointRecord> {
    let origin = Vector3::from(block.origin);
    points
        .iter()
        .enumerate()
        .map(|(k, cp)| {
            let id = k as u64 + 1;
            let w = cp.position + origin;
            ControlPointRecord {
                id,
                name: format!("CC{id}"),
                xyz: [w.x, w.y, w.z],
                sigma: [accuracy.plan_m, accuracy.plan_m, accuracy.height_m],
                normal: [cp.normal.x, cp.normal.y, cp.normal.z],
                quality: PointQuality {
                    interest: cp.interest,
                    coplanarity: cp.coplanarity,
                    class: "ground".into(),
                },
                measurements: cp
                    .measurements
                    .iter()
                    .map(|&(photo, pixel)| PointMeasurement {
                        photo,
                        name: block
                            .photos
                            .get(&photo)
                            .map(|p| p.name.clone())
                            .unwrap_or_default(),
                        pixel,
                    })
                    .collect(),
            }
        })
        .collect()
}

/// Builds the manifest and cuts the chips of a DCP package from a block's photos.
/// `image_of` loads a photo (greyscale chips are cut from it); points whose chip would
/// leave a photo are measured in the other photos only.
pub fn export(
    block: &Block,
    points: &[CloudPoint],
    info: &ExportInfo,
    image_of: impl FnMut(PhotoId) -> Result<DynamicImage, String>,
) -> Result<(Manifest, BTreeMap<String, DynamicImage>), String> {
    export_records(
        block,
        &records(block, points, &info.accuracy),
        info,
        image_of,
    )
}

/// [`export`] of points already turned into world records (see [`records`]).
pub fn export_records(
    block: &Block,
    points: &[ControlPointRecord],
    info: &ExportInfo,
    mut image_of: impl FnMut(PhotoId) -> Result<DynamicImage, String>,
) -> Result<(Manifest, BTreeMap<String, DynamicImage>), String> {
    let plan = ExportPlan::new(block, points, info)?;
    // Photo by photo, so one decoded photo is held at a time (a block of hundreds of
    // photos once held them all here): each photo's chips are cut, then the photo goes.
    let mut cuts = Vec::with_capacity(plan.photos.len());
    for job in &plan.photos {
        cuts.push(job.cut(&image_of(job.photo)?, info.chip_size));
    }
    Ok(plan.assemble(points, cuts))
}

/// A package's manifest before its points, and the chips it wants from each photo: the
/// part of an export that needs the photos' pixels, one photo at a time, in whatever
/// process reads that photo ([`PhotoChips::cut`]), between two global parts.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ExportPlan {
    pub manifest: Manifest,
    pub photos: Vec<PhotoChips>,
}

/// The chips of one photo: per measurement in it, the record (index), the measurement
/// (index in the record), the point id and the pixel.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PhotoChips {
    pub photo: PhotoId,
    pub wanted: Vec<(usize, usize, u64, [f64; 2])>,
}

/// A chip cut from a photo for record `point`'s measurement `measurement`: its file in
/// the package, its pixels (`T`: the image, or its PNG bytes) and its measurement.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CutChip<T> {
    pub point: usize,
    pub measurement: usize,
    pub file: String,
    pub chip: T,
    pub meas: DcpMeasurement,
}

impl<T> CutChip<T> {
    /// The same chip with its pixels mapped (encoded).
    pub fn map<U, E>(self, f: impl FnOnce(T) -> Result<U, E>) -> Result<CutChip<U>, E> {
        Ok(CutChip {
            point: self.point,
            measurement: self.measurement,
            file: self.file,
            chip: f(self.chip)?,
            meas: self.meas,
        })
    }
}

impl ExportPlan {
    /// The manifest's photos (every photo a record is measured in, by id) and each one's
    /// chips.
    pub fn new(
        block: &Block,
        points: &[ControlPointRecord],
        info: &ExportInfo,
    ) -> Result<Self, String> {
        let origin = Vector3::from(block.origin);
        let mut m = Manifest::new(
            &info.crs,
            info.epoch.clone(),
            &info.source,
            info.gsd_m,
            info.accuracy,
        );
        let used: std::collections::BTreeSet<PhotoId> = points
            .iter()
            .flat_map(|p| p.measurements.iter().map(|m| m.photo))
            .collect();
        for &pid in &used {
            let p = block.photos.get(&pid).ok_or_else(|| {
                format!("control point measured in photo {pid}, which the block does not have")
            })?;
            let r = p.pose.rotation;
            let c = p.pose.center + origin;
            m.photos.push(DcpPhoto {
                id: pid,
                name: p.name.clone(),
                camera: block
                    .cameras
                    .get(&p.camera)
                    .ok_or_else(|| {
                        format!("photo {pid} ({}): unknown camera {}", p.name, p.camera)
                    })?
                    .model
                    .clone(),
                // Row-major, as the manifest stores it.
                rotation: std::array::from_fn(|k| r[(k / 3, k % 3)]),
                center: [c.x, c.y, c.z],
                date: p.date.clone(),
            });
        }
        let photos = used
            .iter()
            .map(|&pid| PhotoChips {
                photo: pid,
                wanted: points
                    .iter()
                    .enumerate()
                    .flat_map(|(i, cp)| {
                        cp.measurements
                            .iter()
                            .enumerate()
                            .filter(|(_, ms)| ms.photo == pid)
                            .map(move |(j, ms)| (i, j, cp.id, ms.pixel))
                    })
                    .collect(),
            })
            .collect();
        Ok(Self {
            manifest: m,
            photos,
        })
    }

    /// The manifest with its points (each with the measurements whose chip was cut; a
    /// point without any is left out) and the chips by file, from every photo's cut.
    pub fn assemble<T>(
        self,
        points: &[ControlPointRecord],
        cuts: Vec<Vec<CutChip<T>>>,
    ) -> (Manifest, BTreeMap<String, T>) {
        let mut m = self.manifest;
        let mut chips = BTreeMap::new();
        let mut cut: BTreeMap<(usize, usize), DcpMeasurement> = BTreeMap::new();
        for c in cuts.into_iter().flatten() {
            chips.insert(c.file, c.chip);
            cut.insert((c.point, c.measurement), c.meas);
        }
        for (i, cp) in points.iter().enumerate() {
            let measurements: Vec<DcpMeasurement> = (0..cp.measurements.len())
                .filter_map(|j| cut.remove(&(i, j)))
                .collect();
            if measurements.is_empty() {
                continue;
            }
            m.points.push(DcpPoint {
                id: cp.id,
                name: cp.name.clone(),
                xyz: cp.xyz,
                sigma: cp.sigma,
                normal: Some(cp.normal),
                quality: cp.quality.clone(),
                measurements,
            });
        }
        // Photos that ended with no measurement are dropped to keep the package minimal.
        let measured: std::collections::BTreeSet<u32> = m
            .points
            .iter()
            .flat_map(|p| p.measurements.iter().map(|m| m.photo))
            .collect();
        m.photos.retain(|p| measured.contains(&p.id));
        (m, chips)
    }
}

impl PhotoChips {
    /// The chips of this photo (image `img`) of side `size`; a chip that would leave the
    /// photo is not cut.
    pub fn cut(&self, img: &DynamicImage, size: u32) -> Vec<CutChip<DynamicImage>> {
        self.wanted
            .iter()
            .filter_map(|&(point, measurement, id, pixel)| {
                let (file, chip, meas) = cut_chip(img, id, self.photo, pixel, size)?;
                Some(CutChip {
                    point,
                    measurement,
                    file,
                    chip,
                    meas,
                })
            })
            .collect()
    }
}

/// The chip of point `id` in photo `pid` around `pixel` (side `size`, greyscale), its file
/// in the package and its measurement; `None` when the chip would leave the photo.
fn cut_chip(
    img: &DynamicImage,
    id: u64,
    pid: PhotoId,
    pixel: [f64; 2],
    size: u32,
) -> Option<(String, DynamicImage, DcpMeasurement)> {
    let (x0, y0) = super::chips::chip_origin(pixel, size as usize / 2);
    if x0 < 0
        || y0 < 0
        || x0 + size as i64 > img.width() as i64
        || y0 + size as i64 > img.height() as i64
    {
        return None;
    }
    let chip = img.crop_imm(x0 as u32, y0 as u32, size, size);
    let chip = match chip {
        DynamicImage::ImageLuma16(_) => chip,
        DynamicImage::ImageLuma8(_) => chip,
        other => DynamicImage::ImageLuma8(other.to_luma8()),
    };
    let file = format!("chips/{id}_{pid}.png");
    let meas = DcpMeasurement {
        photo: pid,
        pixel,
        chip: ChipRef {
            file: file.clone(),
            x0: x0 as u32,
            y0: y0 as u32,
            width: size,
            height: size,
        },
    };
    Some((file, chip, meas))
}
