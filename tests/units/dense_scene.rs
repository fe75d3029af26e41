//! Truth test of dense matching on rendered photos: a pair over a synthetic scene
//! (terrain, buildings, trees) is rectified, matched tile by tile and triangulated; the
//! disparities are scored against the scene's true disparities and the heights against
//! its surface, away from height edges.

mod tests {
    use super::super::dense_synthetic::{
        classes, prior_range, render_pair, score, Flight, SyntheticPair,
    };
    use cloudcontrol::dense::{
        match_pair, DisparityPrior, RectifiedPair, SgmOptions, Side, Tiling,
    };

    /// Matches the whole pair in tiles of `tile_rows`.
    pub fn match_whole(
        sp: &SyntheticPair,
        pair: &RectifiedPair,
        options: &SgmOptions,
        tile_rows: usize,
    ) -> Vec<f32> {
        let range = prior_range(sp, pair);
        let mut out = vec![f32::NAN; pair.left.width * pair.height];
        match_pair(
            pair,
            &sp.photos[0],
            &sp.photos[1],
            &DisparityPrior::range(range[0], range[1]),
            options,
            Tiling {
                rows: tile_rows,
                overlap: 64,
                within: 0..pair.height,
            },
            |tile| {
                let w = tile.map.width;
                out[tile.rows.start * w..tile.rows.end * w].copy_from_slice(&tile.map.disparity);
                Ok(())
            },
        )
        .unwrap();
        out
    }

    #[test]
    fn rendered_pair_heights_match_the_scene() {
        for seed in [1, 2] {
            let sp = render_pair(Flight::new(seed));
            let pair = sp.rectify();
            let (truth, points) = sp.truth(&pair);
            let d = match_whole(&sp, &pair, &SgmOptions::default(), 256);
            let s = score(&sp, &pair, &d, &truth, &classes(&sp, &points));
            eprintln!(
                "seed {seed}: {}×{} rectified, completeness {:.3}, >1 px {:.3}, median |e| {:.3} px, \
                 height median {:+.3} GSD, NMAD {:.3} GSD ({} points)",
                pair.left.width,
                pair.height,
                s.completeness,
                s.bad1,
                s.median_abs,
                s.height_median,
                s.height_nmad,
                s.height_points
            );
            assert!(s.completeness > 0.85);
            assert!(s.bad1 < 0.05);
            assert!(
                s.height_median.abs() <= 0.2,
                "height median {}",
                s.height_median
            );
            assert!(s.height_nmad <= 1.0, "height NMAD {}", s.height_nmad);
        }
    }

    #[test]
    fn tiles_agree_with_one_window() {
        let sp = render_pair(Flight {
            width: 600,
            height: 450,
            focal_px: 720.0,
            ..Flight::new(3)
        });
        let pair = sp.rectify();
        let options = SgmOptions::default();
        let whole = match_whole(&sp, &pair, &options, pair.height);
        let tiled = match_whole(&sp, &pair, &options, 120);
        let (mut both, mut agree) = (0usize, 0usize);
        for (a, b) in whole.iter().zip(&tiled) {
            if a.is_finite() && b.is_finite() {
                both += 1;
                agree += ((a - b).abs() < 0.1) as usize;
            }
        }
        let n = whole.iter().filter(|v| v.is_finite()).count();
        eprintln!("tiles: {both} of {n} pixels in both, {agree} agree");
        assert!(both as f64 > 0.97 * n as f64 && agree as f64 > 0.97 * both as f64);
        let _ = Side::Left;
    }
}

/// Diagnostics (run by hand): writes the rectified pair, the true and found disparities
/// and the error image of a rendered pair to $DENSE_DIAG (PNG), and prints the errors by
/// surface class and pixel status.
mod diagnose {
    use super::super::dense_synthetic::prior_range;
    use super::super::dense_synthetic::{render_pair, Flight};
    use cloudcontrol::dense::{
        match_images, DisparityMap, DisparityPrior, RectifiedImage, SgmOptions,
    };
    use cloudcontrol::matching::GreyImage;
    use std::collections::BTreeMap;

    /// The whole rectified pair matched as one window within `range`.
    fn match_window(
        l: &RectifiedImage,
        r: &RectifiedImage,
        range: [f32; 2],
        options: &SgmOptions,
    ) -> DisparityMap {
        match_images(
            &l.image,
            Some(&l.valid),
            &r.image,
            Some(&r.valid),
            &DisparityPrior::range(range[0], range[1]),
            options,
        )
        .unwrap()
    }

