//! A DEM of difference as a picture for the report: dh in a diverging colour over the
//! hillshade of the reference surface, so a reader sees both where the surface changed and
//! what stands there (the roof outlines, the valley) without a GIS.

use super::terrain::Terrain;
use super::{ChangeError, Result};
use crate::geometry::Dem;

/// Sun of the hillshade: azimuth 315° (north-west), 45° above the horizon, as GDAL's
/// `gdaldem hillshade` defaults.
const SUN_AZIMUTH: f64 = 315.0;
const SUN_ALTITUDE: f64 = 45.0;

/// The symmetric colour range (m) of a dh map: the 99th percentile of |dh − median| over
/// the cells with a value, rounded up on the 1-2-5 series and at least 1 m; the same
/// number in `change.json` (`map_range_m`) and under the picture.
pub fn map_range(dh: &[f64], median: f64) -> f64 {
    let mut dev: Vec<f64> = dh
        .iter()
        .filter(|v| v.is_finite())
        .map(|v| (v - median).abs())
        .collect();
    let p99 = super::quantile(&mut dev, 0.99);
    if !(p99.is_finite() && p99 > 1.0) {
        return 1.0;
    }
    let decade = 10f64.powf(p99.log10().floor());
    [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * decade)
        .find(|v| *v >= p99)
        .unwrap_or(10.0 * decade)
}

/// Grey level (0–1) of each cell of the reference surface lit from the north-west; NaN
/// where its slope is not defined.
fn hillshade(terrain: &Terrain) -> Vec<f64> {
    let zenith = (90.0 - SUN_ALTITUDE).to_radians();
    let azimuth = SUN_AZIMUTH.to_radians();
    terrain
        .slope_tan
        .iter()
        .zip(&terrain.aspect)
        .map(|(&t, &up)| {
            let slope = t.atan();
            // The terrain's aspect is upslope; a face is lit when its downslope points
            // towards the sun, hence the minus.
            (zenith.cos() * slope.cos() - zenith.sin() * slope.sin() * (azimuth - up).cos())
                .clamp(0.0, 1.0)
        })
        .collect()
}

/// Colour of dh relative to `median`, `range` the deviation of full colour: red where the
/// compared surface lies lower than the reference, blue where higher, white at none.
fn diverging(v: f64, range: f64) -> [f64; 3] {
    let t = (v / range).clamp(-1.0, 1.0);
    if t < 0.0 {
        [1.0, 1.0 + 0.8 * t, 1.0 + 0.85 * t]
    } else {
        [1.0 - 0.85 * t, 1.0 - 0.6 * t, 1.0]
    }
}

/// PNG of dh (per cell of `grid`, NaN without data; `median` its stable terrain's) over the
/// hillshade of `grid`'s surface (`terrain`), at most `max_side` pixels a side (a cell
/// per pixel when the grid is smaller; otherwise each pixel the cell at its centre).
pub fn dh_map_png(
    grid: &Dem,
    terrain: &Terrain,
    dh: &[f64],
    (median, range): (f64, f64),
    max_side: usize,
) -> Result<Vec<u8>> {
    let (w, h) = (grid.width, grid.height);
    if dh.len() != w * h || terrain.slope_tan.len() != w * h || w == 0 || h == 0 {
        return Err(ChangeError::InvalidInput {
            what: "dh map".into(),
            message: format!("{} values for a grid of {w}×{h}", dh.len()),
        });
    }
    let shade = hillshade(terrain);
    let scale = (w.max(h) as f64 / max_side.max(1) as f64).max(1.0);
    let (pw, ph) = (
        ((w as f64 / scale).round() as u32).max(1),
        ((h as f64 / scale).round() as u32).max(1),
    );
    let mut img = image::RgbImage::new(pw, ph);
    for (px, py, out) in img.enumerate_pixels_mut() {
        let c = (((px as f64 + 0.5) * scale) as usize).min(w - 1);
        let r = (((py as f64 + 0.5) * scale) as usize).min(h - 1);
        let i = r * w + c;
        // Unlit or undefined ground in a mid grey, so that holes still show the relief
        // around them.
        let grey = if shade[i].is_finite() {
            0.35 + 0.65 * shade[i]
        } else {
            0.5
        };
        let rgb = if dh[i].is_finite() {
            diverging(dh[i] - median, range).map(|k| k * grey)
        } else {
            // No dh: the relief alone, dimmed.
            [0.6 * grey; 3]
        };
        *out = image::Rgb(rgb.map(|k| (k * 255.0).round().clamp(0.0, 255.0) as u8));
    }
    let mut png = Vec::new();
    image::DynamicImage::ImageRgb8(img)
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(|e| ChangeError::InvalidInput {
            what: "dh map".into(),
            message: e.to_string(),
        })?;
    Ok(png)
}
