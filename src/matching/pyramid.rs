//! Factor-2 image pyramids. Each level is low-passed with the 5-tap binomial kernel
//! (1 4 6 4 1)/16 before decimation so coarse levels do not alias fine texture into
//! false correlation peaks. A level-l pixel covers exactly 2^l × 2^l level-0 pixels,
//! so coordinates scale by 2^-l (corner origin).

use super::GreyImage;

#[derive(Debug, Clone)]
pub struct Pyramid {
    pub levels: Vec<GreyImage>,
}

/// The levels of an image pyramid as the coarse-to-fine searches read them
/// ([`crate::matching::match_template`], [`crate::matching::ncc_search_pyramid`]): an owned
/// [`Pyramid`], or a [`PyramidOver`] an image the caller holds.
pub trait Levels {
    /// Number of levels, level 0 (full resolution) included.
    fn count(&self) -> usize;
    /// Level `l` (0: full resolution).
    fn level(&self, l: usize) -> &GreyImage;
}

impl Levels for Pyramid {
    fn count(&self) -> usize {
        self.levels.len()
    }
    fn level(&self, l: usize) -> &GreyImage {
        &self.levels[l]
    }
}

impl Pyramid {
    /// Builds levels until the smaller side would drop below `min_size` or `max_levels`
    /// levels (level 0 included) exist. Level 0 is a copy of `image`: a caller that keeps
    /// the image uses [`PyramidOver`], one that does not [`Pyramid::from_image`].
    pub fn new(image: &GreyImage, max_levels: usize, min_size: usize) -> Self {
        Self::from_image(image.clone(), max_levels, min_size)
    }

    /// As [`Pyramid::new`], taking the image as level 0 without copying it.
    pub fn from_image(image: GreyImage, max_levels: usize, min_size: usize) -> Self {
        let coarse = coarse_levels(&image, max_levels, min_size);
        let mut levels = Vec::with_capacity(coarse.len() + 1);
        levels.push(image);
        levels.extend(coarse);
        Self { levels }
    }

    /// Bytes of pixel data held over all levels.
    pub fn bytes(&self) -> u64 {
        self.levels
            .iter()
            .map(|l| (l.data.len() * std::mem::size_of::<f32>()) as u64)
            .sum()
    }
}

/// A pyramid over an image held by the caller: level 0 is the image itself (borrowed, not
/// copied), the coarser levels are owned — a third of the image's bytes beside it.
#[derive(Debug, Clone)]
pub struct PyramidOver<'a> {
    base: &'a GreyImage,
    coarse: Vec<GreyImage>,
}

impl<'a> PyramidOver<'a> {
    /// The levels [`Pyramid::new`] builds, over `image` without copying it.
    pub fn new(image: &'a GreyImage, max_levels: usize, min_size: usize) -> Self {
        Self {
            base: image,
            coarse: coarse_levels(image, max_levels, min_size),
        }
    }
}

impl Levels for PyramidOver<'_> {
    fn count(&self) -> usize {
        self.coarse.len() + 1
    }
    fn level(&self, l: usize) -> &GreyImage {
        match l {
            0 => self.base,
            l => &self.coarse[l - 1],
        }
    }
}

/// Levels 1.. of the pyramid of `image` (see [`Pyramid::new`]).
fn coarse_levels(image: &GreyImage, max_levels: usize, min_size: usize) -> Vec<GreyImage> {
    let mut coarse: Vec<GreyImage> = Vec::new();
    while coarse.len() + 1 < max_levels.max(1) {
        let last = coarse.last().unwrap_or(image);
        if last.width / 2 < min_size.max(1) || last.height / 2 < min_size.max(1) {
            break;
        }
        let next = downsample(last);
        coarse.push(next);
    }
    coarse
}

/// Blur with (1 4 6 4 1)/16 separably (edge-replicated) and keep every second sample;
/// the level-1 pixel (i, j) is centred between level-0 pixels 2i and 2i+1, so the
/// filter is evaluated there by averaging the two filtered neighbours.
pub fn downsample(img: &GreyImage) -> GreyImage {
    let (w, h) = (img.width, img.height);
    let (nw, nh) = (w / 2, h / 2);
    // Horizontal pass at the half-way positions: taps (1 5 10 10 5 1)/32 is the binomial
    // kernel convolved with the 2-sample box, i.e. blur and half-pixel shift in one.
    const K: [f32; 6] = [
        1.0 / 32.0,
        5.0 / 32.0,
        10.0 / 32.0,
        10.0 / 32.0,
        5.0 / 32.0,
        1.0 / 32.0,
    ];
    let clampi = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
    // Outputs whose six taps all lie inside the row: no clamping, so the loop over them
    // compiles to straight loads (the clamped loop was 8 % of a small block's run).
    let lo = 1.min(nw);
    let inner = lo..nw.min(w.saturating_sub(4) / 2 + 1).max(lo);
    let horizontal = |r: usize, out: &mut [f32]| {
        let row = img.row(r);
        let clamped = |i: usize| {
            let base = 2 * i as isize - 2;
            let mut s = 0.0;
            for (k, kv) in K.iter().enumerate() {
                s += kv * row[clampi(base + k as isize, w)];
            }
            s
        };
        for i in (0..inner.start).chain(inner.end..nw) {
            out[i] = clamped(i);
        }
        for (i, o) in out[inner.clone()].iter_mut().enumerate() {
            let t = &row[2 * (i + inner.start) - 2..2 * (i + inner.start) + 4];
            // Same order of summation as the clamped loop: bit-identical levels.
            let mut s = 0.0;
            for (kv, v) in K.iter().zip(t) {
                s += kv * v;
            }
            *o = s;
        }
    };
    // The horizontal pass of the six rows 2j − 2 … 2j + 3 an output row j needs, kept in a
    // ring of eight (row r in slot r mod 8) and each computed once: half an image of f32
    // for the whole pass was the largest buffer of a scan's pyramid.
    const RING: usize = 8;
    let mut ring = vec![0.0f32; RING * nw];
    let mut held = [usize::MAX; RING];
    let mut out = vec![0.0f32; nw * nh];
    for j in 0..nh {
        let base = 2 * j as isize - 2;
        for k in 0..K.len() {
            let r = clampi(base + k as isize, h);
            if held[r % RING] != r {
                horizontal(r, &mut ring[(r % RING) * nw..(r % RING + 1) * nw]);
                held[r % RING] = r;
            }
        }
        let dst = &mut out[j * nw..(j + 1) * nw];
        for (k, kv) in K.iter().enumerate() {
            let r = clampi(base + k as isize, h);
            let src = &ring[(r % RING) * nw..(r % RING + 1) * nw];
            for (d, s) in dst.iter_mut().zip(src) {
                *d += kv * s;
            }
        }
    }
    GreyImage {
        width: nw,
        height: nh,
        data: out,
    }
}
