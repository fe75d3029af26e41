//! LiDAR as ground control (seed 000 §2.2 (1)–(3)): LAS/LAZ ingestion and the source
//! catalogue with a bounded tile store, cleaning (noise filter, strip offsets), evaluation
//! against surveyed checkpoints, DEM gridding, the spatial index with local plane fits and
//! coplanarity weights, and point-to-plane ICP with a 7-parameter similarity.
//!
//! All numerics run in a local frame (block origin subtracted) in f64 so that projected
//! coordinates of several 10⁶ m keep sub-millimetre resolution.

pub mod catalogue;
pub mod clean;
pub mod dem;
pub mod eval;
pub mod grid_index;
pub mod icp;
pub mod las;
mod las_guard;
pub mod las_write;
pub mod planes;
pub mod points_io;
pub mod store;
pub mod surfaces;

pub use catalogue::{Catalogue, CrsSource, ScanOptions, TileEntry};
pub use clean::{
    apply_strip_offsets, clean_tiles, estimate_strip_offsets, statistical_outlier_filter,
    CleanOptions, CleanReport, OutlierOptions, OutlierReport, StripOffsetOptions,
    StripOffsetReport,
};
pub use dem::{grid_dem, DemMethod, DemOptions};
pub use eval::{evaluate_checkpoints, CheckpointOptions, CheckpointReport};
pub use icp::{icp_point_to_plane, IcpIteration, IcpModel, IcpOptions, IcpResult};
pub use las::{LasInfo, LasStream, PointBatch};
pub use las_guard::MAX_LAZ_CHUNK_BYTES;
pub use planes::{LocalPlane, PlaneIndex, PlaneOptions};
pub use store::{Bbox, TileStore};
pub use surfaces::{lidar_surfaces, GroundSurface, LIDAR_CELL_M};

use std::path::PathBuf;

/// Errors of the LiDAR module; each names the input and what was wrong.
#[derive(Debug, thiserror::Error)]
pub enum LidarError {
    #[error("{what}: too few points ({got}, need at least {need})")]
    TooFewPoints {
        what: String,
        got: usize,
        need: usize,
    },
    #[error("{what}: non-finite coordinate at point {index}")]
    NonFinite { what: String, index: usize },
    #[error("invalid option: {0}")]
    InvalidOption(String),
    #[error("ICP did not find enough planar correspondences ({got}, need {need}) at iteration {iteration}")]
    TooFewCorrespondences {
        got: usize,
        need: usize,
        iteration: usize,
    },
    #[error("ICP normal equations are singular at iteration {iteration} (surface lacks relief to fix all parameters)")]
    Singular { iteration: usize },
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// The file is not readable LAS/LAZ (bad signature, header, VLRs or compressed data).
    #[error("{path}: {message}")]
    Las { path: PathBuf, message: String },
    #[error("{path}: truncated: the header declares {declared} points but the file holds only {found} complete point records")]
    Truncated {
        path: PathBuf,
        declared: u64,
        found: u64,
    },
    #[error("{path}: point count mismatch: the header declares {declared} points but the file holds {found}")]
    CountMismatch {
        path: PathBuf,
        declared: u64,
        found: u64,
    },
    /// A count or length in the file claims more than the file (or a documented limit)
    /// can hold: refused before anything is sized from it.
    #[error("{path}: {what} {claimed} exceeds {limit}, {basis} (corrupt or crafted file)")]
    TooLarge {
        path: PathBuf,
        what: String,
        claimed: u64,
        limit: u64,
        basis: String,
    },
    #[error("{path}: no coordinate reference system (no WKT or GeoTIFF keys VLR, or an empty one); pass the CRS explicitly (e.g. --crs EPSG:32650)")]
    MissingCrs { path: PathBuf },
    #[error("{path}: coordinate reference system: {message}")]
    Crs { path: PathBuf, message: String },
    #[error("{path}: coordinate reference system {found} differs from {expected} of {reference}; reproject the tiles to one CRS first")]
    CrsMismatch {
        path: PathBuf,
        found: String,
        expected: String,
        reference: PathBuf,
    },
    #[error("{what}: {message}")]
    Data { what: String, message: String },
    #[error(transparent)]
    Format(#[from] crate::formats::FormatError),
}

impl LidarError {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        LidarError::Io {
            path: path.into(),
            source,
        }
    }
    pub(crate) fn data(what: impl Into<String>, message: impl Into<String>) -> Self {
        LidarError::Data {
            what: what.into(),
            message: message.into(),
        }
    }
}

pub type Result<T> = std::result::Result<T, LidarError>;
