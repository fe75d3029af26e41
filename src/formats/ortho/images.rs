//! The photos an orthophoto is made from. Image files are decoded when a tile first needs
//! them and kept in a least-recently-used cache bounded in bytes, so a block of hundreds
//! of photos (100 film scans at 42 µm are 10 GB of RGB) never holds them all at once.

use super::super::{FormatError, Result};
use crate::block::PhotoId;
use crate::cache::Lru;
use std::collections::BTreeMap;
use std::ops::Deref;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// An 8-bit RGB photo in memory, row-major; pixel (c, r) has its centre at (c+½, r+½).
#[derive(Debug, Clone)]
pub struct RgbImage {
    pub width: u32,
    pub height: u32,
    pub data: Vec<u8>,
}

impl RgbImage {
    pub fn new(width: u32, height: u32, data: Vec<u8>) -> std::result::Result<Self, String> {
        if data.len() != width as usize * height as usize * 3 {
            return Err(format!(
                "RGB image {width}×{height} needs {} bytes, got {}",
                width as usize * height as usize * 3,
                data.len()
            ));
        }
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// Loads any format the `image` crate decodes (TIFF, PNG, JPEG), converted to RGB8.
    pub fn load(path: &Path) -> Result<Self> {
        let img = super::super::image_open::decode_image(path)?.to_rgb8();
        let (w, h) = img.dimensions();
        Ok(Self {
            width: w,
            height: h,
            data: img.into_raw(),
        })
    }

    /// Bilinear sample at a pixel position (our corner-origin convention).
    pub fn sample(&self, x: f64, y: f64) -> Option<[f64; 3]> {
        let (fx, fy) = (x - 0.5, y - 0.5);
        if !(fx >= -0.5 && fy >= -0.5 && x <= self.width as f64 && y <= self.height as f64) {
            return None;
        }
        let (w, h) = (self.width as usize, self.height as usize);
        let fx = fx.clamp(0.0, (w - 1) as f64);
        let fy = fy.clamp(0.0, (h - 1) as f64);
        let (c0, r0) = (fx.floor() as usize, fy.floor() as usize);
        let (c1, r1) = ((c0 + 1).min(w - 1), (r0 + 1).min(h - 1));
        let (u, v) = (fx - c0 as f64, fy - r0 as f64);
        let px = |c: usize, r: usize, k: usize| self.data[(r * w + c) * 3 + k] as f64;
        let mut out = [0.0; 3];
        for (k, o) in out.iter_mut().enumerate() {
            *o = (1.0 - v) * ((1.0 - u) * px(c0, r0, k) + u * px(c1, r0, k))
                + v * ((1.0 - u) * px(c0, r1, k) + u * px(c1, r1, k));
        }
        Some(out)
    }
}

/// The photos an orthophoto is rendered from, by photo id.
#[derive(Debug, Clone, Copy)]
pub enum PhotoImages<'a> {
    /// Images the caller has decoded already.
    Decoded(&'a BTreeMap<PhotoId, RgbImage>),
    /// Image files (any format [`RgbImage::load`] reads), decoded on demand.
    Files(&'a BTreeMap<PhotoId, PathBuf>),
}

impl PhotoImages<'_> {
    pub fn contains(&self, id: PhotoId) -> bool {
        match self {
            PhotoImages::Decoded(m) => m.contains_key(&id),
            PhotoImages::Files(m) => m.contains_key(&id),
        }
    }

    /// Width and height of a photo's image (a file's header only), to check it against
    /// its camera before anything is written.
    pub(super) fn size(&self, id: PhotoId) -> Result<Option<(u32, u32)>> {
        Ok(match self {
            PhotoImages::Decoded(m) => m.get(&id).map(|i| (i.width, i.height)),
            PhotoImages::Files(m) => match m.get(&id) {
                Some(p) => Some(super::super::image_open::image_size(p)?),
                None => None,
            },
        })
    }
}

/// A photo's pixels while a tile is rendered: the caller's, or shared with the cache.
pub(super) enum Held<'a> {
    Borrowed(&'a RgbImage),
    Cached(Arc<RgbImage>),
}

impl Deref for Held<'_> {
    type Target = RgbImage;
    fn deref(&self) -> &RgbImage {
        match self {
            Held::Borrowed(i) => i,
            Held::Cached(i) => i,
        }
    }
}

/// Hands out the images a tile needs, decoding files through the bounded cache, and
/// measures the image bytes alive at once (cache plus entries it evicted that the tile
/// still holds).
pub(super) struct ImageCache<'a> {
    source: PhotoImages<'a>,
    /// The product being made, named in errors.
    out: &'a Path,
    lru: Lru<PhotoId, RgbImage>,
    pub(super) peak_bytes: u64,
}

impl<'a> ImageCache<'a> {
    pub(super) fn new(source: PhotoImages<'a>, bound_bytes: u64, out: &'a Path) -> Self {
        Self {
            source,
            out,
            lru: Lru::new(bound_bytes),
            peak_bytes: 0,
        }
    }

    /// Images decoded so far (a photo decoded again after eviction counts again).
    pub(super) fn loads(&self) -> usize {
        self.lru.loads()
    }

    pub(super) fn get_all(&mut self, ids: &[PhotoId]) -> Result<Vec<Held<'a>>> {
        let path_out = self.out;
        let missing =
            move |id: PhotoId| FormatError::invalid(path_out, format!("photo {id} has no image"));
        let mut out = Vec::with_capacity(ids.len());
        for &id in ids {
            out.push(match self.source {
                PhotoImages::Decoded(m) => Held::Borrowed(m.get(&id).ok_or_else(|| missing(id))?),
                PhotoImages::Files(m) => {
                    let path = m.get(&id).ok_or_else(|| missing(id))?;
                    Held::Cached(self.lru.get_or_load(&id, || {
                        let img = RgbImage::load(path)?;
                        let bytes = img.data.len() as u64;
                        Ok::<_, FormatError>((img, bytes))
                    })?)
                }
            });
        }
        let evicted_but_held: u64 = ids
            .iter()
            .zip(&out)
            .filter(|(id, h)| matches!(h, Held::Cached(_)) && !self.lru.contains(id))
            .map(|(_, h)| h.data.len() as u64)
            .sum();
        self.peak_bytes = self.peak_bytes.max(self.lru.held() + evicted_but_held);
        Ok(out)
    }
}
