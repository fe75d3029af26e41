//! Control from an orthophoto and a DEM (seed 000's third control source; what sPyMicMac
//! and the Swiss archive work use): control points where the orthophoto is textured and
//! the DEM locally planar, their plan position from the orthophoto's georeferencing and
//! their height from the DEM, with chips cut from the orthophoto, as a DCP package.
//!
//! The orthophoto enters the package as one "photo" with the geometry of a vertical view:
//! a nadir frame camera so far above the ground (`virtual_height_m`) that its projection
//! differs from the orthophoto's parallel one by less than a thousandth of a pixel over
//! the DEM's relief, with the focal length making its ground pixel the orthophoto's. Every
//! consumer of packages (chip alignment through the point's plane, view ranking) then
//! treats it as any oriented photo, and the relief displacement between the vertical view
//! and an archive photo is what the chip alignment through the DEM plane predicts.
//!
//! Points lie at orthophoto pixel centres, so each chip (odd, on the pixel grid) is
//! centred on its point. An orthophoto or DEM in the package CRS's projection is used as
//! it is (feet converted); one in another CRS is first reprojected by GDAL's warper.

use super::cloud::{self, CloudPoint, ControlSurface, ExportInfo};
use super::dcp::{Accuracy, DcpPackage, EpochInfo};
use super::epoch::{block_origin, input_err, EpochError};
use crate::block::{Block, BlockCamera, Photo};
use crate::formats::crs::{Crs, Transformer};
use crate::formats::{image_open, raster};
use crate::geometry::{self, Camera, Dem, FrameCamera, GeoTransform, Pose};
use crate::matching::{forstner, ForstnerOptions, GreyImage, Pyramid};
use nalgebra::{Matrix3, Vector3};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::Path;

/// The orthophoto and the DEM, each with its CRS when the file does not state one (a
/// JPEG with a world file has none). A raster in the package CRS's projection is taken
/// as it is (feet converted), one in another CRS is reprojected.
#[derive(Debug, Clone)]
pub struct OrthoSource<'a> {
    pub orthophoto: &'a Path,
    pub orthophoto_crs: Option<&'a str>,
    pub dem: &'a Path,
    pub dem_crs: Option<&'a str>,
    /// Name and date of the orthophoto's flight (the package's epoch).
    pub epoch: EpochInfo,
}

/// Options of [`orthophoto_dcp`].
#[derive(Debug, Clone)]
pub struct OrthoControlOptions {
    /// One control point per cell of this many orthophoto pixels at most.
    pub interval_px: f64,
    /// Pyramid level the interest operator works on (the scale of the archive photos
    /// the package is for; 0 = the orthophoto's pixel).
    pub interest_level: usize,
    /// Chip side (px, odd).
    pub chip_size: u32,
    /// Largest λmin/Σλ of the DEM around a point (0 = planar).
    pub max_coplanarity: f64,
    /// 1σ plan accuracy of the orthophoto (m); None: one orthophoto pixel.
    pub plan_sigma_m: Option<f64>,
    /// 1σ height accuracy of the DEM (m).
    pub dem_sigma_m: f64,
}

impl Default for OrthoControlOptions {
    fn default() -> Self {
        Self {
            interval_px: 150.0,
            interest_level: 1,
            chip_size: 193,
            max_coplanarity: 0.01,
            plan_sigma_m: None,
            dem_sigma_m: 0.5,
        }
    }
}

/// What the selection found.
#[derive(Debug, Clone, Serialize)]
pub struct OrthoControlReport {
    pub orthophoto: String,
    pub dem: String,
    /// The orthophoto's CRS as found (file or option) and the package's.
    pub orthophoto_crs: String,
    pub crs: String,
    /// Metres per orthophoto CRS unit (1 when it was reprojected).
    pub unit_m: f64,
    /// The orthophoto was in another projection and was reprojected into the package's by
    /// GDAL's warper (bilinear) before its control points were taken.
    pub reprojected: bool,
    pub size_px: [usize; 2],
    pub gsd_m: f64,
    /// Height of the virtual nadir camera above the mean DEM height (m).
    pub virtual_height_m: f64,
    pub candidates: usize,
    /// Candidates without DEM under them, or whose DEM is not planar enough.
    pub outside_dem: usize,
    pub not_planar: usize,
    pub points: usize,
}

