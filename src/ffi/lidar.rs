//! LiDAR through the C ABI: the source catalogue as a JSON string and the evaluation of
//! checkpoints. Strings returned by the library are freed with `ccp_string_free`.

use super::handles::{free, free_string, get, hand_out_string, new_handle, read, Handle};
use super::{finite, guard, input, opt_str, output, CcpStatus, FfiError, FfiResult};
use crate::lidar::eval::evaluate_checkpoints_store;
use crate::lidar::{Catalogue, CheckpointOptions, LidarError, ScanOptions, TileStore};
use std::ffi::{c_char, CStr, CString};
use std::path::PathBuf;

impl From<LidarError> for FfiError {
    fn from(e: LidarError) -> Self {
        use LidarError as L;
        // A file error (not a regular file, too large, missing) keeps its own status.
        let e = match e {
            L::Format(f) => return FfiError::from(f),
            e => e,
        };
        let status = match &e {
            L::Io { source, .. } if source.kind() == std::io::ErrorKind::NotFound => {
                CcpStatus::NotFound
            }
            L::Io { .. } => CcpStatus::Io,
            L::NonFinite { .. } => CcpStatus::NotFinite,
            L::InvalidOption(_) | L::TooFewPoints { .. } => CcpStatus::InvalidArgument,
            L::TooFewCorrespondences { .. } | L::Singular { .. } => CcpStatus::Numeric,
            _ => CcpStatus::Format,
        };
        FfiError::new(status, e.to_string())
    }
}

/// Statistics of a checkpoint evaluation (dz = LiDAR − checkpoint, metres).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default)]
pub struct CcpCheckpointStats {
    /// Checkpoints with a LiDAR height.
    pub count: usize,
    /// Checkpoints without enough ground points around them.
    pub skipped: usize,
    pub mean_m: f64,
    pub std_m: f64,
    pub rmse_m: f64,
    pub max_abs_m: f64,
    /// Checkpoints with |dz − mean| > 3σ.
    pub outliers: usize,
}

unsafe fn paths(ptr: *const *const c_char, n: usize) -> FfiResult<Vec<PathBuf>> {
    let list = input(ptr, n, "paths", false)?;
    list.iter()
        .enumerate()
        .map(|(i, &p)| {
            if p.is_null() {
                return Err(FfiError::new(
                    CcpStatus::NullPointer,
                    format!("paths[{i}] is a null pointer"),
                ));
            }
            let s = CStr::from_ptr(p)
                .to_str()
                .map_err(|_| FfiError::invalid(format!("paths[{i}] is not UTF-8")))?;
            Ok(PathBuf::from(s))
        })
        .collect()
}

/// Scans LAS/LAZ files or folders (or loads one catalogue .json) into the source catalogue
/// and returns it as a NUL-terminated JSON string in `*out_json`, owned by the library:
/// release it with `ccp_string_free`. `assume_crs` (nullable) is the CRS of files that
/// carry none.
#[no_mangle]
pub unsafe extern "C" fn ccp_lidar_catalogue_json(
    paths_ptr: *const *const c_char,
    n_paths: usize,
    assume_crs: *const c_char,
    out_json: *mut *mut c_char,
) -> CcpStatus {
    guard(|| {
        if out_json.is_null() {
            return Err(FfiError::new(
                CcpStatus::NullPointer,
                "out_json is a null pointer",
            ));
        }
        *out_json = std::ptr::null_mut();
        let files = paths(paths_ptr, n_paths)?;
        let opts = ScanOptions {
            assume_crs: opt_str(assume_crs, "assume_crs")?,
        };
        let cat = Catalogue::open(&files, &opts)?;
        let c = CString::new(cat.to_json())
            .map_err(|_| FfiError::invalid("catalogue JSON holds a NUL byte"))?;
        *out_json = hand_out_string(c);
        Ok(())
    })
}

/// Frees a string returned by the library (NULL is ignored). A pointer the library did not
/// return, or has freed already, is refused with `CCP_STATUS_INVALID_HANDLE`.
#[no_mangle]
pub unsafe extern "C" fn ccp_string_free(s: *mut c_char) -> CcpStatus {
    free_string(s)
}

