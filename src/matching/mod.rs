//! Image matching (seeds 001 and 003): image pyramids and patch resampling, the Förstner
//! interest operator, normalised cross-correlation over the pyramid, least-squares
//! matching, fiducial interior orientation of film scans and tie-point acquisition.
//!
//! Pixel coordinates follow the project convention: x = column, y = row, origin at the
//! top-left corner of the top-left pixel, so that pixel (i, j) has its centre at
//! (i + 0.5, j + 0.5). With that convention a factor-2 pyramid level maps coordinates by
//! an exact halving, which keeps coarse-to-fine search free of half-pixel offsets.

pub mod fiducial;
pub mod forstner;
pub mod image;
pub mod lsm;
pub mod matcher;
pub mod ncc;
pub mod oriented;
pub mod pair_matching;
pub mod pyramid;
pub mod resample;
pub mod scan_windows;
pub mod smooth;
pub mod ties;

pub use fiducial::{
    interior_orientation, interior_orientation_epoch, interior_orientation_file,
    majority_orientation, CameraDefinition, FiducialDef, FiducialShape, IoOptions, IoResult,
    MarkResult, ScanOrientation,
};
pub use forstner::{forstner, ForstnerOptions, InterestPoint};
pub use image::{GreyImage, Pixels};
pub use lsm::{lsm, LsmOptions, LsmResult};
pub use matcher::{match_template, MatchOptions, MatchResult};
pub use ncc::{ncc_search, ncc_search_pyramid, NccPeak, Window};
pub use oriented::{
    block_tie_points, oriented_tie_points, write_ties, BlockTieOptions, BlockTieReport,
    OrientedPhoto, Surface, TiePhotos,
};
pub use pair_matching::{
    match_photo_pairs, plan_pairs, InMemory, MatchedPairs, PairMatching, PhotoPairs, PreparedPhotos,
};
pub use pyramid::{Levels, Pyramid, PyramidOver};
pub use resample::{warp_patch, Interpolation, PatchWarp};
pub use ties::{
    coverage, link_tracks, match_pair, predict_shift, relative_orientation, tie_points, Coverage,
    FundamentalEstimator, PairMatches, PairPrediction, RobustMethod, TieCandidate, TieOptions,
    TieResult, Track,
};

use std::path::PathBuf;

/// Errors of the matching module; each names the input and what was wrong.
#[derive(Debug, thiserror::Error)]
pub enum MatchingError {
    #[error("{path}: cannot read image: {message}")]
    Read { path: PathBuf, message: String },
    #[error("{what}: {message}")]
    InvalidInput { what: String, message: String },
    #[error("{what}: image of {width}×{height} px is smaller than the template of {tw}×{th} px")]
    TooSmall {
        what: String,
        width: usize,
        height: usize,
        tw: usize,
        th: usize,
    },
    #[error("{what}: no texture (constant grey value), nothing to correlate")]
    Textureless { what: String },
    #[error("{0}")]
    Camera(String),
    #[error("interior orientation of {scan}: {message}")]
    Orientation { scan: String, message: String },
    #[error(
        "interior orientation of {scan}: scan orientation undecided: {best} fits the marks only \
         {margin:.2}× better than {second} ({required}× needed; {detail}); give the orientation \
         (cloudcontrol io --orientation, or the epoch's majority), or describe a distinct mark \
         or the data strip in the camera definition"
    )]
    OrientationUndecided {
        scan: String,
        best: fiducial::ScanOrientation,
        second: fiducial::ScanOrientation,
        margin: f64,
        required: f64,
        detail: String,
    },
    #[error("relative orientation {a}–{b}: {message}")]
    Relative {
        a: String,
        b: String,
        message: String,
    },
    #[error(transparent)]
    Geometry(#[from] crate::geometry::GeometryError),
}

pub type Result<T> = std::result::Result<T, MatchingError>;

pub(crate) fn invalid(what: impl Into<String>, message: impl Into<String>) -> MatchingError {
    MatchingError::InvalidInput {
        what: what.into(),
        message: message.into(),
    }
}

/// Refuses an area (image or search window, named by `what`) that cannot hold the
/// template.
pub(crate) fn holds_template(
    what: &str,
    width: usize,
    height: usize,
    tpl: &GreyImage,
) -> Result<()> {
    if width < tpl.width || height < tpl.height {
        return Err(MatchingError::TooSmall {
            what: what.into(),
            width,
            height,
            tw: tpl.width,
            th: tpl.height,
        });
    }
    Ok(())
}
