//! Raster datasets, bands and drivers.

use super::api::{Api, H};
use super::srs::SpatialRef;
use super::{api, c_string, check, dim, last_error, CStringList, GdalError, GdalResult};
use std::ffi::{c_int, c_void};
use std::marker::PhantomData;
use std::path::Path;

/// A band's pixel type (GDALDataType's values).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DataType {
    UInt8,
    UInt16,
    Int16,
    UInt32,
    Int32,
    Float32,
    Float64,
    Other(i32),
}

impl DataType {
    fn from_gdal(v: c_int) -> Self {
        match v {
            1 => Self::UInt8,
            2 => Self::UInt16,
            3 => Self::Int16,
            4 => Self::UInt32,
            5 => Self::Int32,
            6 => Self::Float32,
            7 => Self::Float64,
            v => Self::Other(v),
        }
    }
}

/// A Rust pixel type with its GDALDataType.
pub trait GdalType: Copy + Default {
    const GDAL: c_int;
}

impl GdalType for u8 {
    const GDAL: c_int = 1;
}
impl GdalType for u16 {
    const GDAL: c_int = 2;
}
impl GdalType for f32 {
    const GDAL: c_int = 6;
}

/// A driver (static in GDAL, never freed).
pub struct Driver {
    api: &'static Api,
    h: H,
}

impl Driver {
    pub fn by_name(name: &str) -> GdalResult<Self> {
        let api = api()?;
        let c = c_string("GDALGetDriverByName", name)?;
        // SAFETY: a NUL-terminated name; the handle is GDAL's static driver or null.
        let h = unsafe { (api.GDALGetDriverByName)(c.as_ptr()) };
        if h.is_null() {
            return Err(GdalError {
                call: "GDALGetDriverByName",
                message: format!("no driver {name}"),
            });
        }
        Ok(Self { api, h })
    }

    /// Creates a `width`×`height` dataset of `bands` bands of `T` with creation `options`.
    pub fn create<T: GdalType>(
        &self,
        path: &Path,
        (width, height): (usize, usize),
        bands: usize,
        options: &[impl AsRef<str>],
    ) -> GdalResult<Dataset> {
        let a = self.api;
        let name = path_string("GDALCreate", path)?;
        let opts = CStringList::new("GDALCreate", options)?;
        let (w, h, b) = (
            dim("GDALCreate", width)?,
            dim("GDALCreate", height)?,
            dim("GDALCreate", bands)?,
        );
        // SAFETY: valid driver, NUL-terminated name, NULL-terminated option list.
        let ds = unsafe { (a.GDALCreate)(self.h, name.as_ptr(), w, h, b, T::GDAL, opts.as_ptr()) };
        Dataset::owned(a, ds, "GDALCreate")
    }
}

/// An open dataset, closed on drop.
pub struct Dataset {
    api: &'static Api,
    h: H,
}

// SAFETY: a GDAL dataset may move between threads; it is used by one thread at a time
// (no `Sync`), as GDAL requires.
unsafe impl Send for Dataset {}

impl Drop for Dataset {
    fn drop(&mut self) {
        // SAFETY: an owned, open handle closed once.
        unsafe { (self.api.GDALClose)(self.h) };
    }
}

/// GDALOpenEx's flags: raster datasets, read-only.
const GDAL_OF_RASTER: u32 = 0x02;

fn path_string(call: &'static str, path: &Path) -> GdalResult<std::ffi::CString> {
    let s = path.to_str().ok_or_else(|| GdalError {
        call,
        message: format!("{} is not UTF-8", path.display()),
    })?;
    c_string(call, s)
}

impl Dataset {
    fn owned(api: &'static Api, h: H, call: &'static str) -> GdalResult<Self> {
        if h.is_null() {
            Err(last_error(api, call))
        } else {
            Ok(Self { api, h })
        }
    }

    /// Opens a raster read-only with only the drivers named.
    pub fn open_raster(path: &Path, drivers: &[&str]) -> GdalResult<Self> {
        let a = api()?;
        let name = path_string("GDALOpenEx", path)?;
        let drivers = CStringList::new("GDALOpenEx", drivers)?;
        // SAFETY: NUL-terminated path, NULL-terminated driver list, no options or siblings.
        let h = unsafe {
            (a.GDALOpenEx)(
                name.as_ptr(),
                GDAL_OF_RASTER,
                drivers.as_ptr(),
                std::ptr::null(),
                std::ptr::null(),
            )
        };
        Self::owned(a, h, "GDALOpenEx")
    }

    /// Width and height in pixels.
    pub fn raster_size(&self) -> (usize, usize) {
        // SAFETY: an open handle.
        let (w, h) = unsafe {
            (
                (self.api.GDALGetRasterXSize)(self.h),
                (self.api.GDALGetRasterYSize)(self.h),
            )
        };
        (w.max(0) as usize, h.max(0) as usize)
    }

