//! Synthetic stereo pairs for the dense matching tests and the StereoSGBM bench
//! (benches/dense_sgbm.rs includes this file): two photos of a synthetic scene rendered by
//! ray casting through `synth`'s renderer, and the true disparity of every left rectified
//! pixel from casting its ray into the same scene.
#![allow(dead_code)]

use cloudcontrol::dense::{RectifiedImage, RectifiedPair, Side};
use cloudcontrol::geometry::{Brown, Camera, FrameCamera, Pose};
use cloudcontrol::matching::GreyImage;
use cloudcontrol::synth::{render_photo, RayCaster, Scene};
use nalgebra::Vector3;
use rayon::prelude::*;

/// How a pair is flown.
#[derive(Debug, Clone, Copy)]
pub struct Flight {
    pub seed: u64,
    pub width: u32,
    pub height: u32,
    pub focal_px: f64,
    /// Ground pixel (m) at the mean terrain height.
    pub gsd: f64,
    /// Forward overlap along the image x axis (0–1).
    pub overlap: f64,
    /// Flight azimuth (rad, from the x axis).
    pub azimuth: f64,
    /// Attitude noise (rad) and radial distortion k1 of the camera.
    pub tilt: f64,
    pub k1: f64,
}

impl Flight {
    pub fn new(seed: u64) -> Self {
        Self {
            seed,
            width: 1000,
            height: 750,
            focal_px: 1200.0,
            gsd: 0.1,
            overlap: 0.6,
            azimuth: 0.0,
            tilt: 0.01,
            k1: -0.04,
        }
    }
}

pub struct SyntheticPair {
    pub flight: Flight,
    pub scene: Scene,
    pub camera: Camera,
    pub poses: [Pose; 2],
    pub photos: [GreyImage; 2],
}

fn unit(seed: u64, k: u64) -> f64 {
    let mut z = seed.wrapping_mul(0x9E3779B97F4A7C15) ^ k.wrapping_mul(0xD1B54A32D192ED03);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58476D1CE4E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D049BB133111EB);
    ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
}

/// The scene point a rectified pixel sees, if any.
type ScenePoint = Option<Vector3<f64>>;

/// Renders the pair of `flight`: a scene of its seed around the origin, two photos whose
/// centres lie `(1 − overlap)·width` ground pixels apart along the azimuth.
pub fn render_pair(flight: Flight) -> SyntheticPair {
    let (w, h) = (flight.width as f64, flight.height as f64);
    let flying = flight.gsd * flight.focal_px;
    let base = (1.0 - flight.overlap) * w * flight.gsd;
    let half = 0.5 * (w + base / flight.gsd) * flight.gsd + 20.0;
    let halfy = 0.5 * h * flight.gsd + 20.0;
    let r = half.max(halfy);
    let scene = Scene::generate(flight.seed, [-r, -r, r, r]);
    let (lo, hi) = scene.terrain_bounds();
    let z = 0.5 * (lo + hi) + flying;
    let camera = Camera::Frame(FrameCamera {
        width: flight.width,
        height: flight.height,
        fx: flight.focal_px,
        fy: flight.focal_px,
        cx: w / 2.0 + 2.3,
        cy: h / 2.0 - 1.7,
        distortion: Brown {
            k1: flight.k1,
            k2: 0.0,
            k3: 0.0,
            p1: 1e-4,
            p2: -5e-5,
        },
    });
    let (s, c) = flight.azimuth.sin_cos();
    let t = flight.tilt;
    let pose = |k: u64, sign: f64| {
        // Nadir with image x along the flight (kappa = azimuth), then attitude noise.
        Pose::from_opk(
            t * unit(flight.seed, k),
            t * unit(flight.seed, k + 1),
            flight.azimuth + 3.0 * t * unit(flight.seed, k + 2),
            Vector3::new(
                sign * 0.5 * base * c,
                sign * 0.5 * base * s,
                z + 2.0 * unit(flight.seed, k + 3),
            ),
        )
    };
    let poses = [pose(10, -1.0), pose(20, 1.0)];
    let photos = [0, 1].map(|i| {
        let px = render_photo(&scene, &camera, &poses[i], flight.seed * 7 + i as u64)
            .expect("render the photo");
        GreyImage::new(
            flight.width as usize,
            flight.height as usize,
            px.into_iter().map(f32::from).collect(),
        )
        .expect("photo")
    });
    SyntheticPair {
        flight,
        scene,
        camera,
        poses,
        photos,
    }
}

