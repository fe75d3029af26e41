//! Control from existing geodata: the reference epoch oriented against LiDAR, cloud
//! control points exported as Digital Control Photo (DCP) packages, and archive epochs
//! oriented from them.
//!
//! - [`epoch`]: an epoch as specified and as held, the one builder, the origin rule,
//!   approximate orientations, the one error type;
//! - [`reference`]: the reference epoch against the LiDAR; [`existing`]: an existing
//!   oriented block taken as an epoch;
//! - [`cloud`], [`export`]: cloud control points of an oriented block and their package;
//!   [`ortho_source`]: control points of an orthophoto with a DEM, as a package;
//! - [`dcp`]: the package format, its store and index;
//! - [`chips`], [`predict`], [`orient`], [`photo`]: one photo from control patches;
//!   [`scan_cameras`]: a film epoch's fiducial interior orientations, measured once;
//! - [`archive`]: an archive epoch, its global passes' per-photo work as [`rounds`];
//!   [`checkpoints`]: the checkpoint evaluation;
//! - [`strips`]: approximate orientation from strip end points.

pub mod archive;
pub mod checkpoints;
pub mod chips;
pub mod cloud;
pub mod dcp;
pub mod dcp_files;
pub mod epoch;
pub mod epoch_ties;
pub mod existing;
pub mod export;
pub mod orient;
pub mod ortho_source;
pub mod photo;
pub mod plan_index;
pub mod predict;
pub mod reference;
pub mod rounds;
pub mod scan_cameras;
pub mod strips;
pub mod task_checks;

pub use dcp::{DcpError, DcpIndex, DcpPackage, Manifest};
pub use epoch::{EpochError, EpochInput, EpochSpec};
