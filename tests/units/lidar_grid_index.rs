//! Unit tests of `lidar::grid_index`.

mod tests {
    use cloudcontrol::lidar::grid_index::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn matches_brute_force() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        // 2.5-D cloud with a wall and a duplicate, plus queries inside and outside.
        let mut pts: Vec<[f64; 3]> = (0..20_000)
            .map(|_| {
                let x: f64 = rng.gen_range(-100.0..100.0);
                let y: f64 = rng.gen_range(-50.0..50.0);
                [x, y, 0.05 * x + (y / 10.0).sin()]
            })
            .collect();
        for i in 0..500 {
            pts.push([10.0, i as f64 * 0.01, i as f64 * 0.02]);
        }
        pts.push(pts[0]);
        let idx = GridIndex::new(pts, 16.0);
        let p = idx.points().to_vec();
        let mut out = Vec::new();
        for _ in 0..300 {
            let q = [
                rng.gen_range(-130.0..130.0),
                rng.gen_range(-80.0..80.0),
                rng.gen_range(-10.0..10.0),
            ];
            let mut all: Vec<(f64, usize)> = p
                .iter()
                .enumerate()
                .map(|(i, a)| {
                    (
                        (a[0] - q[0]).powi(2) + (a[1] - q[1]).powi(2) + (a[2] - q[2]).powi(2),
                        i,
                    )
                })
                .collect();
            all.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            let one = idx.nearest_one(&q).unwrap();
            assert_eq!((one.distance2, one.index), all[0]);
            idx.nearest_k(&q, 12, &mut out);
            let got: Vec<(f64, usize)> = out.iter().map(|n| (n.distance2, n.index)).collect();
            assert_eq!(got, all[..12].to_vec());
        }
        assert!(GridIndex::new(Vec::new(), 16.0)
            .nearest_one(&[0.0; 3])
            .is_none());
    }
}
