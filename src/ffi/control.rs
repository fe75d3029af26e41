//! DCP packages and patch prediction through the C ABI: open, export from an oriented
//! block, import into a store, query. Strings returned are freed with `ccp_string_free`.

use super::camera::camera_arg;
use super::camera::{CcpCamera, CcpPose};
use super::handles::{free, get, hand_out_string, new_handle, read, Handle};
use super::{
    finite, finite_rows, guard, handle, input, opt_str, output, CcpStatus, FfiError, FfiResult,
};
use crate::control::cloud::CloudOptions;
use crate::control::dcp::{Accuracy, DcpError, DcpIndex, DcpPackage, EpochInfo};
use crate::control::epoch::EpochError;
use crate::control::export::{self, DcpExportOptions, OrientedBlock};
use crate::control::ortho_source::{orthophoto_dcp, OrthoControlOptions, OrthoSource};
use crate::control::predict;
use nalgebra::{Matrix3, SMatrix, Vector3};
use std::ffi::{c_char, CStr, CString};
use std::path::{Path, PathBuf};

/// Opaque handle of an opened (verified) DCP package with its spatial index.
/// Thread safety: never changed after creation, so any number of threads may use one
/// package at once.
pub struct CcpDcp {
    pub(crate) package: DcpPackage,
    index: DcpIndex,
}

impl Handle for CcpDcp {
    const TAG: usize = 3;
    const NAME: &'static str = "CcpDcp";
}

pub(crate) fn path_arg<'a>(p: *const c_char, name: &str) -> Result<&'a str, FfiError> {
    if p.is_null() {
        return Err(FfiError::new(
            CcpStatus::NullPointer,
            format!("{name} is a null pointer"),
        ));
    }
    unsafe { CStr::from_ptr(p) }
        .to_str()
        .map_err(|_| FfiError::invalid(format!("{name} is not UTF-8")))
}

fn dcp_status(e: &DcpError) -> CcpStatus {
    match e {
        DcpError::Io { source, .. } if source.kind() == std::io::ErrorKind::NotFound => {
            CcpStatus::NotFound
        }
        DcpError::Io { .. } => CcpStatus::Io,
        _ => CcpStatus::Format,
    }
}

impl From<DcpError> for FfiError {
    fn from(e: DcpError) -> Self {
        FfiError::new(dcp_status(&e), e.to_string())
    }
}

impl From<EpochError> for FfiError {
    fn from(e: EpochError) -> Self {
        let e = match e {
            EpochError::Lidar(l) => return FfiError::from(l),
            EpochError::Format(f) => return FfiError::from(f),
            e => e,
        };
        let status = match &e {
            EpochError::Dcp(d) => dcp_status(d),
            // The message says what was wrong with the file; a file that is not there at
            // all is worth its own status.
            EpochError::Input { path, .. } if !path.exists() => CcpStatus::NotFound,
            EpochError::Input { .. } | EpochError::Lidar(_) => CcpStatus::Format,
            EpochError::Format(_) => CcpStatus::Format,
            EpochError::Epoch { .. } | EpochError::Block(_) => CcpStatus::InvalidArgument,
            EpochError::Adjust { .. } => CcpStatus::Numeric,
        };
        FfiError::new(status, e.to_string())
    }
}

/// Wraps an opened package in a new handle written to `*out_dcp`.
unsafe fn hand_out(package: DcpPackage, out_dcp: *mut *mut CcpDcp) {
    let index = DcpIndex::new(std::slice::from_ref(&package));
    *out_dcp = new_handle(CcpDcp { package, index });
}

/// Clears `*out_dcp`, refusing a null `out_dcp`.
unsafe fn out_handle(out_dcp: *mut *mut CcpDcp) -> FfiResult<()> {
    if out_dcp.is_null() {
        return Err(FfiError::new(
            CcpStatus::NullPointer,
            "out_dcp is a null pointer",
        ));
    }
    *out_dcp = std::ptr::null_mut();
    Ok(())
}

