//! One raster lattice for a whole project, so that any two of its rasters (orthophotos,
//! DSMs, dh maps, the LiDAR's surfaces, of any epoch) subtract cell by cell without
//! resampling: every cell size is the base cell times a power of two, and every raster's
//! upper-left corner is the project's corner.
//!
//! Powers of two, not a 1-2-5 series: 0.2 m and 0.5 m cells do not nest (2.5 cells), 0.25
//! and 0.5 do; and with a base of 1 m every cell (…, 0.125, 0.25, 0.5, 1, 2, …) is exact
//! in binary floating point, so corners computed in different processes agree to the bit.

use super::{GeoTransform, GeometryError, Result};
use serde::{Deserialize, Serialize};

/// The corner is snapped to multiples of this many base cells: every raster whose cell
/// is at most this (32 m at the default base) starts exactly at the corner.
pub const CORNER_CELLS: f64 = 32.0;

/// The cell of a lattice of `base_m` nearest `pixel_m` in ratio: base × 2ⁿ,
/// n = round(log₂(pixel/base)); the base for a pixel that is not a length.
pub fn lattice_cell(base_m: f64, pixel_m: f64) -> f64 {
    if !(pixel_m.is_finite() && pixel_m > 0.0) {
        return base_m;
    }
    base_m * (pixel_m / base_m).log2().round().exp2()
}

/// The finest cell of a lattice of `base_m` not finer than `pixel_m`: base × 2ⁿ,
/// n = ⌈log₂(pixel/base)⌉. A surface made of one point per matched pixel leaves cells
/// empty on a finer grid (0.125 m cells under 0.15 m pixels: 17 % of a tiny block's
/// stereo area), so a DSM takes this one; an orthophoto, resampled from its photos,
/// takes the nearest ([`lattice_cell`]).
pub fn lattice_cell_at_least(base_m: f64, pixel_m: f64) -> f64 {
    if !(pixel_m.is_finite() && pixel_m > 0.0) {
        return base_m;
    }
    // A pixel a rounding error above a lattice cell is that cell.
    base_m * ((pixel_m / base_m).log2() - 1e-9).ceil().exp2()
}

/// A raster's place on the lattice: upper-left corner, cell and size.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LatticeGrid {
    pub x_min: f64,
    pub y_max: f64,
    pub cell: f64,
    pub width: usize,
    pub height: usize,
}

impl LatticeGrid {
    pub fn transform(&self) -> GeoTransform {
        GeoTransform::north_up(self.x_min, self.y_max, self.cell)
    }

    /// Index of the cell holding world (x, y), if inside.
    #[inline]
    pub fn cell_of(&self, x: f64, y: f64) -> Option<u32> {
        let c = ((x - self.x_min) / self.cell).floor();
        let r = ((self.y_max - y) / self.cell).floor();
        (c >= 0.0 && r >= 0.0 && (c as usize) < self.width && (r as usize) < self.height)
            .then(|| (r as usize * self.width + c as usize) as u32)
    }

    /// A world point as a sample of the grid (its cell's index, its height); `None`
    /// outside the grid or when a coordinate is not finite.
    pub fn sample(&self, x: f64, y: f64, z: f64) -> Option<(u32, f32)> {
        if !z.is_finite() {
            return None;
        }
        self.cell_of(x, y).map(|c| (c, z as f32))
    }

    /// Cells of the grid.
    pub fn cells(&self) -> usize {
        self.width * self.height
    }
}

/// The project's lattice: a base cell and the common upper-left corner (world).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Lattice {
    pub base_m: f64,
    pub corner: [f64; 2],
}

impl Lattice {
    /// The lattice of `base_m` whose corner is the upper-left of `extent` (world
    /// `[x_min, y_min, x_max, y_max]`, usually the control surface's) snapped outward to a
    /// multiple of [`CORNER_CELLS`] base cells.
    pub fn around(base_m: f64, extent: [f64; 4]) -> Result<Self> {
        if !(base_m.is_finite() && base_m > 0.0) {
            return Err(GeometryError::InvalidArgument(format!(
                "base cell {base_m} m is not a cell size"
            )));
        }
        if !extent.iter().all(|v| v.is_finite()) {
            return Err(GeometryError::NotFinite {
                what: "lattice extent".into(),
            });
        }
        let step = base_m * CORNER_CELLS;
        Ok(Self {
            base_m,
            corner: [
                (extent[0] / step).floor() * step,
                (extent[3] / step).ceil() * step,
            ],
        })
    }

