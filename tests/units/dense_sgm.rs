//! Unit tests of `dense` semi-global matching on rectified pairs made from one random
//! texture with a known disparity field: a constant shift, a slanted plane, a prior band
//! that excludes the truth, and the statuses of pixels without a match.

pub mod tests {
    use cloudcontrol::dense::{
        match_images, BandGrid, DisparityPrior, PixelStatus, SgmOptions, Subpixel,
    };
    use cloudcontrol::matching::GreyImage;

    /// Random texture: value noise on a lattice of `cell` px, bilinear, with two octaves,
    /// integrated over the pixel by 3 × 3 samples, plus sensor noise.
    pub struct Texture {
        seed: u64,
        cell: f64,
    }

    fn hash(seed: u64, i: i64, j: i64) -> f64 {
        let mut z = seed
            ^ (i as u64).wrapping_mul(0x9E3779B97F4A7C15)
            ^ (j as u64).wrapping_mul(0xC2B2AE3D27D4EB4F);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58476D1CE4E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D049BB133111EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }

    impl Texture {
        pub fn new(seed: u64, cell: f64) -> Self {
            Self { seed, cell }
        }

        fn lattice(&self, seed: u64, x: f64, y: f64, cell: f64) -> f64 {
            let (u, v) = (x / cell, y / cell);
            let (i, j) = (u.floor(), v.floor());
            let (fu, fv) = (u - i, v - j);
            let (i, j) = (i as i64, j as i64);
            let a = hash(seed, i, j) + fu * (hash(seed, i + 1, j) - hash(seed, i, j));
            let b = hash(seed, i, j + 1) + fu * (hash(seed, i + 1, j + 1) - hash(seed, i, j + 1));
            a + fv * (b - a)
        }

        pub fn at(&self, x: f64, y: f64) -> f64 {
            let mut s = 0.0;
            for a in 0..3 {
                for b in 0..3 {
                    let (xx, yy) = (x + (a as f64 - 1.0) / 3.0, y + (b as f64 - 1.0) / 3.0);
                    s += 0.7 * self.lattice(self.seed, xx, yy, self.cell)
                        + 0.3 * self.lattice(self.seed ^ 0xABCD, xx, yy, 4.0 * self.cell);
                }
            }
            30.0 + 190.0 * s / 9.0
        }
    }

    /// Left and right images of `w × h` px: right(x, y) = T(x, y), left(x, y) = T(x − d, y).
    pub fn pair(
        w: usize,
        h: usize,
        seed: u64,
        noise: f64,
        d: impl Fn(f64, f64) -> f64,
    ) -> (GreyImage, GreyImage) {
        let t = Texture::new(seed, 1.7);
        let n = |x: f64, y: f64, k: u64| noise * (hash(seed ^ k, x as i64, y as i64) - 0.5) * 3.46;
        let right = GreyImage::from_fn(w, h, |x, y| t.at(x, y) + n(x, y, 1));
        let left = GreyImage::from_fn(w, h, |x, y| t.at(x - d(x, y), y) + n(x, y, 2));
        (left, right)
    }

    /// Median and 95th percentile of |error| over valid pixels, and the valid share, over
    /// the columns where the right image holds the match.
    pub fn score(
        map: &cloudcontrol::dense::DisparityMap,
        d: impl Fn(f64, f64) -> f64,
        x0: usize,
    ) -> (f64, f64, f64) {
        let mut errs = Vec::new();
        let mut total = 0usize;
        for y in 4..map.height - 4 {
            for x in x0..map.width - 4 {
                total += 1;
                if let Some(v) = map.at(x, y) {
                    errs.push((v as f64 - d(x as f64 + 0.5, y as f64 + 0.5)).abs());
                }
            }
        }
        errs.sort_by(f64::total_cmp);
        let q = |p: f64| errs[((errs.len() - 1) as f64 * p) as usize];
        (q(0.5), q(0.95), errs.len() as f64 / total as f64)
    }

