//! One photo epoch: its camera, flight, rendered images, navigation data for the pipeline,
//! and its truth (exterior orientation, interior orientation, scan affine, fiducials,
//! checkpoint image positions).

use super::checkpoints::CheckpointImage;
use super::film::{self, FilmCameraDef};
use super::flight::{self, FlightGeometry, PlannedPhoto};
use super::render::{self, RayCaster};
use super::{EpochInfo, PosQuality, PresetParams, Scene, SynthConfig, SynthError, ORIGIN};
use crate::formats;
use crate::formats::pos::{FlightAxis, PosRecord, StripEnds};
use crate::geometry::{Brown, Camera, FrameCamera, Pose};
use nalgebra::{Vector2, Vector3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use std::fmt::Write;
use std::path::Path;

#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Kind {
    Frame,
    Film,
}

#[derive(Debug, Clone)]
pub(crate) struct EpochSpec {
    pub name: String,
    pub kind: Kind,
    pub date: String,
    pub gsd: f64,
    pub change: f64,
    /// σ of the navigation data (centre m, attitude rad), or None for strip ends only.
    pub pos_sigma: Option<(f64, f64)>,
}

pub(crate) fn specs(config: &SynthConfig, p: &PresetParams) -> Vec<EpochSpec> {
    let archive_pos = match config.pos {
        PosQuality::Good => Some((1.0, 0.5f64.to_radians())),
        PosQuality::Rough => Some((10.0, 3.0f64.to_radians())),
        PosQuality::None => None,
    };
    // Youngest first: each archive epoch's world is generated from the one before it.
    vec![
        EpochSpec {
            name: "reference_2024".into(),
            kind: Kind::Frame,
            date: "2024-05-29".into(),
            gsd: p.ref_gsd,
            change: 0.0,
            // GNSS/IMU of a current survey flight.
            pos_sigma: Some((0.05, 0.01f64.to_radians())),
        },
        EpochSpec {
            name: "digital_2012".into(),
            kind: Kind::Frame,
            date: "2012-08-14".into(),
            gsd: p.archive_gsd,
            change: config.change,
            pos_sigma: archive_pos,
        },
        EpochSpec {
            name: "film_1978".into(),
            kind: Kind::Film,
            date: "1978-06-06".into(),
            gsd: p.film_gsd,
            change: config.change,
            pos_sigma: archive_pos,
        },
    ]
}

/// The image file of a photo, as the navigation files name it (formats/pos/).
fn image_file(photo: &str) -> String {
    format!("{photo}.png")
}

fn png(path: &Path, data: &[u8], w: u32, h: u32) -> Result<(), SynthError> {
    use image::ImageEncoder;
    let mut buf = Vec::new();
    image::codecs::png::PngEncoder::new_with_quality(
        &mut buf,
        image::codecs::png::CompressionType::Fast,
        image::codecs::png::FilterType::Sub,
    )
    .write_image(data, w, h, image::ExtendedColorType::L8)
    .map_err(|e| SynthError::Image {
        path: path.display().to_string(),
        message: e.to_string(),
    })?;
    formats::write_bytes_atomically(path, &buf)?;
    Ok(())
}

fn json(path: &Path, v: &impl serde::Serialize) -> Result<(), SynthError> {
    let bytes = serde_json::to_vec_pretty(v).expect("serialisable");
    formats::write_bytes_atomically(path, &bytes)?;
    Ok(())
}

/// Intersection of a camera ray with the plane z = `z`.
fn ray_at_height(pose: &Pose, dir_cam: &Vector3<f64>, z: f64) -> Option<[f64; 2]> {
    let d = pose.direction_to_world(dir_cam);
    if d.z >= -1e-6 {
        return None;
    }
    let t = (z - pose.center.z) / d.z;
    Some([pose.center.x + t * d.x, pose.center.y + t * d.y])
}