    pub fn raster_count(&self) -> usize {
        // SAFETY: an open handle.
        unsafe { (self.api.GDALGetRasterCount)(self.h) }.max(0) as usize
    }

    pub fn geo_transform(&self) -> GdalResult<[f64; 6]> {
        let mut gt = [0.0; 6];
        // SAFETY: six doubles to fill.
        let e = unsafe { (self.api.GDALGetGeoTransform)(self.h, gt.as_mut_ptr()) };
        check(self.api, "GDALGetGeoTransform", e)?;
        Ok(gt)
    }

    pub fn set_geo_transform(&mut self, gt: &[f64; 6]) -> GdalResult<()> {
        let mut gt = *gt;
        // SAFETY: six doubles, copied by GDAL.
        let e = unsafe { (self.api.GDALSetGeoTransform)(self.h, gt.as_mut_ptr()) };
        check(self.api, "GDALSetGeoTransform", e)
    }

    /// The dataset's CRS (a copy), or None when it states none.
    pub fn spatial_ref(&self) -> Option<SpatialRef> {
        // SAFETY: the returned reference belongs to the dataset; it is cloned before use.
        let h = unsafe { (self.api.GDALGetSpatialRef)(self.h) };
        if h.is_null() {
            return None;
        }
        SpatialRef::clone_of(self.api, h)
    }

    pub fn set_spatial_ref(&mut self, srs: &SpatialRef) -> GdalResult<()> {
        // SAFETY: GDAL copies the reference.
        let e = unsafe { (self.api.GDALSetSpatialRef)(self.h, srs.handle()) };
        check(self.api, "GDALSetSpatialRef", e)
    }

    /// Band `index` (1-based).
    pub fn rasterband(&self, index: usize) -> GdalResult<RasterBand<'_>> {
        let i = dim("GDALGetRasterBand", index)?;
        // SAFETY: GDAL checks the index and returns null (with an error) outside it.
        let h = unsafe { (self.api.GDALGetRasterBand)(self.h, i) };
        if h.is_null() {
            return Err(last_error(self.api, "GDALGetRasterBand"));
        }
        Ok(RasterBand {
            api: self.api,
            h,
            _dataset: PhantomData,
        })
    }

    /// Builds overviews of every band with `resampling` at the decimation `levels`.
    pub fn build_overviews(&mut self, resampling: &str, levels: &[i32]) -> GdalResult<()> {
        let r = c_string("GDALBuildOverviews", resampling)?;
        let n = dim("GDALBuildOverviews", levels.len())?;
        // SAFETY: the level list outlives the call; no band list means all bands.
        let e = unsafe {
            (self.api.GDALBuildOverviews)(
                self.h,
                r.as_ptr(),
                n,
                levels.as_ptr(),
                0,
                std::ptr::null(),
                std::ptr::null_mut(),
                std::ptr::null_mut(),
            )
        };
        check(self.api, "GDALBuildOverviews", e)
    }

    /// Writes cached blocks to the file; a write error GDAL met is returned.
    pub fn flush_cache(&mut self) -> GdalResult<()> {
        // SAFETY: an open handle; the error state is read from GDAL's thread-local slot.
        unsafe {
            (self.api.CPLErrorReset)();
            (self.api.GDALFlushCache)(self.h);
            check(self.api, "GDALFlushCache", (self.api.CPLGetLastErrorType)())
        }
    }

    /// A copy of this dataset made by `driver` at `path` with creation `options`.
    pub fn create_copy(
        &self,
        driver: &Driver,
        path: &Path,
        options: &[impl AsRef<str>],
    ) -> GdalResult<Dataset> {
        let name = path_string("GDALCreateCopy", path)?;
        let opts = CStringList::new("GDALCreateCopy", options)?;
        // SAFETY: valid handles, NUL-terminated name, NULL-terminated options, no progress.
        let h = unsafe {
            (self.api.GDALCreateCopy)(
                driver.h,
                name.as_ptr(),
                self.h,
                0,
                opts.as_ptr(),
                std::ptr::null_mut(),
                std::ptr::null_mut(),
            )
        };
        Self::owned(self.api, h, "GDALCreateCopy")
    }
}

/// One band of a [`Dataset`], borrowed from it.
pub struct RasterBand<'a> {
    api: &'static Api,
    h: H,
    _dataset: PhantomData<&'a Dataset>,
}

/// GDALRWFlag.
const GF_READ: c_int = 0;
const GF_WRITE: c_int = 1;
/// GDALColorInterp's alpha band.
const GCI_ALPHA_BAND: c_int = 6;

