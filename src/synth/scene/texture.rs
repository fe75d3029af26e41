//! The scene's texture: albedo of roofs, trees, water, targets, roads and field parcels,
//! filtered analytically by the pixel footprint, and the re-texturing of a changed epoch.

use super::surface::segment_distance;
use super::{Class, Roof, Scene, SurfacePoint, TARGET_DISC_RADIUS};
use crate::synth::noise::{self, hash3, unit};

impl Scene {
    /// Albedo in [0, 1] at a surface point seen with a ground footprint of `fp` metres per
    /// pixel; detail finer than the footprint is filtered out analytically.
    pub fn albedo(&self, x: f64, y: f64, sp: &SurfacePoint, hit_z: f64, fp: f64) -> f64 {
        let s = self.seed;
        match sp.class {
            Class::Building => {
                let b = &self.buildings[sp.object as usize];
                let roof_base = b.base + b.eave;
                if hit_z < roof_base - 0.05 {
                    // Wall seen obliquely.
                    return 0.45 + 0.1 * noise::fractal(s ^ 0xA11, x + y, hit_z, 1.0, 3, fp);
                }
                let (u, v) = b.local(x, y);
                let salt = self.salt_for(0xB0 + b.id as u64, b.id as i64, 0);
                let albedo = if salt.1 {
                    0.2 + 0.6 * unit(salt.0)
                } else {
                    b.albedo
                };
                let mut a = albedo;
                match b.roof {
                    Roof::Gable { .. } => {
                        // Tile rows across the slope and the sun on one side of the ridge.
                        a *= if v > 0.0 { 1.12 } else { 0.78 };
                        a += 0.08
                            * noise::attenuation(0.35, fp)
                            * (std::f64::consts::TAU * v / 0.35).sin();
                        // Ridge line.
                        a += 0.15 * band(v, 0.25, fp);
                    }
                    Roof::Flat => {
                        // Roof fixtures: small dark boxes on a 4 m lattice.
                        let (iu, iv) = ((u / 4.0).floor() as i64, (v / 4.0).floor() as i64);
                        if unit(hash3(s ^ b.id as u64, iu, iv)) < 0.15 {
                            let du = (u - (iu as f64 + 0.5) * 4.0)
                                .abs()
                                .max((v - (iv as f64 + 0.5) * 4.0).abs());
                            a *= 1.0 - 0.7 * noise::coverage(du - 0.7, fp);
                        }
                    }
                }
                // Dark parapet/eave edge: roof edges are the strongest corners in a town.
                let edge = (b.half[0] - u.abs()).min(b.half[1] - v.abs());
                a *= 1.0 - 0.5 * noise::coverage(edge - 0.3, fp);
                (a + 0.12 * noise::fractal(s ^ 0x200F ^ b.id as u64, x, y, 2.0, 5, fp))
                    .clamp(0.02, 0.98)
            }
            Class::Vegetation => {
                let t = &self.trees[sp.object as usize];
                let d2 =
                    ((x - t.center[0]).powi(2) + (y - t.center[1]).powi(2)) / (t.radius * t.radius);
                let shade = 0.6 + 0.4 * (1.0 - d2).max(0.0).sqrt();
                let dir = 0.85 + 0.25 * ((x - t.center[0]) - (y - t.center[1])) / t.radius;
                (0.2 * shade * dir + 0.25 * noise::fractal(s ^ 0x7EE, x, y, 1.2, 4, fp))
                    .clamp(0.02, 0.9)
            }
            Class::Water => 0.08 + 0.06 * noise::fractal(s ^ 0x3A7E, x, y, 3.0, 3, fp),
            Class::Target => {
                let t = &self.targets[sp.object as usize];
                let d = ((x - t.center[0]).powi(2) + (y - t.center[1]).powi(2)).sqrt();
                0.06 + 0.86 * noise::coverage(d - TARGET_DISC_RADIUS, fp)
            }
            Class::Road => {
                let mut best = (f64::INFINITY, 0.0, 0.0);
                for r in &self.roads {
                    let (d, along, signed) = segment_distance(r, x, y);
                    if d < best.0 {
                        best = (d, along, signed);
                    }
                }
                let (_, along, across) = best;
                let mut a = 0.28 + 0.18 * noise::fractal(s ^ 0x80AD, x, y, 3.0, 6, fp);
                // Dashed centre line (3 m on, 6 m off) and solid edge lines.
                let dash = along.rem_euclid(9.0);
                let on = noise::coverage(dash - 3.0, fp);
                let centre = band(across, 0.15, fp) * on;
                let hw = self.roads.iter().map(|r| r.half_width).fold(0.0, f64::max);
                let edges = band(across.abs() - (hw - 0.4), 0.15, fp);
                a += (0.85 - a) * (centre + edges).min(1.0);
                a
            }
            Class::Field => self.field_albedo(x, y, fp),
        }
    }

    /// Re-texture decision for an object or parcel: (hash, changed?). Its texture is the
    /// one of the oldest change step that re-textured it (before that step it looked
    /// like that), else today's.
    pub fn salt_for(&self, kind: u64, a: i64, b: i64) -> (u64, bool) {
        for &(salt, fraction) in self.retexture.iter().rev() {
            if unit(hash3(salt ^ kind, a, b)) < fraction {
                return (hash3(salt ^ kind ^ 0xC4A6, a, b), true);
            }
        }
        (hash3(self.field_salt ^ kind, a, b), false)
    }

    fn field_albedo(&self, x: f64, y: f64, fp: f64) -> f64 {
        let (sa, ca) = self.field_axes;
        let u = ca * x + sa * y;
        let v = -sa * x + ca * y;
        let (pw, ph) = (70.0, 38.0);
        let (i, j) = ((u / pw).floor() as i64, (v / ph).floor() as i64);
        let (h, _) = self.salt_for(0xF1E1D, i, j);
        let kind = h % 4;
        let base = 0.3 + 0.3 * unit(mix_hash(h, 1));
        let detail = noise::fractal(h, x, y, 6.0, 6, fp);
        let mut a = match kind {
            // Crop rows: period 0.8–2.5 m along the parcel's long side or across it.
            0 | 1 => {
                let period = 0.8 + 1.7 * unit(mix_hash(h, 2));
                let coord = if kind == 0 { v } else { u };
                base + 0.12
                    * noise::attenuation(period, fp)
                    * (std::f64::consts::TAU * coord / period).sin()
                    + 0.15 * detail
            }
            // Bare soil with clods and tracks.
            2 => base + 0.3 * detail,
            // Meadow.
            _ => 0.25 + 0.1 * unit(mix_hash(h, 3)) + 0.2 * detail,
        };
        // Field boundaries: a dark 0.8 m furrow/ditch between parcels.
        let du = (u - (i as f64) * pw).min((i as f64 + 1.0) * pw - u);
        let dv = (v - (j as f64) * ph).min((j as f64 + 1.0) * ph - v);
        a *= 1.0 - 0.35 * noise::coverage(du.min(dv) - 0.4, fp);
        a.clamp(0.02, 0.98)
    }
}

fn mix_hash(h: u64, k: u64) -> u64 {
    noise::mix(h ^ k.wrapping_mul(0xD6E8_FEB8_6659_FD93))
}

/// Coverage of a band `|d| < width/2` by a pixel of footprint `fp` (box filter).
fn band(d: f64, width: f64, fp: f64) -> f64 {
    let fp = fp.max(1e-9);
    let lo = (d - fp / 2.0).max(-width / 2.0);
    let hi = (d + fp / 2.0).min(width / 2.0);
    ((hi - lo) / fp).clamp(0.0, 1.0)
}