fn non_empty_path(p: *const c_char, name: &str) -> FfiResult<PathBuf> {
    let s = path_arg(p, name)?;
    if s.is_empty() {
        return Err(FfiError::invalid(format!("{name} is empty")));
    }
    Ok(PathBuf::from(s))
}

/// Opens and verifies a DCP package folder (manifest, CRS, every chip's checksum).
#[no_mangle]
pub unsafe extern "C" fn ccp_dcp_open(path: *const c_char, out_dcp: *mut *mut CcpDcp) -> CcpStatus {
    guard(|| {
        out_handle(out_dcp)?;
        let p = path_arg(path, "path")?;
        let package = DcpPackage::open(Path::new(p))?;
        hand_out(package, out_dcp);
        Ok(())
    })
}

/// Options of `ccp_dcp_export`; start from `ccp_dcp_export_options_default`. Strings are
/// NUL-terminated UTF-8, NULL or "" for the default, and only read during the call.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct CcpDcpExportOptions {
    /// Epoch name of the package (default: the package folder's name without extension).
    pub name: *const c_char,
    /// Acquisition date of the photos (ISO 8601), or NULL.
    pub date: *const c_char,
    /// How the control was derived, recorded in the manifest.
    pub source: *const c_char,
    /// Chip side (px, odd); points keep half a chip away from the photo borders.
    pub chip_size: u32,
    /// Spacing of control points in each photo (px, ≤ 1000).
    pub interval_px: f64,
    /// Pyramid level the interest operator runs on (2 = 4× coarser than the photos).
    pub interest_level: u32,
    /// Largest coplanarity (λmin/Σλ) of the LiDAR ground under a point.
    pub max_coplanarity: f64,
    /// Least number of photos that must see a point.
    pub min_photos: u32,
    /// 1σ accuracy of the points' object coordinates (m).
    pub accuracy_plan_m: f64,
    pub accuracy_height_m: f64,
    /// Grid cell of the LiDAR ground model (m).
    pub lidar_cell_m: f64,
}

impl Default for CcpDcpExportOptions {
    fn default() -> Self {
        let d = DcpExportOptions::default();
        Self {
            name: std::ptr::null(),
            date: std::ptr::null(),
            source: std::ptr::null(),
            chip_size: d.chip_size,
            interval_px: d.cloud.interval_px,
            interest_level: d.interest_level as u32,
            max_coplanarity: d.cloud.max_coplanarity,
            min_photos: d.cloud.min_photos as u32,
            accuracy_plan_m: d.accuracy.plan_m,
            accuracy_height_m: d.accuracy.height_m,
            lidar_cell_m: crate::lidar::LIDAR_CELL_M,
        }
    }
}

/// Writes the library's default export options into `*out_options`.
#[no_mangle]
pub unsafe extern "C" fn ccp_dcp_export_options_default(
    out_options: *mut CcpDcpExportOptions,
) -> CcpStatus {
    guard(|| {
        output(out_options, 1, 1, "out_options")?[0] = CcpDcpExportOptions::default();
        Ok(())
    })
}

/// Library options and epoch of a package from the C options.
unsafe fn export_options(
    o: &CcpDcpExportOptions,
    out: &Path,
) -> FfiResult<(DcpExportOptions, EpochInfo, f64)> {
    finite(
        &[
            o.interval_px,
            o.max_coplanarity,
            o.accuracy_plan_m,
            o.accuracy_height_m,
            o.lidar_cell_m,
        ],
        "opts",
    )?;
    let d = DcpExportOptions::default();
    let opts = DcpExportOptions {
        cloud: CloudOptions {
            interval_px: o.interval_px,
            max_coplanarity: o.max_coplanarity,
            min_photos: o.min_photos as usize,
            ..d.cloud.clone()
        },
        chip_size: o.chip_size,
        accuracy: Accuracy {
            plan_m: o.accuracy_plan_m,
            height_m: o.accuracy_height_m,
        },
        source: opt_str(o.source, "opts.source")?.unwrap_or(d.source),
        interest_level: o.interest_level as usize,
    };
    opts.validate()
        .map_err(|m| FfiError::invalid(format!("opts: {m}")))?;
    let epoch = EpochInfo {
        name: opt_str(o.name, "opts.name")?.unwrap_or_else(|| export::package_epoch_name(out)),
        date: opt_str(o.date, "opts.date")?,
    };
    Ok((opts, epoch, o.lidar_cell_m))
}

