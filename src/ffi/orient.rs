//! Orientation of one photo through the C ABI: DCP packages, a camera file, the image and
//! its approximate orientation with σ in; the pose, its covariance and the matched
//! control patches out — so a caller can orient photos one by one or in parallel
//! processes. The work is `control::photo::orient_photo`, with the same options as
//! `cloudcontrol run` and `cloudcontrol orient`.

use super::control::{path_arg, CcpDcp};
use super::handles::{free, get, hand_out_string, new_handle, read, Handle};
use super::{finite, guard, input, output, CcpStatus, FfiError};
use crate::block::PosPrior;
use crate::control::chips::ChipStore;
use crate::control::epoch::{block_origin, EpochCamera, PhotoInput};
use crate::control::photo::{orient_photo, PhotoOrientation};
use crate::formats::crs::Crs;
use crate::geometry::matrix_from_opk;
use crate::pipeline::project::Thresholds;
use nalgebra::Vector3;
use std::ffi::{c_char, CString};
use std::path::Path;

/// Opaque handle of an oriented photo (world coordinates of the packages' CRS).
/// Thread safety: never changed after creation, so any number of threads may use one
/// orientation at once.
pub struct CcpPhotoOrientation {
    origin: Vector3<f64>,
    orientation: PhotoOrientation,
    /// World object coordinates of each match.
    points: Vec<[f64; 3]>,
}

impl Handle for CcpPhotoOrientation {
    const TAG: usize = 5;
    const NAME: &'static str = "CcpPhotoOrientation";
}

/// Orients one photo from the control points of `n_dcps` packages (all in one CRS).
/// `camera_path` is a camera file (formats/cameras/: a frame camera, or a film
/// certificate with fiducials, whose interior orientation is found in the scan);
/// `scan_pixel_um` is the film scan's pixel size (0: estimated). `dem_path` is a ground
/// DEM GeoTIFF in the packages' CRS (the footprint of the approximate orientation).
/// `approximate` holds x, y, z (world, m) and omega, phi, kappa (degrees,
/// formats/pos/); `sigma` the 1σ of the centre (m) and of each angle (degrees).
/// On success `*out` is a new handle (free it with `ccp_photo_orientation_free`); a
/// photo that cannot be oriented returns `CCP_STATUS_NOT_ORIENTED` with the reason as
/// the last error.
#[no_mangle]
pub unsafe extern "C" fn ccp_orient_photo(
    dcps: *const *const CcpDcp,
    n_dcps: usize,
    camera_path: *const c_char,
    scan_pixel_um: f64,
    image_path: *const c_char,
    dem_path: *const c_char,
    approximate: *const f64,
    sigma: *const f64,
    out: *mut *mut CcpPhotoOrientation,
) -> CcpStatus {
    guard(|| {
        if out.is_null() {
            return Err(FfiError::new(
                CcpStatus::NullPointer,
                "out is a null pointer",
            ));
        }
        *out = std::ptr::null_mut();
        let handles = input(dcps, n_dcps, "dcps", false)?;
        let mut packages = Vec::with_capacity(handles.len());
        for (i, h) in handles.iter().enumerate() {
            let name = format!("dcps[{i}]");
            let held = get(*h, &name)?;
            let package = read(&held, &name)?.package.clone();
            packages.push(package);
        }
        let crs = Crs::parse(&packages[0].manifest.crs)
            .map_err(|e| FfiError::invalid(format!("dcps[0]: {e}")))?;
        for (i, p) in packages.iter().enumerate().skip(1) {
            let c = Crs::parse(&p.manifest.crs)
                .map_err(|e| FfiError::invalid(format!("dcps[{i}]: {e}")))?;
            if c.label() != crs.label() {
                return Err(FfiError::invalid(format!(
                    "dcps[{i}] is in {}, dcps[0] in {}",
                    c.label(),
                    crs.label()
                )));
            }
        }
        let approximate = input(approximate, 6, "approximate", false)?;
        let sigma = input(sigma, 2, "sigma", false)?;
        finite(approximate, "approximate")?;
        finite(sigma, "sigma")?;
        if !(sigma[0] > 0.0 && sigma[1] > 0.0) {
            return Err(FfiError::invalid("sigma: both σ must be positive"));
        }
        if scan_pixel_um != 0.0 {
            crate::matching::fiducial::check_scan_pixel_um(scan_pixel_um)
                .map_err(|m| FfiError::invalid(format!("scan_pixel_um (0 to estimate it): {m}")))?;
        }
        let camera = EpochCamera::load(Path::new(path_arg(camera_path, "camera_path")?))?;
        let image = Path::new(path_arg(image_path, "image_path")?).to_path_buf();
        if !image.is_file() {
            return Err(FfiError::new(
                CcpStatus::NotFound,
                format!("image_path {} does not exist", image.display()),
            ));
        }
        let origin = block_origin([[approximate[0], approximate[1]]]);
        let dem_file = Path::new(path_arg(dem_path, "dem_path")?);
        let (dem, _) = crate::formats::raster::read_dem(dem_file)?;
        let dem = dem.shifted(origin)?;
        let o = Vector3::from(origin);
        let prior = PosPrior {
            center: Vector3::new(approximate[0], approximate[1], approximate[2]) - o,
            center_sigma: [sigma[0]; 3],
            rotation: Some(matrix_from_opk(
                approximate[3].to_radians(),
                approximate[4].to_radians(),
                approximate[5].to_radians(),
            )),
            rotation_sigma_rad: sigma[1].to_radians(),
        };
        let store = ChipStore::from_packages(&packages, o);
        let mut opts = Thresholds::default().archive_options().photo;
        if scan_pixel_um > 0.0 {
            opts.io.pixel_mm = Some(scan_pixel_um / 1000.0);
        }
        let photo = PhotoInput {
            name: image
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default(),
            image,
        };
        let orientation = orient_photo(&photo, &camera, Some(&prior), &store, &dem, &opts, None);
        if let Some(reason) = &orientation.report.reason {
            return Err(FfiError::new(
                CcpStatus::NotOriented,
                format!("{}: {reason}", photo.image.display()),
            ));
        }
        let points = orientation
            .matches
            .iter()
            .map(|(i, _, _)| (store.points[*i].position + o).into())
            .collect();
        *out = new_handle(CcpPhotoOrientation {
            origin: o,
            orientation,
            points,
        });
        Ok(())
    })
}

