//! Metric film cameras and their scans: the calibration-certificate JSON (the project's
//! film camera definition), the scanner's pixel→mm affine, fiducial marks rendered into
//! the scan, and the film look (grain, vignetting, dust, gamma and contrast).

use super::noise::{gauss, hash3, unit};
use crate::geometry::{Brown, FilmCamera, InteriorOrientation};
use nalgebra::Vector2;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Shape of a fiducial mark, in the fiducial system (mm).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FiducialShape {
    /// `cross`, `circle` (filled disc), `ring` or `dot`.
    #[serde(rename = "type")]
    pub kind: String,
    /// Overall size: cross arm span, disc/ring outer diameter (mm).
    pub size_mm: f64,
    /// Line width of a cross or ring (mm).
    pub line_mm: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Fiducial {
    pub id: String,
    pub x_mm: f64,
    pub y_mm: f64,
    pub shape: FiducialShape,
}

/// Film camera definition (calibration certificate), the schema fixed by the lead:
/// fiducial coordinates in the fiducial system (x right, y up, mm).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FilmCameraDef {
    pub name: String,
    pub source: String,
    pub focal_mm: f64,
    pub principal_point_mm: [f64; 2],
    pub format_mm: [f64; 2],
    pub distortion: Brown,
    pub fiducials: Vec<Fiducial>,
}

impl FilmCameraDef {
    /// Wild RC10 / Universal Aviogon serial 1945 as calibrated by the USGS in 1978
    /// (report RT-R/427): calibrated focal length, point of symmetry and the eight
    /// fiducials. The certificate's radial distortion (within ±8 µm) is below the scan
    /// pixel and is left at zero.
    pub fn wild_rc10() -> Self {
        let corner = |id: &str, x: f64, y: f64| Fiducial {
            id: id.into(),
            x_mm: x,
            y_mm: y,
            shape: FiducialShape {
                kind: "cross".into(),
                size_mm: 3.0,
                line_mm: 0.2,
            },
        };
        let side = |id: &str, x: f64, y: f64| Fiducial {
            id: id.into(),
            x_mm: x,
            y_mm: y,
            shape: FiducialShape {
                kind: "dot".into(),
                size_mm: 1.0,
                line_mm: 0.0,
            },
        };
        Self {
            name: "Wild RC10 UAg I 6020".into(),
            source: "USGS Report of Calibration RT-R/427 (1978), camera 1945; shapes synthetic"
                .into(),
            focal_mm: 152.865,
            principal_point_mm: [-0.030, -0.001],
            format_mm: [230.0, 230.0],
            distortion: Brown::default(),
            fiducials: vec![
                corner("1", -105.983, -106.005),
                corner("2", 105.996, 106.006),
                corner("3", -105.998, 105.985),
                corner("4", 106.001, -106.005),
                side("5", -110.004, -0.009),
                side("6", 110.013, 0.024),
                side("7", -0.003, 109.999),
                side("8", 0.009, -109.992),
            ],
        }
    }

    /// The film camera of one scan with the scanner affine `interior`.
    pub fn camera(&self, width: u32, height: u32, interior: InteriorOrientation) -> FilmCamera {
        FilmCamera {
            width,
            height,
            focal_mm: self.focal_mm,
            principal_point_mm: self.principal_point_mm,
            distortion: self.distortion,
            interior,
        }
    }
}

/// A scanner's pixel→mm affine: nominal pixel `pixel_mm`, scale differences in x and y,
/// shear and a rotation of the film on the platen, and the frame centre off the scan centre.
pub fn random_scan_affine(
    rng: &mut ChaCha8Rng,
    width: u32,
    height: u32,
    pixel_mm: f64,
) -> InteriorOrientation {
    let sx = pixel_mm * (1.0 + rng.gen_range(-2e-3..2e-3));
    let sy = pixel_mm * (1.0 + rng.gen_range(-2e-3..2e-3));
    let shear = rng.gen_range(-1e-3..1e-3);
    let rot: f64 = rng.gen_range(-0.6f64..0.6).to_radians();
    let (s, c) = rot.sin_cos();
    // mm = R(rot) · [[sx, shear·sx], [0, −sy]] · (col, row) + t  (rows run down, y up).
    let a = nalgebra::Matrix2::new(c, -s, s, c) * nalgebra::Matrix2::new(sx, shear * sx, 0.0, -sy);
    let centre = Vector2::new(width as f64 / 2.0, height as f64 / 2.0);
    let shift = Vector2::new(rng.gen_range(-1.5..1.5), rng.gen_range(-1.5..1.5));
    let t = shift - a * centre;
    InteriorOrientation::affine(&a, &t).expect("scan affine is regular")
}

