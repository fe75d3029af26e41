//! Tie points on a synthetic block: two overlapping strips of three photos each,
//! rendered from a textured relief surface through geometry::back_project and
//! Dem::intersect; matches are checked against the true transfer through the surface,
//! with 30 % false candidates injected before the robust relative orientation.

use cloudcontrol::geometry::{
    back_project, project, rotation_from_vector, Camera, Dem, FrameCamera, InteriorOrientation,
    InteriorTransformKind, Pose,
};
use cloudcontrol::matching::ties::{candidates, coverage, relative_orientation, TieCandidate};
use cloudcontrol::matching::{
    forstner, link_tracks, GreyImage, PairPrediction, Pyramid, RobustMethod, TieOptions,
};
use nalgebra::{Matrix3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const W: usize = 360;
const H: usize = 280;

struct Scene {
    dem: Dem,
    camera: Camera,
    poses: Vec<Pose>,
    photos: Vec<GreyImage>,
}

fn ground_texture() -> impl Fn(f64, f64) -> f64 + Sync {
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    let waves: Vec<(f64, f64, f64, f64)> = (0..40)
        .map(|_| {
            let lambda = rng.gen_range(4.0..30.0);
            let th: f64 = rng.gen_range(0.0..std::f64::consts::PI);
            let k = 2.0 * std::f64::consts::PI / lambda;
            (
                k * th.cos(),
                k * th.sin(),
                rng.gen_range(0.0..6.3),
                rng.gen_range(3.0..10.0),
            )
        })
        .collect();
    move |x, y| {
        120.0
            + waves
                .iter()
                .map(|w| w.3 * (w.0 * x + w.1 * y + w.2).sin())
                .sum::<f64>()
    }
}

fn scene() -> Scene {
    // Relief of ±45 m under a 500 m flying height: up to ~15 px of parallax.
    let dem = Dem::from_fn(-400.0, 400.0, 2.0, 600, 400, |x, y| {
        100.0 + 30.0 * (x / 90.0).sin() * (y / 110.0).cos() + 15.0 * (x / 37.0 + y / 53.0).sin()
    })
    .unwrap();
    let camera = Camera::Frame(FrameCamera::pinhole(W as u32, H as u32, 500.0));
    let nadir = Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0));
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut poses = Vec::new();
    // 60 % forward overlap (base 144 m for a 360 m footprint), 40 % side overlap.
    for y in [60.0, -108.0] {
        for k in 0..3 {
            let small = Vector3::new(
                rng.gen_range(-0.01..0.01),
                rng.gen_range(-0.01..0.01),
                rng.gen_range(-0.02..0.02),
            );
            let r = rotation_from_vector(&small) * nadir;
            poses.push(Pose::new(
                r,
                Vector3::new(-144.0 + 144.0 * k as f64, y, 600.0),
            ));
        }
    }
    let tex = ground_texture();
    let photos = poses
        .iter()
        .map(|pose| {
            GreyImage::from_fn(W, H, |x, y| {
                back_project(&camera, pose, [x, y])
                    .and_then(|ray| dem.intersect(&ray))
                    .map(|p| tex(p.x, p.y))
                    .unwrap_or(0.0)
            })
        })
        .collect();
    Scene {
        dem,
        camera,
        poses,
        photos,
    }
}

fn transfer(s: &Scene, a: usize, b: usize, p: [f64; 2]) -> Option<[f64; 2]> {
    let ray = back_project(&s.camera, &s.poses[a], p).ok()?;
    let x = s.dem.intersect(&ray).ok()?;
    let q = project(&s.camera, &s.poses[b], &x).ok()?;
    Some([q.pixel.x, q.pixel.y])
}

