//! Deterministic synthetic aerial blocks with ground truth for the adjustment's tests and
//! benchmarks: nadir frame photos in strips with given forward/side overlap over a
//! sinusoidal terrain, tie points seen in every photo whose frame they fall in, control
//! and check points on a grid, Gaussian image noise, and an approximate starting block.

use crate::block::{Block, BlockCamera, ObjectPoint, Observation, Photo, PointKind};
use crate::geometry::{project, rotation_from_vector, Brown, Camera, FrameCamera, Pose};
use nalgebra::{Matrix3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

#[derive(Debug, Clone)]
pub struct SyntheticOptions {
    pub strips: usize,
    pub photos_per_strip: usize,
    pub tie_points: usize,
    /// Smallest number of rays of a tie point (a matcher's minimum track length).
    pub min_rays: usize,
    pub noise_px: f64,
    /// A-priori σ written into the observations (px).
    pub sigma_px: f64,
    pub flying_height_m: f64,
    /// Amplitude of the terrain (m).
    pub relief_m: f64,
    pub forward_overlap: f64,
    pub side_overlap: f64,
    pub width: u32,
    pub height: u32,
    pub focal_px: f64,
    pub distortion: Brown,
    pub control_grid: (usize, usize),
    pub control_sigma_m: [f64; 3],
    pub check_points: usize,
    /// Perturbation of the starting values: rotation (rad), centre (m), points (m).
    pub perturb_rotation: f64,
    pub perturb_center: f64,
    pub perturb_points: f64,
    pub seed: u64,
}

impl Default for SyntheticOptions {
    fn default() -> Self {
        Self {
            strips: 5,
            photos_per_strip: 20,
            tie_points: 25_000,
            min_rays: 2,
            noise_px: 0.5,
            sigma_px: 1.0,
            flying_height_m: 1000.0,
            relief_m: 60.0,
            forward_overlap: 0.6,
            side_overlap: 0.3,
            width: 6000,
            height: 4000,
            focal_px: 5000.0,
            distortion: Brown::default(),
            control_grid: (4, 3),
            control_sigma_m: [0.02, 0.02, 0.03],
            check_points: 10,
            perturb_rotation: 0.005,
            perturb_center: 3.0,
            perturb_points: 1.0,
            seed: 1,
        }
    }
}

/// Truth and the perturbed starting block.
#[derive(Debug, Clone)]
pub struct SyntheticBlock {
    pub truth: Block,
    pub start: Block,
}

/// Terrain height of the synthetic scene.
pub fn terrain(relief: f64, x: f64, y: f64) -> f64 {
    relief
        * (0.6 * (x / 700.0).sin() * (y / 500.0).cos()
            + 0.4 * (x / 230.0 + 1.0).sin() * (y / 310.0 + 0.5).sin())
}

/// Unit normal of the terrain at (x, y).
pub fn terrain_normal(relief: f64, x: f64, y: f64) -> Vector3<f64> {
    let h = 0.01;
    let dx = (terrain(relief, x + h, y) - terrain(relief, x - h, y)) / (2.0 * h);
    let dy = (terrain(relief, x, y + h) - terrain(relief, x, y - h)) / (2.0 * h);
    Vector3::new(-dx, -dy, 1.0).normalize()
}

pub fn generate(o: &SyntheticOptions) -> SyntheticBlock {
    let mut rng = ChaCha8Rng::seed_from_u64(o.seed);
    let gsd = o.flying_height_m / o.focal_px;
    let along = o.height as f64 * gsd;
    let across = o.width as f64 * gsd;
    let base = (1.0 - o.forward_overlap) * along;
    let spacing = (1.0 - o.side_overlap) * across;
    let mut truth = Block::new();
    let camera = Camera::Frame(FrameCamera {
        distortion: o.distortion,
        ..FrameCamera::pinhole(o.width, o.height, o.focal_px)
    });
    truth.cameras.insert(
        1,
        BlockCamera {
            id: 1,
            name: "synthetic".into(),
            model: camera.clone(),
            free_params: Vec::new(),
            calibration_group: None,
        },
    );
    let nadir = Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0);
    let flip = Matrix3::new(-1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 1.0);
    let att = Normal::new(0.0, 0.02).expect("σ");
    let mut id = 1;
    for s in 0..o.strips {
        for i in 0..o.photos_per_strip {
            let x = i as f64 * base;
            let y = s as f64 * spacing;
            let c = Vector3::new(
                x + rng.gen_range(-5.0..5.0),
                y + rng.gen_range(-5.0..5.0),
                o.flying_height_m + rng.gen_range(-10.0..10.0),
            );
            // Return strips fly the other way (κ = 180°); a little roll, pitch and crab.
            let r0 = if s % 2 == 1 { flip * nadir } else { nadir };
            let d = Vector3::new(
                att.sample(&mut rng),
                att.sample(&mut rng),
                att.sample(&mut rng),
            );
            truth.photos.insert(
                id,
                Photo::new(
                    id,
                    format!("s{s:02}_p{i:03}.tif"),
                    1,
                    Pose::new(rotation_from_vector(&d) * r0, c),
                )
                .oriented(),
            );
            id += 1;
        }
    }
    let x_max = (o.photos_per_strip.max(1) - 1) as f64 * base;
    let y_max = (o.strips.max(1) - 1) as f64 * spacing;
    let (x0, x1) = (-0.4 * along, x_max + 0.4 * along);
    let (y0, y1) = (-0.4 * across, y_max + 0.4 * across);
    let noise = Normal::new(0.0, o.noise_px.max(1e-300)).expect("σ");
    let photos: Vec<Photo> = truth.photos.values().cloned().collect();
    // A point is projected only into the photos whose centres lie near it: testing every
    // photo made a 3,200-photo block take minutes and a 20,000-photo one hours. The
    // candidates are visited in photo order, so the noise draws (one pair per photo that
    // sees the point) and with them the block are the same as testing every photo.
    let reach = 1.5 * (o.flying_height_m + 3.0 * o.relief_m.abs()) / o.focal_px
        * 0.5
        * (o.width as f64).hypot(o.height as f64);
    let index = CentreIndex::new(&photos, reach);
    let observe = |x: &Vector3<f64>, rng: &mut ChaCha8Rng| -> Vec<Observation> {
        let mut obs = Vec::new();
        for &k in &index.near(x.x, x.y) {
            let p = &photos[k];
            let Ok(pr) = project(&camera, &p.pose, x) else {
                continue;
            };
            let (u, v) = (pr.pixel.x, pr.pixel.y);
            if u < 20.0 || v < 20.0 || u > o.width as f64 - 20.0 || v > o.height as f64 - 20.0 {
                continue;
            }
            let (nu, nv) = if o.noise_px > 0.0 {
                (noise.sample(rng), noise.sample(rng))
            } else {
                (0.0, 0.0)
            };
            obs.push(Observation {
                photo: p.id,
                pixel: [u + nu, v + nv],
                sigma_px: o.sigma_px,
                provenance: "synthetic".into(),
            });
        }
        obs
    };
    let mut pid = 1u64;
    let mut made = 0;
    while made < o.tie_points {
        let x = rng.gen_range(x0..x1);
        let y = rng.gen_range(y0..y1);
        let p = Vector3::new(x, y, terrain(o.relief_m, x, y));
        let obs = observe(&p, &mut rng);
        if obs.len() < o.min_rays.max(2) {
            continue;
        }
        truth.points.insert(
            pid,
            ObjectPoint {
                id: pid,
                name: String::new(),
                kind: PointKind::Tie,
                position: p,
                sigma: None,
                color: [128, 128, 128],
                observations: obs,
            },
        );
        pid += 1;
        made += 1;
    }
    let (gx, gy) = o.control_grid;
    let add_gcp = |x: f64,
                   y: f64,
                   kind: PointKind,
                   name: String,
                   rng: &mut ChaCha8Rng,
                   truth: &mut Block,
                   pid: &mut u64| {
        let p = Vector3::new(x, y, terrain(o.relief_m, x, y));
        let obs = observe(&p, rng);
        if obs.is_empty() {
            return;
        }
        truth.points.insert(
            *pid,
            ObjectPoint {
                id: *pid,
                name,
                kind,
                position: p,
                sigma: (kind == PointKind::Control).then_some(o.control_sigma_m),
                color: [255, 0, 0],
                observations: obs,
            },
        );
        *pid += 1;
    };
    for i in 0..gx {
        for j in 0..gy {
            let x = if gx > 1 {
                i as f64 / (gx - 1) as f64 * x_max
            } else {
                0.5 * x_max
            };
            let y = if gy > 1 {
                j as f64 / (gy - 1) as f64 * y_max
            } else {
                0.5 * y_max
            };
            add_gcp(
                x,
                y,
                PointKind::Control,
                format!("GCP{i}{j}"),
                &mut rng,
                &mut truth,
                &mut pid,
            );
        }
    }
    for k in 0..o.check_points {
        let x = rng.gen_range(0.1 * x_max..0.9 * x_max);
        let y = rng.gen_range(0.0..y_max.max(1.0));
        add_gcp(
            x,
            y,
            PointKind::Check,
            format!("CHK{k}"),
            &mut rng,
            &mut truth,
            &mut pid,
        );
    }
    // Control/check observations carry the true coordinates; the starting block perturbs
    // only the unknowns.
    let mut start = truth.clone();
    let rn = Normal::new(0.0, o.perturb_rotation.max(1e-300)).expect("σ");
    let cn = Normal::new(0.0, o.perturb_center.max(1e-300)).expect("σ");
    let pn = Normal::new(0.0, o.perturb_points.max(1e-300)).expect("σ");
    for p in start.photos.values_mut() {
        let d = Vector3::new(
            rn.sample(&mut rng),
            rn.sample(&mut rng),
            rn.sample(&mut rng),
        );
        let c = Vector3::new(
            cn.sample(&mut rng),
            cn.sample(&mut rng),
            cn.sample(&mut rng),
        );
        p.pose = p.pose.perturbed(&d, &c);
        p.status = crate::block::PhotoStatus::Approximate;
    }
    for p in start.points.values_mut() {
        if p.kind == PointKind::Tie {
            p.position += Vector3::new(
                pn.sample(&mut rng),
                pn.sample(&mut rng),
                pn.sample(&mut rng),
            );
        }
    }
    SyntheticBlock { truth, start }
}