/// Coverage of a fiducial mark at a point `(dx, dy)` mm from its centre (0/1 test; the
/// caller supersamples).
fn inside_mark(shape: &FiducialShape, dx: f64, dy: f64) -> bool {
    let r = dx.hypot(dy);
    match shape.kind.as_str() {
        "cross" => {
            let h = shape.size_mm / 2.0;
            let l = shape.line_mm / 2.0;
            (dx.abs() <= l && dy.abs() <= h) || (dy.abs() <= l && dx.abs() <= h)
        }
        "ring" => (r - (shape.size_mm - shape.line_mm) / 2.0).abs() <= shape.line_mm / 2.0,
        _ => r <= shape.size_mm / 2.0,
    }
}

/// Radius of the dark field around each fiducial (mm): the mark sits in the opaque frame.
pub const FIDUCIAL_FIELD_MM: f64 = 5.0;
/// Grey levels of the opaque frame and of a fiducial mark.
const FRAME_DN: f64 = 18.0;
const MARK_DN: f64 = 225.0;

/// Turns scene radiance on a film scan into the 8-bit scan: photographic area with
/// vignetting, gamma/contrast of the emulsion and development, grain and dust; the opaque
/// frame outside the format; fiducial marks anti-aliased by 8×8 supersampling.
/// `keep_clear` lists pixel positions (e.g. checkpoint targets) that dust must not cover.
#[allow(clippy::too_many_arguments)]
pub fn finish_scan(
    radiance: &[f32],
    camera: &FilmCamera,
    def: &FilmCameraDef,
    seed: u64,
    gamma: f64,
    contrast: f64,
    grain: f64,
    keep_clear: &[[f64; 2]],
) -> Vec<u8> {
    use rayon::prelude::*;
    let (w, h) = (camera.width as usize, camera.height as usize);
    let io = &camera.interior;
    let half = format_half(def);
    let fid_px: Vec<Vector2<f64>> = def
        .fiducials
        .iter()
        .map(|f| io.mm_to_pixel(Vector2::new(f.x_mm, f.y_mm)))
        .collect();
    let pixel_mm = io.mean_pixel_size_mm();
    let field_px = FIDUCIAL_FIELD_MM / pixel_mm + 2.0;
    // Dust: a few specks and hairs, kept off the fiducial fields and the listed targets.
    let mut dust = Vec::new();
    let mut k = 0u64;
    while dust.len() < 25 && k < 500 {
        let hx = hash3(seed ^ 0xD057, k as i64, 0);
        k += 1;
        let p = [unit(hx) * w as f64, unit(hash3(hx, 1, 1)) * h as f64];
        let r = 1.0 + 3.0 * unit(hash3(hx, 2, 2));
        let clear = fid_px
            .iter()
            .all(|f| (f.x - p[0]).hypot(f.y - p[1]) > field_px + r + 2.0)
            && keep_clear
                .iter()
                .all(|c| (c[0] - p[0]).hypot(c[1] - p[1]) > 40.0 + r);
        if clear {
            dust.push((p, r, unit(hash3(hx, 3, 3)) < 0.5));
        }
    }
    // The emulsion's gamma from a table (linear between 4097 nodes: < 0.002 DN from
    // powf): libm's pow per pixel was a twentieth of a 42 µm film epoch's synthesis.
    const GAMMA_NODES: usize = 4096;
    let gamma_table: Vec<f64> = (0..=GAMMA_NODES)
        .map(|i| (i as f64 / GAMMA_NODES as f64).powf(gamma))
        .collect();
    let emulsion = |e: f64| {
        let x = e * GAMMA_NODES as f64;
        let i = (x as usize).min(GAMMA_NODES - 1);
        gamma_table[i] + (x - i as f64) * (gamma_table[i + 1] - gamma_table[i])
    };
    let centre = io.mm_to_pixel(Vector2::new(0.0, 0.0));
    let diag = (def.format_mm[0].hypot(def.format_mm[1]) / 2.0) / pixel_mm;
    (0..h)
        .into_par_iter()
        .flat_map_iter(|row| {
            // The fiducials and specks a row can meet, in their order (the first mark
            // near a pixel is its mark, a later speck covers an earlier one): per pixel,
            // all eight fields and 25 specks were a seventh of the small preset's synthesis.
            let y = row as f64 + 0.5;
            let fields: Vec<usize> = (0..fid_px.len())
                .filter(|&i| (fid_px[i].y - y).abs() <= field_px)
                .collect();
            let specks: Vec<_> = dust
                .iter()
                .filter(|(c, rad, _)| (c[1] - y).abs() < *rad)
                .collect();
            let mut out = Vec::with_capacity(w);
            for col in 0..w {
                let p = Vector2::new(col as f64 + 0.5, y);
                let mm = io.pixel_to_mm(p);
                let near = fields
                    .iter()
                    .copied()
                    .find(|&i| (fid_px[i] - p).norm() <= field_px);
                let v = if let Some(fi) = near {
                    let f = &def.fiducials[fi];
                    let dmm = Vector2::new(mm.x - f.x_mm, mm.y - f.y_mm).norm();
                    if dmm > FIDUCIAL_FIELD_MM && inside(mm, half) {
                        None
                    } else {
                        let mut cov = 0.0;
                        for sy in 0..8 {
                            for sx in 0..8 {
                                let q = Vector2::new(
                                    col as f64 + (sx as f64 + 0.5) / 8.0,
                                    row as f64 + (sy as f64 + 0.5) / 8.0,
                                );
                                let m = io.pixel_to_mm(q);
                                if inside_mark(&f.shape, m.x - f.x_mm, m.y - f.y_mm) {
                                    cov += 1.0;
                                }
                            }
                        }
                        Some(FRAME_DN + (MARK_DN - FRAME_DN) * cov / 64.0)
                    }
                } else if !inside(mm, half) {
                    Some(FRAME_DN)
                } else {
                    None
                };
                let hsh = hash3(seed, col as i64, row as i64);
                let value = match v {
                    Some(v) => v + 1.5 * gauss(hsh),
                    None => {
                        let r = (p - centre).norm() / diag;
                        // Lens fall-off (cos⁴ of the field angle, partly compensated by the
                        // anti-vignetting filter).
                        let vign = 1.0 - 0.35 * r * r;
                        let mut e = radiance[row * w + col] as f64 * vign;
                        e = emulsion((contrast * (e - 0.5) + 0.5).clamp(0.0, 1.0));
                        let mut dn = 12.0 + 235.0 * e + grain * gauss(hsh);
                        for (c, rad, dark) in specks.iter().copied() {
                            // Squared distances: libm's hypot here, 25 specks per pixel,
                            // was a tenth of a 42 µm film block's synthesis time.
                            let (dx, dy) = (c[0] - p.x, c[1] - p.y);
                            if dx * dx + dy * dy < rad * rad {
                                dn = if *dark { dn * 0.3 } else { 240.0 };
                            }
                        }
                        dn
                    }
                };
                out.push(value.round().clamp(0.0, 255.0) as u8);
            }
            out
        })
        .collect()
}

