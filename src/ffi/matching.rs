//! Template matching (NCC + LSM) and fiducial interior orientation over the C ABI.

use super::{finite, guard, input, output, CcpStatus, FfiError, FfiResult};
use crate::geometry::InteriorTransformKind;
use crate::matching::fiducial::{
    check_scan_pixel_um, interior_orientation, CameraDefinition, IoOptions, ScanOrientation,
};
use crate::matching::ncc::Window;
use crate::matching::{
    match_template, GreyImage, MatchOptions, MatchResult, MatchingError, Pyramid,
};
use std::ffi::{c_char, CStr};

impl From<MatchingError> for FfiError {
    fn from(e: MatchingError) -> Self {
        let status = match &e {
            MatchingError::Read { .. } => CcpStatus::Io,
            MatchingError::Orientation { .. } | MatchingError::Relative { .. } => {
                CcpStatus::Numeric
            }
            MatchingError::Geometry(g) => return FfiError::from(g.clone()),
            _ => CcpStatus::InvalidArgument,
        };
        FfiError::new(status, e.to_string())
    }
}

/// Result of `ccp_match_template`. Positions are the template centre in image pixels
/// (origin at the top-left corner of the top-left pixel). `reason` is a NUL-terminated
/// message when `accepted` is 0.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct CcpMatchResult {
    pub accepted: i32,
    pub lsm_converged: i32,
    pub lsm_iterations: u32,
    pub x: f64,
    pub y: f64,
    pub ncc: f64,
    pub ncc_x: f64,
    pub ncc_y: f64,
    /// Second-best correlation peak divided by the best.
    pub ambiguity: f64,
    pub sigma_x: f64,
    pub sigma_y: f64,
    /// LSM affine (row-major 2×2): template offsets → image offsets.
    pub affine: [f64; 4],
    pub reason: [c_char; 200],
}

impl From<&MatchResult> for CcpMatchResult {
    /// `reason` is truncated to 199 bytes so that the buffer stays NUL-terminated.
    fn from(m: &MatchResult) -> Self {
        let mut reason = [0 as c_char; 200];
        if let Some(r) = &m.reason {
            for (d, s) in reason.iter_mut().zip(r.bytes().take(199)) {
                *d = s as c_char;
            }
        }
        CcpMatchResult {
            accepted: m.accepted as i32,
            lsm_converged: m.lsm_converged as i32,
            lsm_iterations: m.lsm_iterations as u32,
            x: m.x,
            y: m.y,
            ncc: m.ncc,
            ncc_x: m.ncc_x,
            ncc_y: m.ncc_y,
            ambiguity: m.ambiguity,
            sigma_x: m.sigma_x,
            sigma_y: m.sigma_y,
            affine: m.affine,
            reason,
        }
    }
}

/// A copy of the caller's grey values as an image, within the photo memory budget
/// (`formats::image_open::photo_memory`: the copy and its pyramid are counted before
/// anything is copied; beyond it the status is `CCP_STATUS_INVALID_ARGUMENT`).
pub(crate) fn image_from(
    ptr: *const f32,
    width: u32,
    height: u32,
    name: &str,
) -> FfiResult<GreyImage> {
    let (w, h) = (width as usize, height as usize);
    if w == 0 || h == 0 {
        return Err(FfiError::invalid(format!("{name}: size {w}×{h} is empty")));
    }
    use crate::formats::image_open;
    image_open::check_photo_memory(
        std::path::Path::new(name),
        w as u64,
        h as u64,
        image_open::MATCHING_BYTES_PER_PIXEL,
        "f32 grey values",
    )
    .map_err(|e| FfiError::invalid(e.to_string()))?;
    let data = unsafe { input(ptr, w * h, name, false)? };
    if let Some(i) = data.iter().position(|v| !v.is_finite()) {
        return Err(FfiError::new(
            CcpStatus::NotFinite,
            format!("{name}[{i}] is not finite"),
        ));
    }
    Ok(GreyImage {
        width: w,
        height: h,
        data: data.to_vec(),
    })
}

/// The image and the template every matching entry takes, both checked.
unsafe fn image_and_template(
    image: *const f32,
    size: [u32; 2],
    templ: *const f32,
    templ_size: [u32; 2],
) -> FfiResult<(GreyImage, GreyImage)> {
    Ok((
        image_from(image, size[0], size[1], "image")?,
        image_from(templ, templ_size[0], templ_size[1], "templ")?,
    ))
}

