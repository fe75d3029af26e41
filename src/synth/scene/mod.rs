//! The procedural world: terrain with relief, ponds, roads, field parcels, buildings with
//! flat and gable roofs, trees, and painted checkpoint targets. A scene is a pure function
//! of its seed and extent; an archive epoch is the same scene with a fraction of it
//! changed ([`Scene::changed`]). Coordinates are block-local metres (x east, y north,
//! z up); the block origin is added only at output.
//!
//! This file holds the objects and the layout of the world; its shape (heights, classes)
//! is in `surface`, its texture (albedo) in `texture`.

mod surface;
mod texture;

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
    pub axis: [f64; 2],
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
    waves: [[f64; 4]; 4],
    base_height: f64,
    pub buildings: Vec<Building>,
    pub trees: Vec<Tree>,
    pub roads: Vec<Road>,
    pub ponds: Vec<Pond>,
    pub targets: Vec<Target>,
    /// Sine and cosine of the field parcels' azimuth (evaluated once, not per pixel).
    field_axes: (f64, f64),
    field_salt: u64,
    /// Re-texturing of each change step back in time, youngest first: (salt, fraction).
    retexture: Vec<(u64, f64)>,
    grid: Vec<Vec<u32>>,
    grid_dims: (usize, usize),
}

impl Scene {
    /// The present-day scene of `seed` over `extent` (block-local metres).
    pub fn generate(seed: u64, extent: [f64; 4]) -> Scene {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5CE4E);
        let area = (extent[2] - extent[0]) * (extent[3] - extent[1]);
        // Relief: long waves for hills, short ones for undulation (Lipschitz ≤ 0.6).
        // A fixed array: the terrain loop unrolls.
        let waves =
            [(9.0, 420.0), (3.0, 170.0), (0.8, 65.0), (0.2, 23.0)].map(|(amp, wavelength)| {
                let az: f64 = rng.gen_range(0.0..std::f64::consts::TAU);
                let k = std::f64::consts::TAU / wavelength;
                [k * az.cos(), k * az.sin(), rng.gen_range(0.0..6.3), amp]
            });
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
            field_axes: rng.gen_range(-0.6f64..0.6).sin_cos(),
            field_salt: rng.gen(),
            retexture: {
                // The stream keeps the draw of a former field, so every seed's scene
                // stays the one earlier versions generated.
                let _: u64 = rng.gen();
                Vec::new()
            },
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
            let c = random_point(&mut rng, extent, [0.15 * w, 0.15 * h]);
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
            let c = random_point(&mut rng, extent, [12.0; 2]);
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
            let c = random_point(&mut rng, extent, [5.0; 2]);
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
        let c = random_point(rng, self.extent, [15.0; 2]);
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

    /// The same world one step earlier in time: a fraction `change` of it differs from
    /// `self`. Half of the changed buildings are absent (built later), as many others
    /// stand that were demolished since; roofs and field parcels are re-textured; trees
    /// were smaller or absent. Targets stay: checkpoints are chosen on stable features.
    /// Steps nest, as a time series does: what an older scene shares with the present
    /// is a subset of what the younger one shares with it.
    pub fn changed(&self, change: f64, salt: u64) -> Scene {
        let change = change.clamp(0.0, 1.0);
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed ^ salt ^ 0xC4A46E);
        let mut s = self.clone();
        s.retexture.push((rng.gen(), change));
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
        // Buildings added by an earlier step keep their ids: new ones follow them.
        let mut next_id = s
            .buildings
            .iter()
            .map(|b| b.id + 1)
            .max()
            .unwrap_or(0)
            .max(100_000);
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

/// A uniform random position in `extent` kept `margin` (x, y) inside its edges.
fn random_point(rng: &mut ChaCha8Rng, extent: [f64; 4], margin: [f64; 2]) -> [f64; 2] {
    [
        rng.gen_range(extent[0] + margin[0]..extent[2] - margin[0]),
        rng.gen_range(extent[1] + margin[1]..extent[3] - margin[1]),
    ]
}