/// Evaluates LiDAR ground heights against `n_points` checkpoints `xyz` (X, Y, Z per
/// checkpoint, in the LiDAR CRS). `ground_class` < 0 takes every point, else that ASPRS
/// class; `radius` (m) bounds the local plane; `max_points` bounds the LiDAR points held
/// in memory (0: 50 million). Writes dz = LiDAR − checkpoint per checkpoint into `out_dz`
/// (NaN where skipped; `out_len` ≥ `n_points`) and the statistics into `*out_stats`.
#[no_mangle]
#[allow(clippy::too_many_arguments)]
pub unsafe extern "C" fn ccp_lidar_eval_checkpoints(
    paths_ptr: *const *const c_char,
    n_paths: usize,
    assume_crs: *const c_char,
    xyz: *const f64,
    n_points: usize,
    ground_class: i32,
    radius: f64,
    max_points: u64,
    out_dz: *mut f64,
    out_len: usize,
    out_stats: *mut CcpCheckpointStats,
) -> CcpStatus {
    guard(|| {
        if out_stats.is_null() {
            return Err(FfiError::new(
                CcpStatus::NullPointer,
                "out_stats is a null pointer",
            ));
        }
        let files = paths(paths_ptr, n_paths)?;
        let pts = input(xyz, n_points.saturating_mul(3), "xyz", false)?;
        finite(pts, "xyz")?;
        if !(radius > 0.0 && radius.is_finite()) {
            return Err(FfiError::invalid(format!(
                "radius {radius} must be positive"
            )));
        }
        if ground_class > 255 {
            return Err(FfiError::invalid(format!(
                "ground_class {ground_class} is not an ASPRS class"
            )));
        }
        let out = output(out_dz, out_len, n_points, "out_dz")?;
        let cps: Vec<(String, [f64; 3])> = pts
            .chunks_exact(3)
            .enumerate()
            .map(|(i, c)| (i.to_string(), [c[0], c[1], c[2]]))
            .collect();
        let cat = Catalogue::open(
            &files,
            &ScanOptions {
                assume_crs: opt_str(assume_crs, "assume_crs")?,
            },
        )?;
        let mut store = TileStore::new(
            cat,
            if max_points == 0 {
                50_000_000
            } else {
                max_points
            },
        );
        let classes = (ground_class >= 0).then(|| vec![ground_class as u8]);
        let opts = CheckpointOptions {
            radius,
            ..Default::default()
        };
        let rep = evaluate_checkpoints_store(&mut store, &cps, classes.as_deref(), &opts)?;
        for (o, r) in out.iter_mut().zip(&rep.rows) {
            *o = r.dz_m.unwrap_or(f64::NAN);
        }
        *out_stats = CcpCheckpointStats {
            count: rep.count,
            skipped: rep.skipped,
            mean_m: rep.mean_m,
            std_m: rep.std_m,
            rmse_m: rep.rmse_m,
            max_abs_m: rep.max_abs_m,
            outliers: rep.outliers.len(),
        };
        Ok(())
    })
}

/// Opaque LiDAR source: the points of a region with their plane index. Create with
/// `ccp_lidar_source_open`, release with `ccp_lidar_source_free`.
/// Thread safety: never changed after creation, so any number of threads may use one
/// source at once.
pub struct CcpLidarSource {
    index: crate::lidar::PlaneIndex,
}

impl Handle for CcpLidarSource {
    const TAG: usize = 4;
    const NAME: &'static str = "CcpLidarSource";
}

/// Statistics of an ICP run.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default)]
pub struct CcpIcpStats {
    pub scale: f64,
    pub rmse_m: f64,
    pub sigma0_m: f64,
    pub inliers: usize,
    pub iterations: usize,
    /// 1 when the convergence test was met, 0 when max_iterations ran out.
    pub converged: i32,
}

