//! GDAL, loaded when the first raster or CRS is opened rather than when the process starts.
//!
//! Why not the `gdal` crate (which links `libgdal` into every binary that uses the
//! library): a distribution's GDAL brings its whole driver tree with it, 113 shared
//! libraries on Debian 12 (HEIF, x265, Poppler, PostgreSQL, Kerberos…), and the dynamic
//! loader resolves and relocates them all before `main`. Measured on the 2-core CI machine:
//! an empty C program linked with `-lgdal` starts in 63 ms against 1 ms without it;
//! `cloudcontrol version` took 50–60 ms, of which 64 % in ld.so's symbol lookups. Most
//! commands never touch a raster or a CRS (`adjust` on a COLMAP model, `synth`, the bundle
//! adjustment behind the C ABI that a COLMAP pipeline calls per block), and that start-up
//! was a fifth of the 50-photo adjustment's whole run. Here the library is opened with
//! `dlopen` on first use ([`api`]) and only the ~50 C functions cloudcontrol calls are
//! bound; the safe types ([`Dataset`], [`RasterBand`], [`SpatialRef`], [`CoordTransform`])
//! cover what the formats need and free everything GDAL allocates. The `gdal` crate stays
//! the tests' independent reader.
//!
//! Which library: `CLOUDCONTROL_GDAL_LIBRARY` (a path) when set, else the system's
//! `libgdal` by the linker's search (`libgdal.so`, then the sonames of GDAL 3.0–3.12).
//! GDAL ≥ 3.4 is needed (`OSRSetPROJEnableNetwork`).

mod api;
mod dataset;
mod srs;

pub use dataset::{reproject, DataType, Dataset, Driver, GdalType, RasterBand};
pub use srs::{CoordTransform, SpatialRef};

use std::ffi::{c_char, CStr};

/// A failed GDAL call: the function and GDAL's message (or why GDAL could not be loaded).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct GdalError {
    pub call: &'static str,
    pub message: String,
}

impl std::fmt::Display for GdalError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.message.is_empty() {
            write!(f, "{} failed", self.call)
        } else {
            write!(f, "{}: {}", self.call, self.message)
        }
    }
}

impl std::error::Error for GdalError {}

pub type GdalResult<T> = std::result::Result<T, GdalError>;

/// The loaded library's function table, or why it could not be loaded.
pub(crate) fn api() -> GdalResult<&'static api::Api> {
    api::get().map_err(|message| GdalError {
        call: "loading GDAL",
        message: message.clone(),
    })
}

/// Copies a C string GDAL owns (None for null or not UTF-8).
///
/// # Safety
/// `p` is null or points at a NUL-terminated string that lives through the call.
unsafe fn string(p: *const c_char) -> Option<String> {
    if p.is_null() {
        return None;
    }
    // SAFETY: non-null and NUL-terminated by the caller's contract.
    unsafe { CStr::from_ptr(p) }
        .to_str()
        .ok()
        .map(str::to_owned)
}

/// The error of `call` from GDAL's thread-local last error (reset afterwards, so that a
/// later call's check does not see it).
fn last_error(a: &api::Api, call: &'static str) -> GdalError {
    // SAFETY: CPLGetLastErrorMsg returns a thread-local string valid until the next GDAL
    // call on this thread; it is copied before CPLErrorReset.
    let message = unsafe { string((a.CPLGetLastErrorMsg)()) }.unwrap_or_default();
    unsafe { (a.CPLErrorReset)() };
    GdalError {
        call,
        message: message.trim().to_string(),
    }
}

/// `Ok` when a CPLErr return is CE_None (0) or a warning (CE_Debug 1, CE_Warning 2).
fn check(a: &api::Api, call: &'static str, err: i32) -> GdalResult<()> {
    if err <= 2 {
        Ok(())
    } else {
        Err(last_error(a, call))
    }
}

/// `v` as GDAL's `int` (sizes, counts, indices), or the error of `call` naming it.
fn dim(call: &'static str, v: usize) -> GdalResult<std::ffi::c_int> {
    std::ffi::c_int::try_from(v).map_err(|_| GdalError {
        call,
        message: format!("{v} exceeds GDAL's int range"),
    })
}

/// A C string of `s`, or the error of `call` naming the NUL byte inside.
fn c_string(call: &'static str, s: &str) -> GdalResult<std::ffi::CString> {
    std::ffi::CString::new(s).map_err(|_| GdalError {
        call,
        message: format!("{s:?} holds a NUL byte"),
    })
}

/// A NULL-terminated `char**` list over owned C strings (GDAL's string lists: creation
/// options, allowed drivers); the strings must outlive the pointers.
struct CStringList {
    _strings: Vec<std::ffi::CString>,
    pointers: Vec<*const c_char>,
}

impl CStringList {
    fn new(call: &'static str, items: &[impl AsRef<str>]) -> GdalResult<Self> {
        let strings = items
            .iter()
            .map(|s| c_string(call, s.as_ref()))
            .collect::<GdalResult<Vec<_>>>()?;
        let mut pointers: Vec<*const c_char> = strings.iter().map(|s| s.as_ptr()).collect();
        pointers.push(std::ptr::null());
        Ok(Self {
            _strings: strings,
            pointers,
        })
    }

    fn as_ptr(&self) -> *const *const c_char {
        self.pointers.as_ptr()
    }
}
