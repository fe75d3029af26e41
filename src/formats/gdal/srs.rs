//! Spatial references (OSR) and coordinate transformations (OCT): PROJ through GDAL.

use super::api::{Api, H};
use super::{api, c_string, dim, last_error, string, GdalError, GdalResult};
use std::ffi::{c_char, c_int};

/// OGRERR_NONE.
const OGRERR_NONE: c_int = 0;
/// OAMS_TRADITIONAL_GIS_ORDER: easting/longitude first, whatever the CRS's axis order.
const OAMS_TRADITIONAL_GIS_ORDER: c_int = 0;

/// A spatial reference, released on drop. Not `Send`: GDAL's OSR objects belong to the
/// thread that made them.
pub struct SpatialRef {
    api: &'static Api,
    h: H,
}

impl Drop for SpatialRef {
    fn drop(&mut self) {
        // SAFETY: a reference this value owns, released once.
        unsafe { (self.api.OSRRelease)(self.h) };
    }
}

impl PartialEq for SpatialRef {
    /// The same CRS (GDAL's `OSRIsSame`: the same definition, whatever its spelling).
    fn eq(&self, other: &Self) -> bool {
        // SAFETY: two valid references.
        unsafe { (self.api.OSRIsSame)(self.h, other.h) != 0 }
    }
}

impl SpatialRef {
    pub(super) fn handle(&self) -> H {
        self.h
    }

    /// An owned copy of a reference GDAL owns.
    pub(super) fn clone_of(api: &'static Api, h: H) -> Option<Self> {
        // SAFETY: a valid reference, cloned into one this value owns.
        let c = unsafe { (api.OSRClone)(h) };
        (!c.is_null()).then_some(Self { api, h: c })
    }

    /// An empty reference filled by `import` (an OSR importer), freed when it refuses.
    fn import(call: &'static str, import: impl FnOnce(&Api, H) -> c_int) -> GdalResult<Self> {
        let api = api()?;
        // SAFETY: an empty reference (a null definition), owned from here on.
        let h = unsafe { (api.OSRNewSpatialReference)(std::ptr::null()) };
        if h.is_null() {
            return Err(last_error(api, "OSRNewSpatialReference"));
        }
        let srs = Self { api, h };
        let e = import(api, h);
        if e != OGRERR_NONE {
            let mut err = last_error(api, call);
            if err.message.is_empty() {
                err.message = format!("OGR error {e}");
            }
            return Err(err);
        }
        Ok(srs)
    }

    pub fn from_wkt(wkt: &str) -> GdalResult<Self> {
        let c = c_string("OSRImportFromWkt", wkt)?;
        Self::import("OSRImportFromWkt", |a, h| {
            let mut p = c.as_ptr() as *mut c_char;
            // SAFETY: GDAL advances its own copy of the pointer over the NUL-terminated WKT.
            unsafe { (a.OSRImportFromWkt)(h, &mut p) }
        })
    }

    pub fn from_proj4(text: &str) -> GdalResult<Self> {
        let c = c_string("OSRImportFromProj4", text)?;
        // SAFETY: a NUL-terminated PROJ string.
        Self::import("OSRImportFromProj4", |a, h| unsafe {
            (a.OSRImportFromProj4)(h, c.as_ptr())
        })
    }

    /// `SetFromUserInput`: only for vetted text (`EPSG:n`, PROJJSON), since it also opens
    /// files and URLs named by the string ([`crate::formats::crs_input`]).
    pub fn from_user_input(text: &str) -> GdalResult<Self> {
        let c = c_string("OSRSetFromUserInput", text)?;
        // SAFETY: a NUL-terminated definition.
        Self::import("OSRSetFromUserInput", |a, h| unsafe {
            (a.OSRSetFromUserInput)(h, c.as_ptr())
        })
    }

    /// Easting/longitude first for every transformation made with this reference.
    pub fn set_traditional_gis_order(&mut self) {
        // SAFETY: a valid reference.
        unsafe { (self.api.OSRSetAxisMappingStrategy)(self.h, OAMS_TRADITIONAL_GIS_ORDER) };
    }

    pub fn auth_name(&self) -> Option<String> {
        // SAFETY: the string belongs to the reference and is copied at once.
        unsafe { string((self.api.OSRGetAuthorityName)(self.h, std::ptr::null())) }
    }

    pub fn auth_code(&self) -> Option<i32> {
        // SAFETY: as auth_name.
        unsafe { string((self.api.OSRGetAuthorityCode)(self.h, std::ptr::null())) }?
            .parse()
            .ok()
    }