/// Matches a template in a window of an image: coarse-to-fine NCC, then LSM from the NCC
/// peak, accepted when NCC ≥ `ncc_threshold`, LSM converged and both agree within
/// `agreement_px`. `image` and `templ` are row-major f32 grey values; `window` is
/// `col, row, width, height` (4 values) or NULL for the whole image. A rejected match is
/// not an error: the status is OK, `accepted` is 0 and `reason` says why.
///
/// # Safety
/// Pointers must be null or point to arrays of the stated lengths (image `width·height`,
/// template `templ_width·templ_height` values, buffers of the given lengths).
#[no_mangle]
pub unsafe extern "C" fn ccp_match_template(
    image: *const f32,
    width: u32,
    height: u32,
    templ: *const f32,
    templ_width: u32,
    templ_height: u32,
    window: *const u32,
    ncc_threshold: f64,
    agreement_px: f64,
    out: *mut CcpMatchResult,
) -> CcpStatus {
    guard(|| {
        let out = output(out, 1, 1, "out")?;
        let (img, tpl) =
            image_and_template(image, [width, height], templ, [templ_width, templ_height])?;
        finite(&[ncc_threshold, agreement_px], "ncc_threshold/agreement_px")?;
        if !(-1.0..=1.0).contains(&ncc_threshold) || agreement_px <= 0.0 {
            return Err(FfiError::invalid(format!(
                "ncc_threshold {ncc_threshold} must be in [-1, 1] and agreement_px {agreement_px} positive"
            )));
        }
        let win = if window.is_null() {
            Window::whole(&img)
        } else {
            let w = input(window, 4, "window", false)?;
            let win = Window {
                col: w[0] as usize,
                row: w[1] as usize,
                width: w[2] as usize,
                height: w[3] as usize,
            };
            if win.col + win.width > img.width || win.row + win.height > img.height {
                return Err(FfiError::invalid(format!(
                    "window {}×{} at ({}, {}) is outside the {}×{} image",
                    win.width, win.height, win.col, win.row, img.width, img.height
                )));
            }
            win
        };
        let opts = MatchOptions {
            ncc_threshold,
            agreement_px,
            ..MatchOptions::default()
        };
        // The copy becomes level 0 of its pyramid: no second one.
        let pyr = Pyramid::from_image(img, 8, 16);
        let m = match_template(&pyr, &tpl, win, None, &opts)?;
        out[0] = CcpMatchResult::from(&m);
        Ok(())
    })
}

/// Fiducial interior orientation of a scan given as row-major f32 grey values.
/// `camera_json` is the camera definition (formats/cameras schema) as NUL-terminated
/// UTF-8 text. `pixel_mm` ≤ 0 estimates the scan pixel size from the format;
/// `projective` 0/1 picks the transform; `orientation` −1 tries all eight scan
/// orientations, else `rotation_deg / 90 + 4 · mirrored`. The io.json document is written
/// NUL-terminated into `out_json`; `*out_needed` receives its size including the NUL
/// (call with `out_len = 0` to ask; status BufferTooSmall when it does not fit).
///
/// # Safety
/// Pointers must be null or point to arrays of the stated lengths (image `width·height`,
/// template `templ_width·templ_height` values, buffers of the given lengths).
#[no_mangle]
pub unsafe extern "C" fn ccp_fiducial_io(
    camera_json: *const c_char,
    scan: *const f32,
    width: u32,
    height: u32,
    pixel_mm: f64,
    projective: i32,
    orientation: i32,
    out_json: *mut c_char,
    out_len: usize,
    out_needed: *mut usize,
) -> CcpStatus {
    guard(|| {
        if out_needed.is_null() {
            return Err(FfiError::new(
                CcpStatus::NullPointer,
                "out_needed is a null pointer",
            ));
        }
        *out_needed = 0;
        if camera_json.is_null() {
            return Err(FfiError::new(
                CcpStatus::NullPointer,
                "camera_json is a null pointer",
            ));
        }
        let text = CStr::from_ptr(camera_json)
            .to_str()
            .map_err(|e| FfiError::invalid(format!("camera_json is not UTF-8: {e}")))?;
        let cam: CameraDefinition = serde_json::from_str(text)
            .map_err(|e| FfiError::new(CcpStatus::Format, format!("camera_json: {e}")))?;
        cam.validate()
            .map_err(|e| FfiError::invalid(format!("camera_json: {e}")))?;
        let img = image_from(scan, width, height, "scan")?;
        finite(&[pixel_mm], "pixel_mm")?;
        if pixel_mm > 0.0 {
            check_scan_pixel_um(pixel_mm * 1000.0)
                .map_err(|m| FfiError::invalid(format!("pixel_mm {pixel_mm}: {m}")))?;
        }
        let orientation = match orientation {
            -1 => None,
            k @ 0..=7 => Some(ScanOrientation {
                rotation_deg: (k % 4) as u16 * 90,
                mirrored: k >= 4,
            }),
            k => {
                return Err(FfiError::invalid(format!(
                    "orientation {k}: expected −1 or 0–7"
                )))
            }
        };
        let opts = IoOptions {
            pixel_mm: (pixel_mm > 0.0).then_some(pixel_mm),
            orientation,
            kind: if projective != 0 {
                InteriorTransformKind::Projective
            } else {
                InteriorTransformKind::Affine
            },
            ..IoOptions::default()
        };
        let io = interior_orientation(&cam, &img, "scan", &opts)?;
        let json = io.to_json().to_string();
        let bytes = json.as_bytes();
        *out_needed = bytes.len() + 1;
        let buf = output(out_json, out_len, bytes.len() + 1, "out_json")?;
        for (d, s) in buf.iter_mut().zip(bytes) {
            *d = *s as c_char;
        }
        buf[bytes.len()] = 0;
        Ok(())
    })
}

