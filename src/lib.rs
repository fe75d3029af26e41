//! cloudcontrol — cloud control photogrammetry.
//!
//! Orients archived aerial photographs without field surveys by taking control from
//! geodata that already exists: airborne LiDAR and previously oriented photos. See
//! `README.md` and the design overview for the architecture; data flows
//! formats/lidar → block → matching/adjust/control → pipeline → outputs, with [`ffi`] and
//! the CLI as thin skins.

pub mod adjust;
pub mod block;
pub mod cache;
pub mod change;
pub mod control;
pub mod dense;
pub mod estimators;
pub mod ffi;
pub mod formats;
pub mod geometry;
pub mod lidar;
pub mod matching;
pub mod pipeline;
pub mod synth;

/// Library version (the crate version).
pub const VERSION: &str = env!("CARGO_PKG_VERSION");
