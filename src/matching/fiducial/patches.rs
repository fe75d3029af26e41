//! The scan as the interior orientation reads it: the windows around the predicted marks
//! (and the data strip), each read once with a pyramid of its own, never the whole scan's
//! grey copy or pyramid (a 21 µm scan is 10⁸ pixels; its marks need a few 10⁶).
//!
//! A search gives the result it would give on the pyramid of the whole scan (of the whole
//! scan smoothed, [`SMOOTH_PX`], for the marks' measurement). A patch's corner lies on the
//! grid of its coarsest level (a multiple of 2^L), so its level-l pixels are those of the
//! whole scan's level l; the smoothing and the blur of each level make at most 3 pixels
//! along a patch edge differ from the whole scan's (the edge is replicated where the scan
//! goes on), which the search never reaches: a patch holds the search window with a
//! margin of 5 coarsest-level pixels and 12 full-resolution ones for the least-squares
//! match beyond it, and the template. A patch read for one search serves the later ones
//! it holds in that way (the eight scan orientations predict the same marks within a few
//! pixels): which patch serves a search changes its result only by the rounding of
//! coordinates within the patch (1e-16 of σ, nothing of the marks' positions on the
//! bench's scans), and the patches are read in the same order in every run.

use super::super::matcher::{match_template, MatchOptions, MatchResult};
use super::super::ncc::Window;
use super::super::pyramid::Pyramid;
use super::super::scan_windows::ScanWindows;
use super::super::smooth::gaussian_blur;
use super::super::{GreyImage, Result};
use super::camera::DataStrip;
use crate::geometry::InteriorOrientation;
use nalgebra::Vector2;

/// The pyramid of a whole scan had at most this many levels…
const SCAN_LEVELS: usize = 8;
/// …and a coarsest level at least this many pixels a side.
const SCAN_LEVEL_SIDE: usize = 16;

/// Pixels a new patch reaches beyond what its search needs, so that the neighbouring
/// predictions of the other scan orientations find it.
const SLACK: usize = 16;

/// Data-strip samples whose pixels are gathered at a time (16 bytes each).
const STRIP_SAMPLES: usize = 1 << 20;

/// Data-strip samples of a scan row further apart than this (pixels) are read apart.
const STRIP_RUN_GAP: usize = 32;

/// Standard deviation (scan pixels) of the Gaussian smoothing of a mark's template and
/// of the scan around it before they are measured. The least-squares match interpolates
/// the scan bicubically, which a sharp (area-sampled) mark edge defeats by an amount that
/// depends on where the edge falls in its pixel: the marks of synthetic RC10 scans were
/// off by 0.064 px RMS at 21 µm and 0.034 px at 42 µm, and by 0.011 and 0.008 px with both
/// smoothed by 1 px (benches/fiducial_opencv.py's scans, seeds 0 and 1).
pub(super) const SMOOTH_PX: f32 = 1.0;

/// Pixels along a template's edge whose smoothed values would take the template's edge
/// for what lies beyond it in the scan (the kernel's reach, 3σ).
const SMOOTH_REACH: usize = 3;

/// A template smoothed as the scan is, for a search in the smoothed scan
/// ([`Ready::search`]), without the [`SMOOTH_REACH`] pixels along its edge: there the blur
/// would replicate the template's edge where the scan has what lies beyond it (the frame's
/// edge beside a real mark's crop pulled its match 0.27 px off). None for a template too
/// small to lose them (fewer than 9 pixels left a side), which is matched unsmoothed.
pub(super) fn smoothed(tpl: &GreyImage) -> Option<GreyImage> {
    let r = SMOOTH_REACH;
    if tpl.width < 2 * r + 9 || tpl.height < 2 * r + 9 {
        return None;
    }
    gaussian_blur(tpl, SMOOTH_PX)
        .crop(r, r, tpl.width - 2 * r, tpl.height - 2 * r)
        .ok()
}

