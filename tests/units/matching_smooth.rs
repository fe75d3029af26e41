//! Unit tests of `matching::smooth`.

mod tests {
    use cloudcontrol::matching::smooth::gaussian_blur;
    use cloudcontrol::matching::GreyImage;

    /// The blur with every tap clamped, as it was before the clamp-free inner columns.
    fn clamped_reference(img: &GreyImage, sigma: f32) -> Vec<f32> {
        let r = (3.0 * sigma).ceil() as isize;
        let mut k: Vec<f32> = (-r..=r)
            .map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp())
            .collect();
        let s: f32 = k.iter().sum();
        k.iter_mut().for_each(|v| *v /= s);
        let (w, h) = (img.width, img.height);
        let at = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
        let mut tmp = vec![0.0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let mut acc = 0.0;
                for (j, kv) in k.iter().enumerate() {
                    acc += kv * img.row(y)[at(x as isize + j as isize - r, w)];
                }
                tmp[y * w + x] = acc;
            }
        }
        let mut out = vec![0.0f32; w * h];
        for y in 0..h {
            for (j, kv) in k.iter().enumerate() {
                let yy = at(y as isize + j as isize - r, h);
                for x in 0..w {
                    out[y * w + x] += kv * tmp[yy * w + x];
                }
            }
        }
        out
    }

    /// The clamp-free inner columns give the same bits as clamping every tap, at every
    /// width, including those too narrow to have inner columns.
    #[test]
    fn inner_columns_are_bit_identical() {
        for sigma in [0.6f32, 1.0, 1.5] {
            for w in 1..20usize {
                for h in [1usize, 3, 8] {
                    let img = GreyImage::from_fn(w, h, |x, y| {
                        ((x * 37.0 + y * 101.0) % 17.0) * 13.0 + x * 0.25
                    });
                    let got = gaussian_blur(&img, sigma);
                    let want = clamped_reference(&img, sigma);
                    assert!(
                        got.data
                            .iter()
                            .zip(&want)
                            .all(|(a, b)| a.to_bits() == b.to_bits()),
                        "σ {sigma}, {w}×{h}"
                    );
                }
            }
        }
    }
}