/// The pose: world→camera rotation (9, row-major) and projection centre (3, world).
#[no_mangle]
pub unsafe extern "C" fn ccp_photo_orientation_pose(
    orientation: *const CcpPhotoOrientation,
    rotation_out: *mut f64,
    center_out: *mut f64,
) -> CcpStatus {
    guard(|| {
        let held = get(orientation, "orientation")?;
        let h = read(&held, "orientation")?;
        let pose = &h.orientation.pose;
        let r = output(rotation_out, 9, 9, "rotation_out")?;
        for i in 0..3 {
            for j in 0..3 {
                r[3 * i + j] = pose.rotation[(i, j)];
            }
        }
        let c = pose.center + h.origin;
        output(center_out, 3, 3, "center_out")?.copy_from_slice(c.as_slice());
        Ok(())
    })
}

/// The 6×6 covariance of the pose (row-major; rotation vector in rad, then centre in m).
#[no_mangle]
pub unsafe extern "C" fn ccp_photo_orientation_covariance(
    orientation: *const CcpPhotoOrientation,
    covariance_out: *mut f64,
) -> CcpStatus {
    guard(|| {
        let held = get(orientation, "orientation")?;
        let h = read(&held, "orientation")?;
        let out = output(covariance_out, 36, 36, "covariance_out")?;
        for i in 0..6 {
            for j in 0..6 {
                out[6 * i + j] = h.orientation.covariance[(i, j)];
            }
        }
        Ok(())
    })
}

/// Number of control patches that support the pose.
#[no_mangle]
pub unsafe extern "C" fn ccp_photo_orientation_match_count(
    orientation: *const CcpPhotoOrientation,
    count_out: *mut usize,
) -> CcpStatus {
    guard(|| {
        let held = get(orientation, "orientation")?;
        let h = read(&held, "orientation")?;
        output(count_out, 1, 1, "count_out")?[0] = h.points.len();
        Ok(())
    })
}

/// The matches: world object coordinates (3 per match), pixel (2 per match) and σ (px),
/// into caller-owned buffers of `len` matches (at least the match count).
#[no_mangle]
pub unsafe extern "C" fn ccp_photo_orientation_matches(
    orientation: *const CcpPhotoOrientation,
    xyz_out: *mut f64,
    pixel_out: *mut f64,
    sigma_out: *mut f64,
    len: usize,
) -> CcpStatus {
    guard(|| {
        let held = get(orientation, "orientation")?;
        let h = read(&held, "orientation")?;
        let n = h.points.len();
        let xyz = output(xyz_out, len.saturating_mul(3), 3 * n, "xyz_out")?;
        let px = output(pixel_out, len.saturating_mul(2), 2 * n, "pixel_out")?;
        let s = output(sigma_out, len, n, "sigma_out")?;
        for (k, ((_, p, sg), x)) in h.orientation.matches.iter().zip(&h.points).enumerate() {
            xyz[3 * k..3 * k + 3].copy_from_slice(x);
            px[2 * k] = p.x;
            px[2 * k + 1] = p.y;
            s[k] = *sg;
        }
        Ok(())
    })
}

/// The per-photo report (iterations, matching statistics, interior orientation RMSE) as
/// a JSON string owned by the library: release it with `ccp_string_free`.
#[no_mangle]
pub unsafe extern "C" fn ccp_photo_orientation_report_json(
    orientation: *const CcpPhotoOrientation,
    json_out: *mut *mut c_char,
) -> CcpStatus {
    guard(|| {
        let held = get(orientation, "orientation")?;
        let h = read(&held, "orientation")?;
        let out = output(json_out, 1, 1, "json_out")?;
        let text = serde_json::to_string(&h.orientation.report)
            .map_err(|e| FfiError::invalid(e.to_string()))?;
        out[0] = hand_out_string(
            CString::new(text).map_err(|_| FfiError::invalid("report holds a NUL byte"))?,
        );
        Ok(())
    })
}

/// Releases a handle from `ccp_orient_photo` (NULL is ignored). A handle already freed or
/// of another type is refused with `CCP_STATUS_INVALID_HANDLE` (nothing is freed).
#[no_mangle]
pub unsafe extern "C" fn ccp_photo_orientation_free(
    orientation: *mut CcpPhotoOrientation,
) -> CcpStatus {
    free(orientation, "orientation")
}
