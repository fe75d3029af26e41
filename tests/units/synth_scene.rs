//! Unit tests of `synth::scene`.

use cloudcontrol::synth::render::RayCaster;
use cloudcontrol::synth::scene::*;
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
fn change_steps_nest_back_in_time() {
    // reference → one step back → two steps back, each step re-texturing half the world.
    let s0 = Scene::generate(3, EXTENT);
    let s1 = s0.changed(0.5, 1);
    let s2 = s1.changed(0.5, 2);
    let (mut same_01, mut same_02, mut same_12, mut n) = (0, 0, 0, 0);
    for i in -20..20 {
        for j in -20..20 {
            let [h0, h1, h2] = [&s0, &s1, &s2].map(|s| s.salt_for(0xF1E1D, i, j).0);
            n += 1;
            same_01 += (h0 == h1) as usize;
            same_02 += (h0 == h2) as usize;
            same_12 += (h1 == h2) as usize;
            // What the oldest scene shares with today, the younger one shares too.
            assert!(h0 != h2 || h0 == h1, "parcel {i},{j}");
        }
    }
    let f = |k: usize| k as f64 / n as f64;
    // Each step keeps half; two steps keep a quarter.
    assert!((f(same_01) - 0.5).abs() < 0.06, "{}", f(same_01));
    assert!((f(same_12) - 0.5).abs() < 0.06, "{}", f(same_12));
    assert!((f(same_02) - 0.25).abs() < 0.06, "{}", f(same_02));
    // Buildings: none of today's that the older scene has is missing from the younger
    // one, and the ids stay unique.
    let ids = |s: &Scene| s.buildings.iter().map(|b| b.id).collect::<Vec<_>>();
    let (i0, i1, i2) = (ids(&s0), ids(&s1), ids(&s2));
    assert!(i2
        .iter()
        .filter(|id| i0.contains(id))
        .all(|id| i1.contains(id)));
    let mut u = i2.clone();
    u.sort_unstable();
    u.dedup();
    assert_eq!(u.len(), i2.len());
}

#[test]
fn render_photo_shows_a_target_where_it_projects() {
    use cloudcontrol::geometry::{Camera, FrameCamera, Pose};
    let s = Scene::generate(3, EXTENT);
    let t = &s.targets[0];
    let cam = Camera::Frame(FrameCamera::pinhole(200, 160, 900.0));
    let pose = Pose::from_opk(
        0.01,
        -0.02,
        0.3,
        Vector3::new(t.center[0] + 3.0, t.center[1] - 2.0, t.center[2] + 90.0),
    );
    let img = cloudcontrol::synth::render_photo(&s, &cam, &pose, 1).unwrap();
    assert_eq!(
        img,
        cloudcontrol::synth::render_photo(&s, &cam, &pose, 1).unwrap()
    );
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