/// Writes a DCP package at `out_dir` from an oriented block: `block_json` and
/// `images_json` are the paths of the two files the workflow writes per epoch (the block;
/// photo id → image path), `lidar_paths` LAS/LAZ files or folders of them. Selects cloud
/// control points (textured, planar, stable LiDAR ground, one per interval), cuts their
/// chips, writes the package atomically and returns it opened in `*out_dcp` (release with
/// `ccp_dcp_free`). `opts` NULL takes the defaults.
#[no_mangle]
#[allow(clippy::too_many_arguments)]
pub unsafe extern "C" fn ccp_dcp_export(
    block_json: *const c_char,
    images_json: *const c_char,
    lidar_paths: *const *const c_char,
    n_lidar: usize,
    out_dir: *const c_char,
    opts: *const CcpDcpExportOptions,
    out_dcp: *mut *mut CcpDcp,
) -> CcpStatus {
    guard(|| {
        out_handle(out_dcp)?;
        let block = non_empty_path(block_json, "block_json")?;
        let images = non_empty_path(images_json, "images_json")?;
        let out = non_empty_path(out_dir, "out_dir")?;
        let lidar = input(lidar_paths, n_lidar, "lidar_paths", false)?
            .iter()
            .enumerate()
            .map(|(i, &p)| non_empty_path(p, &format!("lidar_paths[{i}]")))
            .collect::<FfiResult<Vec<_>>>()?;
        let defaults = CcpDcpExportOptions::default();
        let o = opts.as_ref().unwrap_or(&defaults);
        let (opts, epoch, cell) = export_options(o, &out)?;
        let b = OrientedBlock::load(&block, &images, &lidar, cell)?;
        let package = b.export(epoch, &out, &opts)?;
        hand_out(package, out_dcp);
        Ok(())
    })
}

/// Writes a DCP package at `out_dir` from a georeferenced orthophoto (GeoTIFF, or an image
/// with a world file) and a DEM GeoTIFF: control points where the orthophoto is textured
/// and the DEM planar, chips from the orthophoto, in the CRS `crs` (projected, metres;
/// rasters in another CRS are reprojected). `orthophoto_crs` / `dem_crs` give a raster's
/// CRS when its file has none (NULL: the file's); `name` (NULL: the folder's name) and
/// `date` (NULL: unknown) describe the orthophoto's flight. Default selection options
/// (formats/dcp/, "Orthophoto and DEM"). Returns the package opened in `*out_dcp`
/// (release with `ccp_dcp_free`).
#[no_mangle]
#[allow(clippy::too_many_arguments)]
pub unsafe extern "C" fn ccp_dcp_from_orthophoto(
    orthophoto: *const c_char,
    orthophoto_crs: *const c_char,
    dem: *const c_char,
    dem_crs: *const c_char,
    crs: *const c_char,
    out_dir: *const c_char,
    name: *const c_char,
    date: *const c_char,
    out_dcp: *mut *mut CcpDcp,
) -> CcpStatus {
    guard(|| {
        out_handle(out_dcp)?;
        let ortho = non_empty_path(orthophoto, "orthophoto")?;
        let dem = non_empty_path(dem, "dem")?;
        let out = non_empty_path(out_dir, "out_dir")?;
        let crs = opt_str(crs, "crs")?
            .ok_or_else(|| FfiError::new(CcpStatus::NullPointer, "crs is null or empty"))?;
        let ortho_crs = opt_str(orthophoto_crs, "orthophoto_crs")?;
        let dem_crs = opt_str(dem_crs, "dem_crs")?;
        let src = OrthoSource {
            orthophoto: &ortho,
            orthophoto_crs: ortho_crs.as_deref(),
            dem: &dem,
            dem_crs: dem_crs.as_deref(),
            epoch: EpochInfo {
                name: opt_str(name, "name")?.unwrap_or_else(|| export::package_epoch_name(&out)),
                date: opt_str(date, "date")?,
            },
        };
        let (package, _) = orthophoto_dcp(&src, &crs, &out, &OrthoControlOptions::default())?;
        hand_out(package, out_dcp);
        Ok(())
    })
}