    #[test]
    fn constant_shift_is_found_to_a_tenth_of_a_pixel() {
        let truth = |_: f64, _: f64| 17.3;
        let (l, r) = pair(320, 240, 3, 1.0, truth);
        let map = match_images(
            &l,
            None,
            &r,
            None,
            &DisparityPrior::range(0.0, 64.0),
            &SgmOptions::default(),
        )
        .unwrap();
        let (med, p95, valid) = score(&map, truth, 24);
        eprintln!("shift: median {med:.3} px, 95 % {p95:.3} px, valid {valid:.3}");
        assert!(med < 0.1 && p95 < 0.4 && valid > 0.97);
    }

    #[test]
    fn slanted_plane_is_found_with_either_sub_pixel_fit() {
        let truth = |x: f64, y: f64| 6.0 + 0.05 * x + 0.03 * y;
        let (l, r) = pair(400, 300, 5, 1.0, truth);
        for subpixel in [Subpixel::Parabola, Subpixel::Equiangular] {
            let options = SgmOptions {
                subpixel,
                ..Default::default()
            };
            let map = match_images(
                &l,
                None,
                &r,
                None,
                &DisparityPrior::range(-8.0, 96.0),
                &options,
            )
            .unwrap();
            let (med, p95, valid) = score(&map, truth, 40);
            eprintln!("plane {subpixel:?}: median {med:.3} px, 95 % {p95:.3} px, valid {valid:.3}");
            assert!(med < 0.15 && p95 < 0.6 && valid > 0.95);
        }
    }

    #[test]
    fn a_prior_band_narrows_the_search_but_never_supplies_the_answer() {
        let truth = |x: f64, _: f64| 20.0 + 0.02 * x;
        let (l, r) = pair(256, 192, 9, 1.0, truth);
        let options = SgmOptions::default();
        // A band around the truth gives the same answer as the wide range.
        let mut grid = BandGrid::covering(16, 256, 192);
        for j in 0..grid.rows {
            for i in 0..grid.cols {
                let d = truth((i * 16) as f64, 0.0) as f32;
                grid.min[j * grid.cols + i] = d - 6.0;
                grid.max[j * grid.cols + i] = d + 6.0;
            }
        }
        let narrow = DisparityPrior {
            range: [0.0, 64.0],
            grid: Some(&grid),
            first_row: 0,
            grid_only: false,
        };
        let a = match_images(&l, None, &r, None, &narrow, &options).unwrap();
        let (med, _, valid) = score(&a, truth, 30);
        assert!(med < 0.1 && valid > 0.95, "median {med}, valid {valid}");
        assert!(a.stats.levels[0].mean_band < 20.0);
        // A band that misses the truth by 5 px yields no disparities, not wrong ones.
        for v in grid.min.iter_mut().chain(grid.max.iter_mut()) {
            *v += 11.0;
        }
        let wrong = DisparityPrior {
            range: [0.0, 64.0],
            grid: Some(&grid),
            first_row: 0,
            grid_only: false,
        };
        let b = match_images(&l, None, &r, None, &wrong, &options).unwrap();
        let (_, _, valid) = score(&b, truth, 30);
        let mut hist = std::collections::BTreeMap::new();
        for s in &b.status {
            *hist.entry(format!("{s:?}")).or_insert(0) += 1;
        }
        let vals: Vec<f32> = b
            .disparity
            .iter()
            .copied()
            .filter(|d| d.is_finite())
            .take(20)
            .collect();
        eprintln!("wrong band: {hist:?} {vals:?} {:?}", b.stats);
        assert!(
            valid < 0.02,
            "{valid} of the pixels matched outside the truth"
        );
    }