    #[test]
    #[ignore]
    fn dump() {
        let dir =
            std::path::PathBuf::from(std::env::var("DENSE_DIAG").unwrap_or("/tmp/dense".into()));
        std::fs::create_dir_all(&dir).unwrap();
        let seed: u64 = std::env::var("DENSE_SEED")
            .ok()
            .and_then(|s| s.parse().ok())
            .unwrap_or(1);
        let sp = render_pair(Flight::new(seed));
        let pair = sp.rectify();
        let (truth, points) = sp.truth(&pair);
        let [l, r] = sp.rectified_images(&pair);
        let range = prior_range(&sp, &pair);
        let t0 = std::time::Instant::now();
        let options: SgmOptions =
            serde_json::from_str(&std::env::var("DENSE_OPTS").unwrap_or("{}".into())).unwrap();
        let map = match_window(&l, &r, range, &options);
        eprintln!(
            "range {range:?}, {:.3} s, {:?}",
            t0.elapsed().as_secs_f64(),
            map.stats
        );
        l.image.save(&dir.join("left.png"), false).unwrap();
        r.image.save(&dir.join("right.png"), false).unwrap();
        let (w, h) = (map.width, map.height);
        let scale = |v: f32| {
            if v.is_finite() {
                (v - range[0]) / (range[1] - range[0]) * 255.0
            } else {
                0.0
            }
        };
        GreyImage::new(w, h, truth.iter().map(|&v| scale(v)).collect())
            .unwrap()
            .save(&dir.join("truth.png"), false)
            .unwrap();
        GreyImage::new(w, h, map.disparity.iter().map(|&v| scale(v)).collect())
            .unwrap()
            .save(&dir.join("disparity.png"), false)
            .unwrap();
        GreyImage::new(
            w,
            h,
            map.disparity
                .iter()
                .zip(&truth)
                .map(|(&d, &t)| {
                    if d.is_finite() && t.is_finite() {
                        (128.0 + 50.0 * (d - t)).clamp(0.0, 255.0)
                    } else if t.is_finite() {
                        0.0
                    } else {
                        255.0
                    }
                })
                .collect(),
        )
        .unwrap()
        .save(&dir.join("error.png"), false)
        .unwrap();
        // Pixels off by more than one (white), matched within one (grey), unmatched (black).
        GreyImage::new(
            w,
            h,
            map.disparity
                .iter()
                .zip(&truth)
                .map(|(&d, &t)| match (d.is_finite(), t.is_finite()) {
                    (true, true) if (d - t).abs() > 1.0 => 255.0,
                    (true, true) => 128.0,
                    (false, true) => 0.0,
                    _ => 64.0,
                })
                .collect(),
        )
        .unwrap()
        .save(&dir.join("bad.png"), false)
        .unwrap();
        let mut by_class: BTreeMap<String, (usize, usize, usize, Vec<f32>)> = BTreeMap::new();
        let mut by_status: BTreeMap<String, usize> = BTreeMap::new();
        for k in 0..w * h {
            if !truth[k].is_finite() {
                continue;
            }
            *by_status.entry(format!("{:?}", map.status[k])).or_default() += 1;
            let p = points[k].unwrap();
            let class = format!("{:?}", sp.scene.class_at(p.x, p.y));
            let e = by_class.entry(class).or_default();
            e.0 += 1;
            if map.disparity[k].is_finite() {
                e.1 += 1;
                let err = map.disparity[k] - truth[k];
                e.2 += (err.abs() > 1.0) as usize;
                e.3.push(err);
            }
        }
        eprintln!("statuses of pixels with a true disparity: {by_status:?}");
        for (c, (n, m, bad, mut errs)) in by_class {
            errs.sort_by(f32::total_cmp);
            let med = errs.get(errs.len() / 2).copied().unwrap_or(f32::NAN);
            let mut dev: Vec<f32> = errs.iter().map(|e| (e - med).abs()).collect();
            dev.sort_by(f32::total_cmp);
            let nmad = 1.4826 * dev.get(dev.len() / 2).copied().unwrap_or(f32::NAN);
            eprintln!(
                "{c:>12}: {n:>7} px, matched {:.3}, >1 px {:.3}, median {med:+.3}, NMAD {nmad:.3}",
                m as f64 / n as f64,
                bad as f64 / m.max(1) as f64
            );
        }
    }

    /// Variants of the options (run by hand): DENSE_VARIANTS is a JSON list of partial
    /// options, DENSE_SEEDS a comma-separated list of seeds; prints the scores per class.
    #[test]
    #[ignore]
    fn variants() {
        let variants: Vec<serde_json::Value> =
            serde_json::from_str(&std::env::var("DENSE_VARIANTS").unwrap_or("[{}]".into()))
                .unwrap();
        let seeds: Vec<u64> = std::env::var("DENSE_SEEDS")
            .unwrap_or("1".into())
            .split(',')
            .map(|s| s.parse().unwrap())
            .collect();
        for seed in seeds {
            let sp = render_pair(Flight::new(seed));
            let pair = sp.rectify();
            let (truth, points) = sp.truth(&pair);
            let [l, r] = sp.rectified_images(&pair);
            let range = prior_range(&sp, &pair);
            let classes = super::super::dense_synthetic::classes(&sp, &points);
            for v in &variants {
                let options: SgmOptions = serde_json::from_value(v.clone()).unwrap();
                let c0 = cloudcontrol::dense::cpu_seconds();
                let map = match_window(&l, &r, range, &options);
                let cpu_s = cloudcontrol::dense::cpu_seconds() - c0;
                let s = super::super::dense_synthetic::score(
                    &sp,
                    &pair,
                    &map.disparity,
                    &truth,
                    &classes,
                );
                let mut line = format!(
                    "seed {seed} {v}: {cpu_s:.3} s CPU | all {:.3} {:.3} {:.3} dz {:+.2} {:.2}",
                    s.completeness, s.bad1, s.median_abs, s.height_median, s.height_nmad
                );
                for (c, _, m, b) in &s.by_class {
                    line += &format!(" | {} {m:.3} {b:.3}", &c[..4]);
                }
                eprintln!("{line}");
            }
        }
    }
}