/// Verifies the package `package` in full and copies it into the store folder
/// `store_dir` (created when missing) as `store_dir/<package folder name>`, returning the
/// stored copy opened in `*out_dcp`. A damaged package, or one whose CRS differs from
/// the packages already in the store, is refused and nothing is written.
#[no_mangle]
pub unsafe extern "C" fn ccp_dcp_import(
    package: *const c_char,
    store_dir: *const c_char,
    out_dcp: *mut *mut CcpDcp,
) -> CcpStatus {
    guard(|| {
        out_handle(out_dcp)?;
        let src = non_empty_path(package, "package")?;
        let store = non_empty_path(store_dir, "store_dir")?;
        let mut stored = DcpPackage::import(&[src], &store)?;
        let p = stored
            .pop()
            .ok_or_else(|| FfiError::new(CcpStatus::Format, "import returned no package"))?;
        hand_out(p, out_dcp);
        Ok(())
    })
}

/// The package folder of a handle as a NUL-terminated UTF-8 string in `*out_path`, owned
/// by the library: release it with `ccp_string_free`.
#[no_mangle]
pub unsafe extern "C" fn ccp_dcp_path(dcp: *const CcpDcp, out_path: *mut *mut c_char) -> CcpStatus {
    guard(|| {
        if out_path.is_null() {
            return Err(FfiError::new(
                CcpStatus::NullPointer,
                "out_path is a null pointer",
            ));
        }
        *out_path = std::ptr::null_mut();
        let held = get(dcp, "dcp")?;
        let d = read(&held, "dcp")?;
        let s = d
            .package
            .dir
            .to_str()
            .ok_or_else(|| FfiError::invalid("the package path is not UTF-8"))?;
        let c =
            CString::new(s).map_err(|_| FfiError::invalid("the package path holds a NUL byte"))?;
        *out_path = hand_out_string(c);
        Ok(())
    })
}

/// Releases a DCP handle; NULL is ignored. A handle already freed or of another type is
/// refused with `CCP_STATUS_INVALID_HANDLE` (nothing is freed).
#[no_mangle]
pub unsafe extern "C" fn ccp_dcp_free(dcp: *mut CcpDcp) -> CcpStatus {
    free(dcp, "dcp")
}

/// Number of control points of the package.
#[no_mangle]
pub unsafe extern "C" fn ccp_dcp_point_count(
    dcp: *const CcpDcp,
    out_count: *mut usize,
) -> CcpStatus {
    guard(|| {
        let held = get(dcp, "dcp")?;
        let d = read(&held, "dcp")?;
        output(out_count, 1, 1, "out_count")?[0] = d.package.manifest.points.len();
        Ok(())
    })
}

/// Copies the control points' world coordinates (x, y, z interleaved, `out_len` ≥ 3·count)
/// and their σ (same layout) when `out_sigma` is not NULL.
#[no_mangle]
pub unsafe extern "C" fn ccp_dcp_points(
    dcp: *const CcpDcp,
    out_xyz: *mut f64,
    out_sigma: *mut f64,
    out_len: usize,
) -> CcpStatus {
    guard(|| {
        let held = get(dcp, "dcp")?;
        let d = read(&held, "dcp")?;
        let pts = &d.package.manifest.points;
        let xyz = output(out_xyz, out_len, 3 * pts.len(), "out_xyz")?;
        for (o, p) in xyz.chunks_exact_mut(3).zip(pts) {
            o.copy_from_slice(&p.xyz);
        }
        if !out_sigma.is_null() {
            let s = output(out_sigma, out_len, 3 * pts.len(), "out_sigma")?;
            for (o, p) in s.chunks_exact_mut(3).zip(pts) {
                o.copy_from_slice(&p.sigma);
            }
        }
        Ok(())
    })
}

