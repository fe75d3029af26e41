//! Slope and aspect of a surface model, from central differences (one-sided at the grid's
//! edge, NaN next to a hole), as numpy's `gradient` gives them and xdem's Nuth & Kääb
//! derives them: the fit then sees the same slopes as its users' tools.

use crate::geometry::Dem;

/// Per cell: tangent of the slope (rise over run, m/m) and aspect (radians, azimuth of the
/// upslope direction clockwise from north, in [0, 2π)); NaN where not defined.
#[derive(Debug, Clone)]
pub struct Terrain {
    pub slope_tan: Vec<f64>,
    pub aspect: Vec<f64>,
}

impl Terrain {
    /// Slope of cell `i` in degrees.
    pub fn slope_deg(&self, i: usize) -> f64 {
        self.slope_tan[i].atan().to_degrees()
    }
}

/// [`Terrain`] of `dem` (a north-up grid in metres).
pub fn slope_aspect(dem: &Dem) -> Terrain {
    let (w, h) = (dem.width, dem.height);
    let cell_x = dem.transform.0[1];
    let cell_y = -dem.transform.0[5];
    let z = |c: usize, r: usize| f64::from(dem.data[r * w + c]);
    // numpy.gradient along one axis: central inside, one-sided at the ends.
    let diff = |a: f64, b: f64, span: f64| (b - a) / span;
    let mut slope_tan = vec![f64::NAN; w * h];
    let mut aspect = vec![f64::NAN; w * h];
    if w < 2 || h < 2 {
        return Terrain { slope_tan, aspect };
    }
    for r in 0..h {
        for c in 0..w {
            let gx = match c {
                0 => diff(z(0, r), z(1, r), 1.0),
                _ if c == w - 1 => diff(z(c - 1, r), z(c, r), 1.0),
                _ => diff(z(c - 1, r), z(c + 1, r), 2.0),
            } / cell_x;
            // Rows run south: dz/dnorth is minus the row derivative.
            let gy = -match r {
                0 => diff(z(c, 0), z(c, 1), 1.0),
                _ if r == h - 1 => diff(z(c, r - 1), z(c, r), 1.0),
                _ => diff(z(c, r - 1), z(c, r + 1), 2.0),
            } / cell_y;
            let i = r * w + c;
            if gx.is_finite() && gy.is_finite() {
                slope_tan[i] = gx.hypot(gy);
                aspect[i] = gx.atan2(gy).rem_euclid(std::f64::consts::TAU);
            }
        }
    }
    Terrain { slope_tan, aspect }
}
