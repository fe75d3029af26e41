//! C ABI of the synthetic block generator.

use super::{guard, CcpStatus, FfiError};
use crate::synth::{self, PosQuality, Preset, SynthConfig, SynthError};
use std::ffi::{c_char, CStr};

impl From<SynthError> for FfiError {
    fn from(e: SynthError) -> Self {
        match e {
            SynthError::Format(f) => FfiError::from(f),
            SynthError::Geometry(g) => FfiError::from(g),
            SynthError::InvalidConfig(_) => FfiError::invalid(e.to_string()),
            _ => FfiError::new(CcpStatus::Format, e.to_string()),
        }
    }
}

/// Writes a synthetic block with ground truth into `out_dir` (UTF-8 path).
/// `preset`: 0 tiny, 1 small, 2 medium, 3 large; `pos`: 0 good, 1 rough, 2 none;
/// `change` in [0, 1]; `laz` non-zero writes LAZ tiles. Same arguments give
/// byte-identical files. Layout: formats/synth/README.md.
///
/// # Safety
/// `out_dir` must be null or a NUL-terminated string valid for the duration of the call.
#[no_mangle]
pub unsafe extern "C" fn ccp_synth_generate(
    out_dir: *const c_char,
    preset: u32,
    seed: u64,
    change: f64,
    pos: u32,
    laz: u32,
) -> CcpStatus {
    guard(|| {
        if out_dir.is_null() {
            return Err(FfiError::new(CcpStatus::NullPointer, "out_dir is null"));
        }
        // SAFETY: non-null and NUL-terminated per the contract above.
        let dir = unsafe { CStr::from_ptr(out_dir) }
            .to_str()
            .map_err(|_| FfiError::invalid("out_dir is not valid UTF-8"))?;
        if !change.is_finite() {
            return Err(FfiError::new(
                CcpStatus::NotFinite,
                format!("change is not finite ({change})"),
            ));
        }
        let preset = match preset {
            0 => Preset::Tiny,
            1 => Preset::Small,
            2 => Preset::Medium,
            3 => Preset::Large,
            p => return Err(FfiError::invalid(format!("preset must be 0..=3, got {p}"))),
        };
        let pos = match pos {
            0 => PosQuality::Good,
            1 => PosQuality::Rough,
            2 => PosQuality::None,
            p => return Err(FfiError::invalid(format!("pos must be 0..=2, got {p}"))),
        };
        let config = SynthConfig {
            preset,
            seed,
            change,
            pos,
            laz: laz != 0,
        };
        synth::generate(&config, std::path::Path::new(dir))?;
        Ok(())
    })
}
