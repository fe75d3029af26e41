//! Control from previously oriented photos: Digital Control Photo (DCP) packages, their
//! spatial index, and approximate orientation of archive photos (strip interpolation when
//! no POS exists).

pub mod archive;
pub mod cloud;
pub mod dcp;
pub mod orient;
pub mod predict;
pub mod reference;
pub mod strips;

pub use dcp::{DcpError, DcpIndex, DcpPackage, Manifest};