/// The window centred on (x, y) with the given half-size, clipped to a scan of `size`
/// ([`Window::around`] of the whole scan).
pub(super) fn around(
    (width, height): (usize, usize),
    x: f64,
    y: f64,
    half_w: f64,
    half_h: f64,
) -> Option<Window> {
    let c0 = (x - half_w).floor().max(0.0);
    let r0 = (y - half_h).floor().max(0.0);
    let c1 = (x + half_w).ceil().min(width as f64);
    let r1 = (y + half_h).ceil().min(height as f64);
    if c1 <= c0 || r1 <= r0 {
        return None;
    }
    Some(Window {
        col: c0 as usize,
        row: r0 as usize,
        width: (c1 - c0) as usize,
        height: (r1 - r0) as usize,
    })
}

/// A window of the scan with its pyramid.
struct Patch {
    col: usize,
    row: usize,
    width: usize,
    height: usize,
    /// Level 0 is the scan smoothed by [`SMOOTH_PX`].
    smooth: bool,
    pyr: Pyramid,
}

/// The scan's size and the levels its whole pyramid had: what decides the patch a search
/// needs.
struct Grid {
    width: usize,
    height: usize,
    scan_levels: usize,
}

/// A search as the patches see it: the template's size, the window, its pyramid levels
/// and whether it is made in the smoothed scan.
#[derive(Clone, Copy)]
struct Need {
    window: Window,
    levels: usize,
    margin: usize,
    /// The template's size, at most the scan's: the patch holds it, so that a template
    /// larger than a window clipped by the scan's edge fails as on the whole scan.
    least: (usize, usize),
    smooth: bool,
}

impl Grid {
    /// What the coarse-to-fine search of `tpl` in `window` needs.
    fn need(&self, tpl: &GreyImage, window: Window, opts: &MatchOptions, smooth: bool) -> Need {
        let levels = self.levels_for(tpl, window, opts.min_template_px);
        let grid = 1usize << (levels - 1);
        Need {
            window,
            levels,
            margin: 5 * grid + 12,
            least: (tpl.width.min(self.width), tpl.height.min(self.height)),
            smooth,
        }
    }

    /// Pyramid levels the coarse-to-fine search of `tpl` in `window` goes through on the
    /// whole scan's pyramid (at most; a template that blurs to a constant stops earlier,
    /// on any pyramid): the sizes `ncc_search_pyramid` checks, level by level.
    fn levels_for(&self, tpl: &GreyImage, window: Window, min_template_px: usize) -> usize {
        let min = min_template_px.max(3);
        let (mut tw, mut th, mut level) = (tpl.width, tpl.height, 0);
        while level + 1 < self.scan_levels {
            let s = 1usize << (level + 1);
            if tw / 2 < min
                || th / 2 < min
                || window.width / s < tw / 2 + 2
                || window.height / s < th / 2 + 2
            {
                break;
            }
            tw /= 2;
            th /= 2;
            level += 1;
        }
        level + 1
    }

    /// Whether `p` holds what `need` reads, on the whole scan's grid (module documentation).
    fn serves(&self, p: &Patch, need: &Need) -> bool {
        let grid = 1usize << (need.levels - 1);
        let (m, w) = (need.margin, need.window);
        let (c1, r1) = (w.col + w.width, w.row + w.height);
        let (pc1, pr1) = (p.col + p.width, p.row + p.height);
        p.smooth == need.smooth
            && p.pyr.levels.len() >= need.levels
            && p.width >= need.least.0
            && p.height >= need.least.1
            && p.col % grid == 0
            && p.row % grid == 0
            && (p.col == 0 || w.col >= p.col + m)
            && (p.row == 0 || w.row >= p.row + m)
            && (pc1 == self.width || c1 + m <= pc1)
            && (pr1 == self.height || r1 + m <= pr1)
            && p.col <= w.col
            && p.row <= w.row
            && c1 <= pc1
            && r1 <= pr1
    }
}

/// The windows of one scan read so far (module documentation).
pub(super) struct Patches<'a> {
    scan: ScanWindows<'a>,
    grid: Grid,
    patches: Vec<Patch>,
}

/// The patches read, for searches that read nothing more (shared between threads).
pub(super) struct Ready<'p> {
    grid: &'p Grid,
    patches: &'p [Patch],
}

