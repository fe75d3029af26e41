//! The report's tie statistics on a block written by hand: a strip of three nadir photos
//! at 60 % overlap over flat ground, a fourth photo not oriented, tie points on a grid with
//! a gap, one control point, one checkpoint and one tie point left with a single ray.

use cloudcontrol::block::{Block, BlockCamera, ObjectPoint, Observation, Photo, PointKind};
use cloudcontrol::geometry::{self, Camera, FrameCamera, Pose};
use cloudcontrol::pipeline::tie_statistics::{tie_statistics, MIN_PER_POSITION};
use nalgebra::Vector3;
use std::collections::BTreeMap;

/// 1200 × 1200 px, f = 1200 px, 600 m above the ground: 0.5 m pixels, 600 m footprints.
fn camera() -> Camera {
    Camera::Frame(FrameCamera::pinhole(1200, 1200, 1200.0))
}

/// Photos A (x = 0), B (+240 m), C (−240 m) oriented; D (−480 m) not.
fn block() -> Block {
    let mut b = Block::new();
    b.cameras.insert(
        1,
        BlockCamera {
            id: 1,
            name: "c".into(),
            model: camera(),
            free_params: vec![],
            calibration_group: None,
        },
    );
    for (id, (name, x, oriented)) in [
        ("A", 0.0, true),
        ("B", 240.0, true),
        ("C", -240.0, true),
        ("D", -480.0, false),
    ]
    .into_iter()
    .enumerate()
    {
        let mut p = Photo::new(
            id as u32 + 1,
            name,
            1,
            Pose::from_opk(0.0, 0.0, 0.0, Vector3::new(x, 0.0, 600.0)),
        );
        if oriented {
            p = p.oriented();
        }
        b.photos.insert(p.id, p);
    }
    b
}

fn observations(b: &Block, x: &Vector3<f64>) -> Vec<Observation> {
    let cam = camera();
    // As after the adjustment: only oriented photos keep observations.
    b.photos
        .values()
        .filter(|p| p.is_oriented())
        .filter_map(|p| {
            let q = geometry::project(&cam, &p.pose, x).ok()?;
            let inside = q.depth > 0.0
                && (0.0..1200.0).contains(&q.pixel.x)
                && (0.0..1200.0).contains(&q.pixel.y);
            inside.then(|| Observation {
                photo: p.id,
                pixel: [q.pixel.x, q.pixel.y],
                sigma_px: 0.5,
                provenance: String::new(),
            })
        })
        .collect()
}

fn add(b: &mut Block, kind: PointKind, x: Vector3<f64>, obs: Vec<Observation>) {
    let id = b.next_point_id();
    b.points.insert(
        id,
        ObjectPoint {
            id,
            name: String::new(),
            kind,
            position: x,
            sigma: None,
            color: [0; 3],
            observations: obs,
        },
    );
}

#[test]
fn tie_statistics_count_the_adjusted_block_and_find_the_overlaps() {
    let mut b = block();
    // Tie points every 40 m, none where |x − 240| < 100 and y > 100 (a gap in B).
    let mut expected_mult = BTreeMap::new();
    let mut expected_obs: BTreeMap<u32, usize> = BTreeMap::new();
    let (mut points, mut obs_total) = (0, 0);
    for i in -14..=14 {
        for j in -7..=7 {
            let (x, y) = (40.0 * i as f64 + 0.3, 40.0 * j as f64 + 0.3);
            if (x - 240.0).abs() < 100.0 && y > 100.0 {
                continue;
            }
            let xyz = Vector3::new(x, y, 0.0);
            let obs = observations(&b, &xyz);
            if obs.len() >= 2 {
                points += 1;
                obs_total += obs.len();
                *expected_mult.entry(obs.len()).or_insert(0) += 1;
                for o in &obs {
                    *expected_obs.entry(o.photo).or_insert(0) += 1;
                }
                add(&mut b, PointKind::Tie, xyz, obs);
            }
        }
    }
    // Not counted: a tie point with one ray left, a checkpoint. Counted: one control point.
    let lone = observations(&b, &Vector3::new(10.0, 10.0, 0.0));
    add(
        &mut b,
        PointKind::Tie,
        Vector3::new(10.0, 10.0, 0.0),
        lone[..1].to_vec(),
    );
    let c = Vector3::new(20.0, -20.0, 0.0);
    let control_obs = observations(&b, &c);
    add(&mut b, PointKind::Check, c, control_obs.clone());
    assert_eq!(control_obs.len(), 3, "A, B and C see the control point");
    add(&mut b, PointKind::Control, c, control_obs);

    let (stats, photos) = tie_statistics(&b);
    assert_eq!(stats.points, points);
    assert_eq!(stats.observations, obs_total);
    assert_eq!(stats.multiplicity, expected_mult);
    assert_eq!(
        *stats.multiplicity.keys().max().unwrap(),
        3,
        "60 % overlap: three photos at most"
    );
    assert_eq!((stats.control_points, stats.control_observations), (1, 3));
    assert_eq!(stats.min_per_position, MIN_PER_POSITION);
    for (name, id) in [("A", 1), ("B", 2), ("C", 3)] {
        assert_eq!(photos[name].tie_observations, expected_obs[&id], "{name}");
        assert_eq!(photos[name].control_observations, 1, "{name}");
    }

    // Standard positions: ground x of A's columns ±200 and 0; B's 40, 240, 440; C's −40,
    // −240, −440. B's column at 440 m lies in no other photo; C's at −440 m only in D,
    // which is not oriented. Which image column that is follows from the projection.
    let column_of = |photo: u32, x: f64| {
        let p = &b.photos[&photo];
        let px = geometry::project(&camera(), &p.pose, &Vector3::new(x, 0.0, 0.0))
            .unwrap()
            .pixel
            .x;
        ((px / 1200.0) * 3.0).floor() as usize
    };
    assert_eq!(photos["A"].required, [true; 9]);
    for (name, id, x) in [("B", 2, 440.0), ("C", 3, -440.0)] {
        let col = column_of(id, x);
        for k in 0..9 {
            assert_eq!(
                photos[name].required[k],
                k % 3 != col,
                "{name} position {k}"
            );
        }
    }
    assert_eq!(photos["D"].required, [false; 9], "D is not oriented");
    assert_eq!(photos["D"].tie_observations, 0);

    // The gap: B's centre column (x = 240 m) has no tie point at its y > 0 end.
    let row_of_north = {
        let p = &b.photos[&2];
        let py = geometry::project(&camera(), &p.pose, &Vector3::new(240.0, 200.0, 0.0))
            .unwrap()
            .pixel
            .y;
        ((py / 1200.0) * 3.0).floor() as usize
    };
    let gap = row_of_north * 3 + 1;
    assert_eq!(photos["B"].positions[gap], 0);
    assert_eq!(photos["B"].short(), vec![gap]);
    assert!(photos["A"].short().is_empty() && photos["C"].short().is_empty());
    assert_eq!(stats.photos_short, 1);
}
