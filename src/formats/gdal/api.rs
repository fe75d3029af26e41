//! The GDAL C functions cloudcontrol calls, bound from the library opened on first use.
//!
//! Loading also registers GDAL's drivers and pins PROJ's network access (below), so every
//! path into GDAL passes through the same one-time set-up.
//!
//! PROJ network access (grids fetched from PROJ's CDN) is switched off unless the host has
//! switched it on (`PROJ_NETWORK=ON`, `network = on` in proj.ini, or
//! `OSRSetPROJEnableNetwork(1)` in the host's own GDAL before the first call into
//! cloudcontrol): a host's explicit choice is kept and a warning says so. Either way no
//! URL or file named by data reaches GDAL or PROJ ([`crate::formats::crs_input`],
//! [`crate::formats::image_open`]), so with the network on PROJ can only reach its
//! configured endpoint, for the grids of a transformation between two vetted CRSs.
//! GDAL's own network settings (`CPL_VSIL_CURL_ALLOWED_EXTENSIONS`, `GDAL_HTTP_*`) are left
//! to the host: cloudcontrol never hands GDAL a `/vsi…` path or a URL.

use std::ffi::{c_char, c_int, c_uint, c_void};
use std::sync::OnceLock;

/// A GDAL handle (dataset, band, driver, spatial reference, transformation).
pub(super) type H = *mut c_void;
type Str = *const c_char;
type StrList = *const *const c_char;

macro_rules! gdal_api {
    ($($name:ident: fn($($arg:ty),*) $(-> $ret:ty)?;)*) => {
        #[allow(non_snake_case)]
        pub(crate) struct Api {
            $(pub(super) $name: unsafe extern "C" fn($($arg),*) $(-> $ret)?,)*
        }

        impl Api {
            /// Binds every function; the first one missing names itself.
            ///
            /// # Safety
            /// `lib` is a GDAL library, whose functions have the C signatures declared here.
            unsafe fn bind(lib: &libloading::Library) -> Result<Self, String> {
                Ok(Self {
                    $($name: {
                        // SAFETY: the symbol's type is GDAL's documented C signature.
                        let f = unsafe { lib.get(concat!(stringify!($name), "\0").as_bytes()) }
                            .map_err(|e| format!("{} is missing ({e})", stringify!($name)))?;
                        *f
                    },)*
                })
            }
        }
    };
}

// Functions whose return type changed between GDAL versions (GDALClose and GDALFlushCache
// return CPLErr since 3.7–3.8, void before) are bound as void: their errors are read from
// CPLGetLastErrorType instead, which works on every version.
gdal_api! {
    GDALAllRegister: fn();
    GDALGetDriverByName: fn(Str) -> H;
    GDALOpenEx: fn(Str, c_uint, StrList, StrList, StrList) -> H;
    GDALClose: fn(H);
    GDALCreate: fn(H, Str, c_int, c_int, c_int, c_int, StrList) -> H;
    GDALCreateCopy: fn(H, Str, H, c_int, StrList, *mut c_void, *mut c_void) -> H;
    GDALFlushCache: fn(H);
    GDALGetRasterXSize: fn(H) -> c_int;
    GDALGetRasterYSize: fn(H) -> c_int;
    GDALGetRasterCount: fn(H) -> c_int;
    GDALGetGeoTransform: fn(H, *mut f64) -> c_int;
    GDALSetGeoTransform: fn(H, *mut f64) -> c_int;
    GDALGetSpatialRef: fn(H) -> H;
    GDALSetSpatialRef: fn(H, H) -> c_int;
    GDALGetRasterBand: fn(H, c_int) -> H;
    GDALBuildOverviews: fn(H, Str, c_int, *const c_int, c_int, *const c_int, *mut c_void, *mut c_void) -> c_int;
    GDALRasterIO: fn(H, c_int, c_int, c_int, c_int, c_int, *mut c_void, c_int, c_int, c_int, c_int, c_int) -> c_int;
    GDALGetRasterDataType: fn(H) -> c_int;
    GDALGetBlockSize: fn(H, *mut c_int, *mut c_int);
    GDALGetDataTypeSizeBytes: fn(c_int) -> c_int;
    GDALGetRasterNoDataValue: fn(H, *mut c_int) -> f64;
    GDALSetRasterNoDataValue: fn(H, f64) -> c_int;
    GDALSetRasterColorInterpretation: fn(H, c_int) -> c_int;
    GDALFillRaster: fn(H, f64, f64) -> c_int;
    GDALReprojectImage: fn(H, Str, H, Str, c_int, f64, f64, *mut c_void, *mut c_void, *mut c_void) -> c_int;
    CPLGetLastErrorMsg: fn() -> Str;
    CPLGetLastErrorType: fn() -> c_int;
    CPLErrorReset: fn();
    VSIFree: fn(*mut c_void);
    OSRNewSpatialReference: fn(Str) -> H;
    OSRRelease: fn(H);
    OSRClone: fn(H) -> H;
    OSRImportFromWkt: fn(H, *mut *mut c_char) -> c_int;
    OSRImportFromProj4: fn(H, Str) -> c_int;
    OSRSetFromUserInput: fn(H, Str) -> c_int;
    OSRSetAxisMappingStrategy: fn(H, c_int);
    OSRGetAuthorityName: fn(H, Str) -> Str;
    OSRGetAuthorityCode: fn(H, Str) -> Str;
    OSRGetName: fn(H) -> Str;
    OSRExportToWkt: fn(H, *mut *mut c_char) -> c_int;
    OSRExportToPROJJSON: fn(H, *mut *mut c_char, StrList) -> c_int;
    OSRIsGeographic: fn(H) -> c_int;
    OSRIsProjected: fn(H) -> c_int;
    OSRIsCompound: fn(H) -> c_int;
    OSRIsGeocentric: fn(H) -> c_int;
    OSRIsSame: fn(H, H) -> c_int;
    OSRGetAngularUnits: fn(H, *mut *mut c_char) -> f64;
    OSRGetLinearUnits: fn(H, *mut *mut c_char) -> f64;
    OSRGetPROJEnableNetwork: fn() -> c_int;
    OSRSetPROJEnableNetwork: fn(c_int);
    OCTNewCoordinateTransformation: fn(H, H) -> H;
    OCTDestroyCoordinateTransformation: fn(H);
    OCTTransform: fn(H, c_int, *mut f64, *mut f64, *mut f64) -> c_int;
}

