//! LiDAR as ground control: spatial index with local plane fits and coplanarity weights,
//! and point-to-plane ICP with a 7-parameter similarity (seed 000 §2.2 (1)–(3)).
//!
//! All numerics run in a local frame (block origin subtracted) in f64 so that projected
//! coordinates of several 10⁶ m keep sub-millimetre resolution.

pub mod icp;
pub mod planes;

pub use icp::{icp_point_to_plane, IcpIteration, IcpModel, IcpOptions, IcpResult};
pub use planes::{LocalPlane, PlaneIndex, PlaneOptions};

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
}

pub type Result<T> = std::result::Result<T, LidarError>;