    #[test]
    fn pixels_without_a_match_say_why() {
        let truth = |_: f64, _: f64| 12.0;
        let (mut l, r) = pair(200, 160, 11, 1.0, truth);
        // A flat patch: no texture.
        for y in 60..100 {
            for x in 80..140 {
                l.data[y * 200 + x] = 128.0;
            }
        }
        let mut valid = vec![true; 200 * 160];
        for v in valid[..200 * 10].iter_mut() {
            *v = false;
        }
        let options = SgmOptions {
            min_texture: 2.0,
            ..Default::default()
        };
        let map = match_images(
            &l,
            Some(&valid),
            &r,
            None,
            &DisparityPrior::range(4.0, 40.0),
            &options,
        )
        .unwrap();
        assert!(map.status[..200 * 10]
            .iter()
            .all(|&s| s == PixelStatus::NoData));
        // Columns left of the smallest disparity (4) have no right pixel in their band.
        assert_eq!(map.status[50 * 200 + 2], PixelStatus::NoData);
        assert_eq!(map.status[80 * 200 + 110], PixelStatus::LowTexture);
        assert!(map.disparity[80 * 200 + 110].is_nan());
        let ok = map
            .status
            .iter()
            .zip(&map.disparity)
            .all(|(s, d)| (*s == PixelStatus::Valid) == d.is_finite());
        assert!(ok, "valid status and finite disparity disagree");
    }
}

mod depth_edges {
    use super::tests::Texture;
    use cloudcontrol::dense::{
        match_images, DisparityMap, DisparityPrior, PixelStatus, SgmOptions,
    };
    use cloudcontrol::matching::GreyImage;

    const W: usize = 320;
    const H: usize = 240;
    /// The roof: left-image columns and rows, its disparity and the ground's.
    const ROOF: (usize, usize, usize, usize) = (140, 200, 80, 160);
    const D_ROOF: f64 = 34.0;
    const D_GROUND: f64 = 12.0;

    fn on_roof(x: f64, y: f64) -> bool {
        let (x0, x1, y0, y1) = ROOF;
        x >= x0 as f64 && x < x1 as f64 && y >= y0 as f64 && y < y1 as f64
    }

    /// A brighter textured roof standing on textured ground, seen from both views: the
    /// right view sees the roof shifted by its own disparity and, beside it, ground the
    /// left view cannot see (and the other way round).
    fn building() -> (GreyImage, GreyImage) {
        let (ground, roof) = (Texture::new(21, 1.7), Texture::new(22, 1.7));
        let left = GreyImage::from_fn(W, H, |x, y| {
            if on_roof(x, y) {
                roof.at(x, y) * 0.5 + 120.0
            } else {
                ground.at(x, y) * 0.5
            }
        });
        let right = GreyImage::from_fn(W, H, |x, y| {
            if on_roof(x + D_ROOF, y) {
                roof.at(x + D_ROOF, y) * 0.5 + 120.0
            } else {
                ground.at(x + D_GROUND, y) * 0.5
            }
        });
        (left, right)
    }

    /// Ground pixels within 8 px of the roof (outside the ground the right view cannot
    /// see) matched nearer than half way to the roof: the roof fattened onto the ground.
    fn fattened(map: &DisparityMap) -> usize {
        let (x0, x1, y0, y1) = ROOF;
        let occluded_from = x0 - (D_ROOF - D_GROUND) as usize;
        let mut n = 0;
        for y in y0 - 8..y1 + 8 {
            for x in occluded_from - 8..x1 + 8 {
                let near = !on_roof(x as f64 + 0.5, y as f64 + 0.5);
                let hidden = x >= occluded_from && x < x0 && y >= y0 && y < y1;
                if near
                    && !hidden
                    && map
                        .at(x, y)
                        .is_some_and(|d| d as f64 > (D_ROOF + D_GROUND) / 2.0)
                {
                    n += 1;
                }
            }
        }
        n
    }

    fn run(options: &SgmOptions) -> DisparityMap {
        let (l, r) = building();
        match_images(
            &l,
            None,
            &r,
            None,
            &DisparityPrior::range(0.0, 48.0),
            options,
        )
        .unwrap()
    }

