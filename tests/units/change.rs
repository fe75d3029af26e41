//! Elevation change (src/change/): Nuth & Kääb against a known shift of an analytic
//! terrain, the stable terrain leaving out what changed, and the statistics by hand.

use cloudcontrol::change::{compare_dems, dh_statistics, slope_aspect, ChangeOptions};
use cloudcontrol::geometry::{Dem, GeoTransform};

/// Hills of every aspect: a sum of sines and a cone, smooth at the 1 m cell.
fn terrain(x: f64, y: f64) -> f64 {
    100.0
        + 6.0 * (x / 23.0).sin() * (y / 31.0).cos()
        + 4.0 * ((x + y) / 17.0).sin()
        + 0.02 * ((x - 120.0).powi(2) + (y - 90.0).powi(2)).sqrt()
}

/// A `w × h` grid of 1 m cells from (0, h) of `f`, sampled at cell centres.
fn grid(w: usize, h: usize, cell: f64, f: impl Fn(f64, f64) -> f64) -> Dem {
    let t = GeoTransform::north_up(0.0, h as f64 * cell, cell);
    let data = (0..w * h)
        .map(|i| {
            let (x, y) = t.pixel_to_world((i % w) as f64 + 0.5, (i / w) as f64 + 0.5);
            f(x, y) as f32
        })
        .collect();
    Dem::new(w, h, t, data).unwrap()
}

/// B is A moved by (1.3, −0.7, +0.45) m with a 12 m block built on it: the shift found is
/// the one that moves B back (to 0.05 cells and 1 cm; 0.006 cells measured), the block is
/// not stable terrain, and after the shift dh is zero there (median and NMAD below 1 cm).
#[test]
fn nuth_kaab_finds_a_known_shift_and_the_change_is_not_stable() {
    let (sx, sy, sz) = (1.3, -0.7, 0.45);
    let a = grid(240, 180, 1.0, terrain);
    let building = |x: f64, y: f64| (60.0..90.0).contains(&x) && (40.0..75.0).contains(&y);
    let b = grid(240, 180, 1.0, |x, y| {
        terrain(x - sx, y - sy) + sz + if building(x, y) { 12.0 } else { 0.0 }
    });
    let cmp = compare_dems(&a, &b, &Default::default(), &ChangeOptions::default()).unwrap();
    let nk = &cmp.report.nuth_kaab;
    eprintln!("{nk:?}");
    assert!(nk.converged, "{nk:?}");
    assert!(
        (nk.shift_m[0] + sx).abs() < 0.05 && (nk.shift_m[1] + sy).abs() < 0.05,
        "{nk:?}"
    );
    assert!((nk.shift_m[2] + sz).abs() < 0.01, "{nk:?}");
    // Not one cell of the block's inside is stable.
    let inside = (0..a.data.len()).filter(|&i| {
        let (x, y) = a
            .transform
            .pixel_to_world((i % 240) as f64 + 0.5, (i / 240) as f64 + 0.5);
        building(x - 3.0, y - 3.0) && building(x + 3.0, y + 3.0)
    });
    for i in inside {
        assert!(!cmp.stable[i], "cell {i} of the block is stable");
    }
    let after = &cmp.report.statistics_after_shift;
    assert!(
        after.median_m.abs() < 0.01 && after.nmad_m < 0.01,
        "{after:?}"
    );
    // Before the shift, dh carries it: the median is about sz, the spread the slopes'.
    let before = &cmp.report.statistics;
    assert!(
        (before.median_m - sz).abs() < 0.1 && before.nmad_m > 0.1,
        "{before:?}"
    );
    assert!(!cmp.report.resampled && !cmp.report.shift_applied);
    // No tilt was put in: fitted together with one, the shift is Nuth & Kääb's, and what
    // the tilt finds is the bilinear sampling of curved terrain.
    let joint = cmp
        .report
        .shift_and_tilt
        .as_ref()
        .expect("hills of every aspect");
    assert!(
        (joint.shift_m[0] + sx).abs() < 0.05
            && (joint.shift_m[1] + sy).abs() < 0.05
            && (joint.shift_m[2] + sz).abs() < 0.01,
        "{joint:?}"
    );
    assert!(joint.tilt.max_over_extent_m < 0.05, "{joint:?}");
}

