//! Process-wide GDAL/PROJ settings for data the library did not choose, made once, before
//! the first CRS or raster is opened.
//!
//! PROJ network access (grids fetched from PROJ's CDN) is switched off unless the host has
//! switched it on (`PROJ_NETWORK=ON`, `network = on` in proj.ini, or
//! `OSRSetPROJEnableNetwork(1)` before the first call into cloudcontrol): a host's explicit
//! choice is kept and a warning says so. Either way no URL or file named by data reaches
//! GDAL or PROJ ([`super::crs_input`], [`super::image_open`]), so with the network on PROJ
//! can only reach its configured endpoint, for the grids of a transformation between two
//! vetted CRSs.
//!
//! GDAL's own network settings (`CPL_VSIL_CURL_ALLOWED_EXTENSIONS`, `GDAL_HTTP_*`) and
//! `GDAL_DISABLE_READDIR_ON_OPEN` are left to the host: they are process-wide and would
//! change what a host's own GDAL code can open, and cloudcontrol never hands GDAL a
//! `/vsi…` path or a URL, and opens rasters only with the GTiff, PNG and JPEG drivers.

use std::sync::Once;

static INIT: Once = Once::new();

/// Applies the settings above; cheap after the first call.
pub fn init() {
    INIT.call_once(|| {
        // SAFETY: plain getters/setters of GDAL's global PROJ network flag.
        let on = unsafe { gdal_sys::OSRGetPROJEnableNetwork() } != 0;
        if on {
            tracing::warn!(
                "PROJ network access is on (set by the host: PROJ_NETWORK, proj.ini or \
                 OSRSetPROJEnableNetwork); cloudcontrol keeps it: transformation grids may \
                 be fetched from PROJ's endpoint (CRS definitions from data never name URLs \
                 or files)"
            );
        } else {
            // Pinned off, so that PROJ contexts of threads created later do not read a
            // different default.
            unsafe { gdal_sys::OSRSetPROJEnableNetwork(0) };
        }
    });
}

/// Whether PROJ may use the network (after [`init`]).
pub fn proj_network_enabled() -> bool {
    init();
    // SAFETY: a getter of GDAL's global flag.
    unsafe { gdal_sys::OSRGetPROJEnableNetwork() != 0 }
}