/// Plane homography a → b through the mean terrain height (the approximate orientation
/// prediction), estimated from the four image corners.
fn prediction(s: &Scene, a: usize, b: usize) -> PairPrediction {
    let mut pa = Vec::new();
    let mut pb = Vec::new();
    for p in [
        [0.0, 0.0],
        [W as f64, 0.0],
        [0.0, H as f64],
        [W as f64, H as f64],
    ] {
        let ray = back_project(&s.camera, &s.poses[a], p).unwrap();
        let t = (100.0 - ray.origin.z) / ray.direction.z;
        let x = ray.at(t);
        let q = project(&s.camera, &s.poses[b], &x).unwrap();
        pa.push(p);
        pb.push([q.pixel.x, q.pixel.y]);
    }
    // The projective interior-orientation solver is a general 4-point homography.
    let (h, _) =
        InteriorOrientation::estimate(InteriorTransformKind::Projective, &pa, &pb).unwrap();
    PairPrediction {
        a,
        b,
        homography: h.pixel_to_mm,
        search_radius_px: 20.0,
    }
}

#[test]
fn ties_on_a_synthetic_block_survive_30_percent_false_candidates() {
    let s = scene();
    let opts = TieOptions::default();
    let pairs_ab = [
        (0, 1),
        (1, 2),
        (0, 2),
        (3, 4),
        (4, 5),
        (3, 5),
        (0, 3),
        (1, 4),
        (2, 5),
        (0, 4),
        (1, 3),
        (1, 5),
        (2, 4),
    ];
    let preds: Vec<PairPrediction> = pairs_ab
        .iter()
        .map(|&(a, b)| prediction(&s, a, b))
        .collect();
    let pyrs: Vec<Pyramid> = s.photos.iter().map(|p| Pyramid::new(p, 6, 32)).collect();
    let mut rng = ChaCha8Rng::seed_from_u64(99);
    for method in [RobustMethod::Lmeds, RobustMethod::Ransac] {
        let o = TieOptions {
            robust: method,
            ..opts.clone()
        };
        let mut results = Vec::new();
        let (mut good, mut total, mut false_in, mut false_total) = (0usize, 0usize, 0usize, 0usize);
        for pred in &preds {
            let (a, b) = (pred.a, pred.b);
            let pts: Vec<[f64; 2]> = forstner(&s.photos[a], &o.forstner)
                .iter()
                .map(|p| [p.x, p.y])
                .filter(|p| {
                    let q = pred.transfer(*p);
                    q[0] > 0.0 && q[1] > 0.0 && q[0] < W as f64 && q[1] < H as f64
                })
                .collect();
            let mut c = candidates(&s.photos[a], &pyrs[b], pred, &pts, &o);
            let real = c.len();
            // 30 % of the final candidate list are false correspondences.
            let n_false = (real as f64 * 0.3 / 0.7).round() as usize;
            for _ in 0..n_false {
                let p = pts[rng.gen_range(0..pts.len())];
                c.push(TieCandidate {
                    a: p,
                    b: [rng.gen_range(0.0..W as f64), rng.gen_range(0.0..H as f64)],
                    ncc: 0.8,
                    sigma_px: 0.05,
                });
            }
            let pm = relative_orientation(a, b, c, &o).unwrap();
            for (k, (cand, &inl)) in pm.candidates.iter().zip(&pm.inliers).enumerate() {
                if !inl {
                    continue;
                }
                total += 1;
                if k >= real {
                    false_in += 1;
                }
                if let Some(t) = transfer(&s, a, b, cand.a) {
                    if (t[0] - cand.b[0]).hypot(t[1] - cand.b[1]) <= 1.0 {
                        good += 1;
                    }
                }
            }
            false_total += n_false;
            assert!(
                pm.inliers.iter().filter(|&&i| i).count() >= 20,
                "pair {a}-{b}: too few ties"
            );
            results.push(pm);
        }
        let frac = good as f64 / total as f64;
        eprintln!(
            "{method:?}: {total} accepted, {:.1} % within 1 px of truth, {false_in} of {false_total} injected false candidates accepted",
            100.0 * frac
        );
        assert!(
            frac >= 0.95,
            "{method:?}: only {:.1} % within 1 px",
            100.0 * frac
        );
        // Tracks across and within strips, and the standard positions of every photo.
        let tracks = link_tracks(&results, o.merge_px);
        let multi = tracks.iter().filter(|t| t.observations.len() >= 3).count();
        let across = tracks
            .iter()
            .filter(|t| {
                t.observations.iter().any(|o| o.0 < 3) && t.observations.iter().any(|o| o.0 >= 3)
            })
            .count();
        eprintln!(
            "{} tracks, {multi} with ≥ 3 photos, {across} across strips",
            tracks.len()
        );
        assert!(multi >= 20 && across >= 20);
        let sizes = vec![(W, H); 6];
        for cov in coverage(&sizes, &preds, &tracks) {
            assert!(cov.required.iter().filter(|&&r| r).count() >= 4, "{cov:?}");
            assert!(
                cov.missing(1).is_empty(),
                "photo {}: standard positions without points {:?} ({cov:?})",
                cov.photo,
                cov.missing(1)
            );
        }
    }
}

