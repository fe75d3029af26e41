//! LiDAR through the C ABI: the source catalogue as a JSON string and the evaluation of
//! checkpoints. Strings returned by the library are freed with `ccp_string_free`.

use super::{finite, guard, input, output, CcpStatus, FfiError, FfiResult};
use crate::lidar::eval::evaluate_checkpoints_store;
use crate::lidar::{Catalogue, CheckpointOptions, LidarError, ScanOptions, TileStore};
use std::ffi::{c_char, CStr, CString};
use std::path::PathBuf;

impl From<LidarError> for FfiError {
    fn from(e: LidarError) -> Self {
        use LidarError as L;
        let status = match &e {
            L::Io { source, .. } if source.kind() == std::io::ErrorKind::NotFound => {
                CcpStatus::NotFound
            }
            L::Io { .. } => CcpStatus::Io,
            L::NonFinite { .. } => CcpStatus::NotFinite,
            L::InvalidOption(_) | L::TooFewPoints { .. } => CcpStatus::InvalidArgument,
            L::TooFewCorrespondences { .. } | L::Singular { .. } => CcpStatus::Numeric,
            L::Format(f) => return FfiError::new(CcpStatus::Format, f.to_string()),
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

unsafe fn opt_str(p: *const c_char, name: &str) -> FfiResult<Option<String>> {
    if p.is_null() {
        return Ok(None);
    }
    let s = CStr::from_ptr(p)
        .to_str()
        .map_err(|_| FfiError::invalid(format!("{name} is not UTF-8")))?;
    Ok((!s.is_empty()).then(|| s.to_string()))
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
        *out_json = c.into_raw();
        Ok(())
    })
}

/// Frees a string returned by the library (NULL is ignored).
#[no_mangle]
pub unsafe extern "C" fn ccp_string_free(s: *mut c_char) {
    if !s.is_null() {
        let _ = std::panic::catch_unwind(|| drop(CString::from_raw(s)));
    }
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
