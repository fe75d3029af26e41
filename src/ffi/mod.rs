//! The C ABI: status codes, a thread-local last-error message, opaque handles and
//! caller-owned buffers with explicit lengths. No logic lives here: every function
//! validates its arguments, calls the library and maps errors to a status. No panic
//! crosses the boundary (each entry point runs under `catch_unwind`).
//!
//! Handles (`handles`) are registered tokens, not addresses: a freed handle, a handle of
//! another type, a double free or a pointer that never was a handle is refused with
//! `CCP_STATUS_INVALID_HANDLE`, and every handle may be used from several threads at once
//! (each type's documentation says which calls share it and which take it exclusively).
//!
//! # Safety
//! One contract holds for every `unsafe extern "C"` function here: pointer arguments that
//! are not handles are NULL or valid for the element count passed beside them. NULL,
//! absurd lengths, misalignment and non-finite values are detected and reported, not
//! trusted.
#![allow(clippy::missing_safety_doc)] // the contract above applies to every entry point

mod adjust;
mod camera;
mod control;
mod dense;
mod formats;
mod handles;
mod lidar;
mod matching;
mod orient;
mod pipeline;
mod synth;

pub use adjust::*;
pub use camera::*;
pub use control::*;
pub use dense::*;
pub use formats::*;
pub use lidar::*;
pub use matching::*;
pub use orient::*;
pub use pipeline::*;
pub use synth::*;

use std::cell::RefCell;
use std::ffi::{c_char, CString};
use std::panic::{catch_unwind, AssertUnwindSafe};

/// Status of every fallible call. On anything but `CCP_STATUS_OK`, `ccp_last_error`
/// returns a message naming the argument or input and the problem (the message is kept
/// per thread, so threads do not see each other's errors).
///
/// Handles (`CcpCamera`, `CcpBlock`, `CcpDcp`, `CcpLidarSource`, `CcpPhotoOrientation`)
/// are checked before use: a freed handle, one of another type, a double free, or a
/// pointer that never was a handle returns `CCP_STATUS_INVALID_HANDLE`. Every handle may
/// be used from several threads at once; freeing one while another thread is inside a
/// call on it is safe (the object lives until that call returns).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CcpStatus {
    Ok = 0,
    NullPointer = 1,
    InvalidArgument = 2,
    NotFinite = 3,
    Io = 4,
    Format = 5,
    Numeric = 6,
    NotFound = 7,
    BufferTooSmall = 8,
    /// The photo could not be oriented (the last error says why: too few matches, no
    /// control in view, failed interior orientation, …).
    NotOriented = 9,
    /// A handle (or a string to free) that is not live: freed already, of another handle
    /// type, or never made by this library. Nothing was done with it.
    InvalidHandle = 10,
    /// The destination is held by another call: a run (`ccp_project_run`,
    /// `ccp_project_plan`) is writing the same output folder, in this process or another.
    /// Nothing was done; call again once it ended, or give another output.
    Busy = 11,
    /// The call did its work, but its result is incomplete: a run in which an epoch
    /// oriented fewer photos than it has. Its outputs are set as on success (the summary
    /// JSON, whose `partial` lists each such epoch with its photos and reasons; release it
    /// as usual) and the last error says which epoch, how many and why.
    Partial = 12,
    Panic = 99,
}

/// An error on its way out through the C ABI.
#[derive(Debug)]
pub(crate) struct FfiError {
    pub status: CcpStatus,
    pub message: String,
}

impl FfiError {
    pub fn new(status: CcpStatus, message: impl Into<String>) -> Self {
        Self {
            status,
            message: message.into(),
        }
    }
    pub fn invalid(message: impl Into<String>) -> Self {
        Self::new(CcpStatus::InvalidArgument, message)
    }
}

impl From<crate::geometry::GeometryError> for FfiError {
    fn from(e: crate::geometry::GeometryError) -> Self {
        use crate::geometry::GeometryError as G;
        let status = match &e {
            G::NotFinite { .. } => CcpStatus::NotFinite,
            G::NotConverged { .. } | G::Degenerate(_) | G::NoIntersection(_) => CcpStatus::Numeric,
            _ => CcpStatus::InvalidArgument,
        };
        Self::new(status, e.to_string())
    }
}

impl From<crate::formats::FormatError> for FfiError {
    fn from(e: crate::formats::FormatError) -> Self {
        use crate::formats::FormatError as F;
        let status = match &e {
            // A FIFO, a device, a socket or a link cycle named as an input file.
            F::Io { .. } | F::NotRegularFile { .. } => CcpStatus::Io,
            F::Geometry(_) => CcpStatus::Numeric,
            _ => CcpStatus::Format,
        };
        Self::new(status, e.to_string())
    }
}

pub(crate) type FfiResult<T> = Result<T, FfiError>;

thread_local! {
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

fn set_last_error(message: &str) {
    let c = CString::new(message.replace('\0', "\\0")).unwrap_or_default();
    LAST_ERROR.with(|e| *e.borrow_mut() = c);
}

/// Runs an entry point: clears the last error, catches panics, maps errors to a status.
pub(crate) fn guard(f: impl FnOnce() -> FfiResult<()>) -> CcpStatus {
    set_last_error("");
    guard_keeping_error(f)
}

/// [`guard`] for the free functions: a success leaves the last error as it was. A
/// destructor that runs between a failed call and the read of its message (a Python
/// object collected by the garbage collector right then) must not erase the message, as
/// POSIX's `free` leaves `errno` alone.
pub(crate) fn guard_keeping_error(f: impl FnOnce() -> FfiResult<()>) -> CcpStatus {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(Ok(())) => CcpStatus::Ok,
        Ok(Err(e)) => {
            set_last_error(&e.message);
            e.status
        }
        Err(payload) => {
            let what = payload
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown".into());
            set_last_error(&format!(
                "internal error (panic caught at the C ABI): {what}"
            ));
            CcpStatus::Panic
        }
    }
}