impl RasterBand<'_> {
    pub fn band_type(&self) -> DataType {
        // SAFETY: a valid band.
        DataType::from_gdal(unsafe { (self.api.GDALGetRasterDataType)(self.h) })
    }

    /// Bytes of one pixel of the band's type.
    pub fn pixel_bytes(&self) -> usize {
        // SAFETY: a valid band; the size query takes any type value.
        let t = unsafe { (self.api.GDALGetRasterDataType)(self.h) };
        // SAFETY: a pure function of the type value.
        unsafe { (self.api.GDALGetDataTypeSizeBytes)(t) }.max(0) as usize
    }

    /// The band's natural block (columns, rows): what GDAL decodes whole to read any part
    /// of it.
    pub fn block_size(&self) -> (usize, usize) {
        let (mut x, mut y): (c_int, c_int) = (0, 0);
        // SAFETY: a valid band and two out values.
        unsafe { (self.api.GDALGetBlockSize)(self.h, &mut x, &mut y) };
        (x.max(0) as usize, y.max(0) as usize)
    }

    pub fn no_data_value(&self) -> Option<f64> {
        let mut set: c_int = 0;
        // SAFETY: a valid band and flag.
        let v = unsafe { (self.api.GDALGetRasterNoDataValue)(self.h, &mut set) };
        (set != 0).then_some(v)
    }

    pub fn set_no_data_value(&mut self, v: f64) -> GdalResult<()> {
        // SAFETY: a valid band.
        let e = unsafe { (self.api.GDALSetRasterNoDataValue)(self.h, v) };
        check(self.api, "GDALSetRasterNoDataValue", e)
    }

    /// Marks the band as alpha (transparency).
    pub fn set_alpha(&mut self) -> GdalResult<()> {
        // SAFETY: a valid band.
        let e = unsafe { (self.api.GDALSetRasterColorInterpretation)(self.h, GCI_ALPHA_BAND) };
        check(self.api, "GDALSetRasterColorInterpretation", e)
    }

    pub fn fill(&mut self, v: f64) -> GdalResult<()> {
        // SAFETY: a valid band.
        let e = unsafe { (self.api.GDALFillRaster)(self.h, v, 0.0) };
        check(self.api, "GDALFillRaster", e)
    }

    fn io<T: GdalType>(
        &self,
        flag: c_int,
        (x, y): (usize, usize),
        (w, h): (usize, usize),
        (bw, bh): (usize, usize),
        buf: *mut c_void,
    ) -> GdalResult<()> {
        const CALL: &str = "GDALRasterIO";
        let d = |v| dim(CALL, v);
        // SAFETY: `buf` holds bw·bh values of T (the callers' buffers), packed.
        let e = unsafe {
            (self.api.GDALRasterIO)(
                self.h,
                flag,
                d(x)?,
                d(y)?,
                d(w)?,
                d(h)?,
                buf,
                d(bw)?,
                d(bh)?,
                T::GDAL,
                0,
                0,
            )
        };
        check(self.api, CALL, e)
    }

    /// Reads the window at `offset` of `size` pixels into a `buffer`-sized grid (GDAL
    /// resamples, from overviews where they exist), row-major.
    pub fn read<T: GdalType>(
        &self,
        offset: (usize, usize),
        size: (usize, usize),
        buffer: (usize, usize),
    ) -> GdalResult<Vec<T>> {
        let n = buffer.0.checked_mul(buffer.1).ok_or_else(|| GdalError {
            call: "GDALRasterIO",
            message: format!("a {}×{} buffer overflows", buffer.0, buffer.1),
        })?;
        let mut data = vec![T::default(); n];
        self.io::<T>(GF_READ, offset, size, buffer, data.as_mut_ptr().cast())?;
        Ok(data)
    }

    /// Writes `data` (row-major, `size` pixels) at `offset`.
    pub fn write<T: GdalType>(
        &mut self,
        offset: (usize, usize),
        size: (usize, usize),
        data: &[T],
    ) -> GdalResult<()> {
        if size.0.checked_mul(size.1) != Some(data.len()) {
            return Err(GdalError {
                call: "GDALRasterIO",
                message: format!("{} values for a {}×{} window", data.len(), size.0, size.1),
            });
        }
        // GF_Write only reads the buffer; GDALRasterIO's pointer is not const.
        self.io::<T>(GF_WRITE, offset, size, size, data.as_ptr() as *mut c_void)
    }
}

/// GDALResampleAlg's bilinear.
const GRA_BILINEAR: c_int = 1;

/// Warps `src` into `dst` (both with CRS and geotransform) bilinearly.
pub fn reproject(src: &Dataset, dst: &mut Dataset) -> GdalResult<()> {
    let a = src.api;
    // SAFETY: two open datasets; null WKTs mean the datasets' own CRSs; no options.
    let e = unsafe {
        (a.GDALReprojectImage)(
            src.h,
            std::ptr::null(),
            dst.h,
            std::ptr::null(),
            GRA_BILINEAR,
            0.0,
            0.0,
            std::ptr::null_mut(),
            std::ptr::null_mut(),
            std::ptr::null_mut(),
        )
    };
    check(a, "GDALReprojectImage", e)
}