    /// The lattice cell nearest `pixel_m` in ratio ([`lattice_cell`]).
    pub fn cell_for(&self, pixel_m: f64) -> f64 {
        lattice_cell(self.base_m, pixel_m)
    }

    /// The grid of `cell` (a lattice cell) covering `area` (world `[x_min, y_min, x_max,
    /// y_max]`) from the corner. An area reaching beyond the corner (left or above) moves
    /// the grid's corner out by whole cells of the coarsest nesting size, so it stays on
    /// the lattice; cells coarser than [`CORNER_CELLS`] base cells start on a multiple of
    /// themselves.
    pub fn grid(&self, cell: f64, area: [f64; 4]) -> Result<LatticeGrid> {
        if !(cell.is_finite() && cell > 0.0) {
            return Err(GeometryError::InvalidArgument(format!(
                "cell {cell} m is not a cell size"
            )));
        }
        let [x0, y0, x1, y1] = area;
        if !(area.iter().all(|v| v.is_finite()) && x1 > x0 && y1 > y0) {
            return Err(GeometryError::InvalidArgument(format!(
                "{area:?} is not an area"
            )));
        }
        let step = cell.max(self.base_m * CORNER_CELLS);
        let snap_out = |corner: f64, reach: f64, down: bool| {
            let beyond = if down { corner - reach } else { reach - corner };
            let steps = (beyond / step).ceil().max(0.0);
            let c = if down {
                corner - steps * step
            } else {
                corner + steps * step
            };
            if cell > self.base_m * CORNER_CELLS {
                if down {
                    (c / cell).floor() * cell
                } else {
                    (c / cell).ceil() * cell
                }
            } else {
                c
            }
        };
        let x_min = snap_out(self.corner[0], x0, true);
        let y_max = snap_out(self.corner[1], y1, false);
        let width = ((x1 - x_min) / cell).ceil().max(1.0);
        let height = ((y_max - y0) / cell).ceil().max(1.0);
        if width * height >= u32::MAX as f64 {
            return Err(GeometryError::InvalidArgument(format!(
                "{width}×{height} cells of {cell} m: more than 2³² cells"
            )));
        }
        Ok(LatticeGrid {
            x_min,
            y_max,
            cell,
            width: width as usize,
            height: height as usize,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_are_powers_of_two_of_the_base() {
        let l = Lattice::around(1.0, [499_849.9, 4_399_889.9, 500_150.0, 4_400_110.1]).unwrap();
        assert_eq!(l.corner, [499_840.0, 4_400_128.0]);
        assert_eq!(l.cell_for(0.104), 0.125);
        assert_eq!(l.cell_for(0.21), 0.25);
        assert_eq!(l.cell_for(0.633), 0.5);
        assert_eq!(l.cell_for(1.0), 1.0);
        assert_eq!(l.cell_for(2.5), 2.0);
        assert_eq!(l.cell_for(2.9), 4.0);
        assert_eq!(lattice_cell_at_least(1.0, 0.104), 0.125);
        assert_eq!(lattice_cell_at_least(1.0, 0.15), 0.25);
        assert_eq!(lattice_cell_at_least(1.0, 0.25), 0.25);
        assert_eq!(lattice_cell_at_least(1.0, 0.633), 1.0);
    }

    #[test]
    fn every_grid_starts_at_the_corner_and_nests() {
        let l = Lattice::around(1.0, [100.5, 200.5, 400.0, 500.0]).unwrap();
        let a = l.grid(0.125, [130.0, 250.0, 300.0, 480.0]).unwrap();
        let b = l.grid(0.5, [101.0, 201.0, 399.0, 499.0]).unwrap();
        assert_eq!((a.x_min, a.y_max), (b.x_min, b.y_max));
        assert_eq!((a.x_min, a.y_max), (96.0, 512.0));
        assert!(a.x_min + a.width as f64 * a.cell >= 300.0);
        assert!(a.y_max - a.height as f64 * a.cell <= 250.0);
        // An area beyond the corner moves it out by whole 32 m steps.
        let c = l.grid(0.25, [50.0, 250.0, 300.0, 540.0]).unwrap();
        assert_eq!((c.x_min, c.y_max), (32.0, 544.0));
        assert!(l.grid(0.25, [1.0, 1.0, 1.0, 2.0]).is_err());
    }
}
