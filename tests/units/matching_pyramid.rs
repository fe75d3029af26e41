//! Unit tests of `matching::pyramid`.

mod tests {
    use cloudcontrol::matching::pyramid::*;
    use cloudcontrol::matching::GreyImage;

    /// The blur with every tap clamped, as it was before the interior fast path.
    fn clamped_reference(img: &GreyImage) -> Vec<f32> {
        let (w, h) = (img.width, img.height);
        let (nw, nh) = (w / 2, h / 2);
        let k = [1.0f32, 5.0, 10.0, 10.0, 5.0, 1.0].map(|v| v / 32.0);
        let at = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
        let mut tmp = vec![0.0f32; nw * h];
        for r in 0..h {
            for i in 0..nw {
                let mut s = 0.0;
                for (t, kv) in k.iter().enumerate() {
                    s += kv * img.row(r)[at(2 * i as isize - 2 + t as isize, w)];
                }
                tmp[r * nw + i] = s;
            }
        }
        let mut out = vec![0.0f32; nw * nh];
        for j in 0..nh {
            for (t, kv) in k.iter().enumerate() {
                let r = at(2 * j as isize - 2 + t as isize, h);
                for i in 0..nw {
                    out[j * nw + i] += kv * tmp[r * nw + i];
                }
            }
        }
        out
    }

    /// The unclamped interior loop gives the same bits as clamping every tap, at every
    /// width, including those too narrow to have an interior.
    #[test]
    fn interior_fast_path_is_bit_identical() {
        for w in 1..16usize {
            for h in [1usize, 2, 5] {
                let data: Vec<f32> = (0..w * h)
                    .map(|i| ((i * 7919) % 251) as f32 * 0.37)
                    .collect();
                let img = GreyImage::new(w, h, data).unwrap();
                let d = downsample(&img);
                assert_eq!((d.width, d.height), (w / 2, h / 2));
                let want = clamped_reference(&img);
                assert!(
                    d.data
                        .iter()
                        .zip(&want)
                        .all(|(a, b)| a.to_bits() == b.to_bits()),
                    "{w}×{h}"
                );
            }
        }
    }
}
