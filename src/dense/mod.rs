//! Dense image matching of oriented photo pairs: epipolar rectification, hierarchical
//! semi-global matching (census cost, eight paths, per-pixel disparity bands narrowed
//! coarse to fine) and the mapping of disparities back to object points.
//!
//! A pair is rectified onto two virtual pinhole cameras that share their rotation, focal
//! length and principal-point row ([`RectifiedPair`]); rectified rows are rendered from the
//! source photos window by window ([`RectifiedPair::render_rows`]) so a film pair never
//! holds both rectified images whole. [`match_images`] matches one rectified window within
//! a per-pixel band of disparities from a prior ([`DisparityPrior`]); [`match_pair`] runs it
//! tile by tile over a whole pair. A disparity `d` of left pixel position `u` means the
//! same object point lies at `u − d` in the right rectified image (OpenCV's convention);
//! [`RectifiedPair::triangulate`] turns it into an object point.
//!
//! Conventions as everywhere (design overview §2): `X_cam = R (X − C)`, camera x right,
//! y down, z forward; pixel positions with the origin at the top-left corner of the
//! top-left pixel, so pixel (col, row) has its centre at (col + 0.5, row + 0.5).

mod aggregate;
mod census;
pub mod epoch;
mod filter;
pub mod fusion;
mod pair;
pub mod pairs;
pub mod products;
mod rectify;
mod refine;
mod sgm;
pub mod simd;
mod volume;

pub use census::census_transform;
pub use filter::{median3, remove_occluded, remove_speckles, texture_mask, trim_depth_edges};
pub use pair::{match_pair, PairTile, Tiling};
pub use rectify::{BandGrid, RectifiedImage, RectifiedPair, RectifiedView, Side};
pub use sgm::{
    cpu_seconds, match_images, DisparityMap, DisparityPrior, LevelStats, MatchStats, PixelStatus,
    SgmOptions, Subpixel,
};

/// Errors of dense matching; each names the input and what was wrong.
#[derive(Debug, thiserror::Error)]
pub enum DenseError {
    #[error("{what}: {message}")]
    InvalidInput { what: String, message: String },
    #[error("rectification: {0}")]
    Rectification(String),
    /// Nothing to make a surface of: fewer than two oriented photos, no stereo pair, or
    /// no pair matched a pixel.
    #[error("no surface: {0}")]
    NoSurface(String),
    #[error(transparent)]
    Geometry(#[from] crate::geometry::GeometryError),
    #[error(transparent)]
    Format(#[from] crate::formats::FormatError),
}

pub type Result<T> = std::result::Result<T, DenseError>;

pub(crate) fn invalid(what: &str, message: impl Into<String>) -> DenseError {
    DenseError::InvalidInput {
        what: what.to_string(),
        message: message.into(),
    }
}