impl SyntheticPair {
    /// Both photos rendered whole into `pair`'s rectified views (left, right).
    pub fn rectified_images(&self, pair: &RectifiedPair) -> [RectifiedImage; 2] {
        [Side::Left, Side::Right].map(|side| {
            let k = (side == Side::Right) as usize;
            pair.render_rows(side, &self.photos[k], [0, 0], 0..pair.height)
                .unwrap()
        })
    }

    pub fn rectify(&self) -> RectifiedPair {
        RectifiedPair::new(
            (&self.camera, &self.poses[0]),
            (&self.camera, &self.poses[1]),
        )
        .expect("rectify")
    }

    /// A ray caster over the scene.
    pub fn caster(&self) -> RayCaster<'_> {
        let e = self.scene.extent;
        RayCaster::new(
            &self.scene,
            [e[0] - 50.0, e[1] - 50.0, e[2] + 50.0, e[3] + 50.0],
            1.0,
        )
    }

    /// True disparity of every left rectified pixel of the pair (NaN where the ray misses
    /// the scene, the point is hidden from the right photo or outside it), and the true
    /// surface point.
    pub fn truth(&self, pair: &RectifiedPair) -> (Vec<f32>, Vec<Option<Vector3<f64>>>) {
        let caster = self.caster();
        let w = pair.left.width;
        let (sw, sh) = self.camera.image_size();
        let rows: Vec<(Vec<f32>, Vec<ScenePoint>)> = (0..pair.height)
            .into_par_iter()
            .map(|row| {
                let mut d = vec![f32::NAN; w];
                let mut pts = vec![None; w];
                for col in 0..w {
                    let p = [col as f64 + 0.5, row as f64 + 0.5];
                    // Only pixels the left photo covers.
                    let Some(s) = pair.to_source(Side::Left, p) else {
                        continue;
                    };
                    if !(s[0] > 0.5
                        && s[1] > 0.5
                        && s[0] < sw as f64 - 0.5
                        && s[1] < sh as f64 - 0.5)
                    {
                        continue;
                    }
                    let dir = pair.rotation.transpose()
                        * Vector3::new(
                            (p[0] - pair.left.cx) / pair.focal_px,
                            (p[1] - pair.cy) / pair.focal_px,
                            1.0,
                        );
                    let dir = dir.normalize();
                    let Some(hit) = caster.cast(&pair.left.center, &dir) else {
                        continue;
                    };
                    pts[col] = Some(hit.point);
                    // Seen from the right centre?
                    let to = hit.point - pair.right.center;
                    let dist = to.norm();
                    let Some(back) = caster.cast(&pair.right.center, &(to / dist)) else {
                        continue;
                    };
                    if (back.t - dist).abs() > 0.05 {
                        continue;
                    }
                    let Some(q) = pair.project(Side::Right, &hit.point) else {
                        continue;
                    };
                    let Some(sr) = pair.to_source(Side::Right, q) else {
                        continue;
                    };
                    if !(sr[0] > 0.5
                        && sr[1] > 0.5
                        && sr[0] < sw as f64 - 0.5
                        && sr[1] < sh as f64 - 0.5)
                    {
                        continue;
                    }
                    d[col] = (p[0] - q[0]) as f32;
                }
                (d, pts)
            })
            .collect();
        let mut disparity = Vec::with_capacity(w * pair.height);
        let mut points = Vec::with_capacity(w * pair.height);
        for (d, p) in rows {
            disparity.extend(d);
            points.extend(p);
        }
        (disparity, points)
    }
}

