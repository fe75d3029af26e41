//! The handles the C ABI hands out, and the strings it returns.
//!
//! A handle is not the address of its object but a token: a serial number (never reused)
//! with the handle's type in its low bits. The objects live in a registry of live handles,
//! each behind a read-write lock. So a call with a freed handle, a handle of another type,
//! a double free or a pointer that was never a handle is refused with
//! `CCP_STATUS_INVALID_HANDLE` — the registry is consulted before anything is touched —
//! and a handle used from several threads at once is safe: calls that change the object
//! hold its lock exclusively (they run one after the other), calls that only read share
//! it. Freeing a handle while another thread is inside a call on it is safe too: the
//! object lives until that call returns; later calls are refused.
//!
//! Strings returned by the library are registered likewise, so `ccp_string_free` refuses
//! a pointer it did not hand out or has already freed.

use super::{CcpStatus, FfiError, FfiResult};
use std::any::Any;
use std::collections::{HashMap, HashSet};
use std::ffi::{c_char, CString};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, OnceLock, RwLock, RwLockReadGuard, RwLockWriteGuard};

/// A type handed out as a handle: its tag (1..[`TAGS`]) and its C name.
pub(crate) trait Handle: Send + Sync + 'static {
    const TAG: usize;
    const NAME: &'static str;
}

const TAG_BITS: u32 = 4;
const TAG_MASK: usize = (1 << TAG_BITS) - 1;

/// The C names of the handle types by tag (0: none).
const TAGS: [&str; 6] = [
    "",
    "CcpCamera",
    "CcpBlock",
    "CcpDcp",
    "CcpLidarSource",
    "CcpPhotoOrientation",
];

/// Serial of the next handle; serials start at 1 so that no token is NULL.
static NEXT: AtomicUsize = AtomicUsize::new(1);

type Object = Arc<dyn Any + Send + Sync>;

fn registry() -> MutexGuard<'static, HashMap<usize, Object>> {
    static LIVE: OnceLock<Mutex<HashMap<usize, Object>>> = OnceLock::new();
    // The map is only inserted into and removed from under the lock; a panic elsewhere
    // cannot leave it half-changed.
    LIVE.get_or_init(Default::default)
        .lock()
        .unwrap_or_else(|p| p.into_inner())
}

fn strings() -> MutexGuard<'static, HashSet<usize>> {
    static LIVE: OnceLock<Mutex<HashSet<usize>>> = OnceLock::new();
    LIVE.get_or_init(Default::default)
        .lock()
        .unwrap_or_else(|p| p.into_inner())
}

/// Registers `value` and returns its handle.
pub(crate) fn new_handle<T: Handle>(value: T) -> *mut T {
    let serial = NEXT.fetch_add(1, Ordering::Relaxed);
    let token = (serial << TAG_BITS) | T::TAG;
    let object: Object = Arc::new(RwLock::new(value));
    registry().insert(token, object);
    token as *mut T
}

/// Why `token` is not a live `T` handle, for the message of `CCP_STATUS_INVALID_HANDLE`.
fn not_live<T: Handle>(token: usize, name: &str) -> FfiError {
    let serial = token >> TAG_BITS;
    let issued = serial > 0 && serial < NEXT.load(Ordering::Relaxed);
    let kind = TAGS
        .get(token & TAG_MASK)
        .copied()
        .filter(|k| !k.is_empty());
    let message = match kind {
        Some(k) if issued && k == T::NAME => {
            format!("{name} is a {k} handle that was freed (used after free, or freed twice)")
        }
        Some(k) if issued => format!("{name} is a {k} handle, not a {}", T::NAME),
        _ => format!("{name} is not a {} handle made by this library", T::NAME),
    };
    FfiError::new(CcpStatus::InvalidHandle, message)
}

/// The object of a live `T` handle (held alive while the caller keeps the `Arc`).
pub(crate) fn get<T: Handle>(h: *const T, name: &str) -> FfiResult<Arc<RwLock<T>>> {
    if h.is_null() {
        return Err(FfiError::new(
            CcpStatus::NullPointer,
            format!("{name} is a null handle"),
        ));
    }
    let token = h as usize;
    let object = registry().get(&token).cloned();
    object
        .filter(|_| token & TAG_MASK == T::TAG)
        .and_then(|o| o.downcast::<RwLock<T>>().ok())
        .ok_or_else(|| not_live::<T>(token, name))
}

fn poisoned<T: Handle>(name: &str) -> FfiError {
    FfiError::new(
        CcpStatus::Panic,
        format!(
            "{name}: an earlier call that changed this {} failed with an internal error, so \
             it is no longer used; free it",
            T::NAME
        ),
    )
}

/// Shared access for a call that only reads the object.
pub(crate) fn read<'a, T: Handle>(
    object: &'a RwLock<T>,
    name: &str,
) -> FfiResult<RwLockReadGuard<'a, T>> {
    object.read().map_err(|_| poisoned::<T>(name))
}

/// Exclusive access for a call that changes the object.
pub(crate) fn write<'a, T: Handle>(
    object: &'a RwLock<T>,
    name: &str,
) -> FfiResult<RwLockWriteGuard<'a, T>> {
    object.write().map_err(|_| poisoned::<T>(name))
}

/// Frees a handle: NULL is ignored; a handle that is not a live `T` is refused (nothing
/// is freed) with `CCP_STATUS_INVALID_HANDLE`.
pub(crate) fn free<T: Handle>(h: *mut T, name: &str) -> CcpStatus {
    super::guard_keeping_error(|| {
        if h.is_null() {
            return Ok(());
        }
        let token = h as usize;
        let removed = {
            let mut live = registry();
            if token & TAG_MASK == T::TAG {
                live.remove(&token)
            } else {
                None
            }
        };
        // Dropped outside the registry's lock (a LiDAR source takes a while); a call in
        // flight on another thread keeps the object until it returns.
        match removed {
            Some(object) => {
                drop(object);
                Ok(())
            }
            None => Err(not_live::<T>(token, name)),
        }
    })
}

/// Hands a string to the caller (to be released with `ccp_string_free`).
pub(crate) fn hand_out_string(s: CString) -> *mut c_char {
    let p = s.into_raw();
    strings().insert(p as usize);
    p
}

/// Releases a string from [`hand_out_string`]; anything else is refused.
pub(crate) fn free_string(p: *mut c_char) -> CcpStatus {
    super::guard_keeping_error(|| {
        if p.is_null() {
            return Ok(());
        }
        if !strings().remove(&(p as usize)) {
            return Err(FfiError::new(
                CcpStatus::InvalidHandle,
                "s is not a string returned by this library, or was freed already",
            ));
        }
        // SAFETY: `p` came from `CString::into_raw` in `hand_out_string` and was live.
        drop(unsafe { CString::from_raw(p) });
        Ok(())
    })
}