/// Photo centres bucketed on a plan grid of cells as wide as a footprint's reach.
struct CentreIndex {
    cell: f64,
    origin: (f64, f64),
    cols: usize,
    rows: usize,
    buckets: Vec<Vec<usize>>,
}

impl CentreIndex {
    fn new(photos: &[Photo], reach: f64) -> Self {
        let cell = reach.max(1.0);
        let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
        for p in photos {
            let c = p.pose.center;
            (x0, y0, x1, y1) = (x0.min(c.x), y0.min(c.y), x1.max(c.x), y1.max(c.y));
        }
        if photos.is_empty() {
            (x0, y0, x1, y1) = (0.0, 0.0, 0.0, 0.0);
        }
        let cols = ((x1 - x0) / cell).floor() as usize + 1;
        let rows = ((y1 - y0) / cell).floor() as usize + 1;
        let mut buckets = vec![Vec::new(); cols * rows];
        for (k, p) in photos.iter().enumerate() {
            let c = p.pose.center;
            let i = ((c.x - x0) / cell).floor() as usize;
            let j = ((c.y - y0) / cell).floor() as usize;
            buckets[j * cols + i].push(k);
        }
        Self {
            cell,
            origin: (x0, y0),
            cols,
            rows,
            buckets,
        }
    }

    /// Indices, ascending, of the photos whose centre lies within a cell of (x, y)'s: every
    /// photo within `reach` of it, and some beyond.
    fn near(&self, x: f64, y: f64) -> Vec<usize> {
        let fi = ((x - self.origin.0) / self.cell).floor();
        let fj = ((y - self.origin.1) / self.cell).floor();
        let span = |f: f64, n: usize| {
            let lo = (f - 1.0).max(0.0);
            let hi = (f + 1.0).min(n as f64 - 1.0);
            (lo as usize, hi as usize, lo <= hi)
        };
        let (i0, i1, ok_i) = span(fi, self.cols);
        let (j0, j1, ok_j) = span(fj, self.rows);
        let mut out = Vec::new();
        if ok_i && ok_j {
            for j in j0..=j1 {
                for i in i0..=i1 {
                    out.extend_from_slice(&self.buckets[j * self.cols + i]);
                }
            }
        }
        out.sort_unstable();
        out
    }
}