/// Largest element count we accept for any array; guards against negative lengths
/// converted to `size_t` by callers.
const MAX_ELEMENTS: usize = 1 << 40;

/// Refuses an absurd length and a null pointer, the checks input and output arrays share.
fn plausible<T>(ptr: *const T, len: usize, name: &str) -> FfiResult<()> {
    if len > MAX_ELEMENTS {
        return Err(FfiError::invalid(format!(
            "{name}: length {len} is not plausible (a negative value passed as size_t?)"
        )));
    }
    if ptr.is_null() {
        return Err(FfiError::new(
            CcpStatus::NullPointer,
            format!("{name} is a null pointer"),
        ));
    }
    Ok(())
}

fn aligned<T>(ptr: *const T, name: &str) -> FfiResult<()> {
    if (ptr as usize) % std::mem::align_of::<T>() != 0 {
        return Err(FfiError::invalid(format!("{name} is not aligned")));
    }
    Ok(())
}

/// Borrows a caller-owned input array of `len` elements, refusing null, zero length when
/// `allow_empty` is false, and absurd lengths.
pub(crate) unsafe fn input<'a, T>(
    ptr: *const T,
    len: usize,
    name: &str,
    allow_empty: bool,
) -> FfiResult<&'a [T]> {
    if len == 0 {
        if allow_empty {
            return Ok(&[]);
        }
        return Err(FfiError::invalid(format!("{name}: length is zero")));
    }
    plausible(ptr, len, name)?;
    aligned(ptr, name)?;
    Ok(std::slice::from_raw_parts(ptr, len))
}

/// Borrows a caller-owned output array that must hold at least `needed` elements.
pub(crate) unsafe fn output<'a, T>(
    ptr: *mut T,
    len: usize,
    needed: usize,
    name: &str,
) -> FfiResult<&'a mut [T]> {
    plausible(ptr, len, name)?;
    if len < needed {
        return Err(FfiError::new(
            CcpStatus::BufferTooSmall,
            format!("{name} holds {len} values but {needed} are needed"),
        ));
    }
    aligned(ptr, name)?;
    Ok(std::slice::from_raw_parts_mut(ptr, needed))
}

/// Refuses NaN and infinities in an input array, naming the first bad element.
pub(crate) fn finite(values: &[f64], name: &str) -> FfiResult<()> {
    match values.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(i) => Err(FfiError::new(
            CcpStatus::NotFinite,
            format!("{name}[{i}] is not finite"),
        )),
    }
}

/// Refuses NaN and infinities in an interleaved array of `cols`-vectors, naming the row
/// and the coordinate (`points[7].z is not finite`).
pub(crate) fn finite_rows(values: &[f64], cols: usize, name: &str) -> FfiResult<()> {
    const AXES: [&str; 4] = ["x", "y", "z", "w"];
    match values.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(i) => {
            let axis = AXES.get(i % cols).copied().unwrap_or("?");
            Err(FfiError::new(
                CcpStatus::NotFinite,
                format!("{name}[{}].{axis} is not finite", i / cols),
            ))
        }
    }
}

/// Borrows a caller-owned struct passed by pointer (a pose, options), refusing null.
/// Library handles go through `handles::get` instead.
pub(crate) unsafe fn handle<'a, T>(ptr: *const T, name: &str) -> FfiResult<&'a T> {
    ptr.as_ref()
        .ok_or_else(|| FfiError::new(CcpStatus::NullPointer, format!("{name} is a null handle")))
}

/// The library version as a static NUL-terminated string (never freed).
#[no_mangle]
pub extern "C" fn ccp_version() -> *const c_char {
    concat!(env!("CARGO_PKG_VERSION"), "\0").as_ptr() as *const c_char
}

/// Copies the calling thread's last error message into `buf` (NUL-terminated, truncated
/// to `buf_len`) and returns the buffer size the whole message needs, NUL included.
/// Call with `buf = NULL, buf_len = 0` to ask for the size. The message is empty after a
/// successful call, except after the free functions (`ccp_*_free`, `ccp_string_free`),
/// which leave it as it was when they succeed.
#[no_mangle]
pub unsafe extern "C" fn ccp_last_error(buf: *mut c_char, buf_len: usize) -> usize {
    catch_unwind(|| {
        LAST_ERROR.with(|e| {
            let e = e.borrow();
            let bytes = e.as_bytes();
            if !buf.is_null() && buf_len > 0 {
                let n = bytes.len().min(buf_len - 1);
                std::ptr::copy_nonoverlapping(bytes.as_ptr() as *const c_char, buf, n);
                *buf.add(n) = 0;
            }
            bytes.len() + 1
        })
    })
    .unwrap_or(0)
}

/// An optional C string argument: NULL or empty is `None`; invalid UTF-8 is an error
/// naming the argument.
pub(crate) unsafe fn opt_str(p: *const std::ffi::c_char, name: &str) -> FfiResult<Option<String>> {
    if p.is_null() {
        return Ok(None);
    }
    let s = std::ffi::CStr::from_ptr(p)
        .to_str()
        .map_err(|_| FfiError::invalid(format!("{name} is not UTF-8")))?;
    Ok((!s.is_empty()).then(|| s.to_string()))
}