/// One 10 m Gaussian hill (slopes up to 5°, the synthetic blocks' terrain): B is A tilted by
/// 2 m/km east and −1 m/km north about the grid's centre, then moved by `moved`. Nuth &
/// Kääb alone reads the tilt as a shift of metres (4.9 m measured), with a standard error
/// from its bins of a twentieth of that (0.21 m); fitted together, the shift is `moved` to
/// 0.1 m (0.01 m measured) and the tilt is found to 0.1 m/km (0.005).
#[test]
fn a_tilt_is_not_read_as_a_shift_when_fitted_together() {
    let hill = |x: f64, y: f64| {
        let r2 = (x - 150.0).powi(2) + (y - 150.0).powi(2);
        100.0 + 10.0 * (-r2 / (2.0 * 69.0f64.powi(2))).exp()
    };
    let a = grid(300, 300, 1.0, hill);
    for moved in [[0.0, 0.0], [0.8, -0.5]] {
        let b = grid(300, 300, 1.0, |x, y| {
            hill(x - moved[0], y - moved[1]) + 2e-3 * (x - 150.0) - 1e-3 * (y - 150.0)
        });
        let cmp = compare_dems(&a, &b, &Default::default(), &ChangeOptions::default()).unwrap();
        let nk = &cmp.report.nuth_kaab;
        let joint = cmp
            .report
            .shift_and_tilt
            .as_ref()
            .expect("a hill of every aspect");
        eprintln!("moved {moved:?}: {nk:?}\n{joint:?}");
        let nk_error = (nk.shift_m[0] + moved[0]).hypot(nk.shift_m[1] + moved[1]);
        assert!(nk_error > 1.0, "Nuth & Kääb alone: {nk:?}");
        assert!(
            nk.sigma_m[0].max(nk.sigma_m[1]) < 0.2 * nk_error,
            "the bins' standard error understates the misreading: {nk:?}"
        );
        let joint_error = (joint.shift_m[0] + moved[0]).hypot(joint.shift_m[1] + moved[1]);
        assert!(joint_error < 0.1, "{joint:?}");
        assert!(
            (joint.tilt.east_m_per_km - 2.0).abs() < 0.1
                && (joint.tilt.north_m_per_km + 1.0).abs() < 0.1,
            "{joint:?}"
        );
        // The up part is the tilted B's level at the grid's centre: no offset was put in.
        assert!(joint.shift_m[2].abs() < 0.02, "{joint:?}");
        assert!(joint.sigma_m.iter().all(|v| v.is_finite()), "{joint:?}");
        assert_eq!(joint.blocks, 16);
    }
}

/// The statistics of a hand-made dh: median, NMAD, mean, std, quantiles as numpy gives.
#[test]
fn statistics_of_a_hand_made_difference() {
    let a = grid(4, 2, 1.0, |_, _| 0.0);
    let terrain = slope_aspect(&a);
    let dh = [1.0, -2.0, 3.0, 0.5, f64::NAN, 10.0, -1.0, 0.0];
    let mask = [true, true, true, true, true, false, true, true];
    let s = dh_statistics(&dh, &mask, &terrain);
    // Values: -2, -1, 0, 0.5, 1, 3.
    assert_eq!(s.cells, 6);
    assert!((s.median_m - 0.25).abs() < 1e-12);
    // |v − 0.25|: 2.25, 1.25, 0.25, 0.25, 0.75, 2.75 → median 1.0.
    assert!((s.nmad_m - 1.4826).abs() < 1e-12);
    assert!((s.mean_m - 1.5 / 6.0).abs() < 1e-12);
    let var = [-2.0f64, -1.0, 0.0, 0.5, 1.0, 3.0]
        .iter()
        .map(|v| (v - 0.25).powi(2))
        .sum::<f64>()
        / 6.0;
    assert!((s.std_m - var.sqrt()).abs() < 1e-12);
    // numpy.quantile(values, 0.16) = -2 + ... linear: position 0.8 → -2 + 0.8 = -1.2.
    assert!(
        (s.quantiles_m[1] + 1.2).abs() < 1e-12,
        "{:?}",
        s.quantiles_m
    );
    // Flat terrain: every cell in the first slope class.
    assert_eq!(s.by_slope[0].cells, 6);
}

/// Slope and aspect of a plane rising to the east at 10 %: tan 0.1, aspect 90°.
#[test]
fn slope_and_aspect_of_a_plane() {
    let a = grid(6, 5, 2.0, |x, _| 0.1 * x);
    let t = slope_aspect(&a);
    for i in 0..30 {
        assert!((t.slope_tan[i] - 0.1).abs() < 1e-6);
        assert!((t.aspect[i].to_degrees() - 90.0).abs() < 1e-4);
    }
    let n = grid(6, 5, 2.0, |_, y| 0.2 * y);
    let t = slope_aspect(&n);
    assert!(
        t.aspect[7].to_degrees().abs() < 1e-4 || (t.aspect[7].to_degrees() - 360.0).abs() < 1e-4
    );
}

