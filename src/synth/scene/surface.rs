//! The shape of the scene: terrain and ponds, the visible surface (first return) with its
//! class, and height bounds for ray casting.

use super::{Class, Road, Roof, Scene, SurfacePoint, CELL, TARGET_SQUARE_HALF, TREE_BIT};
use crate::synth::noise;

impl Scene {
    /// Terrain relief without ponds (m).
    pub fn terrain(&self, x: f64, y: f64) -> f64 {
        let mut h = self.base_height;
        for w in &self.waves {
            h += w[3] * noise::fast_sin(w[0] * x + w[1] * y + w[2]);
        }
        h
    }

    /// Lower and upper bound of the terrain height anywhere (m).
    pub fn terrain_bounds(&self) -> (f64, f64) {
        let a: f64 = self.waves.iter().map(|w| w[3]).sum();
        (self.base_height - a, self.base_height + a)
    }

    /// Upper bound of the terrain slope (m/m), for safe ray-casting bounds.
    pub fn terrain_lipschitz(&self) -> f64 {
        self.waves.iter().map(|w| w[3] * w[0].hypot(w[1])).sum()
    }

    /// Bare-earth height: terrain with ponds levelled (m).
    pub fn ground(&self, x: f64, y: f64) -> f64 {
        let t = self.terrain(x, y);
        for p in &self.ponds {
            let (dx, dy) = (x - p.center[0], y - p.center[1]);
            let r2 = p.radius * p.radius;
            if dx * dx + dy * dy >= r2 {
                continue;
            }
            let d = ((dx * dx + dy * dy) / r2).sqrt();
            if t > p.level {
                let s = ((d - 0.7) / 0.3).clamp(0.0, 1.0);
                let s = s * s * (3.0 - 2.0 * s);
                return p.level + (t - p.level) * s;
            }
        }
        t
    }

    pub(super) fn road_distance(&self, x: f64, y: f64) -> f64 {
        self.roads
            .iter()
            .map(|r| segment_distance(r, x, y).0 - r.half_width)
            .fold(f64::INFINITY, f64::min)
    }

    /// Whether (x, y) lies on a road's carriageway: [`Scene::road_distance`] ≤ 0 without
    /// its square roots, since every surface sample of open land asks it.
    fn on_road(&self, x: f64, y: f64) -> bool {
        self.roads.iter().any(|r| {
            let (dx, dy) = (r.b[0] - r.a[0], r.b[1] - r.a[1]);
            let (px, py) = (x - r.a[0], y - r.a[1]);
            let s = ((px * dx + py * dy) / (dx * dx + dy * dy)).clamp(0.0, 1.0);
            let (ex, ey) = (px - s * dx, py - s * dy);
            ex * ex + ey * ey <= r.half_width * r.half_width
        })
    }

    pub(super) fn road_azimuth(&self, x: f64, y: f64) -> f64 {
        let mut best = (f64::INFINITY, 0.0);
        for r in &self.roads {
            let d = segment_distance(r, x, y).0;
            if d < best.0 {
                best = (d, (r.b[1] - r.a[1]).atan2(r.b[0] - r.a[0]));
            }
        }
        best.1
    }

    /// The visible surface (first return) at a horizontal position.
    pub fn sample(&self, x: f64, y: f64) -> SurfacePoint {
        self.sample_on_ground(x, y, self.ground(x, y))
    }

    /// [`Scene::sample`] where the caller has just evaluated `ground` = [`Scene::ground`]
    /// at (x, y): the ray caster's last root-finding step has, and the terrain's four
    /// waves were a third of a film frame's render time.
    pub fn sample_on_ground(&self, x: f64, y: f64, ground: f64) -> SurfacePoint {
        let mut sp = SurfacePoint {
            height: ground,
            ground,
            class: Class::Field,
            object: 0,
        };
        for &tag in self.objects_at(x, y) {
            let z = self.object_height(tag, x, y);
            if z > sp.height {
                sp.height = z;
                (sp.class, sp.object) = if tag & TREE_BIT != 0 {
                    (Class::Vegetation, tag & !TREE_BIT)
                } else {
                    (Class::Building, tag)
                };
            }
        }
        if sp.class == Class::Field {
            if self.ponds.iter().any(|p| {
                (x - p.center[0]).powi(2) + (y - p.center[1]).powi(2) < p.radius * p.radius
                    && ground <= p.level + 0.02
            }) {
                sp.class = Class::Water;
            } else if let Some(k) = self.targets.iter().position(|t| {
                (x - t.center[0]).abs() <= TARGET_SQUARE_HALF
                    && (y - t.center[1]).abs() <= TARGET_SQUARE_HALF
            }) {
                sp.class = Class::Target;
                sp.object = k as u32;
            } else if self.on_road(x, y) {
                sp.class = Class::Road;
            }
        }
        sp
    }