/// Whether a scan pixel (column, row) shows the scene: inside the format, where
/// [`finish_scan`] reads the radiance; the frame around it is film base and marks.
pub fn exposed(camera: &FilmCamera, def: &FilmCameraDef) -> Box<dyn Fn(u32, u32) -> bool + Sync> {
    let io = camera.interior.clone();
    let half = format_half(def);
    Box::new(move |col, row| {
        inside(
            io.pixel_to_mm(Vector2::new(col as f64 + 0.5, row as f64 + 0.5)),
            half,
        )
    })
}

/// Half the exposed format (mm): a millimetre inside the frame's edge.
fn format_half(def: &FilmCameraDef) -> [f64; 2] {
    [def.format_mm[0] / 2.0 - 1.0, def.format_mm[1] / 2.0 - 1.0]
}

/// Whether a point of the film (mm) lies inside the exposed format of half size `half`.
fn inside(mm: Vector2<f64>, half: [f64; 2]) -> bool {
    mm.x.abs() < half[0] && mm.y.abs() < half[1]
}

/// Digital sensor output: exposure, gain, vignetting and shot/read noise, 8-bit.
pub fn finish_digital(
    radiance: &[f32],
    width: u32,
    height: u32,
    seed: u64,
    gain: f64,
    offset: f64,
    noise_dn: f64,
) -> Vec<u8> {
    use rayon::prelude::*;
    let (w, h) = (width as usize, height as usize);
    let diag = (w as f64).hypot(h as f64) / 2.0;
    (0..h)
        .into_par_iter()
        .flat_map_iter(|row| {
            (0..w).map(move |col| {
                let r = (col as f64 + 0.5 - w as f64 / 2.0)
                    .hypot(row as f64 + 0.5 - h as f64 / 2.0)
                    / diag;
                let e = radiance[row * w + col] as f64 * (1.0 - 0.12 * r * r);
                let dn = offset
                    + gain * 255.0 * e
                    + noise_dn * gauss(hash3(seed, col as i64, row as i64));
                dn.round().clamp(0.0, 255.0) as u8
            })
        })
        .collect()
}
