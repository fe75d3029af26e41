//! Elevation change between two surface models, as glaciologists and geomorphologists
//! measure it (xdem, demcoreg, the historical-photo intercomparisons): the DEM of
//! difference `dh = B − A` on A's grid, the stable terrain it is judged on, the
//! Nuth & Kääb (2011) co-registration shift and tilt of B against A on that terrain
//! (reported as a check of the orientation, applied only when asked), and the
//! statistics of dh there (median, NMAD, quantiles, by slope class).
//!
//! The steps compose as xdem's: [`terrain`] (slope and aspect of A) → [`stable`] (the mask)
//! → [`nuth_kaab`] (the shift) → [`shift_tilt`] (shift and tilt together) → [`stats`] →
//! [`areas`] (what changed, as polygons); [`compare`] runs them on two rasters, [`render`] draws dh for the report.

pub mod areas;
pub mod compare;
pub mod nuth_kaab;
pub mod render;
pub mod shift_tilt;
pub mod stable;
pub mod stats;
pub mod terrain;

pub use areas::{areas_geojson, changed_areas, AreaOptions, ChangedArea};
pub use compare::{compare_dems, write_change, CellKnowledge, ChangeOptions, ChangeReport};
pub use nuth_kaab::{nuth_kaab, NuthKaab, NuthKaabOptions};
pub use shift_tilt::{shift_and_tilt, ShiftTilt};
pub use stable::{stable_terrain, StableOptions, StableTerrain};
pub use stats::{dh_statistics, DhStatistics, SlopeClass};
pub use terrain::{slope_aspect, Terrain};

/// Errors of a comparison; each names the input and what was wrong.
#[derive(Debug, thiserror::Error)]
pub enum ChangeError {
    #[error("{what}: {message}")]
    InvalidInput { what: String, message: String },
    /// Too little overlap or stable terrain to measure anything.
    #[error("too little data: {0}")]
    TooLittle(String),
    #[error(transparent)]
    Geometry(#[from] crate::geometry::GeometryError),
    #[error(transparent)]
    Format(#[from] crate::formats::FormatError),
}

pub type Result<T> = std::result::Result<T, ChangeError>;

pub(crate) fn invalid(what: &str, message: impl Into<String>) -> ChangeError {
    ChangeError::InvalidInput {
        what: what.to_string(),
        message: message.into(),
    }
}

/// Median of finite `values` (reordered in place); NaN when there is none.
pub(crate) fn median(values: &mut [f64]) -> f64 {
    quantile(values, 0.5)
}

/// The `q` quantile of `values` (reordered in place) by linear interpolation between order
/// statistics (numpy's default, so numbers agree with xdem's); NaN when empty. The two
/// order statistics are selected, not sorted for: a sort was half of a change stage's
/// time (perf, the demo's digital epoch: 14.4 s, 32 % in the sort).
pub(crate) fn quantile(values: &mut [f64], q: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let pos = q.clamp(0.0, 1.0) * (values.len() - 1) as f64;
    let (lo, hi) = (pos.floor() as usize, pos.ceil() as usize);
    let (_, &mut low, above) = values.select_nth_unstable_by(lo, f64::total_cmp);
    let high = if hi > lo {
        above.iter().copied().min_by(f64::total_cmp).unwrap_or(low)
    } else {
        low
    };
    low + (high - low) * (pos - lo as f64)
}

/// 1.4826 × the median absolute deviation from the median (xdem's `nmad`).
pub(crate) fn nmad(values: &[f64]) -> f64 {
    let mut v = values.to_vec();
    let m = median(&mut v);
    let mut dev: Vec<f64> = values.iter().map(|x| (x - m).abs()).collect();
    1.4826 * median(&mut dev)
}