    /// Class at a horizontal position.
    pub fn class_at(&self, x: f64, y: f64) -> Class {
        self.sample(x, y).class
    }

    /// Surface height (DSM) at a horizontal position (the first-return surface; cheaper
    /// than [`Scene::sample`] because it skips the ground classes).
    pub fn height_at(&self, x: f64, y: f64) -> f64 {
        let mut h = self.ground(x, y);
        for &tag in self.objects_at(x, y) {
            h = h.max(self.object_height(tag, x, y));
        }
        h
    }

    /// Buildings and trees (grid tags) whose footprint may cover (x, y).
    #[inline]
    fn objects_at(&self, x: f64, y: f64) -> &[u32] {
        let e = self.extent;
        if x >= e[0] && y >= e[1] && x <= e[2] && y <= e[3] {
            let i = ((x - e[0]) / CELL) as usize;
            let j = ((y - e[1]) / CELL) as usize;
            if i < self.grid_dims.0 && j < self.grid_dims.1 {
                return &self.grid[j * self.grid_dims.0 + i];
            }
        }
        &[]
    }

    /// Height of a building or tree at (x, y), −∞ outside its footprint.
    #[inline]
    fn object_height(&self, tag: u32, x: f64, y: f64) -> f64 {
        if tag & TREE_BIT != 0 {
            let t = &self.trees[(tag & !TREE_BIT) as usize];
            let d2 =
                ((x - t.center[0]).powi(2) + (y - t.center[1]).powi(2)) / (t.radius * t.radius);
            if d2 < 1.0 {
                return t.base + t.height * (1.0 - d2).sqrt();
            }
        } else {
            let b = &self.buildings[tag as usize];
            let (u, v) = b.local(x, y);
            if u.abs() <= b.half[0] && v.abs() <= b.half[1] {
                return b.base
                    + b.eave
                    + match b.roof {
                        Roof::Flat => 0.0,
                        Roof::Gable { rise } => rise * (1.0 - v.abs() / b.half[1]),
                    };
            }
        }
        f64::NEG_INFINITY
    }

    /// Highest point of any object (m), for ray-casting bounds.
    pub fn object_top(&self) -> f64 {
        self.buildings
            .iter()
            .map(|b| b.top())
            .chain(self.trees.iter().map(|t| t.base + t.height))
            .fold(f64::NEG_INFINITY, f64::max)
    }

    /// Objects whose footprint may cover the rectangle [x0, x1] × [y0, y1]: their tops.
    pub fn object_tops_in(&self, x0: f64, y0: f64, x1: f64, y1: f64) -> f64 {
        let mut top = f64::NEG_INFINITY;
        for b in &self.buildings {
            let r = b.radius();
            if b.center[0] + r >= x0
                && b.center[0] - r <= x1
                && b.center[1] + r >= y0
                && b.center[1] - r <= y1
            {
                top = top.max(b.top());
            }
        }
        for t in &self.trees {
            let r = t.radius;
            if t.center[0] + r >= x0
                && t.center[0] - r <= x1
                && t.center[1] + r >= y0
                && t.center[1] - r <= y1
            {
                top = top.max(t.base + t.height);
            }
        }
        top
    }
}

/// Distance to the road centreline, position along it, signed offset across it.
pub(super) fn segment_distance(r: &Road, x: f64, y: f64) -> (f64, f64, f64) {
    let dx = r.b[0] - r.a[0];
    let dy = r.b[1] - r.a[1];
    let len = (dx * dx + dy * dy).sqrt();
    let (ux, uy) = (dx / len, dy / len);
    let px = x - r.a[0];
    let py = y - r.a[1];
    let along = (px * ux + py * uy).clamp(0.0, len);
    let across = -px * uy + py * ux;
    let ex = px - along * ux;
    let ey = py - along * uy;
    ((ex * ex + ey * ey).sqrt(), along, across)
}
