//! Stable terrain: the cells a DEM of difference is judged on, where the surface did not
//! change between the two models. Each step is kept with the cells it left, so a report
//! can say why the mask is what it is:
//! 1. both models have a height (and the cell is not excluded by the caller: a LiDAR
//!    cell without ground returns, a known change);
//! 2. slope at most `max_slope_deg` on the reference (steep cells carry the largest
//!    errors for the smallest horizontal shift, and are rarely stable ground);
//! 3. |dh − median| ≤ `k_nmad` · NMAD, repeated until no cell leaves (what moved: a
//!    building built or torn down, a tree grown), at most `max_iterations` times.

use super::terrain::Terrain;
use super::{median, nmad};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct StableOptions {
    pub max_slope_deg: f64,
    pub k_nmad: f64,
    pub max_iterations: usize,
}

impl Default for StableOptions {
    fn default() -> Self {
        Self {
            max_slope_deg: 40.0,
            k_nmad: 3.0,
            max_iterations: 10,
        }
    }
}

/// One step of the mask and the cells it kept.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StableStep {
    pub step: String,
    pub cells: usize,
}

#[derive(Debug, Clone)]
pub struct StableTerrain {
    pub mask: Vec<bool>,
    pub steps: Vec<StableStep>,
}

impl StableTerrain {
    pub fn cells(&self) -> usize {
        self.mask.iter().filter(|&&m| m).count()
    }
}

/// The stable terrain of `dh` (per cell of the reference's grid, NaN without data) on the
/// reference's `terrain`; `exclude` marks cells the caller knows are not stable.
pub fn stable_terrain(
    dh: &[f64],
    terrain: &Terrain,
    exclude: Option<&[bool]>,
    options: &StableOptions,
) -> StableTerrain {
    let mut steps = Vec::new();
    let mut mask: Vec<bool> = dh
        .iter()
        .enumerate()
        .map(|(i, v)| v.is_finite() && !exclude.is_some_and(|e| e.get(i).copied().unwrap_or(true)))
        .collect();
    let count = |m: &[bool]| m.iter().filter(|&&x| x).count();
    steps.push(StableStep {
        step: "both models have a height, not excluded".into(),
        cells: count(&mask),
    });
    let tan_max = options.max_slope_deg.to_radians().tan();
    for (i, m) in mask.iter_mut().enumerate() {
        *m = *m && terrain.slope_tan[i] <= tan_max;
    }
    steps.push(StableStep {
        step: format!("slope ≤ {}°", options.max_slope_deg),
        cells: count(&mask),
    });
    for _ in 0..options.max_iterations {
        let values: Vec<f64> = dh
            .iter()
            .zip(&mask)
            .filter_map(|(v, &m)| m.then_some(*v))
            .collect();
        if values.len() < 2 {
            break;
        }
        let spread = nmad(&values);
        let centre = median(&mut values.clone());
        let mut left = 0;
        for (v, m) in dh.iter().zip(mask.iter_mut()) {
            if *m && (v - centre).abs() > options.k_nmad * spread {
                *m = false;
                left += 1;
            }
        }
        steps.push(StableStep {
            step: format!(
                "|dh − {centre:.3}| ≤ {} × NMAD {spread:.3} m",
                options.k_nmad
            ),
            cells: count(&mask),
        });
        if left == 0 {
            break;
        }
    }
    StableTerrain { mask, steps }
}
