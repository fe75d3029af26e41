//! Runtime dispatch of the hot loops: the same plain Rust kernels (slices the compiler
//! vectorises) compiled once for the baseline target and once with AVX2 (16 i16 lanes,
//! popcnt), chosen per row by CPU detection as the NCC kernels are.

use super::aggregate::{sweep_row_generic, SweepInput, SweepState};
use super::census::{census_row_generic, support_row_generic};
use super::sgm::{wta_row_generic, PixelStatus, WtaRow};
use super::volume::costs_row_generic;
use crate::matching::GreyImage;

/// Whether the AVX2 instantiation runs on this CPU.
pub fn avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("popcnt")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Declares `pub(crate) fn $name` that runs `$generic` compiled with AVX2 and popcnt when
/// the CPU has them, else as compiled for the baseline target. One declaration per kernel
/// keeps each signature written once.
macro_rules! dispatch {
    ($name:ident $(<const $g:ident: $gt:ty>)? ($($arg:ident: $ty:ty),* $(,)?) => $generic:ident) => {
        pub(crate) fn $name$(<const $g: $gt>)?($($arg: $ty),*) {
            #[cfg(target_arch = "x86_64")]
            if avx2() {
                #[target_feature(enable = "avx2,popcnt")]
                unsafe fn with_avx2$(<const $g: $gt>)?($($arg: $ty),*) {
                    $generic$(::<$g>)?($($arg),*)
                }
                // SAFETY: the CPU supports AVX2 and popcnt (checked above).
                unsafe { with_avx2$(::<$g>)?($($arg),*) };
                return;
            }
            $generic$(::<$g>)?($($arg),*)
        }
    };
}

dispatch!(sweep_row<const INIT: bool>(
    input: &SweepInput<'_>,
    st: &mut SweepState,
    y: usize,
    forward: bool,
    first_row: bool,
    sum: &mut [i16],
) => sweep_row_generic);

dispatch!(costs_row(
    left: (&[u64], &[u64], &[u16]),
    cr: &[u64],
    penalty: &[u8],
    dmin: &[i32],
    offset: &[u32],
    row0: usize,
    out: &mut [u8],
) => costs_row_generic);

dispatch!(wta_row(
    r: &WtaRow<'_>,
    disp: &mut [f32],
    stat: &mut [PixelStatus],
    wc: &mut [u8],
) => wta_row_generic);

dispatch!(census_row(
    img: &GreyImage,
    y: usize,
    cw: usize,
    ch: usize,
    stride: usize,
    bits: &mut [u64],
) => census_row_generic);

dispatch!(support_row(
    img: &GreyImage,
    y: usize,
    window: [usize; 3],
    tau: f32,
    bits: &mut [u64],
) => support_row_generic);