/// Loads the LiDAR points of LAS/LAZ files, folders or a catalogue .json inside `bbox`
/// (min_x, min_y, max_x, max_y; NULL for everything) and builds the plane index with `k`
/// neighbours per fit (0: 12) and the coplanarity limit `max_coplanarity` (≤ 0: 0.02).
/// More than `max_points` points in the region (0: 200 million) is an error.
#[no_mangle]
#[allow(clippy::too_many_arguments)]
pub unsafe extern "C" fn ccp_lidar_source_open(
    paths_ptr: *const *const c_char,
    n_paths: usize,
    assume_crs: *const c_char,
    bbox: *const f64,
    k: u32,
    max_coplanarity: f64,
    max_points: u64,
    out_source: *mut *mut CcpLidarSource,
) -> CcpStatus {
    guard(|| {
        use crate::lidar::{Bbox, PlaneIndex, PlaneOptions};
        if out_source.is_null() {
            return Err(FfiError::new(
                CcpStatus::NullPointer,
                "out_source is a null pointer",
            ));
        }
        *out_source = std::ptr::null_mut();
        let files = paths(paths_ptr, n_paths)?;
        let cat = Catalogue::open(
            &files,
            &ScanOptions {
                assume_crs: opt_str(assume_crs, "assume_crs")?,
            },
        )?;
        let region = if bbox.is_null() {
            Bbox::new(cat.bounds[0], cat.bounds[1], cat.bounds[3], cat.bounds[4])
        } else {
            let b = input(bbox, 4, "bbox", false)?;
            finite(b, "bbox")?;
            if b[0] > b[2] || b[1] > b[3] {
                return Err(FfiError::invalid("bbox: min exceeds max"));
            }
            Bbox::new(b[0], b[1], b[2], b[3])
        };
        let limit = if max_points == 0 {
            200_000_000
        } else {
            max_points
        };
        let in_region: u64 = cat
            .tiles_in(&region)
            .iter()
            .map(|&i| cat.tiles[i].point_count)
            .sum();
        let mut store = TileStore::new(cat, limit);
        let pts = store.query(&region, None)?;
        drop(store);
        if pts.len() as u64 > limit {
            return Err(FfiError::invalid(format!(
                "the region holds {} LiDAR points (tiles: {in_region}), more than max_points {limit}",
                pts.len()
            )));
        }
        if pts.is_empty() {
            return Err(FfiError::new(
                CcpStatus::NotFound,
                "no LiDAR point in the region",
            ));
        }
        let c = Bbox::of_points(&pts.xyz, 0.0).expect("non-empty");
        let origin = nalgebra::Vector3::new(
            0.5 * (c.min_x + c.max_x),
            0.5 * (c.min_y + c.max_y),
            pts.xyz[0][2],
        );
        let mut local = pts.xyz;
        for p in local.iter_mut() {
            p[0] -= origin.x;
            p[1] -= origin.y;
            p[2] -= origin.z;
        }
        let defaults = PlaneOptions::default();
        let opts = PlaneOptions {
            k: if k == 0 { defaults.k } else { k as usize },
            max_coplanarity: if max_coplanarity > 0.0 {
                max_coplanarity
            } else {
                defaults.max_coplanarity
            },
            ..defaults
        };
        let index = PlaneIndex::from_local(local, origin, opts)?;
        *out_source = new_handle(CcpLidarSource { index });
        Ok(())
    })
}

/// Releases a source (NULL is ignored). A handle already freed or of another type is
/// refused with `CCP_STATUS_INVALID_HANDLE` (nothing is freed).
#[no_mangle]
pub unsafe extern "C" fn ccp_lidar_source_free(source: *mut CcpLidarSource) -> CcpStatus {
    free(source, "source")
}

/// Number of LiDAR points held by a source.
#[no_mangle]
pub unsafe extern "C" fn ccp_lidar_source_len(
    source: *const CcpLidarSource,
    out_len: *mut u64,
) -> CcpStatus {
    guard(|| {
        let held = get(source, "source")?;
        let s = read(&held, "source")?;
        if out_len.is_null() {
            return Err(FfiError::new(
                CcpStatus::NullPointer,
                "out_len is a null pointer",
            ));
        }
        *out_len = s.index.len() as u64;
        Ok(())
    })
}

