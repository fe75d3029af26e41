//! Photo rendering by ray casting through the true surface: each pixel's ray (through the
//! camera model, so distortion and the film scan's interior orientation are exact) is
//! marched over a grid of per-cell height bounds and refined by bisection, which gives
//! occlusions and relief displacement as a real camera sees them.

use super::scene::{Scene, SurfacePoint};
use crate::geometry::{Camera, Pose};
use nalgebra::Vector3;
use rayon::prelude::*;

/// Where a ray met the surface.
#[derive(Debug, Clone, Copy)]
pub struct Hit {
    pub t: f64,
    pub point: Vector3<f64>,
    pub surface: SurfacePoint,
}

/// Height-bound grid over a rectangle of the scene, for fast empty-space skipping.
pub struct RayCaster<'a> {
    scene: &'a Scene,
    x0: f64,
    y0: f64,
    cell: f64,
    nx: usize,
    ny: usize,
    max: Vec<f64>,
    /// Cells that hold a building or tree (discontinuous heights).
    objects: Vec<bool>,
    top: f64,
    lipschitz: f64,
}

impl<'a> RayCaster<'a> {
    /// Bounds over `bbox` = [xmin, ymin, xmax, ymax] with `cell`-metre cells.
    pub fn new(scene: &'a Scene, bbox: [f64; 4], cell: f64) -> Self {
        let nx = ((bbox[2] - bbox[0]) / cell).ceil().max(1.0) as usize;
        let ny = ((bbox[3] - bbox[1]) / cell).ceil().max(1.0) as usize;
        // Terrain bound per block of 8×8 cells from 3×3 samples: no point of a block is
        // further than 0.354·block from one, and the slope bound turns that into a safe
        // margin. The ray marcher's slope-bounded steps do not need a tighter bound.
        let block = 8usize;
        let bsize = cell * block as f64;
        let (bx, by) = (nx.div_ceil(block), ny.div_ceil(block));
        let margin = scene.terrain_lipschitz() * bsize * 0.3536 + 0.01;
        let bmax: Vec<f64> = (0..bx * by)
            .into_par_iter()
            .map(|k| {
                let (i, j) = (k % bx, k / bx);
                let mut m = f64::NEG_INFINITY;
                for a in 0..3 {
                    for b in 0..3 {
                        let x = bbox[0] + (i as f64 + 0.5 * a as f64) * bsize;
                        let y = bbox[1] + (j as f64 + 0.5 * b as f64) * bsize;
                        m = m.max(scene.ground(x, y));
                    }
                }
                m + margin
            })
            .collect();
        let mut max: Vec<f64> = (0..nx * ny)
            .map(|k| bmax[(k / nx / block) * bx + (k % nx) / block])
            .collect();
        let mut objects = vec![false; nx * ny];
        let mut stamp = |cx: f64, cy: f64, rx: f64, ry: f64, top: f64| {
            let i0 = ((cx - rx - bbox[0]) / cell).floor().max(0.0) as usize;
            let j0 = ((cy - ry - bbox[1]) / cell).floor().max(0.0) as usize;
            let i1 = ((((cx + rx - bbox[0]) / cell).floor()) as isize).min(nx as isize - 1);
            let j1 = ((((cy + ry - bbox[1]) / cell).floor()) as isize).min(ny as isize - 1);
            if i1 < 0 || j1 < 0 {
                return;
            }
            for j in j0..=j1 as usize {
                for i in i0..=i1 as usize {
                    let m = &mut max[j * nx + i];
                    *m = m.max(top + 0.01);
                    objects[j * nx + i] = true;
                }
            }
        };
        for b in &scene.buildings {
            // Axis-aligned box of the rotated footprint.
            let (sn, cs) = b.angle.sin_cos();
            let rx = cs.abs() * b.half[0] + sn.abs() * b.half[1];
            let ry = sn.abs() * b.half[0] + cs.abs() * b.half[1];
            stamp(b.center[0], b.center[1], rx, ry, b.top());
        }
        for p in &scene.ponds {
            // Pond rims can be steeper than the terrain slope bound: march them finely.
            stamp(
                p.center[0],
                p.center[1],
                p.radius,
                p.radius,
                f64::NEG_INFINITY,
            );
        }
        for t in &scene.trees {
            stamp(
                t.center[0],
                t.center[1],
                t.radius,
                t.radius,
                t.base + t.height,
            );
        }
        let top = max.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        Self {
            scene,
            x0: bbox[0],
            y0: bbox[1],
            cell,
            nx,
            ny,
            max,
            objects,
            top,
            lipschitz: scene.terrain_lipschitz(),
        }
    }