    /// The adaptive support and the trimming of depth edges keep the roof's disparity off
    /// the ground beside it (138 such pixels with the centred census window, 80 with
    /// both; either alone 105), and the ground the right view cannot see is not matched.
    #[test]
    fn a_roof_is_not_fattened_onto_the_ground_and_hidden_ground_is_not_matched() {
        let plain = run(&SgmOptions {
            support: 0.0,
            occlusion_tolerance: -1.0,
            edge_jump: 0.0,
            ..Default::default()
        });
        let map = run(&SgmOptions::default());
        let (before, after) = (fattened(&plain), fattened(&map));
        eprintln!("fattened ground pixels: {before} with the centred window, {after} with support and edge trimming");
        assert!(before > 100 && after * 3 < before * 2, "{before} → {after}");
        // The roof itself is still matched.
        let (x0, x1, y0, y1) = ROOF;
        let mut roof = (0, 0);
        for y in y0 + 8..y1 - 8 {
            for x in x0 + 8..x1 - 8 {
                roof.1 += 1;
                if map
                    .at(x, y)
                    .is_some_and(|d| (d as f64 - D_ROOF).abs() < 0.5)
                {
                    roof.0 += 1;
                }
            }
        }
        assert!(
            roof.0 * 10 > roof.1 * 9,
            "roof matched {} of {}",
            roof.0,
            roof.1
        );
        // Ground hidden from the right view: not matched (the left–right check).
        let occluded_from = x0 - (D_ROOF - D_GROUND) as usize;
        let hidden: Vec<PixelStatus> = (y0 + 4..y1 - 4)
            .flat_map(|y| (occluded_from + 2..x0 - 2).map(move |x| (x, y)))
            .map(|(x, y)| map.status[y * W + x])
            .collect();
        let valid = hidden.iter().filter(|s| **s == PixelStatus::Valid).count();
        eprintln!("hidden ground: {valid} valid of {}", hidden.len());
        assert!(
            valid * 10 < hidden.len(),
            "{valid} of {} hidden pixels valid",
            hidden.len()
        );
    }
}

mod occlusion_filters {
    use cloudcontrol::dense::{remove_occluded, trim_depth_edges, PixelStatus};
    use cloudcontrol::matching::GreyImage;

    /// One row: ground (disparity 10), a wall the left view sees but matched at the
    /// ground's disparity behind it, then the roof (30). In the right view the roof covers
    /// right positions from 8 − 30 = −22 on, where the wall's and the ground's pixels
    /// would land (−10 … −3): both are hidden there, the roof and the ground beyond it
    /// are not.
    #[test]
    fn pixels_the_right_view_cannot_see_are_told_occluded() {
        let mut d = vec![10.0f32; 8];
        d.extend([30.0f32; 8]);
        d.extend([10.0f32; 8]);
        let mut status = vec![PixelStatus::Valid; d.len()];
        remove_occluded(&mut d, &mut status, 24, 1.0);
        let occluded: Vec<usize> = (0..24)
            .filter(|&x| status[x] == PixelStatus::Occluded)
            .collect();
        assert_eq!(occluded, (0..8).collect::<Vec<_>>());
        assert!(d[..8].iter().all(|v| v.is_nan()) && d[8..].iter().all(|v| v.is_finite()));
    }

    /// A depth edge matched 3 px past the grey-value edge (the roof fattened onto the
    /// ground): the 3 pixels between them are removed, the rest kept; a jump that lies on
    /// the grey-value edge removes nothing.
    #[test]
    fn a_depth_edge_is_trimmed_back_to_the_grey_value_edge() {
        let w = 20;
        // Ground dark, roof bright from column 10; the roof's disparity (30) matched from
        // column 7 on.
        let image = GreyImage::from_fn(w, 1, |x, _| if x < 10.0 { 40.0 } else { 200.0 });
        let mut d: Vec<f32> = (0..w).map(|x| if x < 7 { 10.0 } else { 30.0 }).collect();
        let mut status = vec![PixelStatus::Valid; w];
        trim_depth_edges(&mut d, &mut status, &image, [8, 0], 2.0);
        let removed: Vec<usize> = (0..w).filter(|&x| d[x].is_nan()).collect();
        assert_eq!(removed, vec![7, 8, 9]);
        assert!(removed.iter().all(|&x| status[x] == PixelStatus::DepthEdge));
        let mut on_edge: Vec<f32> = (0..w).map(|x| if x < 10 { 10.0 } else { 30.0 }).collect();
        let mut status = vec![PixelStatus::Valid; w];
        trim_depth_edges(&mut on_edge, &mut status, &image, [8, 0], 2.0);
        assert!(on_edge.iter().all(|v| v.is_finite()));
    }
}