impl Ready<'_> {
    /// [`match_template`] of `tpl` in `window` of the scan, positions in scan pixels, in
    /// the smoothed scan when `smooth` (with a template [`smoothed`] likewise), in a patch
    /// [`Patches::prepare`] read for it.
    pub fn search(
        &self,
        tpl: &GreyImage,
        window: Window,
        opts: &MatchOptions,
        smooth: bool,
    ) -> Result<MatchResult> {
        let need = self.grid.need(tpl, window, opts, smooth);
        let Some(p) = self.patches.iter().find(|p| self.grid.serves(p, &need)) else {
            return Err(super::super::invalid(
                "scan window",
                format!("{window:?} was not read before its search"),
            ));
        };
        let local = Window {
            col: window.col - p.col,
            row: window.row - p.row,
            ..window
        };
        let (dx, dy) = (p.col as f64, p.row as f64);
        match_template(&p.pyr, tpl, local, None, opts).map(|mut m| {
            m.x += dx;
            m.y += dy;
            m.ncc_x += dx;
            m.ncc_y += dy;
            m
        })
    }
}

impl<'a> Patches<'a> {
    pub fn new(scan: ScanWindows<'a>) -> Self {
        let (width, height) = scan.size();
        let (mut w, mut h, mut scan_levels) = (width, height, 1);
        while scan_levels < SCAN_LEVELS && w / 2 >= SCAN_LEVEL_SIDE && h / 2 >= SCAN_LEVEL_SIDE {
            w /= 2;
            h /= 2;
            scan_levels += 1;
        }
        Self {
            scan,
            grid: Grid {
                width,
                height,
                scan_levels,
            },
            patches: Vec::new(),
        }
    }

    /// Width and height of the scan.
    pub fn size(&self) -> (usize, usize) {
        (self.grid.width, self.grid.height)
    }

    /// Pixels read from the scan so far.
    pub fn pixels_read(&self) -> u64 {
        self.scan.pixels_read()
    }

    /// The window centred on (x, y) with the given half-size, clipped to the scan.
    pub fn around(&self, x: f64, y: f64, half_w: f64, half_h: f64) -> Option<Window> {
        around(self.size(), x, y, half_w, half_h)
    }

    /// Drops the patches of the unsmoothed scan (the wide searches' windows).
    pub fn drop_unsmoothed(&mut self) {
        self.patches.retain(|p| p.smooth);
    }