fn srs_of(ds: &crate::formats::gdal::Dataset) -> Option<String> {
    let wkt = ds.spatial_ref()?.to_wkt().ok()?;
    (!wkt.is_empty()).then_some(wkt)
}

/// The CRS of a raster: the file's, or the one given for it; both must agree.
fn raster_crs(
    path: &Path,
    in_file: Option<String>,
    given: Option<&str>,
) -> Result<Crs, EpochError> {
    let parse =
        |d: &str, what: &str| Crs::parse(d).map_err(|e| input_err(path, format!("{what}: {e}")));
    match (in_file, given) {
        (Some(f), Some(g)) => {
            let (f, g) = (parse(&f, "the file's CRS")?, parse(g, "the CRS given")?);
            let same = f
                .same_horizontal(&g)
                .map_err(|e| input_err(path, e.to_string()))?;
            if !same {
                return Err(input_err(
                    path,
                    format!("states {} but {} was given for it", f.label(), g.label()),
                ));
            }
            Ok(f)
        }
        (Some(f), None) => parse(&f, "the file's CRS"),
        (None, Some(g)) => parse(g, "the CRS given"),
        (None, None) => Err(input_err(
            path,
            "has no CRS (a world file gives none): give its CRS",
        )),
    }
}

/// Metres per unit of `crs`'s horizontal axes when `crs` is `target` but for its unit
/// over `extent` (x0, y0, x1, y1 in `crs`): a projection in feet is the same map scaled.
/// None when it is another map, which turns and bends the raster. Checked by transforming
/// the extent's corners and centre, so that one CRS described two ways (a WKT and what
/// GDAL wrote of it into a GeoTIFF) is one.
fn same_projection(
    path: &Path,
    crs: &Crs,
    target: &Crs,
    extent: [f64; 4],
) -> Result<Option<f64>, EpochError> {
    let e = |x: crate::formats::FormatError| input_err(path, x.to_string());
    let unit = crs.horizontal_unit().map_err(e)?;
    let k = unit.metres;
    if !(crs.is_projected() && k.is_finite() && k > 0.0) {
        return Ok(None);
    }
    let t = Transformer::new(crs, target).map_err(e)?;
    let [x0, y0, x1, y1] = extent;
    let samples = [
        [x0, y0],
        [x1, y0],
        [x0, y1],
        [x1, y1],
        [0.5 * (x0 + x1), 0.5 * (y0 + y1)],
    ];
    Ok(samples
        .iter()
        .all(|[x, y]| {
            t.transform_point([*x, *y, 0.0])
                .is_ok_and(|p| (p[0] - k * x).hypot(p[1] - k * y) < 1e-3)
        })
        .then_some(k))
}

/// A raster in the package CRS: the file itself when its CRS is the package's projection
/// (`unit_m` metres per unit), else its reprojection by GDAL's warper into a temporary
/// GeoTIFF, removed when this is dropped.
struct Projected {
    path: std::path::PathBuf,
    unit_m: f64,
    temporary: bool,
}