/// Local planes at `n_points` world points `xyz`: per point 8 values into `out`
/// (`out_len` ≥ 8·n): unit normal (3, upward), centroid of the fitted neighbourhood
/// (3, world), weight (0..1, from coplanarity) and the signed distance of the point to the
/// plane (m). Rows are NaN where the surface is not planar (vegetation, edges, gaps) or
/// the point lies farther than the plane-fit radius from the fitted patch along it.
#[no_mangle]
pub unsafe extern "C" fn ccp_lidar_planes(
    source: *const CcpLidarSource,
    xyz: *const f64,
    n_points: usize,
    out: *mut f64,
    out_len: usize,
) -> CcpStatus {
    guard(|| {
        let held = get(source, "source")?;
        let s = read(&held, "source")?;
        let pts = input(xyz, n_points.saturating_mul(3), "xyz", false)?;
        finite(pts, "xyz")?;
        let out = output(out, out_len, n_points * 8, "out")?;
        let o = s.index.origin();
        for (p, row) in pts.chunks_exact(3).zip(out.chunks_exact_mut(8)) {
            let q = nalgebra::Vector3::new(p[0], p[1], p[2]) - o;
            let radius = s.index.options().max_radius;
            let near = |pl: &crate::lidar::LocalPlane| {
                let d = q - pl.centroid;
                (d - pl.normal * pl.normal.dot(&d)).norm() <= radius
            };
            match s.index.plane_at(&q).filter(near) {
                Some(pl) => {
                    let c = pl.centroid + o;
                    row.copy_from_slice(&[
                        pl.normal.x,
                        pl.normal.y,
                        pl.normal.z,
                        c.x,
                        c.y,
                        c.z,
                        pl.weight,
                        pl.distance(&q),
                    ]);
                }
                None => row.fill(f64::NAN),
            }
        }
        Ok(())
    })
}

/// Point-to-plane ICP of `n_points` world points `xyz` onto the source, from the identity:
/// `rigid` ≠ 0 estimates a rigid transform, else a 7-parameter similarity. Gates in metres
/// (`initial_gate` must cover the start error; ≤ 0 takes 30 and 0.3), `max_iterations`
/// (0: 100). Writes the row-major 4×4 matrix mapping the points onto the LiDAR into
/// `out_matrix` (16 values) and the statistics into `*out_stats`.
#[no_mangle]
#[allow(clippy::too_many_arguments)]
pub unsafe extern "C" fn ccp_lidar_icp(
    source: *const CcpLidarSource,
    xyz: *const f64,
    n_points: usize,
    rigid: i32,
    initial_gate: f64,
    min_gate: f64,
    max_iterations: u32,
    out_matrix: *mut f64,
    out_stats: *mut CcpIcpStats,
) -> CcpStatus {
    guard(|| {
        use crate::lidar::{icp_point_to_plane, IcpModel, IcpOptions};
        let held = get(source, "source")?;
        let s = read(&held, "source")?;
        let pts = input(xyz, n_points.saturating_mul(3), "xyz", false)?;
        finite(pts, "xyz")?;
        let m_out = output(out_matrix, 16, 16, "out_matrix")?;
        if out_stats.is_null() {
            return Err(FfiError::new(
                CcpStatus::NullPointer,
                "out_stats is a null pointer",
            ));
        }
        let d = IcpOptions::default();
        let opts = IcpOptions {
            model: if rigid != 0 {
                IcpModel::Rigid
            } else {
                IcpModel::Similarity
            },
            initial_gate: if initial_gate > 0.0 {
                initial_gate
            } else {
                d.initial_gate
            },
            min_gate: if min_gate > 0.0 { min_gate } else { d.min_gate },
            max_iterations: if max_iterations == 0 {
                d.max_iterations
            } else {
                max_iterations as usize
            },
            ..d
        };
        let src: Vec<[f64; 3]> = pts.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        let r = icp_point_to_plane(
            &s.index,
            &src,
            &crate::geometry::Similarity::identity(),
            &opts,
        )?;
        let m = r.matrix();
        for i in 0..4 {
            for j in 0..4 {
                m_out[i * 4 + j] = m[(i, j)];
            }
        }
        *out_stats = CcpIcpStats {
            scale: r.transform.scale,
            rmse_m: r.rmse_m,
            sigma0_m: r.sigma0_m,
            inliers: r.inliers,
            iterations: r.iterations.len(),
            converged: r.converged as i32,
        };
        Ok(())
    })
}