    pub fn name(&self) -> Option<String> {
        // SAFETY: as auth_name.
        unsafe { string((self.api.OSRGetName)(self.h)) }
    }

    /// Text GDAL allocates (`export` fills the pointer), copied and freed.
    fn exported(
        &self,
        call: &'static str,
        export: impl FnOnce(&Api, *mut *mut c_char) -> c_int,
    ) -> GdalResult<String> {
        let mut p: *mut c_char = std::ptr::null_mut();
        let e = export(self.api, &mut p);
        // SAFETY: null or a string GDAL allocated for us, freed once after the copy.
        let text = unsafe { string(p) };
        unsafe { (self.api.VSIFree)(p.cast()) };
        match (e, text) {
            (OGRERR_NONE, Some(t)) => Ok(t),
            _ => Err(last_error(self.api, call)),
        }
    }

    pub fn to_wkt(&self) -> GdalResult<String> {
        // SAFETY: a valid reference and out-pointer.
        self.exported("OSRExportToWkt", |a, p| unsafe {
            (a.OSRExportToWkt)(self.h, p)
        })
    }

    pub fn to_projjson(&self) -> GdalResult<String> {
        // SAFETY: a valid reference and out-pointer; no options.
        self.exported("OSRExportToPROJJSON", |a, p| unsafe {
            (a.OSRExportToPROJJSON)(self.h, p, std::ptr::null())
        })
    }

    pub fn is_geographic(&self) -> bool {
        // SAFETY: a valid reference.
        unsafe { (self.api.OSRIsGeographic)(self.h) != 0 }
    }

    pub fn is_projected(&self) -> bool {
        // SAFETY: a valid reference.
        unsafe { (self.api.OSRIsProjected)(self.h) != 0 }
    }

    pub fn is_compound(&self) -> bool {
        // SAFETY: a valid reference.
        unsafe { (self.api.OSRIsCompound)(self.h) != 0 }
    }

    pub fn is_geocentric(&self) -> bool {
        // SAFETY: a valid reference.
        unsafe { (self.api.OSRIsGeocentric)(self.h) != 0 }
    }

    /// Radians per angular unit and the unit's name.
    pub fn angular_units(&self) -> (f64, Option<String>) {
        let mut name: *mut c_char = std::ptr::null_mut();
        // SAFETY: the name belongs to the reference and is copied at once.
        let v = unsafe { (self.api.OSRGetAngularUnits)(self.h, &mut name) };
        (v, unsafe { string(name) })
    }

    /// Metres per linear unit and the unit's name.
    pub fn linear_units(&self) -> (f64, Option<String>) {
        let mut name: *mut c_char = std::ptr::null_mut();
        // SAFETY: as angular_units.
        let v = unsafe { (self.api.OSRGetLinearUnits)(self.h, &mut name) };
        (v, unsafe { string(name) })
    }
}

/// A transformation between two references, destroyed on drop.
pub struct CoordTransform {
    api: &'static Api,
    h: H,
}

impl Drop for CoordTransform {
    fn drop(&mut self) {
        // SAFETY: a transformation this value owns, destroyed once.
        unsafe { (self.api.OCTDestroyCoordinateTransformation)(self.h) };
    }
}

impl CoordTransform {
    pub fn new(source: &SpatialRef, target: &SpatialRef) -> GdalResult<Self> {
        let api = source.api;
        // SAFETY: two valid references (GDAL clones them).
        let h = unsafe { (api.OCTNewCoordinateTransformation)(source.h, target.h) };
        if h.is_null() {
            return Err(last_error(api, "OCTNewCoordinateTransformation"));
        }
        Ok(Self { api, h })
    }

    /// Transforms the arrays in place (`z` empty for 2-D); the caller checks the lengths.
    pub fn transform_coords(&self, x: &mut [f64], y: &mut [f64], z: &mut [f64]) -> GdalResult<()> {
        let n = dim("OCTTransform", x.len())?;
        if y.len() != x.len() || !(z.is_empty() || z.len() == x.len()) {
            return Err(GdalError {
                call: "OCTTransform",
                message: format!("arrays of {}, {} and {} values", x.len(), y.len(), z.len()),
            });
        }
        let zp = if z.is_empty() {
            std::ptr::null_mut()
        } else {
            z.as_mut_ptr()
        };
        // SAFETY: n values in each array (z null for 2-D).
        let ok = unsafe { (self.api.OCTTransform)(self.h, n, x.as_mut_ptr(), y.as_mut_ptr(), zp) };
        if ok == 1 {
            Ok(())
        } else {
            Err(last_error(self.api, "OCTTransform"))
        }
    }
}