    /// The patches read so far, for searches in them ([`Ready::search`]).
    pub fn ready(&self) -> Ready<'_> {
        Ready {
            grid: &self.grid,
            patches: &self.patches,
        }
    }

    /// [`Ready::search`] after reading what it needs. The outer error is the scan's (it
    /// could not be read), the inner one the match's.
    pub fn search(
        &mut self,
        tpl: &GreyImage,
        window: Window,
        opts: &MatchOptions,
        smooth: bool,
    ) -> Result<Result<MatchResult>> {
        self.prepare(tpl, window, opts, smooth)?;
        Ok(self.ready().search(tpl, window, opts, smooth))
    }

    /// Reads a patch for the search of `tpl` in `window` ([`Ready::search`]) unless one
    /// read before serves it.
    pub fn prepare(
        &mut self,
        tpl: &GreyImage,
        window: Window,
        opts: &MatchOptions,
        smooth: bool,
    ) -> Result<()> {
        let need = self.grid.need(tpl, window, opts, smooth);
        if self.patches.iter().any(|p| self.grid.serves(p, &need)) {
            return Ok(());
        }
        let grid = 1usize << (need.levels - 1);
        let reach = need.margin + SLACK;
        let Window {
            col: c0,
            row: r0,
            width,
            height,
        } = window;
        // From `lo` to `hi` along a side of `n` pixels, at least `least` long, starting on
        // the grid.
        let span = |lo: usize, hi: usize, n: usize, least: usize| {
            let (mut lo, mut hi) = (lo.saturating_sub(reach), (hi + reach).min(n));
            if hi - lo < least {
                hi = (lo + least).min(n);
                lo = hi - least;
            }
            let lo = lo / grid * grid;
            (lo, hi - lo)
        };
        let (col, w) = span(c0, c0 + width, self.grid.width, need.least.0);
        let (row, h) = span(r0, r0 + height, self.grid.height, need.least.1);
        let area = Window {
            col,
            row,
            width: w,
            height: h,
        };
        let mut img = self.scan.read(area)?;
        if smooth {
            img = gaussian_blur(&img, SMOOTH_PX);
        }
        self.patches.push(Patch {
            col,
            row,
            width: area.width,
            height: area.height,
            smooth,
            pyr: Pyramid::from_image(img, need.levels, 1),
        });
        Ok(())
    }

    /// Grey-value standard deviation of the scan over the data strip as `io` places it,
    /// sampled every scan pixel (at least every 0.1 mm); None when less than half of it
    /// lies inside the scan.
    pub fn strip_std(
        &mut self,
        io: &InteriorOrientation,
        strip: &DataStrip,
    ) -> Result<Option<f64>> {
        let step_mm = io.mean_pixel_size_mm().max(0.1);
        let nx = (((strip.x_mm[1] - strip.x_mm[0]) / step_mm).ceil() as usize).clamp(1, 4000);
        let ny = (((strip.y_mm[1] - strip.y_mm[0]) / step_mm).ceil() as usize).clamp(1, 4000);
        let (w, h) = (self.grid.width as f64, self.grid.height as f64);
        let (mut n, mut sum, mut sq) = (0usize, 0.0, 0.0);
        let rows_at_once = (STRIP_SAMPLES / nx).max(1);
        for j0 in (0..ny).step_by(rows_at_once) {
            let mut pixels = Vec::new();
            for j in j0..(j0 + rows_at_once).min(ny) {
                for i in 0..nx {
                    let mm = Vector2::new(
                        strip.x_mm[0]
                            + (i as f64 + 0.5) * (strip.x_mm[1] - strip.x_mm[0]) / nx as f64,
                        strip.y_mm[0]
                            + (j as f64 + 0.5) * (strip.y_mm[1] - strip.y_mm[0]) / ny as f64,
                    );
                    let p = io.mm_to_pixel(mm);
                    if p.x >= 0.0 && p.y >= 0.0 && p.x < w && p.y < h {
                        pixels.push((p.x as usize, p.y as usize));
                    }
                }
            }
            // Summed in the order of the samples, however the pixels were read.
            for v in self.values_at(&pixels)? {
                let v = v as f64;
                n += 1;
                sum += v;
                sq += v * v;
            }
        }
        if 2 * n < nx * ny {
            return Ok(None);
        }
        let mean = sum / n as f64;
        Ok(Some((sq / n as f64 - mean * mean).max(0.0).sqrt()))
    }

    /// The grey values at pixels (col, row) of the scan: from the scan when it is held,
    /// else by runs of one row (samples at most [`STRIP_RUN_GAP`] apart), so that a strip
    /// sampled every few pixels reads little more than its samples.
    fn values_at(&mut self, pixels: &[(usize, usize)]) -> Result<Vec<f32>> {
        if let Some(img) = self.scan.image() {
            return Ok(pixels.iter().map(|&(c, r)| img.at(c, r)).collect());
        }
        let mut order: Vec<usize> = (0..pixels.len()).collect();
        order.sort_unstable_by_key(|&k| (pixels[k].1, pixels[k].0));
        let mut values = vec![0f32; pixels.len()];
        let mut s = 0;
        while s < order.len() {
            let (left, row) = pixels[order[s]];
            let mut e = s + 1;
            while e < order.len()
                && pixels[order[e]].1 == row
                && pixels[order[e]].0 <= pixels[order[e - 1]].0 + STRIP_RUN_GAP
            {
                e += 1;
            }
            let right = pixels[order[e - 1]].0;
            let run = self.scan.read(Window {
                col: left,
                row,
                width: right + 1 - left,
                height: 1,
            })?;
            for &k in &order[s..e] {
                values[k] = run.at(pixels[k].0 - left, 0);
            }
            s = e;
        }
        Ok(values)
    }
}