#[test]
fn global_shift_prediction_finds_the_strip_overlap() {
    let s = scene();
    let pa = Pyramid::new(&s.photos[0], 6, 32);
    let pb = Pyramid::new(&s.photos[1], 6, 32);
    let pred = cloudcontrol::matching::predict_shift(&pa, &pb, 0, 1).unwrap();
    // The centre of photo 0 appears about 144 m × 500/500 = 144 px to the left in photo 1.
    let t = transfer(&s, 0, 1, [W as f64 / 2.0, H as f64 / 2.0]).unwrap();
    let q = pred.transfer([W as f64 / 2.0, H as f64 / 2.0]);
    assert!(
        (q[0] - t[0]).abs() < pred.search_radius_px && (q[1] - t[1]).abs() < pred.search_radius_px,
        "{q:?} vs {t:?}"
    );
}

/// End to end from approximate orientations: the block's photos carry EO perturbed by
/// about 2 m and 0.5° (as from a POS), the matcher predicts each Förstner point through
/// that EO and a DEM (or a mean height) into the overlapping photos, searches around
/// the prediction, verifies pairs by robust relative orientation, links tracks and
/// writes tie points into the block. Checked against the true orientations.
#[test]
fn block_ties_from_approximate_orientation() {
    use cloudcontrol::block::{Block, BlockCamera, Photo, PosPrior};
    use cloudcontrol::matching::{block_tie_points, BlockTieOptions, Surface};
    use std::collections::BTreeMap;

    let s = scene();
    let mut rng = ChaCha8Rng::seed_from_u64(2024);
    let mut signed = |m: f64| {
        let v = rng.gen_range(0.5..1.0) * m;
        if rng.gen_bool(0.5) {
            v
        } else {
            -v
        }
    };
    let deg = 0.5f64.to_radians();
    let mut block = Block::new();
    block.cameras.insert(
        1,
        BlockCamera {
            id: 1,
            name: "synthetic".into(),
            model: s.camera.clone(),
            free_params: vec![],
            calibration_group: None,
        },
    );
    let mut images = BTreeMap::new();
    for (k, (pose, img)) in s.poses.iter().zip(&s.photos).enumerate() {
        let dr = Vector3::new(signed(deg), signed(deg), signed(deg));
        let dc = Vector3::new(signed(2.0), signed(2.0), signed(2.0));
        let approx = Pose::new(rotation_from_vector(&dr) * pose.rotation, pose.center + dc);
        let id = k as u32 + 1;
        block.photos.insert(
            id,
            Photo {
                id,
                name: format!("photo_{id}.tif"),
                camera: 1,
                pose: approx,
                status: cloudcontrol::block::PhotoStatus::Approximate,
                prior: Some(PosPrior {
                    center: approx.center,
                    center_sigma: [2.0; 3],
                    rotation: Some(approx.rotation),
                    rotation_sigma_rad: deg,
                }),
                date: None,
                image: None,
                provenance: String::new(),
            },
        );
        images.insert(id, img.clone());
    }
    let surfaces = [
        (
            "DEM",
            Surface::Dem {
                dem: &s.dem,
                origin: Vector3::zeros(),
                sigma_m: 1.0,
            },
        ),
        (
            "mean height",
            Surface::Plane {
                height: 100.0,
                sigma_m: 25.0,
            },
        ),
    ];
    const MIN_PER_POSITION: usize = 3;
    for (label, surface) in surfaces {
        let mut b = block.clone();
        let t0 = std::time::Instant::now();
        let report = block_tie_points(
            &mut b,
            &held(&images),
            &surface,
            MIN_PER_POSITION,
            &BlockTieOptions::default(),
        )
        .unwrap();
        let elapsed = t0.elapsed().as_secs_f64();
        b.validate().unwrap();
        for p in &report.pairs {
            eprintln!(
                "{label}: pair {}–{}: overlap {:.2}, radius {:.1} px, {} points, {} candidates, {} accepted, σ {:.2} px{}",
                p.a, p.b, p.overlap, p.search_radius_px, p.points, p.candidates, p.accepted, p.sigma_px,
                p.skipped.as_deref().map(|r| format!(" (skipped: {r})")).unwrap_or_default()
            );
        }
        // Truth: the object point under the first observation's true ray; every other
        // observation must lie within 1 px of that point's true projection.
        let (mut good, mut total) = (0usize, 0usize);
        for pt in b.points.values() {
            assert_eq!(pt.kind, cloudcontrol::block::PointKind::Tie);
            let o0 = &pt.observations[0];
            let k0 = (o0.photo - 1) as usize;
            let x = s
                .dem
                .intersect(&back_project(&s.camera, &s.poses[k0], o0.pixel).unwrap())
                .unwrap();
            for o in &pt.observations[1..] {
                assert!(o.sigma_px >= 0.25 && o.provenance.contains("approximate EO"));
                let q = project(&s.camera, &s.poses[(o.photo - 1) as usize], &x).unwrap();
                total += 1;
                if (q.pixel.x - o.pixel[0]).hypot(q.pixel.y - o.pixel[1]) <= 1.0 {
                    good += 1;
                }
            }
        }
        let frac = good as f64 / total as f64;
        let triple = |ids: [u32; 3]| {
            b.points
                .values()
                .filter(|p| {
                    ids.iter()
                        .all(|i| p.observations.iter().any(|o| o.photo == *i))
                })
                .count()
        };
        let (t1, t2) = (triple([1, 2, 3]), triple([4, 5, 6]));
        eprintln!(
            "{label}: {} points, {} observations, {:.1} % within 1 px of truth ({good}/{total}), track lengths {:?}, triple-overlap tracks {t1} / {t2}, {elapsed:.2} s",
            report.points_added, report.observations_added, 100.0 * frac, report.track_lengths
        );
        assert!(
            frac >= 0.95,
            "{label}: only {:.1} % within 1 px",
            100.0 * frac
        );
        assert!(report.points_added >= 200, "{label}: {report:?}");
        assert!(
            t1 >= 10 && t2 >= 10,
            "{label}: triple-overlap tracks {t1}, {t2}"
        );
        for c in &report.coverage {
            eprintln!(
                "{label}: photo {} {} observations, counts {:?}, required {:?}",
                c.photo,
                c.observations,
                c.counts,
                c.required.map(|r| r as u8)
            );
            assert!(c.required.iter().filter(|&&r| r).count() >= 6, "{c:?}");
            assert!(
                c.missing.is_empty(),
                "{label}: photo {}: standard positions with fewer than {MIN_PER_POSITION} points: {:?}",
                c.photo,
                c.missing
            );
        }
    }

    // Photos are prepared when their pairs are matched and kept in a cache bounded in
    // bytes: with no room at all (each photo dropped as the next is prepared) the tie
    // points are the same, only prepared more often.
    let surface = surfaces[0].1;
    let (mut a, mut b) = (block.clone(), block.clone());
    let roomy = block_tie_points(
        &mut a,
        &held(&images),
        &surface,
        1,
        &BlockTieOptions::default(),
    )
    .unwrap();
    let tight = BlockTieOptions {
        image_cache_bytes: 0,
        ..BlockTieOptions::default()
    };
    let cramped = block_tie_points(&mut b, &held(&images), &surface, 1, &tight).unwrap();
    assert_eq!(a.points, b.points);
    assert_eq!(roomy.photos_prepared, images.len());
    eprintln!(
        "prepared {} times with no cache room, {} photos",
        cramped.photos_prepared,
        images.len()
    );
    assert!(cramped.photos_prepared > images.len());

    // Each photo's pairs matched on its own, in reverse order, by a "process" with nothing
    // prepared and its result passed through MessagePack (what a reference epoch's `pairs`
    // task does): the same tie points.
    use cloudcontrol::matching::{
        match_photo_pairs, plan_pairs, write_ties, MatchedPairs, PreparedPhotos, TiePhotos,
    };
    let opts = BlockTieOptions::default();
    let mut c = block.clone();
    let pixels = held(&images);
    let tp = TiePhotos::of(&c, &pixels, &opts).unwrap();
    let photos = tp.photos();
    let jobs = plan_pairs(&photos, &surface, &opts);
    let mut matched: Vec<MatchedPairs> = jobs
        .iter()
        .rev()
        .map(|j| {
            let mut own = PreparedPhotos::new(opts.image_cache_bytes);
            let m = match_photo_pairs(&photos, tp.ids(), j, &surface, &opts, &mut own).unwrap();
            rmp_serde::from_slice(&rmp_serde::to_vec_named(&m).unwrap()).unwrap()
        })
        .collect();
    matched.reverse();
    let apart = write_ties(&mut c, &tp, jobs, matched, &surface, 1, &opts);
    assert_eq!(a.points, c.points);
    assert_eq!(apart.tracks, roomy.tracks);
    assert!(apart.photos_prepared > images.len());
}

