//! The procedural world: terrain with relief, ponds, roads, field parcels, buildings with
//! flat and gable roofs, trees, and painted checkpoint targets. A scene is a pure function
//! of its seed and extent; an archive epoch is the same scene with a fraction of it
//! changed ([`Scene::changed`]). Coordinates are block-local metres (x east, y north,
//! z up); the block origin is added only at output.

use super::noise::{self, hash3, unit};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

/// Surface class at a ground position (LiDAR classification and texture).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Class {
    Field,
    Road,
    Water,
    Building,
    Vegetation,
    Target,
}

impl Class {
    /// ASPRS LAS classification code.
    pub fn las_code(self) -> u8 {
        match self {
            Class::Field | Class::Road | Class::Target => 2,
            Class::Water => 9,
            Class::Building => 6,
            Class::Vegetation => 5,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Roof {
    Flat,
    /// Ridge along the long axis, `rise` metres above the eaves.
    Gable {
        rise: f64,
    },
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Building {
    pub id: u32,
    pub center: [f64; 2],
    /// Half length (along the ridge) and half width.
    pub half: [f64; 2],
    /// Azimuth of the long axis from east, radians.
    pub angle: f64,
    /// Ground floor height (m).
    pub base: f64,
    /// Eave height above the base (m).
    pub eave: f64,
    pub roof: Roof,
    pub albedo: f64,
    /// (sin, cos) of `angle`, cached for the per-ray footprint test.
    #[serde(skip)]
    axis: [f64; 2],
}

impl Building {
    fn local(&self, x: f64, y: f64) -> (f64, f64) {
        let [s, c] = self.axis;
        let dx = x - self.center[0];
        let dy = y - self.center[1];
        (c * dx + s * dy, -s * dx + c * dy)
    }
    fn radius(&self) -> f64 {
        self.half[0].hypot(self.half[1])
    }
    pub fn top(&self) -> f64 {
        self.base
            + self.eave
            + match self.roof {
                Roof::Flat => 0.0,
                Roof::Gable { rise } => rise,
            }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Tree {
    pub center: [f64; 2],
    pub radius: f64,
    pub height: f64,
    pub base: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Road {
    pub a: [f64; 2],
    pub b: [f64; 2],
    pub half_width: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Pond {
    pub center: [f64; 2],
    pub radius: f64,
    pub level: f64,
}

/// A painted checkpoint target: a white disc on a black square, on open flat ground.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Target {
    pub id: String,
    /// True centre, block-local (x, y, z on the ground surface).
    pub center: [f64; 3],
}

/// Radius of the white disc of a target (m).
pub const TARGET_DISC_RADIUS: f64 = 1.2;
/// Half side of the black square around it (m).
pub const TARGET_SQUARE_HALF: f64 = 2.5;

/// What the surface is at one horizontal position.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfacePoint {
    pub height: f64,
    pub ground: f64,
    pub class: Class,
    /// Index of the building or tree (for texture), or of the target.
    pub object: u32,
}

const CELL: f64 = 8.0;
const TREE_BIT: u32 = 1 << 31;

/// A procedural scene: terrain, objects and texture as deterministic functions of the seed.
#[derive(Debug, Clone)]
pub struct Scene {
    pub seed: u64,
    /// Area holding buildings, trees, roads and targets: [xmin, ymin, xmax, ymax] (m);
    /// outside it the world continues as open fields on the same terrain.
    pub extent: [f64; 4],
    waves: Vec<[f64; 4]>,
    base_height: f64,
    pub buildings: Vec<Building>,
    pub trees: Vec<Tree>,
    pub roads: Vec<Road>,
    pub ponds: Vec<Pond>,
    pub targets: Vec<Target>,
    field_angle: f64,
    field_salt: u64,
    retexture_salt: u64,
    retexture_fraction: f64,
    grid: Vec<Vec<u32>>,
    grid_dims: (usize, usize),
}

impl Scene {
    /// The present-day scene of `seed` over `extent` (block-local metres).
    pub fn generate(seed: u64, extent: [f64; 4]) -> Scene {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5CE4E);
        let area = (extent[2] - extent[0]) * (extent[3] - extent[1]);
        // Relief: long waves for hills, short ones for undulation (Lipschitz ≤ 0.6).
        let mut waves = Vec::new();
        for (amp, wavelength) in [(9.0, 420.0), (3.0, 170.0), (0.8, 65.0), (0.2, 23.0)] {
            let az: f64 = rng.gen_range(0.0..std::f64::consts::TAU);
            let k = std::f64::consts::TAU / wavelength;
            waves.push([k * az.cos(), k * az.sin(), rng.gen_range(0.0..6.3), amp]);
        }
        let mut scene = Scene {
            seed,
            extent,
            waves,
            base_height: 110.0 + rng.gen_range(0.0..30.0),
            buildings: Vec::new(),
            trees: Vec::new(),
            roads: Vec::new(),
            ponds: Vec::new(),
            targets: Vec::new(),
            field_angle: rng.gen_range(-0.6..0.6),
            field_salt: rng.gen(),
            retexture_salt: rng.gen(),
            retexture_fraction: 0.0,
            grid: Vec::new(),
            grid_dims: (0, 0),
        };
        let w = extent[2] - extent[0];
        let h = extent[3] - extent[1];
        let cx = 0.5 * (extent[0] + extent[2]);
        let cy = 0.5 * (extent[1] + extent[3]);
        // Two crossing roads through the area plus one more per 0.2 km².
        let n_roads = 2 + (area / 200_000.0) as usize;
        for i in 0..n_roads {
            let horizontal = i % 2 == 0;
            let off: f64 = rng.gen_range(-0.35..0.35);
            let tilt: f64 = rng.gen_range(-0.15..0.15);
            let hw = rng.gen_range(3.0..4.5);
            let (a, b) = if horizontal {
                let y0 = cy + off * h;
                (
                    [extent[0] - 50.0, y0 - tilt * (w + 100.0) / 2.0],
                    [extent[2] + 50.0, y0 + tilt * (w + 100.0) / 2.0],
                )
            } else {
                let x0 = cx + off * w;
                (
                    [x0 - tilt * (h + 100.0) / 2.0, extent[1] - 50.0],
                    [x0 + tilt * (h + 100.0) / 2.0, extent[3] + 50.0],
                )
            };
            scene.roads.push(Road {
                a,
                b,
                half_width: hw,
            });
        }
        let n_ponds = 1 + (area / 300_000.0) as usize;
        let mut tries = 0;
        while scene.ponds.len() < n_ponds && tries < 200 {
            tries += 1;
            let c = [
                rng.gen_range(extent[0] + 0.15 * w..extent[2] - 0.15 * w),
                rng.gen_range(extent[1] + 0.15 * h..extent[3] - 0.15 * h),
            ];
            let radius = rng.gen_range(8.0..18.0f64.min(0.12 * w.min(h)).max(8.5));
            if scene.road_distance(c[0], c[1]) < radius + 8.0
                || scene.ponds.iter().any(|p| {
                    (p.center[0] - c[0]).hypot(p.center[1] - c[1]) < p.radius + radius + 20.0
                })
            {
                continue;
            }
            let level = scene.terrain(c[0], c[1]) - 1.0;
            scene.ponds.push(Pond {
                center: c,
                radius,
                level,
            });
        }
        // Surveyed targets first: buildings and trees then keep clear of them.
        let n_targets = ((area / 6000.0) as usize).clamp(8, 400);
        tries = 0;
        while scene.targets.len() < n_targets && tries < n_targets * 400 {
            tries += 1;
            let c = [
                rng.gen_range(extent[0] + 12.0..extent[2] - 12.0),
                rng.gen_range(extent[1] + 12.0..extent[3] - 12.0),
            ];
            if scene.road_distance(c[0], c[1]) < 6.0 || !scene.is_free(c, 6.0) {
                continue;
            }
            // Surveyors pick open, level ground away from other targets.
            let slope = (scene.ground(c[0] + 3.0, c[1]) - scene.ground(c[0] - 3.0, c[1]))
                .abs()
                .max((scene.ground(c[0], c[1] + 3.0) - scene.ground(c[0], c[1] - 3.0)).abs())
                / 6.0;
            if slope > 0.12
                || scene
                    .targets
                    .iter()
                    .any(|t| (t.center[0] - c[0]).hypot(t.center[1] - c[1]) < 20.0)
            {
                continue;
            }
            let z = scene.ground(c[0], c[1]);
            scene.targets.push(Target {
                id: format!("CP{:03}", scene.targets.len() + 1),
                center: [c[0], c[1], z],
            });
        }
        let n_buildings = (area / 1500.0) as usize;
        tries = 0;
        while scene.buildings.len() < n_buildings && tries < n_buildings * 30 {
            tries += 1;
            if let Some(b) = scene.random_building(&mut rng, scene.buildings.len() as u32) {
                scene.buildings.push(b);
            }
        }
        let n_trees = (area / 500.0) as usize;
        tries = 0;
        while scene.trees.len() < n_trees && tries < n_trees * 20 {
            tries += 1;
            // Trees cluster along roads and in groves: half near a road.
            let c = [
                rng.gen_range(extent[0] + 5.0..extent[2] - 5.0),
                rng.gen_range(extent[1] + 5.0..extent[3] - 5.0),
            ];
            let radius = rng.gen_range(1.5..4.0);
            let rd = scene.road_distance(c[0], c[1]);
            let near_road = rd < 12.0;
            if rd < radius + 4.0 || (!near_road && rng.gen_bool(0.5)) {
                continue;
            }
            if !scene.is_free(c, radius + 1.0) {
                continue;
            }
            let base = scene.ground(c[0], c[1]);
            scene.trees.push(Tree {
                center: c,
                radius,
                height: rng.gen_range(radius * 1.5..radius * 3.5 + 3.0),
                base,
            });
        }
        scene.rebuild_grid();
        scene
    }

    fn random_building(&self, rng: &mut ChaCha8Rng, id: u32) -> Option<Building> {
        let e = self.extent;
        let c = [
            rng.gen_range(e[0] + 15.0..e[2] - 15.0),
            rng.gen_range(e[1] + 15.0..e[3] - 15.0),
        ];
        let half: [f64; 2] = [rng.gen_range(5.0..14.0), rng.gen_range(4.0..7.5)];
        let r = half[0].hypot(half[1]);
        let rd = self.road_distance(c[0], c[1]);
        // Houses front the roads: most within 40 m of one.
        if rd < r + 5.0 || (rd > 40.0 && rng.gen_bool(0.7)) {
            return None;
        }
        if !self.is_free(c, r + 3.0) {
            return None;
        }
        let mut base = f64::INFINITY;
        for (sx, sy) in [
            (-1.0, -1.0),
            (1.0, -1.0),
            (-1.0, 1.0),
            (1.0, 1.0),
            (0.0, 0.0),
        ] {
            base = base.min(self.ground(c[0] + sx * r, c[1] + sy * r));
        }
        let roof = if rng.gen_bool(0.55) {
            Roof::Gable {
                rise: rng.gen_range(1.5..4.0),
            }
        } else {
            Roof::Flat
        };
        let angle = if rng.gen_bool(0.7) {
            self.road_azimuth(c[0], c[1])
        } else {
            rng.gen_range(0.0..std::f64::consts::PI)
        };
        Some(Building {
            id,
            center: c,
            half,
            angle,
            base,
            eave: rng.gen_range(3.0..15.0),
            roof,
            albedo: rng.gen_range(0.25..0.8),
            axis: [angle.sin(), angle.cos()],
        })
    }

    /// True when a disc of `radius` around `c` is clear of buildings, trees, ponds and targets.
    fn is_free(&self, c: [f64; 2], radius: f64) -> bool {
        self.buildings
            .iter()
            .all(|b| (b.center[0] - c[0]).hypot(b.center[1] - c[1]) > b.radius() + radius)
            && self
                .trees
                .iter()
                .all(|t| (t.center[0] - c[0]).hypot(t.center[1] - c[1]) > t.radius + radius)
            && self
                .ponds
                .iter()
                .all(|p| (p.center[0] - c[0]).hypot(p.center[1] - c[1]) > p.radius + radius)
            && self.targets.iter().all(|t| {
                (t.center[0] - c[0]).hypot(t.center[1] - c[1]) > TARGET_SQUARE_HALF * 1.5 + radius
            })
    }

    fn rebuild_grid(&mut self) {
        let e = self.extent;
        let nx = ((e[2] - e[0]) / CELL).ceil() as usize + 1;
        let ny = ((e[3] - e[1]) / CELL).ceil() as usize + 1;
        let mut grid = vec![Vec::new(); nx * ny];
        let mut insert = |cx: f64, cy: f64, r: f64, tag: u32| {
            let i0 = (((cx - r - e[0]) / CELL).floor().max(0.0)) as usize;
            let i1 = (((cx + r - e[0]) / CELL).floor() as usize).min(nx - 1);
            let j0 = (((cy - r - e[1]) / CELL).floor().max(0.0)) as usize;
            let j1 = (((cy + r - e[1]) / CELL).floor() as usize).min(ny - 1);
            for j in j0..=j1 {
                for i in i0..=i1 {
                    grid[j * nx + i].push(tag);
                }
            }
        };
        for (k, b) in self.buildings.iter().enumerate() {
            insert(b.center[0], b.center[1], b.radius(), k as u32);
        }
        for (k, t) in self.trees.iter().enumerate() {
            insert(t.center[0], t.center[1], t.radius, k as u32 | TREE_BIT);
        }
        self.grid = grid;
        self.grid_dims = (nx, ny);
    }

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

    fn road_distance(&self, x: f64, y: f64) -> f64 {
        self.roads
            .iter()
            .map(|r| segment_distance(r, x, y).0 - r.half_width)
            .fold(f64::INFINITY, f64::min)
    }

    fn road_azimuth(&self, x: f64, y: f64) -> f64 {
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
        let ground = self.ground(x, y);
        let mut sp = SurfacePoint {
            height: ground,
            ground,
            class: Class::Field,
            object: 0,
        };
        let e = self.extent;
        if x >= e[0] && y >= e[1] && x <= e[2] && y <= e[3] {
            let i = ((x - e[0]) / CELL) as usize;
            let j = ((y - e[1]) / CELL) as usize;
            if i < self.grid_dims.0 && j < self.grid_dims.1 {
                for &tag in &self.grid[j * self.grid_dims.0 + i] {
                    if tag & TREE_BIT != 0 {
                        let k = tag & !TREE_BIT;
                        let t = &self.trees[k as usize];
                        let d2 = ((x - t.center[0]).powi(2) + (y - t.center[1]).powi(2))
                            / (t.radius * t.radius);
                        if d2 < 1.0 {
                            let z = t.base + t.height * (1.0 - d2).sqrt();
                            if z > sp.height {
                                sp.height = z;
                                sp.class = Class::Vegetation;
                                sp.object = k;
                            }
                        }
                    } else {
                        let b = &self.buildings[tag as usize];
                        let (u, v) = b.local(x, y);
                        if u.abs() <= b.half[0] && v.abs() <= b.half[1] {
                            let z = b.base
                                + b.eave
                                + match b.roof {
                                    Roof::Flat => 0.0,
                                    Roof::Gable { rise } => rise * (1.0 - v.abs() / b.half[1]),
                                };
                            if z > sp.height {
                                sp.height = z;
                                sp.class = Class::Building;
                                sp.object = tag;
                            }
                        }
                    }
                }
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
            } else if self.road_distance(x, y) <= 0.0 {
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
        let e = self.extent;
        if x >= e[0] && y >= e[1] && x <= e[2] && y <= e[3] {
            let i = ((x - e[0]) / CELL) as usize;
            let j = ((y - e[1]) / CELL) as usize;
            if i < self.grid_dims.0 && j < self.grid_dims.1 {
                for &tag in &self.grid[j * self.grid_dims.0 + i] {
                    h = h.max(self.object_height(tag, x, y));
                }
            }
        }
        h
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

    /// Re-texture decision for an object or parcel: (hash, changed?).
    fn salt_for(&self, kind: u64, a: i64, b: i64) -> (u64, bool) {
        let changed = self.retexture_fraction > 0.0
            && unit(hash3(self.retexture_salt ^ kind, a, b)) < self.retexture_fraction;
        if changed {
            (hash3(self.retexture_salt ^ kind ^ 0xC4A6, a, b), true)
        } else {
            (hash3(self.field_salt ^ kind, a, b), false)
        }
    }

    fn field_albedo(&self, x: f64, y: f64, fp: f64) -> f64 {
        let (sa, ca) = self.field_angle.sin_cos();
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

    /// The same world at another time: a fraction `change` of it differs. Half of the
    /// changed buildings are absent (built later), as many others stand that were
    /// demolished since; roofs and field parcels are re-textured; trees were smaller or
    /// absent. Targets stay: checkpoints are chosen on stable features.
    pub fn changed(&self, change: f64, salt: u64) -> Scene {
        let change = change.clamp(0.0, 1.0);
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed ^ salt ^ 0xC4A46E);
        let mut s = self.clone();
        s.retexture_salt = rng.gen();
        s.retexture_fraction = change;
        let n0 = s.buildings.len();
        s.buildings.retain(|_| !rng.gen_bool(change * 0.5));
        s.trees.retain(|_| !rng.gen_bool(change * 0.3));
        for t in &mut s.trees {
            if rng.gen_bool(change) {
                t.height *= 0.6;
                t.radius *= 0.7;
            }
        }
        let added = (n0 as f64 * change * 0.5).round() as usize;
        let mut tries = 0;
        let mut next_id = 100_000;
        let target = s.buildings.len() + added;
        while s.buildings.len() < target && tries < added * 40 + 10 {
            tries += 1;
            if let Some(b) = s.random_building(&mut rng, next_id) {
                next_id += 1;
                s.buildings.push(b);
            }
        }
        s.rebuild_grid();
        s
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

/// Distance to the road centreline, position along it, signed offset across it.
fn segment_distance(r: &Road, x: f64, y: f64) -> (f64, f64, f64) {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::render::RayCaster;
    use nalgebra::Vector3;

    const EXTENT: [f64; 4] = [-150.0, -110.0, 150.0, 110.0];

    #[test]
    fn scene_is_a_pure_function_of_the_seed() {
        let a = Scene::generate(7, EXTENT);
        let b = Scene::generate(7, EXTENT);
        let c = Scene::generate(8, EXTENT);
        assert_eq!(a.buildings, b.buildings);
        assert_eq!(a.targets, b.targets);
        assert_ne!(a.buildings, c.buildings);
        for k in 0..500 {
            let (x, y) = (-149.0 + 0.597 * k as f64, -100.0 + 0.41 * k as f64);
            assert_eq!(a.height_at(x, y).to_bits(), b.height_at(x, y).to_bits());
            assert_eq!(
                a.albedo(x, y, &a.sample(x, y), a.height_at(x, y), 0.1)
                    .to_bits(),
                b.albedo(x, y, &b.sample(x, y), b.height_at(x, y), 0.1)
                    .to_bits()
            );
        }
    }

    #[test]
    fn surface_holds_every_class_and_never_lies_below_the_ground() {
        let s = Scene::generate(3, EXTENT);
        let mut seen = std::collections::BTreeSet::new();
        for i in 0..600 {
            for j in 0..440 {
                let (x, y) = (-150.0 + 0.5 * i as f64, -110.0 + 0.5 * j as f64);
                let sp = s.sample(x, y);
                assert!(sp.height >= sp.ground);
                assert_eq!(sp.height.to_bits(), s.height_at(x, y).to_bits());
                seen.insert(format!("{:?}", sp.class));
            }
        }
        for c in ["Field", "Road", "Water", "Building", "Vegetation", "Target"] {
            assert!(seen.contains(c), "{c} missing: {seen:?}");
        }
        assert!(s
            .buildings
            .iter()
            .any(|b| matches!(b.roof, Roof::Gable { .. })));
        assert!(s.buildings.iter().any(|b| b.roof == Roof::Flat));
    }

    #[test]
    fn gable_roof_rises_from_eaves_to_ridge() {
        let s = Scene::generate(3, EXTENT);
        let b = s
            .buildings
            .iter()
            .find(|b| matches!(b.roof, Roof::Gable { .. }))
            .unwrap();
        let Roof::Gable { rise } = b.roof else {
            unreachable!()
        };
        let at = |u: f64, v: f64| {
            let [sn, cs] = b.axis;
            (b.center[0] + cs * u - sn * v, b.center[1] + sn * u + cs * v)
        };
        let (x, y) = at(0.3, 0.0);
        assert!((s.height_at(x, y) - (b.base + b.eave + rise)).abs() < 1e-9);
        let (x, y) = at(0.3, b.half[1] * 0.999);
        assert!((s.height_at(x, y) - (b.base + b.eave + rise * 0.001)).abs() < 1e-6);
    }

    #[test]
    fn changed_epoch_differs_but_keeps_the_targets() {
        let s = Scene::generate(3, EXTENT);
        let old = s.changed(0.5, 1);
        assert_eq!(old.targets, s.targets);
        assert_ne!(old.buildings, s.buildings);
        let same = s.changed(0.0, 1);
        assert_eq!(same.buildings, s.buildings);
    }

    #[test]
    fn render_photo_shows_a_target_where_it_projects() {
        use crate::geometry::{Camera, FrameCamera, Pose};
        let s = Scene::generate(3, EXTENT);
        let t = &s.targets[0];
        let cam = Camera::Frame(FrameCamera::pinhole(200, 160, 900.0));
        let pose = Pose::from_opk(
            0.01,
            -0.02,
            0.3,
            Vector3::new(t.center[0] + 3.0, t.center[1] - 2.0, t.center[2] + 90.0),
        );
        let img = crate::synth::render_photo(&s, &cam, &pose, 1).unwrap();
        assert_eq!(img, crate::synth::render_photo(&s, &cam, &pose, 1).unwrap());
        let px = cam
            .project(&pose.to_camera(&Vector3::from(t.center)))
            .unwrap();
        let (mut sw, mut sx, mut sy) = (0.0, 0.0, 0.0);
        let r = TARGET_DISC_RADIUS / 0.1 + 1.5;
        for y in 0..160 {
            for x in 0..200 {
                let (cx, cy) = (x as f64 + 0.5, y as f64 + 0.5);
                if (cx - px.x).hypot(cy - px.y) <= r {
                    let v = (img[y * 200 + x] as f64 - 30.0).max(0.0);
                    sw += v;
                    sx += v * cx;
                    sy += v * cy;
                }
            }
        }
        let err = (sx / sw - px.x).hypot(sy / sw - px.y);
        assert!(err < 0.2, "target centroid {err} px from its projection");
    }

    #[test]
    fn ray_caster_hits_the_surface_and_sees_walls() {
        let s = Scene::generate(3, EXTENT);
        let caster = RayCaster::new(&s, [-200.0, -160.0, 200.0, 160.0], 1.0);
        let o = Vector3::new(10.0, -20.0, 400.0);
        let mut worst: f64 = 0.0;
        for k in 0..400 {
            let target = Vector3::new(-120.0 + 0.6 * k as f64, -90.0 + 0.45 * k as f64, 0.0);
            let d = (Vector3::new(target.x, target.y, 0.0) - o).normalize();
            let hit = caster.cast(&o, &d).expect("ray meets the surface");
            // The hit lies on the surface (or on a wall below a roof edge).
            let h = s.height_at(hit.point.x, hit.point.y);
            if hit.surface.class != Class::Building || hit.point.z > h - 0.01 {
                worst = worst.max((hit.point.z - h).abs());
            }
        }
        assert!(worst < 1e-3, "hit off the surface by {worst} m");
        // A low oblique ray towards a building's base hits its wall first.
        let b = &s.buildings[0];
        let base = Vector3::new(b.center[0], b.center[1], b.base + 0.5);
        let o = base + Vector3::new(60.0, 0.0, 20.0);
        let hit = caster.cast(&o, &(base - o).normalize()).unwrap();
        assert!(
            hit.t < (base - o).norm() - 0.5,
            "the wall occludes the base"
        );
    }
}
