//! The order in which a first round searches its patches: every prefix spread over the
//! photo.

use cloudcontrol::control::orient::spread_order;
use nalgebra::Vector2;

fn grid(n: usize, size: f64) -> Vec<Vector2<f64>> {
    let step = size / n as f64;
    (0..n * n)
        .map(|k| Vector2::new((k % n) as f64 * step + 1.0, (k / n) as f64 * step + 1.0))
        .collect()
}

fn cells(order: &[usize], pixels: &[Vector2<f64>], side: usize, size: f64) -> usize {
    let c = size / side as f64;
    let set: std::collections::BTreeSet<(usize, usize)> = order
        .iter()
        .map(|&k| ((pixels[k].x / c) as usize, (pixels[k].y / c) as usize))
        .collect();
    set.len()
}

#[test]
fn every_position_comes_once() {
    let px = grid(37, 1000.0);
    let mut o = spread_order(&px, 1000.0, 1000.0);
    assert_eq!(o.len(), px.len());
    o.sort_unstable();
    assert!(o.iter().enumerate().all(|(i, &k)| i == k));
    assert!(spread_order(&[], 10.0, 10.0).is_empty());
}

#[test]
fn each_level_covers_its_grid_and_a_cut_level_is_spread() {
    let size = 4000.0;
    let px = grid(40, size);
    let o = spread_order(&px, size, size);
    // Levels 1 × 1, 2 × 2 and 4 × 4 come first, complete.
    assert_eq!(cells(&o[1..5], &px, 2, size), 4);
    assert_eq!(cells(&o[5..21], &px, 4, size), 16);
    assert_eq!(cells(&o[21..85], &px, 8, size), 64);
    // The first quarter of the 16 × 16 level already touches most of the 4 × 4 cells.
    assert!(cells(&o[85..149], &px, 4, size) >= 14);
    // The first position is the one nearest the centre.
    let c = Vector2::new(size / 2.0, size / 2.0);
    let nearest = (0..px.len())
        .min_by(|&a, &b| (px[a] - c).norm().total_cmp(&(px[b] - c).norm()))
        .unwrap();
    assert_eq!(o[0], nearest);
}

#[test]
fn clustered_positions_and_positions_outside_keep_their_place() {
    // A cluster in one corner and a few points elsewhere: the few come early.
    let mut px: Vec<Vector2<f64>> = (0..500)
        .map(|k| Vector2::new(10.0 + (k % 25) as f64, 10.0 + (k / 25) as f64))
        .collect();
    px.extend([
        Vector2::new(900.0, 900.0),
        Vector2::new(100.0, 900.0),
        Vector2::new(900.0, 100.0),
        Vector2::new(-5.0, 2000.0),
    ]);
    let o = spread_order(&px, 1000.0, 1000.0);
    assert_eq!(o.len(), px.len());
    let early: Vec<usize> = o[..12].to_vec();
    for k in 500..504 {
        assert!(early.contains(&k), "{k} not in {early:?}");
    }
}