/// A photo turned by 35° about its axis against its neighbour (a crab angle or a cross
/// strip): NCC alone is not rotation invariant, so the guided search resamples each
/// template into the other photo's geometry from the approximate orientation.
#[test]
fn oriented_ties_handle_a_rotated_photo() {
    use cloudcontrol::matching::{
        oriented_tie_points, BlockTieOptions, OrientedPhoto, Pixels, Surface,
    };

    let s = scene();
    let turn = rotation_from_vector(&Vector3::new(0.0, 0.0, 35f64.to_radians()));
    let rotated = Pose::new(turn * s.poses[1].rotation, s.poses[1].center);
    let tex = ground_texture();
    let img1 = GreyImage::from_fn(W, H, |x, y| {
        back_project(&s.camera, &rotated, [x, y])
            .and_then(|ray| s.dem.intersect(&ray))
            .map(|p| tex(p.x, p.y))
            .unwrap_or(0.0)
    });
    let off = rotation_from_vector(&Vector3::new(0.004, -0.006, 0.005));
    let photos = [
        OrientedPhoto {
            image: Pixels::Held(&s.photos[0]),
            camera: &s.camera,
            pose: Pose::new(
                off * s.poses[0].rotation,
                s.poses[0].center + Vector3::new(1.5, -2.0, 1.0),
            ),
            center_sigma_m: 2.0,
            angle_sigma_rad: 0.5f64.to_radians(),
        },
        OrientedPhoto {
            image: Pixels::Held(&img1),
            camera: &s.camera,
            pose: Pose::new(off.transpose() * rotated.rotation, rotated.center),
            center_sigma_m: 2.0,
            angle_sigma_rad: 0.5f64.to_radians(),
        },
    ];
    let surface = Surface::Dem {
        dem: &s.dem,
        origin: Vector3::zeros(),
        sigma_m: 1.0,
    };
    let r = oriented_tie_points(&photos, &[1, 2], &surface, &BlockTieOptions::default()).unwrap();
    assert_eq!(r.matches.len(), 1, "{:?}", r.reports);
    let pm = &r.matches[0];
    let (mut good, mut total) = (0, 0);
    for c in pm.accepted() {
        let x = s
            .dem
            .intersect(&back_project(&s.camera, &s.poses[0], c.a).unwrap())
            .unwrap();
        let q = project(&s.camera, &rotated, &x).unwrap().pixel;
        total += 1;
        good += ((q.x - c.b[0]).hypot(q.y - c.b[1]) <= 1.0) as usize;
    }
    eprintln!("rotated photo: {good}/{total} within 1 px; {:?}", r.reports);
    assert!(total >= 40 && good as f64 >= 0.95 * total as f64);
}