/// Disparity range of the scene's height bounds over the left view, widened by 5 m.
pub fn prior_range(sp: &SyntheticPair, pair: &RectifiedPair) -> [f32; 2] {
    let (lo, hi) = sp.scene.terrain_bounds();
    let top = sp.scene.object_top().max(hi);
    let (mut a, mut b) = (f64::INFINITY, f64::NEG_INFINITY);
    for j in 0..=8 {
        for i in 0..=8 {
            let p = [
                pair.left.width as f64 * i as f64 / 8.0,
                pair.height as f64 * j as f64 / 8.0,
            ];
            let dir = pair.rotation.transpose()
                * Vector3::new(
                    (p[0] - pair.left.cx) / pair.focal_px,
                    (p[1] - pair.cy) / pair.focal_px,
                    1.0,
                );
            for z in [lo - 5.0, top + 5.0] {
                let t = (z - pair.left.center.z) / dir.z;
                let (_, d) = pair.disparity_of(&(pair.left.center + dir * t)).unwrap();
                a = a.min(d);
                b = b.max(d);
            }
        }
    }
    [a.floor() as f32, b.ceil() as f32]
}

pub struct Scores {
    /// Of the pixels with a true disparity: share with a disparity.
    pub completeness: f64,
    /// Of the matched pixels with a true disparity: share more than 1 px off.
    pub bad1: f64,
    pub median_abs: f64,
    /// Heights minus the surface away from height edges, in GSD.
    pub height_median: f64,
    pub height_nmad: f64,
    pub height_points: usize,
    /// Per surface class of the true point: (class, pixels with a true disparity,
    /// completeness, share more than 1 px off).
    pub by_class: Vec<(String, usize, f64, f64)>,
}

/// Surface class of each true point ("" without one).
pub fn classes(sp: &SyntheticPair, points: &[Option<Vector3<f64>>]) -> Vec<String> {
    points
        .par_iter()
        .map(|p| {
            p.map(|p| format!("{:?}", sp.scene.class_at(p.x, p.y)))
                .unwrap_or_default()
        })
        .collect()
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

pub fn score(
    sp: &SyntheticPair,
    pair: &RectifiedPair,
    disparity: &[f32],
    truth: &[f32],
    classes: &[String],
) -> Scores {
    let mut by: std::collections::BTreeMap<&str, (usize, usize, usize)> = Default::default();
    for k in 0..truth.len() {
        if !truth[k].is_finite() {
            continue;
        }
        let e = by.entry(classes[k].as_str()).or_default();
        e.0 += 1;
        if disparity[k].is_finite() {
            e.1 += 1;
            e.2 += ((disparity[k] - truth[k]).abs() > 1.0) as usize;
        }
    }
    let by_class = by
        .into_iter()
        .map(|(c, (n, m, b))| {
            (
                c.to_string(),
                n,
                m as f64 / n.max(1) as f64,
                b as f64 / m.max(1) as f64,
            )
        })
        .collect();
    let w = pair.left.width;
    let (mut with_truth, mut matched, mut bad) = (0usize, 0usize, 0usize);
    let mut abs = Vec::new();
    let mut dz = Vec::new();
    let gsd = sp.flight.gsd;
    for (k, (&d, &t)) in disparity.iter().zip(truth).enumerate() {
        if t.is_finite() {
            with_truth += 1;
            if d.is_finite() {
                matched += 1;
                let e = (d - t).abs() as f64;
                bad += (e > 1.0) as usize;
                abs.push(e);
            }
        }
        if !d.is_finite() {
            continue;
        }
        let (col, row) = (k % w, k / w);
        let Some(x) = pair.triangulate([col as f64 + 0.5, row as f64 + 0.5], d as f64) else {
            continue;
        };
        let h = sp.scene.height_at(x.x, x.y);
        // Away from height edges: the surface within 2 GSD stays within 0.5 m.
        let edge = (0..8).any(|a| {
            let (s, c) = (a as f64 * std::f64::consts::FRAC_PI_4).sin_cos();
            (sp.scene.height_at(x.x + 2.0 * gsd * c, x.y + 2.0 * gsd * s) - h).abs() > 0.5
        });
        if !edge {
            dz.push((x.z - h) / gsd);
        }
    }
    let height_points = dz.len();
    let height_median = median(&mut dz);
    let mut dev: Vec<f64> = dz.iter().map(|v| (v - height_median).abs()).collect();
    Scores {
        completeness: matched as f64 / with_truth.max(1) as f64,
        bad1: bad as f64 / matched.max(1) as f64,
        median_abs: median(&mut abs),
        height_median,
        height_nmad: 1.4826 * median(&mut dev),
        height_points,
        by_class,
    }
}