mod grid_only {
    use super::tests::pair;
    use cloudcontrol::dense::{match_images, BandGrid, DisparityPrior, PixelStatus, SgmOptions};

    /// A prior grid that ends half way (a DEM smaller than the photos): with `grid_only`
    /// the pixels beyond it are not searched, without it they search the range.
    #[test]
    fn pixels_beyond_a_prior_grid_are_searched_only_when_asked() {
        let truth = |_: f64, _: f64| 14.0;
        let (l, r) = pair(256, 192, 21, 1.0, truth);
        let mut grid = BandGrid::covering(16, 256, 192);
        for j in 0..grid.rows {
            for i in 0..grid.cols {
                if j * 16 < 96 {
                    grid.min[j * grid.cols + i] = 8.0;
                    grid.max[j * grid.cols + i] = 20.0;
                }
            }
        }
        for grid_only in [true, false] {
            let prior = DisparityPrior {
                range: [0.0, 40.0],
                grid: Some(&grid),
                first_row: 0,
                grid_only,
            };
            let map = match_images(&l, None, &r, None, &prior, &SgmOptions::default()).unwrap();
            let lower = &map.status[140 * 256..150 * 256];
            let valid = lower.iter().filter(|&&s| s == PixelStatus::Valid).count();
            if grid_only {
                assert!(lower.iter().all(|&s| s == PixelStatus::NoData));
            } else {
                assert!(valid > lower.len() / 2, "{valid} of {}", lower.len());
            }
            // Above, on the grid, the truth either way.
            let upper = map.at(128, 40).unwrap();
            assert!((upper - 14.0).abs() < 0.2, "{upper}");
        }
    }
}

/// Cost of the sub-pixel refinement against the project's general least-squares matcher
/// (`matching::lsm`, shifts and radiometry only) on the same pixels (run by hand:
/// `cargo test --release --test units refinement_cost -- --ignored --nocapture`).
mod refinement_cost {
    use super::tests::pair;
    use cloudcontrol::dense::{cpu_seconds, match_images, DisparityPrior, SgmOptions};
    use cloudcontrol::matching::{lsm, LsmOptions};

    #[test]
    #[ignore]
    fn refinement_against_matching_lsm() {
        let (l, r) = pair(640, 480, 3, 1.0, |_, _| 17.3);
        let prior = DisparityPrior::range(0.0, 64.0);
        // SGM with and without refinement differ by the refinement alone: measured as the
        // whole match, the best of three.
        let best = |f: &dyn Fn()| {
            (0..3)
                .map(|_| {
                    let c0 = cpu_seconds();
                    f();
                    cpu_seconds() - c0
                })
                .fold(f64::INFINITY, f64::min)
        };
        let map = match_images(&l, None, &r, None, &prior, &SgmOptions::default()).unwrap();
        let sgm = best(&|| {
            match_images(&l, None, &r, None, &prior, &SgmOptions::default()).unwrap();
        });
        let pixels: Vec<(usize, usize, f32)> = (8..472)
            .flat_map(|y| (40..632).map(move |x| (x, y)))
            .filter_map(|(x, y)| map.at(x, y).map(|d| (x, y, d)))
            .collect();
        let opts = LsmOptions {
            affine: false,
            ..LsmOptions::default()
        };
        let general = best(&|| {
            for &(x, y, d) in &pixels {
                let tpl = l.crop(x - 3, y - 3, 7, 7).unwrap();
                let _ = lsm(
                    &r,
                    &tpl,
                    x as f64 + 0.5 - d as f64,
                    y as f64 + 0.5,
                    None,
                    &opts,
                );
            }
        });
        eprintln!(
            "{} pixels: SGM with its refinement {:.3} s CPU; matching::lsm on the same pixels {:.3} s CPU",
            pixels.len(),
            sgm,
            general
        );
    }
}