impl Drop for Projected {
    fn drop(&mut self) {
        if self.temporary {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

fn projected(
    path: &Path,
    crs: &Crs,
    target: &Crs,
    gt: &GeoTransform,
    (w, h): (usize, usize),
) -> Result<Projected, EpochError> {
    let (x0, y1) = gt.pixel_to_world(0.0, 0.0);
    let (x1, y0) = gt.pixel_to_world(w as f64, h as f64);
    let extent = [x0.min(x1), y0.min(y1), x0.max(x1), y0.max(y1)];
    if let Some(unit_m) = same_projection(path, crs, target, extent)? {
        return Ok(Projected {
            path: path.to_path_buf(),
            unit_m,
            temporary: false,
        });
    }
    // The cell keeps the raster's ground size: one pixel step at its centre, measured in
    // the target CRS.
    let e = |x: crate::formats::FormatError| input_err(path, x.to_string());
    let t = Transformer::new(crs, target).map_err(e)?;
    let at = |c: f64, r: f64| {
        let (x, y) = gt.pixel_to_world(c, r);
        t.transform_point([x, y, 0.0]).map_err(e)
    };
    let (c, r) = (w as f64 / 2.0, h as f64 / 2.0);
    let (p, px, py) = (at(c, r)?, at(c + 1.0, r)?, at(c, r + 1.0)?);
    let step = |q: [f64; 3]| (q[0] - p[0]).hypot(q[1] - p[1]);
    let pixel = step(px).min(step(py));
    static WARPS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let n = WARPS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let tmp =
        std::env::temp_dir().join(format!("cloudcontrol-warp-{}-{n}.tif", std::process::id()));
    tracing::info!(raster = %path.display(), from = %crs.label(), to = %target.label(), pixel, "reprojecting");
    raster::warp_to(path, crs, target, pixel, &tmp).map_err(e)?;
    Ok(Projected {
        path: tmp,
        unit_m: 1.0,
        temporary: true,
    })
}

/// The DEM at `path` (its CRS the file's, or `given`) in `target`'s metres (heights in
/// the CRS's vertical unit, else in its horizontal one, as LiDAR deliveries in feet have
/// them), world coordinates.
pub fn dem_in_metres(path: &Path, given: Option<&str>, target: &Crs) -> Result<Dem, EpochError> {
    let (dem, file_crs) = raster::read_dem(path).map_err(|e| input_err(path, e.to_string()))?;
    let crs = raster_crs(path, file_crs.map(|c| c.definition().to_string()), given)?;
    let kv = match crs.vertical_unit() {
        Ok(Some(u)) => u.metres,
        _ => crs.horizontal_unit().map_or(1.0, |u| u.metres),
    };
    let p = projected(path, &crs, target, &dem.transform, (dem.width, dem.height))?;
    let dem = if p.temporary {
        raster::read_dem(&p.path)
            .map_err(|e| input_err(path, format!("reprojected: {e}")))?
            .0
    } else {
        dem
    };
    let kh = p.unit_m;
    if !dem.transform.is_north_up() {
        return Err(input_err(path, "is not a north-up grid"));
    }
    let g = dem.transform.0.map(|v| v * kh);
    let data = dem.data.iter().map(|z| z * kv as f32).collect();
    Dem::new(dem.width, dem.height, GeoTransform(g), data)
        .map_err(|e| input_err(path, e.to_string()))
}

/// Control points of an orthophoto with a DEM as a DCP package in `crs` (projected,
/// metres) at `out`.
pub fn orthophoto_dcp(
    src: &OrthoSource,
    crs: &str,
    out: &Path,
    opts: &OrthoControlOptions,
) -> Result<(DcpPackage, OrthoControlReport), EpochError> {
    if opts.chip_size < 11 || opts.chip_size % 2 == 0 {
        return Err(EpochError::Block(format!(
            "chip size {} must be odd and ≥ 11",
            opts.chip_size
        )));
    }
    if !(opts.interval_px >= 4.0 && opts.dem_sigma_m > 0.0 && opts.interest_level <= 8) {
        return Err(EpochError::Block(
            "options: interval_px ≥ 4, dem_sigma_m > 0 and interest_level ≤ 8 are needed".into(),
        ));
    }
    let target = Crs::parse(crs).map_err(|e| EpochError::Block(format!("package CRS: {e}")))?;
    target
        .require_metric_projected(None)
        .map_err(|e| EpochError::Block(format!("package CRS: {e}")))?;
    let path = src.orthophoto;
    let ds = image_open::open_raster(path).map_err(|e| input_err(path, e.to_string()))?;
    let (w, h) = ds.raster_size();
    image_open::check_pixels(path, w as u64, h as u64)
        .map_err(|e| input_err(path, e.to_string()))?;
    let gt = ds.geo_transform().map_err(|e| {
        input_err(
            path,
            format!("no georeferencing (GeoTIFF or world file): {e}"),
        )
    })?;
    let ortho_crs = raster_crs(path, srs_of(&ds), src.orthophoto_crs)?;
    drop(ds);
    let proj = projected(path, &ortho_crs, &target, &GeoTransform(gt), (w, h))?;
    let (w, h, gt) = if proj.temporary {
        let ds = image_open::open_raster(&proj.path).map_err(|e| input_err(path, e.to_string()))?;
        let (w, h) = ds.raster_size();
        let gt = ds
            .geo_transform()
            .map_err(|e| input_err(path, e.to_string()))?;
        (w, h, gt)
    } else {
        (w, h, gt)
    };
    // Chips and interest come from the raster in the package CRS; the package names the
    // orthophoto as given.
    let pixels = proj.path.as_path();
    let gt = GeoTransform(gt.map(|v| v * proj.unit_m));
    if !gt.is_north_up() {
        return Err(input_err(
            path,
            "is not north-up (a rotated geotransform); resample it north-up first",
        ));
    }
    let (gx, gy) = (gt.0[1], -gt.0[5]);
    let dem = dem_in_metres(src.dem, src.dem_crs, &target)?;
    let (z0, z1) = dem.z_range();
    if !(z0.is_finite() && z1.is_finite()) {
        return Err(input_err(src.dem, "holds no height"));
    }

    // The vertical view: principal point at the orthophoto's centre, so far up that the
    // relief moves no point by 1/1000 px.
    let (xc, yc) = gt.pixel_to_world(w as f64 / 2.0, h as f64 / 2.0);
    let zref = 0.5 * (z0 + z1);
    let r_px = 0.5 * ((w * w + h * h) as f64).sqrt();
    let height = (1000.0 * r_px * (0.5 * (z1 - z0)).max(1.0)).max(1e6);
    let (x_min, y_max) = gt.pixel_to_world(0.0, 0.0);
    let (x_max, y_min) = gt.pixel_to_world(w as f64, h as f64);
    let origin = block_origin([[x_min, y_min], [x_max, y_max]]);
    let o = Vector3::from(origin);
    let camera = Camera::Frame(FrameCamera {
        width: w as u32,
        height: h as u32,
        fx: height / gx,
        fy: height / gy,
        cx: w as f64 / 2.0,
        cy: h as f64 / 2.0,
        distortion: Default::default(),
    });
    let pose = Pose::new(
        Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0)),
        Vector3::new(xc, yc, zref + height) - o,
    );
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let mut block = Block {
        crs: Some(crs.to_string()),
        origin,
        ..Block::default()
    };
    block.cameras.insert(
        1,
        BlockCamera {
            id: 1,
            name: format!("vertical view of {name}"),
            model: camera.clone(),
            free_params: Vec::new(),
            calibration_group: None,
        },
    );
    let mut photo = Photo::new(1, name.clone(), 1, pose).oriented();
    photo.image = Some(pixels.to_path_buf());
    photo.date = src.epoch.date.clone();
    photo.provenance = "orthophoto georeferencing".into();
    block.photos.insert(1, photo);

    // Interest at the archive photos' scale, one point per cell, snapped to the pixel
    // centre it falls in so that its chip is centred on it.
    let full = GreyImage::load(pixels).map_err(|e| input_err(path, e.to_string()))?;
    let pyr = Pyramid::new(&full, opts.interest_level + 1, 32);
    drop(full);
    let level = pyr.levels.len() - 1;
    let f = (1usize << level) as f64;
    let img = &pyr.levels[level];
    let half = (opts.chip_size / 2) as f64;
    let fo = ForstnerOptions {
        grid: (
            ((w as f64 / opts.interval_px).ceil() as usize).max(1),
            ((h as f64 / opts.interval_px).ceil() as usize).max(1),
        ),
        per_cell: 5,
        border: ((half + 2.0) / f).ceil() as usize,
        ..ForstnerOptions::default()
    };
    let mut by_cell: BTreeMap<(i64, i64), Vec<cloud::Candidate>> = BTreeMap::new();
    let mut candidates = 0;
    for p in forstner(img, &fo) {
        let px = [(p.x * f).floor() + 0.5, (p.y * f).floor() + 0.5];
        let inside = px[0] > half + 1.0
            && px[1] > half + 1.0
            && px[0] < w as f64 - half - 1.0
            && px[1] < h as f64 - half - 1.0;
        if inside {
            candidates += 1;
            let key = (
                (px[0] / opts.interval_px) as i64,
                (px[1] / opts.interval_px) as i64,
            );
            by_cell.entry(key).or_default().push((px, p.w));
        }
    }
    drop(pyr);
    let (mut outside_dem, mut not_planar) = (0, 0);
    let mut points = Vec::new();
    for (_, mut cands) in by_cell {
        cands.sort_by(|a, b| b.1.total_cmp(&a.1));
        for (px, interest) in cands {
            let (x, y) = gt.pixel_to_world(px[0], px[1]);
            let Some(plane) = dem.plane_near(x, y) else {
                outside_dem += 1;
                continue;
            };
            if plane.coplanarity > opts.max_coplanarity {
                not_planar += 1;
                continue;
            }
            let position = plane.point - o;
            let pixel = geometry::project(&camera, &block.photos[&1].pose, &position)
                .map_err(|e| input_err(path, e.to_string()))?
                .pixel;
            points.push(CloudPoint {
                position,
                normal: plane.normal,
                interest,
                coplanarity: plane.coplanarity,
                measurements: vec![(1, [pixel.x, pixel.y])],
            });
            break;
        }
    }
    if points.is_empty() {
        return Err(input_err(
            path,
            format!(
                "no control point: of {candidates} textured candidates {outside_dem} have no DEM under them and {not_planar} are on ground that is not planar"
            ),
        ));
    }
    let plan = opts.plan_sigma_m.unwrap_or(gx.max(gy));
    let accuracy = Accuracy {
        plan_m: plan,
        height_m: opts.dem_sigma_m,
    };
    let mut records = cloud::records(&block, &points, &accuracy);
    for (r, p) in records.iter_mut().zip(&points) {
        // A plan error moves the point along the slope: its height inherits tan(slope)·σ.
        let tan = p.normal.xy().norm() / p.normal.z.abs().max(1e-9);
        r.sigma[2] = (opts.dem_sigma_m.powi(2) + (tan * plan).powi(2)).sqrt();
        r.quality.class = "orthophoto + DEM".into();
    }
    let gsd_m = 0.5 * (gx + gy);
    let info = ExportInfo {
        crs: crs.to_string(),
        epoch: src.epoch.clone(),
        source: format!(
            "orthophoto {} with heights from the DEM {}",
            path.display(),
            src.dem.display()
        ),
        gsd_m,
        accuracy,
        chip_size: opts.chip_size,
    };
    let (manifest, chips) =
        cloud::export_records(&block, &records, &info, |_| orthophoto_image(pixels))
            .map_err(|e| input_err(out, e))?;
    let package = DcpPackage::write(out, manifest, &chips)?;
    let report = OrthoControlReport {
        orthophoto: path.display().to_string(),
        dem: src.dem.display().to_string(),
        orthophoto_crs: ortho_crs.label(),
        crs: target.label(),
        unit_m: proj.unit_m,
        reprojected: proj.temporary,
        size_px: [w, h],
        gsd_m,
        virtual_height_m: height,
        candidates,
        outside_dem,
        not_planar,
        points: package.manifest.points.len(),
    };
    Ok((package, report))
}

/// The orthophoto's pixels for its chips: decoded as an image where the image crate can,
/// else through GDAL (tiled or compressed GeoTIFFs), as greyscale.
fn orthophoto_image(path: &Path) -> Result<image::DynamicImage, String> {
    match image_open::decode_image(path) {
        Ok(i) => Ok(i),
        Err(first) => {
            let g = GreyImage::load(path).map_err(|e| format!("{}; {e}", first.detail()))?;
            let max = g.data.iter().copied().fold(0.0f32, f32::max);
            let (w, h) = (g.width as u32, g.height as u32);
            let img = if max > 255.0 {
                image::ImageBuffer::from_raw(w, h, g.data.iter().map(|v| *v as u16).collect())
                    .map(image::DynamicImage::ImageLuma16)
            } else {
                image::ImageBuffer::from_raw(w, h, g.data.iter().map(|v| *v as u8).collect())
                    .map(image::DynamicImage::ImageLuma8)
            };
            img.ok_or_else(|| "orthophoto pixels do not fill its size".into())
        }
    }
}