/// Indices of the control points inside a polygon (world x, y interleaved, ≥ 3 vertices).
/// Writes at most `capacity` indices and the number found to `*out_count`; when
/// `*out_count` > `capacity` the call fails with CCP_STATUS_BUFFER_TOO_SMALL.
#[no_mangle]
pub unsafe extern "C" fn ccp_dcp_query_polygon(
    dcp: *const CcpDcp,
    polygon: *const f64,
    n_vertices: usize,
    out_indices: *mut u64,
    capacity: usize,
    out_count: *mut usize,
) -> CcpStatus {
    guard(|| {
        let held = get(dcp, "dcp")?;
        let d = read(&held, "dcp")?;
        if n_vertices < 3 {
            return Err(FfiError::invalid(format!(
                "polygon needs at least 3 vertices, got {n_vertices}"
            )));
        }
        let poly = input(polygon, 2 * n_vertices, "polygon", false)?;
        finite_rows(poly, 2, "polygon")?;
        let verts: Vec<[f64; 2]> = poly.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
        let hits = d.index.query_polygon(&verts);
        output(out_count, 1, 1, "out_count")?[0] = hits.len();
        let out = output(out_indices, capacity, hits.len(), "out_indices")?;
        for (o, (_, i)) in out.iter_mut().zip(hits) {
            *o = i as u64;
        }
        Ok(())
    })
}

/// Predicts object points in a photo with approximate orientation: pixels (x, y
/// interleaved, `out_len` ≥ 2·n) and their 2×2 covariances (row-major, `cov_len` ≥ 4·n)
/// propagated from `eo_covariance` (6×6 row-major; rotation vector rad, then centre m) and
/// the points' σ (x, y, z interleaved, may be NULL for exact points).
#[no_mangle]
pub unsafe extern "C" fn ccp_predict(
    camera: *const CcpCamera,
    pose: *const CcpPose,
    eo_covariance: *const f64,
    points: *const f64,
    point_sigma: *const f64,
    n_points: usize,
    out_pixels: *mut f64,
    out_len: usize,
    out_covariance: *mut f64,
    cov_len: usize,
) -> CcpStatus {
    guard(|| {
        let cam = &camera_arg(camera, "camera")?;
        let pose = handle(pose, "pose")?.to_pose()?;
        let cov = input(eo_covariance, 36, "eo_covariance", false)?;
        finite(cov, "eo_covariance")?;
        let eo = SMatrix::<f64, 6, 6>::from_row_slice(cov);
        let n3 = n_points
            .checked_mul(3)
            .ok_or_else(|| FfiError::invalid("n_points overflows"))?;
        let pts = input(points, n3, "points", false)?;
        finite_rows(pts, 3, "points")?;
        let sig = if point_sigma.is_null() {
            None
        } else {
            Some(input(point_sigma, n3, "point_sigma", false)?)
        };
        if let Some(s) = sig {
            finite_rows(s, 3, "point_sigma")?;
        }
        let px = output(out_pixels, out_len, 2 * n_points, "out_pixels")?;
        let pc = output(out_covariance, cov_len, 4 * n_points, "out_covariance")?;
        for i in 0..n_points {
            let x = Vector3::new(pts[3 * i], pts[3 * i + 1], pts[3 * i + 2]);
            let pcov = sig.map_or(Matrix3::zeros(), |s| {
                Matrix3::from_diagonal(&Vector3::new(
                    s[3 * i].powi(2),
                    s[3 * i + 1].powi(2),
                    s[3 * i + 2].powi(2),
                ))
            });
            let p = predict::predict(cam, &pose, &eo, &x, &pcov)
                .map_err(|e| FfiError::from(e).prefixed(&format!("points[{i}]")))?;
            px[2 * i] = p.pixel.x;
            px[2 * i + 1] = p.pixel.y;
            pc[4 * i..4 * i + 4].copy_from_slice(&[
                p.covariance[(0, 0)],
                p.covariance[(0, 1)],
                p.covariance[(1, 0)],
                p.covariance[(1, 1)],
            ]);
        }
        Ok(())
    })
}