/// Changed areas by hand: a 6 × 5 block raised 3 m with a 2 × 1 hole, a 2-cell bump below
/// the least area, and noise below the least dh. One area: 28 cells, its outline the
/// block's 22-corner boundary walked counter-clockwise, the hole's clockwise; its volume
/// 28 × 3 m³.
#[test]
fn changed_areas_by_hand() {
    let (w, h) = (12, 10);
    let grid = grid(w, h, 1.0, |_, _| 0.0);
    let mut dh = vec![0.0; w * h];
    for (i, v) in dh.iter_mut().enumerate() {
        *v = 0.01 * ((i * 7919) % 13) as f64 - 0.06;
    }
    for r in 2..7 {
        for c in 3..9 {
            dh[r * w + c] = 3.0;
        }
    }
    dh[4 * w + 5] = 0.0;
    dh[4 * w + 6] = 0.0;
    dh[9 * w] = -2.0;
    dh[9 * w + 1] = -2.0;
    let opts = cloudcontrol::change::AreaOptions {
        min_area_m2: 4.0,
        ..Default::default()
    };
    let areas = cloudcontrol::change::changed_areas(&dh, &grid, (0.0, 0.05), None, &opts).unwrap();
    assert_eq!(areas.len(), 1, "{areas:?}");
    let a = &areas[0];
    assert_eq!(a.cells, 28);
    assert!((a.area_m2 - 28.0).abs() < 1e-9 && (a.volume_m3 - 84.0).abs() < 1e-9);
    assert_eq!(a.rings.len(), 2);
    let signed = |ring: &[[f64; 2]]| {
        ring.windows(2)
            .map(|p| p[0][0] * p[1][1] - p[1][0] * p[0][1])
            .sum::<f64>()
            / 2.0
    };
    // Outer ring: the 6 × 5 block, counter-clockwise; hole: 2 × 1, clockwise.
    assert!(
        (signed(&a.rings[0]) - 30.0).abs() < 1e-9,
        "{:?}",
        a.rings[0]
    );
    assert!((signed(&a.rings[1]) + 2.0).abs() < 1e-9, "{:?}", a.rings[1]);
    assert_eq!(a.rings[0].first(), a.rings[0].last());
    // Corners of the block in world coordinates (grid origin (0, 10), 1 m cells).
    let xs: Vec<f64> = a.rings[0].iter().map(|p| p[0]).collect();
    let ys: Vec<f64> = a.rings[0].iter().map(|p| p[1]).collect();
    assert_eq!(xs.iter().cloned().fold(f64::MAX, f64::min), 3.0);
    assert_eq!(xs.iter().cloned().fold(f64::MIN, f64::max), 9.0);
    assert_eq!(ys.iter().cloned().fold(f64::MAX, f64::min), 3.0);
    assert_eq!(ys.iter().cloned().fold(f64::MIN, f64::max), 8.0);
    // Two members touching only at a corner stay two areas (4-neighbours).
    let mut diag = vec![0.0; w * h];
    for (r, c) in [(1, 1), (2, 2)] {
        diag[r * w + c] = 5.0;
    }
    let one = cloudcontrol::change::AreaOptions {
        min_area_m2: 1.0,
        ..Default::default()
    };
    let d = cloudcontrol::change::changed_areas(&diag, &grid, (0.0, 0.05), None, &one).unwrap();
    assert_eq!(d.len(), 2);
    assert!(d
        .iter()
        .all(|a| a.rings.len() == 1 && a.rings[0].len() == 5));
}

/// The level of detection cell by cell: two 3 m steps of 36 cells, one on cells whose own
/// σ is 0.1 m, one on cells whose σ is 1.5 m (a fused DSM's pairs disagreeing there).
/// 3 m exceeds 3·sqrt(0.05² + 0.1²) but not 3·sqrt(0.05² + 1.5²): only the first is a
/// changed area, and a σ of NaN (unknown) counts as none.
#[test]
fn changed_areas_against_each_cells_sigma() {
    let (w, h) = (20, 8);
    let grid = grid(w, h, 1.0, |_, _| 0.0);
    let mut dh = vec![0.0; w * h];
    let mut sigma = vec![f64::NAN; w * h];
    for r in 1..7 {
        for c in 1..7 {
            dh[r * w + c] = 3.0;
            sigma[r * w + c] = 0.1;
        }
        for c in 11..17 {
            dh[r * w + c] = 3.0;
            sigma[r * w + c] = 1.5;
        }
    }
    let opts = cloudcontrol::change::AreaOptions {
        min_area_m2: 4.0,
        ..Default::default()
    };
    let areas =
        cloudcontrol::change::changed_areas(&dh, &grid, (0.0, 0.05), Some(&sigma), &opts).unwrap();
    assert_eq!(areas.len(), 1, "{areas:?}");
    let xs: Vec<f64> = areas[0].rings[0].iter().map(|p| p[0]).collect();
    assert_eq!(xs.iter().cloned().fold(f64::MAX, f64::min), 1.0);
    assert_eq!(areas[0].cells, 36);
    let without =
        cloudcontrol::change::changed_areas(&dh, &grid, (0.0, 0.05), None, &opts).unwrap();
    assert_eq!(without.len(), 2);
    let short =
        cloudcontrol::change::changed_areas(&dh, &grid, (0.0, 0.05), Some(&sigma[1..]), &opts);
    assert!(short.is_err());
}