    /// First intersection of the ray `o + t·d` (d pointing down) with the surface.
    pub fn cast(&self, o: &Vector3<f64>, d: &Vector3<f64>) -> Option<Hit> {
        if d.z >= -1e-9 {
            return None;
        }
        let mut t = ((o.z - self.top) / -d.z).max(0.0);
        let p = o + d * t;
        let fx = (p.x - self.x0) / self.cell;
        let fy = (p.y - self.y0) / self.cell;
        if fx < 0.0 || fy < 0.0 || fx >= self.nx as f64 || fy >= self.ny as f64 {
            return None;
        }
        let (mut i, mut j) = (fx as isize, fy as isize);
        let step_i: isize = if d.x > 0.0 { 1 } else { -1 };
        let step_j: isize = if d.y > 0.0 { 1 } else { -1 };
        let next_boundary = |k: isize, step: isize, origin: f64, dir: f64| -> f64 {
            if dir.abs() < 1e-15 {
                return f64::INFINITY;
            }
            origin + (k + if step > 0 { 1 } else { 0 }) as f64 * self.cell
        };
        let horizontal = d.x.hypot(d.y).max(1e-12);
        // Cells with objects: fixed steps of at most 10 cm horizontally (finer than any
        // roof edge or crown) and 0.5 m vertically, then bisection. Terrain-only cells:
        // safe steps from the slope bound (the gap cannot close faster than
        // |d.z| + L·|d_xy| per unit t), which converge geometrically.
        let dt = (0.1 / horizontal).min(0.5 / -d.z);
        let closing = -d.z + self.lipschitz * horizontal;
        let mut safe_until = 0.0f64;
        loop {
            let bx = next_boundary(i, step_i, self.x0, d.x);
            let by = next_boundary(j, step_j, self.y0, d.y);
            let tx = if bx.is_finite() {
                (bx - o.x) / d.x
            } else {
                f64::INFINITY
            };
            let ty = if by.is_finite() {
                (by - o.y) / d.y
            } else {
                f64::INFINITY
            };
            let t_exit = tx.min(ty);
            let cell = j as usize * self.nx + i as usize;
            let cell_max = self.max[cell];
            let z_exit = o.z + d.z * t_exit;
            if z_exit <= cell_max {
                if self.objects[cell] {
                    let mut a = t.max((o.z - cell_max) / -d.z);
                    if self.gap(o, d, a) <= 0.0 {
                        return Some(self.hit(o, d, a));
                    }
                    while a < t_exit {
                        let b = (a + dt).min(t_exit);
                        if self.gap(o, d, b) <= 0.0 {
                            return Some(self.refine(o, d, a, b));
                        }
                        a = b;
                    }
                } else {
                    // `safe_until` carries the last slope-bounded step across cells: the
                    // ray is known to stay above the terrain up to there.
                    let mut a = t.max((o.z - cell_max) / -d.z).max(safe_until);
                    if a < t_exit {
                        let mut g = self.gap(o, d, a);
                        if g <= 0.0 {
                            return Some(self.hit(o, d, a));
                        }
                        for _ in 0..64 {
                            if g < 1e-4 {
                                return Some(self.hit(o, d, a));
                            }
                            a += g / closing;
                            safe_until = a;
                            if a >= t_exit {
                                break;
                            }
                            g = self.gap(o, d, a);
                        }
                    }
                }
            }
            t = t_exit;
            if tx < ty {
                i += step_i;
            } else {
                j += step_j;
            }
            if i < 0 || j < 0 || i as usize >= self.nx || j as usize >= self.ny {
                return None;
            }
        }
    }

    #[inline]
    fn gap(&self, o: &Vector3<f64>, d: &Vector3<f64>, t: f64) -> f64 {
        let p = o + d * t;
        p.z - self.scene.height_at(p.x, p.y)
    }

    fn refine(&self, o: &Vector3<f64>, d: &Vector3<f64>, mut a: f64, mut b: f64) -> Hit {
        // Bisection to 1/4096 of the step: well under a millimetre.
        for _ in 0..12 {
            let m = 0.5 * (a + b);
            if self.gap(o, d, m) > 0.0 {
                a = m;
            } else {
                b = m;
            }
        }
        self.hit(o, d, b)
    }

    fn hit(&self, o: &Vector3<f64>, d: &Vector3<f64>, t: f64) -> Hit {
        let point = o + d * t;
        Hit {
            t,
            point,
            surface: self.scene.sample(point.x, point.y),
        }
    }

    pub fn scene(&self) -> &Scene {
        self.scene
    }
}

/// Renders the scene radiance (albedo × illumination, 0..1) seen by a camera, row-major.
/// `spp` samples per pixel side (spp² rays, box filter). Rows render in parallel; each
/// pixel depends only on its own rays, so the result is independent of scheduling.
pub fn render(
    caster: &RayCaster,
    camera: &Camera,
    pose: &Pose,
    spp: u32,
    background: f32,
) -> Vec<f32> {
    let (w, h) = camera.image_size();
    let f = camera.focal_px();
    let rt = pose.rotation.transpose();
    let scene = caster.scene();
    let n = spp.max(1);
    let rows: Vec<Vec<f32>> = (0..h)
        .into_par_iter()
        .map(|row| {
            let mut out = Vec::with_capacity(w as usize);
            for col in 0..w {
                let mut acc = 0.0;
                for sy in 0..n {
                    for sx in 0..n {
                        let px = [
                            col as f64 + (sx as f64 + 0.5) / n as f64,
                            row as f64 + (sy as f64 + 0.5) / n as f64,
                        ];
                        acc += match camera.unproject(px) {
                            Ok(dc) => {
                                let d = rt * dc;
                                match caster.cast(&pose.center, &d) {
                                    Some(hit) => {
                                        let fp = hit.t / (f * n as f64) / (-d.z).max(0.2);
                                        scene.albedo(
                                            hit.point.x,
                                            hit.point.y,
                                            &hit.surface,
                                            hit.point.z,
                                            fp,
                                        )
                                    }
                                    None => background as f64,
                                }
                            }
                            Err(_) => background as f64,
                        };
                    }
                }
                out.push((acc / (n * n) as f64) as f32);
            }
            out
        })
        .collect();
    rows.into_iter().flatten().collect()
}