/// Full NCC surface of `templ` over the whole `image` at one resolution (what OpenCV's
/// matchTemplate TM_CCOEFF_NORMED computes): `out` receives
/// (height − templ_height + 1) × (width − templ_width + 1) values, row-major, value (i, j)
/// for the template's top-left corner at column i, row j.
///
/// # Safety
/// Pointers must be null or point to arrays of the stated lengths (image `width·height`,
/// template `templ_width·templ_height` values, buffers of the given lengths).
#[no_mangle]
pub unsafe extern "C" fn ccp_ncc_surface(
    image: *const f32,
    width: u32,
    height: u32,
    templ: *const f32,
    templ_width: u32,
    templ_height: u32,
    out: *mut f32,
    out_len: usize,
) -> CcpStatus {
    guard(|| {
        let (img, tpl) =
            image_and_template(image, [width, height], templ, [templ_width, templ_height])?;
        let s = crate::matching::ncc::ncc_surface(&img, &tpl, Window::whole(&img))?;
        let o = output(out, out_len, s.values.len(), "out")?;
        o.copy_from_slice(&s.values);
        Ok(())
    })
}

/// Least-squares matching alone (6 affine + 2 radiometric parameters) from the template
/// centre (x, y). Fills `out` like `ccp_match_template` (`ncc` fields are NaN);
/// `accepted` means converged.
///
/// # Safety
/// Pointers must be null or point to arrays of the stated lengths (image `width·height`,
/// template `templ_width·templ_height` values, buffers of the given lengths).
#[no_mangle]
pub unsafe extern "C" fn ccp_lsm(
    image: *const f32,
    width: u32,
    height: u32,
    templ: *const f32,
    templ_width: u32,
    templ_height: u32,
    x: f64,
    y: f64,
    out: *mut CcpMatchResult,
) -> CcpStatus {
    guard(|| {
        let out = output(out, 1, 1, "out")?;
        let (img, tpl) =
            image_and_template(image, [width, height], templ, [templ_width, templ_height])?;
        finite(&[x, y], "x/y")?;
        let l = crate::matching::lsm(
            &img,
            &tpl,
            x,
            y,
            None,
            &crate::matching::LsmOptions::default(),
        );
        out[0] = CcpMatchResult::from(&MatchResult {
            accepted: l.converged,
            reason: l.reason,
            x: l.x,
            y: l.y,
            ncc: f64::NAN,
            ncc_x: f64::NAN,
            ncc_y: f64::NAN,
            ambiguity: f64::NAN,
            lsm_converged: l.converged,
            lsm_iterations: l.iterations,
            sigma_x: l.sigma_x,
            sigma_y: l.sigma_y,
            sigma0: l.sigma0,
            affine: l.affine,
        });
        Ok(())
    })
}