/// Bad input on the guided path: an image that does not fit its camera and an unknown
/// photo are clear errors; a textureless photo gives pairs skipped with their reason.
#[test]
fn block_ties_bad_input() {
    use cloudcontrol::block::{Block, BlockCamera, Photo};
    use cloudcontrol::matching::{block_tie_points, BlockTieOptions, Surface};
    use std::collections::BTreeMap;

    let s = scene();
    let mut block = Block::new();
    block.cameras.insert(
        1,
        BlockCamera {
            id: 1,
            name: "c".into(),
            model: s.camera.clone(),
            free_params: vec![],
            calibration_group: None,
        },
    );
    for k in 0..2u32 {
        block.photos.insert(
            k + 1,
            Photo {
                id: k + 1,
                name: format!("{k}"),
                camera: 1,
                pose: s.poses[k as usize],
                status: cloudcontrol::block::PhotoStatus::Approximate,
                prior: None,
                date: None,
                image: None,
                provenance: String::new(),
            },
        );
    }
    let surface = Surface::Plane {
        height: 100.0,
        sigma_m: 20.0,
    };
    let opts = BlockTieOptions::default();
    let mut images = BTreeMap::new();
    images.insert(1, s.photos[0].clone());
    images.insert(2, s.photos[1].crop(0, 0, W - 10, H).unwrap());
    let e = block_tie_points(&mut block.clone(), &held(&images), &surface, 1, &opts).unwrap_err();
    assert!(e.to_string().contains("camera is 360×280"), "{e}");
    images.insert(2, GreyImage::filled(W, H, 90.0));
    let r = block_tie_points(&mut block.clone(), &held(&images), &surface, 1, &opts).unwrap();
    assert_eq!(r.points_added, 0);
    let skipped = r.pairs[0].skipped.as_deref().unwrap();
    assert!(skipped.contains("candidates"), "{skipped}");
    images.insert(7, s.photos[2].clone());
    let e = block_tie_points(&mut block.clone(), &held(&images), &surface, 1, &opts).unwrap_err();
    assert!(e.to_string().contains("photo 7"), "{e}");
    images.clear();
    images.insert(1, s.photos[0].clone());
    let e = block_tie_points(&mut block, &held(&images), &surface, 1, &opts).unwrap_err();
    assert!(e.to_string().contains("at least 2"), "{e}");
}

/// The caller's decoded images as the pixels tie matching takes.
fn held(
    images: &std::collections::BTreeMap<u32, GreyImage>,
) -> std::collections::BTreeMap<u32, cloudcontrol::matching::Pixels<'_>> {
    images
        .iter()
        .map(|(k, v)| (*k, cloudcontrol::matching::Pixels::Held(v)))
        .collect()
}