/// Where GDAL is looked for, in order (see the module documentation).
fn candidates() -> Vec<String> {
    if let Some(path) = std::env::var_os("CLOUDCONTROL_GDAL_LIBRARY") {
        return vec![path.to_string_lossy().into_owned()];
    }
    let mut names = Vec::new();
    if cfg!(target_os = "macos") {
        names.push("libgdal.dylib".to_string());
    } else if cfg!(windows) {
        names.push("gdal.dll".to_string());
        names.extend((300..=312).rev().map(|v| format!("gdal{v}.dll")));
    } else {
        names.push("libgdal.so".to_string());
        // Sonames of GDAL 3.0 (26) to 3.12 (38), newest first.
        names.extend((26..=38).rev().map(|v| format!("libgdal.so.{v}")));
    }
    names
}

fn load() -> Result<Api, String> {
    let mut tried = Vec::new();
    for name in candidates() {
        // SAFETY: opening GDAL runs its library initialisers, which have no preconditions.
        match unsafe { libloading::Library::new(&name) } {
            Ok(lib) => {
                // SAFETY: a library named libgdal is GDAL.
                let api = unsafe { Api::bind(&lib) }.map_err(|e| format!("{name}: {e}"))?;
                // The library stays loaded for the process: every handle made through it
                // may outlive any one caller.
                std::mem::forget(lib);
                // SAFETY: driver registration and PROJ's global network flag take no
                // arguments beyond the flag.
                unsafe {
                    (api.GDALAllRegister)();
                    if (api.OSRGetPROJEnableNetwork)() != 0 {
                        tracing::warn!(
                            "PROJ network access is on (set by the host: PROJ_NETWORK, \
                             proj.ini or OSRSetPROJEnableNetwork); cloudcontrol keeps it: \
                             transformation grids may be fetched from PROJ's endpoint (CRS \
                             definitions from data never name URLs or files)"
                        );
                    } else {
                        // Pinned off, so that PROJ contexts of threads created later do
                        // not read a different default.
                        (api.OSRSetPROJEnableNetwork)(0);
                    }
                }
                tracing::debug!(library = %name, "GDAL loaded");
                return Ok(api);
            }
            Err(e) => tried.push(format!("{name} ({e})")),
        }
    }
    Err(format!(
        "no GDAL library could be opened (set CLOUDCONTROL_GDAL_LIBRARY to its path); tried: {}",
        tried.join("; ")
    ))
}

static API: OnceLock<Result<Api, String>> = OnceLock::new();

/// The function table, loading GDAL on the first call.
pub(super) fn get() -> Result<&'static Api, &'static String> {
    API.get_or_init(load).as_ref()
}