pub(crate) fn generate_epoch(
    spec: &EpochSpec,
    scene: &Scene,
    config: &SynthConfig,
    p: &PresetParams,
    out: &Path,
    rng: &mut ChaCha8Rng,
) -> Result<(EpochInfo, Vec<CheckpointImage>), SynthError> {
    let edir = out.join("epochs").join(&spec.name);
    let tdir = out.join("truth/epochs").join(&spec.name);
    let (zlo, zhi) = scene.terrain_bounds();
    let mean_ground = 0.5 * (zlo + zhi);
    let film_def = FilmCameraDef::wild_rc10();

    // Camera and flight geometry.
    let (w, h, geo, true_frame, nominal_frame) = match spec.kind {
        Kind::Frame => {
            // The archive was flown with an earlier, smaller digital camera.
            let (w, h, f) = if spec.change > 0.0 {
                (
                    p.frame_size.0 * 2 / 3,
                    p.frame_size.1 * 2 / 3,
                    p.frame_focal_px * 2.0 / 3.0,
                )
            } else {
                (p.frame_size.0, p.frame_size.1, p.frame_focal_px)
            };
            let nominal = FrameCamera::pinhole(w, h, f);
            let truth = if spec.change > 0.0 {
                // An archive camera whose calibration we do not have exactly.
                FrameCamera {
                    fx: f * (1.0 + rng.gen_range(-4e-3..4e-3)),
                    fy: 0.0,
                    cx: w as f64 / 2.0 + rng.gen_range(-3.0..3.0),
                    cy: h as f64 / 2.0 + rng.gen_range(-3.0..3.0),
                    distortion: Brown {
                        k1: rng.gen_range(-0.06..-0.02),
                        k2: rng.gen_range(0.0..0.02),
                        ..Brown::default()
                    },
                    ..nominal.clone()
                }
            } else {
                FrameCamera {
                    distortion: Brown {
                        k1: -0.03,
                        k2: 0.01,
                        p1: 2e-4,
                        p2: -1e-4,
                        ..Brown::default()
                    },
                    ..nominal.clone()
                }
            };
            let truth = FrameCamera {
                fy: if truth.fy == 0.0 { truth.fx } else { truth.fy },
                ..truth
            };
            let geo = FlightGeometry {
                across_m: w as f64 * spec.gsd,
                along_m: h as f64 * spec.gsd,
                forward_overlap: 0.6,
                side_overlap: 0.3,
                height_m: f * spec.gsd,
            };
            let input = if spec.change > 0.0 {
                nominal
            } else {
                truth.clone()
            };
            (w, h, geo, Some(truth), Some(input))
        }
        Kind::Film => {
            let n = ((film_def.format_mm[0] + 10.0) / p.film_scan_mm).round() as u32;
            let format_m = film_def.format_mm[0] * spec.gsd / p.film_scan_mm;
            let geo = FlightGeometry {
                across_m: format_m,
                along_m: format_m,
                forward_overlap: 0.6,
                side_overlap: 0.3,
                height_m: film_def.focal_mm * spec.gsd / p.film_scan_mm,
            };
            (n, n, geo, None, None)
        }
    };
    // At least a stereo pair per strip, even when one photo would cover the area; film
    // at least its preset's layout, centred on the area.
    let (strips, per_strip) = match spec.kind {
        Kind::Frame => (1, 2),
        Kind::Film => p.film_layout,
    };
    let mut plan_area = p.area;
    let spacing = geo.across_m * (1.0 - geo.side_overlap);
    let base = geo.along_m * (1.0 - geo.forward_overlap);
    // Just under the extent that gives that many strips and photos (flight::plan rounds up).
    let need = [
        geo.across_m + (strips as f64 - 1.0 - 1e-6) * spacing,
        geo.along_m + (per_strip as f64 - 1.0 - 1e-6) * base,
    ];
    for (axis, need) in need.into_iter().enumerate() {
        let (lo, hi) = (plan_area[axis], plan_area[axis + 2]);
        if hi - lo < need {
            let c = 0.5 * (lo + hi);
            plan_area[axis] = c - need / 2.0;
            plan_area[axis + 2] = c + need / 2.0;
        }
    }
    let prefix = spec.name.split('_').next().unwrap_or("p");
    let photos: Vec<PlannedPhoto> = flight::plan(plan_area, &geo, mean_ground, prefix, rng);

    // Per-photo cameras (film scans each have their own scanner affine).
    let cameras: Vec<Camera> = photos
        .iter()
        .map(|_| match spec.kind {
            Kind::Frame => Camera::Frame(true_frame.clone().expect("frame camera")),
            Kind::Film => {
                let io = film::random_scan_affine(rng, w, h, p.film_scan_mm);
                Camera::Film(film_def.camera(w, h, io))
            }
        })
        .collect();

    // Ground bounds of all footprints for the height-bound grid.
    let mut bbox = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for (ph, cam) in photos.iter().zip(&cameras) {
        for (c, r) in [
            (0.0, 0.0),
            (w as f64, 0.0),
            (0.0, h as f64),
            (w as f64, h as f64),
        ] {
            let d = cam.unproject([c, r])?;
            for z in [zlo - 5.0, zhi + 40.0] {
                if let Some(q) = ray_at_height(&ph.pose, &d, z) {
                    bbox[0] = bbox[0].min(q[0]);
                    bbox[1] = bbox[1].min(q[1]);
                    bbox[2] = bbox[2].max(q[0]);
                    bbox[3] = bbox[3].max(q[1]);
                }
            }
        }
    }
    let bbox = [
        bbox[0] - 20.0,
        bbox[1] - 20.0,
        bbox[2] + 20.0,
        bbox[3] + 20.0,
    ];
    let caster = RayCaster::new(scene, bbox, 1.0);

    let mut cp_rows = Vec::new();
    let mut eo = String::from(
        "photo,strip,index,x,y,z,omega_deg,phi_deg,kappa_deg,r11,r12,r13,r21,r22,r23,r31,r32,r33\n",
    );
    let mut pos: Vec<PosRecord> = Vec::new();
    let mut affine = String::from("photo,a11,a12,a13,a21,a22,a23\n");
    let mut fids = String::from("photo,fiducial,col,row,x_mm,y_mm\n");
    let nav_name = if spec.pos_sigma.is_some() {
        "pos.csv"
    } else {
        "strips.csv"
    };
    let photo_seed =
        config.seed ^ super::noise::mix(spec.name.len() as u64 * 7 + spec.gsd.to_bits());
    for (k, (ph, cam)) in photos.iter().zip(&cameras).enumerate() {
        // A film scan's frame around the format is painted by `finish_scan`, not seen.
        let radiance = match cam {
            Camera::Film(fc) => film::exposed(fc, &film_def),
            _ => Box::new(|_, _| true),
        };
        let radiance = render::render(&caster, cam, &ph.pose, 1, 0.4, &radiance);
        // Checkpoints visible in this photo (inside the image, not occluded).
        let mut visible = Vec::new();
        for t in &scene.targets {
            let x = Vector3::new(t.center[0], t.center[1], t.center[2]);
            let Ok(px) = cam.project(&ph.pose.to_camera(&x)) else {
                continue;
            };
            let margin = 40.0;
            if px.x < margin
                || px.y < margin
                || px.x > w as f64 - margin
                || px.y > h as f64 - margin
            {
                continue;
            }
            if let Camera::Film(fc) = cam {
                let mm = fc.interior.pixel_to_mm(px);
                if mm.x.abs() > 100.0 || mm.y.abs() > 100.0 {
                    continue;
                }
            }
            let dir = (x - ph.pose.center).normalize();
            let clear = caster
                .cast(&ph.pose.center, &dir)
                .map(|hit| {
                    (hit.point - x).norm() < 0.05 * (x - ph.pose.center).norm() / 100.0 + 0.05
                })
                .unwrap_or(false);
            // The whole disc must be unoccluded: check its rim too.
            let rim_clear = clear
                && (0..8).all(|a| {
                    let ang = a as f64 * std::f64::consts::FRAC_PI_4;
                    let r = super::TARGET_SQUARE_HALF;
                    let q = Vector3::new(
                        x.x + r * ang.cos(),
                        x.y + r * ang.sin(),
                        scene.ground(x.x + r * ang.cos(), x.y + r * ang.sin()),
                    );
                    let d = (q - ph.pose.center).normalize();
                    caster
                        .cast(&ph.pose.center, &d)
                        .map(|hit| (hit.point - q).norm() < 0.1)
                        .unwrap_or(false)
                });
            if rim_clear {
                visible.push([px.x, px.y]);
                cp_rows.push((spec.name.clone(), ph.name.clone(), t.id.clone(), px.x, px.y));
            }
        }
        let seed_k = photo_seed ^ super::noise::mix(k as u64 + 1);
        let bytes = match (spec.kind, cam) {
            (Kind::Film, Camera::Film(fc)) => {
                film::finish_scan(&radiance, fc, &film_def, seed_k, 1.25, 1.3, 5.0, &visible)
            }
            _ => {
                let (gain, offset) = if spec.change > 0.0 {
                    (0.85, 22.0)
                } else {
                    (1.0, 8.0)
                };
                film::finish_digital(&radiance, w, h, seed_k, gain, offset, 1.5)
            }
        };
        drop(radiance);
        png(
            &edir.join("images").join(image_file(&ph.name)),
            &bytes,
            w,
            h,
        )?;

        // Truth.
        let c = ph.pose.center;
        let [o, pphi, kap] = flight::opk_deg(&ph.pose);
        let r = ph.pose.rotation;
        let _ = writeln!(
            eo,
            "{},{},{},{:.4},{:.4},{:.4},{:.6},{:.6},{:.6},{:.9},{:.9},{:.9},{:.9},{:.9},{:.9},{:.9},{:.9},{:.9}",
            ph.name, ph.strip, ph.index,
            c.x + ORIGIN[0], c.y + ORIGIN[1], c.z + ORIGIN[2], o, pphi, kap,
            r[(0, 0)], r[(0, 1)], r[(0, 2)], r[(1, 0)], r[(1, 1)], r[(1, 2)], r[(2, 0)], r[(2, 1)], r[(2, 2)]
        );
        if let Camera::Film(fc) = cam {
            let m = fc.interior.pixel_to_mm;
            let _ = writeln!(
                affine,
                "{},{:.10},{:.10},{:.6},{:.10},{:.10},{:.6}",
                ph.name,
                m[(0, 0)],
                m[(0, 1)],
                m[(0, 2)],
                m[(1, 0)],
                m[(1, 1)],
                m[(1, 2)]
            );
            for f in &film_def.fiducials {
                let px = fc.interior.mm_to_pixel(Vector2::new(f.x_mm, f.y_mm));
                let _ = writeln!(
                    fids,
                    "{},{},{:.4},{:.4},{:.3},{:.3}",
                    ph.name, f.id, px.x, px.y, f.x_mm, f.y_mm
                );
            }
        }
        if let Some((s_xyz, s_att)) = spec.pos_sigma {
            let noisy = flight::noisy_pose(&ph.pose, s_xyz, s_att, rng);
            let (o, pp, kk) = crate::geometry::opk_from_matrix(&noisy.rotation);
            let c = noisy.center;
            pos.push(PosRecord {
                name: image_file(&ph.name),
                center: [c.x + ORIGIN[0], c.y + ORIGIN[1], c.z + ORIGIN[2]],
                opk: [o, pp, kk],
                sigma_xyz: Some(s_xyz),
                sigma_angle: Some(s_att),
            });
        }
        tracing::debug!(epoch = %spec.name, photo = %ph.name, "rendered");
    }
    if spec.pos_sigma.is_none() {
        // Strip ends only, as read from a flight index map (≈ 5 m); the strips are flown
        // with image up along the track.
        let strips: std::collections::BTreeMap<usize, Vec<&PlannedPhoto>> =
            photos.iter().fold(Default::default(), |mut m, ph| {
                m.entry(ph.strip).or_insert_with(Vec::new).push(ph);
                m
            });
        let n = rand_distr::Normal::new(0.0, 5.0).expect("sigma");
        let mut ends = Vec::with_capacity(strips.len());
        for (s, list) in strips {
            let (a, b) = (list[0], list[list.len() - 1]);
            let mut q = |v: f64| v + rand_distr::Distribution::sample(&n, rng);
            let first = [
                q(a.pose.center.x + ORIGIN[0]),
                q(a.pose.center.y + ORIGIN[1]),
                q(a.pose.center.z + ORIGIN[2]),
            ];
            let last = [
                q(b.pose.center.x + ORIGIN[0]),
                q(b.pose.center.y + ORIGIN[1]),
                q(b.pose.center.z + ORIGIN[2]),
            ];
            ends.push(StripEnds {
                name: s.to_string(),
                photos: list.iter().map(|ph| image_file(&ph.name)).collect(),
                first,
                last,
                flight_axis: FlightAxis::MinusY,
            });
        }
        formats::pos::write_strips(&edir.join(nav_name), &ends)?;
    } else {
        formats::pos::write_pos(&edir.join(nav_name), &pos)?;
    }
    formats::write_bytes_atomically(&tdir.join("eo.csv"), eo.as_bytes())?;
    let camera_file = match spec.kind {
        Kind::Frame => {
            json(
                &edir.join("camera.json"),
                &Camera::Frame(nominal_frame.expect("frame")),
            )?;
            json(&tdir.join("camera.json"), &cameras[0])?;
            "camera.json"
        }
        Kind::Film => {
            json(&edir.join("camera.json"), &film_def)?;
            json(&tdir.join("camera.json"), &film_def)?;
            formats::write_bytes_atomically(&tdir.join("scan_affine.csv"), affine.as_bytes())?;
            formats::write_bytes_atomically(&tdir.join("fiducials.csv"), fids.as_bytes())?;
            "camera.json"
        }
    };
    let rel = format!("epochs/{}", spec.name);
    let info = EpochInfo {
        name: spec.name.clone(),
        kind: match spec.kind {
            Kind::Frame => "frame",
            Kind::Film => "film",
        }
        .into(),
        date: spec.date.clone(),
        gsd_m: spec.gsd,
        photos: photos.iter().map(|p| p.name.clone()).collect(),
        image_size: [w, h],
        images_dir: format!("{rel}/images"),
        camera: format!("{rel}/{camera_file}"),
        navigation: format!("{rel}/{nav_name}"),
        scene_change: spec.change,
        truth_dir: format!("truth/epochs/{}", spec.name),
    };
    Ok((info, cp_rows))
}
