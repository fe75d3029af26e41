//! Statistics of a DEM of difference on stable terrain, as the DEM-comparison literature
//! reports them (Höhle & Höhle 2009; xdem): median and NMAD (robust bias and spread),
//! mean and standard deviation, the 68 % and 95 % intervals of dh and of |dh| (LE68,
//! LE95), and the median and NMAD by slope class.

use super::terrain::Terrain;
use super::{median, nmad, quantile};
use serde::{Deserialize, Serialize};

/// Slope classes (degrees) the statistics are split by.
pub const SLOPE_CLASSES: [[f64; 2]; 4] = [[0.0, 5.0], [5.0, 15.0], [15.0, 30.0], [30.0, 90.0]];

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SlopeClass {
    pub slope_deg: [f64; 2],
    pub cells: usize,
    pub median_m: Option<f64>,
    pub nmad_m: Option<f64>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct DhStatistics {
    pub cells: usize,
    pub median_m: f64,
    pub nmad_m: f64,
    pub mean_m: f64,
    /// Population standard deviation (numpy's default).
    pub std_m: f64,
    /// Quantiles 2.5, 16, 84 and 97.5 % of dh.
    pub quantiles_m: [f64; 4],
    /// 68th and 95th percentiles of |dh|.
    pub le68_m: f64,
    pub le95_m: f64,
    pub by_slope: Vec<SlopeClass>,
}

/// The statistics of `dh` on the cells of `mask`, split by the slope of `terrain`.
pub fn dh_statistics(dh: &[f64], mask: &[bool], terrain: &Terrain) -> DhStatistics {
    let values: Vec<f64> = dh
        .iter()
        .zip(mask)
        .filter_map(|(v, &m)| (m && v.is_finite()).then_some(*v))
        .collect();
    let n = values.len();
    let mean = values.iter().sum::<f64>() / n.max(1) as f64;
    let std = (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n.max(1) as f64).sqrt();
    let mut sorted = values.clone();
    let q = |s: &mut Vec<f64>, p: f64| quantile(s, p);
    let quantiles_m = [
        q(&mut sorted, 0.025),
        q(&mut sorted, 0.16),
        q(&mut sorted, 0.84),
        q(&mut sorted, 0.975),
    ];
    let mut abs: Vec<f64> = values.iter().map(|v| v.abs()).collect();
    let by_slope = SLOPE_CLASSES
        .iter()
        .map(|&[lo, hi]| {
            let class: Vec<f64> = dh
                .iter()
                .enumerate()
                .filter(|&(i, v)| {
                    let s = terrain.slope_deg(i);
                    mask[i] && v.is_finite() && s >= lo && s < hi
                })
                .map(|(_, v)| *v)
                .collect();
            SlopeClass {
                slope_deg: [lo, hi],
                cells: class.len(),
                median_m: (!class.is_empty()).then(|| median(&mut class.clone())),
                nmad_m: (!class.is_empty()).then(|| nmad(&class)),
            }
        })
        .collect();
    DhStatistics {
        cells: n,
        median_m: median(&mut sorted),
        nmad_m: nmad(&values),
        mean_m: if n > 0 { mean } else { f64::NAN },
        std_m: if n > 0 { std } else { f64::NAN },
        quantiles_m,
        le68_m: quantile(&mut abs, 0.68),
        le95_m: quantile(&mut abs, 0.95),
        by_slope,
    }
}
