//! Where an orthophoto's tiles need which photos. Each photo gets a conservative ground
//! bounding box of its frame; a tile is rendered from the photos whose box meets it, and
//! tiles are visited along a Hilbert curve, so consecutive tiles need mostly the same
//! photos and the image cache decodes each photo about once.

use crate::geometry::Camera;
use nalgebra::{Matrix3, Vector3};

/// Border pixels sampled per frame edge.
const EDGE_SAMPLES: usize = 16;

/// Ground box `[x_min, y_min, x_max, y_max]` that holds every ground point of height in
/// `z_range` which projects into the frame of `camera` at (`rotation`, `center`, world).
/// A ground point seen through a pixel lies on that pixel's ray between the ray's
/// crossings of the lowest and highest terrain plane, and the frame at a height between
/// them is a convex combination of the frames on the two planes, so the box of the border
/// rays' crossings holds it; a margin of 5 % covers the curvature of a distorted border
/// between samples. `None` when a border ray does not descend to both planes in front of
/// the camera (horizon in the frame, camera below the terrain): the photo may then see
/// any cell.
pub fn footprint(
    camera: &Camera,
    rotation: &Matrix3<f64>,
    center: &Vector3<f64>,
    z_range: (f64, f64),
) -> Option<[f64; 4]> {
    let (w, h) = camera.image_size();
    let (w, h) = (w as f64, h as f64);
    let n = EDGE_SAMPLES as f64;
    let mut bb = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for k in 0..EDGE_SAMPLES {
        let t = k as f64 / n;
        for px in [
            [w * t, 0.0],
            [w, h * t],
            [w * (1.0 - t), h],
            [0.0, h * (1.0 - t)],
        ] {
            let d = rotation.transpose() * camera.unproject(px).ok()?;
            for z in [z_range.0, z_range.1] {
                let s = (z - center.z) / d.z;
                if !(s > 0.0 && s.is_finite()) {
                    return None;
                }
                let g = center + d * s;
                bb = [
                    bb[0].min(g.x),
                    bb[1].min(g.y),
                    bb[2].max(g.x),
                    bb[3].max(g.y),
                ];
            }
        }
    }
    let (mx, my) = (0.05 * (bb[2] - bb[0]), 0.05 * (bb[3] - bb[1]));
    let bb = [bb[0] - mx, bb[1] - my, bb[2] + mx, bb[3] + my];
    bb.iter().all(|v| v.is_finite()).then_some(bb)
}

/// Whether two boxes `[x_min, y_min, x_max, y_max]` overlap (touching counts).
pub fn overlaps(a: &[f64; 4], b: &[f64; 4]) -> bool {
    a[0] <= b[2] && b[0] <= a[2] && a[1] <= b[3] && b[1] <= a[3]
}

/// The tiles `(column, row)` of an `nx` × `ny` grid in the order of a Hilbert curve over
/// the enclosing power-of-two square: each tile is followed by a neighbour wherever the
/// grid allows, so the photos needed change slowly from tile to tile.
pub fn hilbert_order(nx: usize, ny: usize) -> Vec<(usize, usize)> {
    let n = nx.max(ny).max(1).next_power_of_two() as u64;
    let mut tiles: Vec<(u64, (usize, usize))> = (0..ny)
        .flat_map(|r| (0..nx).map(move |c| (hilbert_index(n, c as u64, r as u64), (c, r))))
        .collect();
    tiles.sort_unstable_by_key(|t| t.0);
    tiles.into_iter().map(|t| t.1).collect()
}

/// Distance along the Hilbert curve of side `n` (a power of two) of cell (x, y).
fn hilbert_index(n: u64, mut x: u64, mut y: u64) -> u64 {
    let mut d = 0;
    let mut s = n / 2;
    while s > 0 {
        let rx = u64::from(x & s > 0);
        let ry = u64::from(y & s > 0);
        d += s * s * ((3 * rx) ^ ry);
        // Rotate the quadrant so the sub-curve enters where the previous one left.
        if ry == 0 {
            if rx == 1 {
                x = n - 1 - x;
                y = n - 1 - y;
            }
            std::mem::swap(&mut x, &mut y);
        }
        s /= 2;
    }
    d
}
