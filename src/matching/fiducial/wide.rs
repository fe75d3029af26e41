//! The wide search: a scan orientation's two marks found in ±`search_mm` windows around
//! where the nominal scan geometry (the pixel size about the scan's centre, turned and
//! mirrored as the orientation says) puts them, by NCC alone. The first pair's searches
//! of all eight orientations are read one after the other and made in parallel; another
//! pair, tried when a mark of the first is missing, one search at a time.

use super::super::matcher::MatchOptions;
use super::super::ncc::Window;
use super::super::{GreyImage, Result};
use super::patches::{around, Patches};
use super::shape::render_template;
use super::{CameraDefinition, FiducialDef, IoOptions, ScanOrientation};
use nalgebra::Vector2;
use rayon::prelude::*;
use std::collections::HashMap;

/// Search key: rounded predicted pixel, mark shape, scan orientation.
type WideKey = (i64, i64, String, u16, bool);

/// A mark found: its pixel position and NCC.
pub(super) type Found = Option<(f64, f64, f64)>;

/// The wide searches of one scan, each made once.
pub(super) struct Wide<'o> {
    /// Nominal scan pixel (mm).
    s: f64,
    centre: Vector2<f64>,
    margin_mm: f64,
    io: &'o IoOptions,
    matching: MatchOptions,
    found: HashMap<WideKey, Found>,
}

/// A search to make: its key, and the template and window (None: the mark cannot be
/// searched, not found).
struct Job {
    key: WideKey,
    search: Option<(GreyImage, Window)>,
}

impl<'o> Wide<'o> {
    pub fn new(s: f64, centre: Vector2<f64>, margin_mm: f64, io: &'o IoOptions) -> Self {
        let mut matching = io.matching.clone();
        matching.use_lsm = false;
        Self {
            s,
            centre,
            margin_mm,
            io,
            matching,
            found: HashMap::new(),
        }
    }

    /// The key of `f`'s search in orientation `o` and where it is predicted; None for an
    /// orientation without a pixel → mm map.
    fn key(&self, f: &FiducialDef, o: ScanOrientation) -> Option<(WideKey, Vector2<f64>)> {
        let inv = o.linear(self.s).try_inverse()?;
        let p = self.centre + inv * Vector2::new(f.x_mm, f.y_mm);
        let key = (
            p.x.round() as i64,
            p.y.round() as i64,
            f.shape.key(),
            o.rotation_deg,
            o.mirrored,
        );
        Some((key, p))
    }

    /// The template of `f` in orientation `o` and its window around `p` in a scan of
    /// `size`.
    fn template_and_window(
        &self,
        size: (usize, usize),
        f: &FiducialDef,
        o: ScanOrientation,
        p: Vector2<f64>,
    ) -> Option<(GreyImage, Window)> {
        let tpl = render_template(&f.shape, &o.linear(self.s), self.margin_mm)?;
        let half = self.io.search_mm / self.s + tpl.width.max(tpl.height) as f64 / 2.0;
        let w = around(size, p.x, p.y, half, half)?;
        Some((tpl, w))
    }

    /// Makes the searches of the marks `pair` in every orientation: templates drawn in
    /// parallel, windows read in turn, searches in parallel.
    pub fn prefetch(
        &mut self,
        scan: &mut Patches,
        cam: &CameraDefinition,
        pair: (usize, usize),
    ) -> Result<()> {
        let mut wanted = Vec::new();
        for o in ScanOrientation::all() {
            for f in [&cam.fiducials[pair.0], &cam.fiducials[pair.1]] {
                if let Some((key, p)) = self.key(f, o) {
                    if !self.found.contains_key(&key) {
                        wanted.push((key, f, o, p));
                    }
                }
            }
        }
        let jobs: Vec<Job> = {
            let (this, size) = (&*self, scan.size());
            wanted
                .into_par_iter()
                .map(|(key, f, o, p)| Job {
                    key,
                    search: this.template_and_window(size, f, o, p),
                })
                .collect()
        };
        for j in &jobs {
            if let Some((tpl, w)) = &j.search {
                scan.prepare(tpl, *w, &self.matching, false)?;
            }
        }
        let found: Vec<(WideKey, Found)> = {
            let ready = scan.ready();
            jobs.into_par_iter()
                .map(|j| {
                    let v = j
                        .search
                        .and_then(|(tpl, w)| ready.search(&tpl, w, &self.matching, false).ok());
                    (j.key, self.accepted(v))
                })
                .collect()
        };
        self.found.extend(found);
        Ok(())
    }

    /// The position and NCC of a match good enough to carry the orientation's geometry.
    fn accepted(&self, m: Option<super::super::MatchResult>) -> Found {
        m.filter(|m| m.ncc >= self.io.matching.ncc_threshold)
            .map(|m| (m.x, m.y, m.ncc))
    }

    /// Mark `f` in orientation `o`: searched before, or now.
    pub fn find(
        &mut self,
        scan: &mut Patches,
        f: &FiducialDef,
        o: ScanOrientation,
    ) -> Result<Found> {
        let Some((key, p)) = self.key(f, o) else {
            return Ok(None);
        };
        if let Some(v) = self.found.get(&key) {
            return Ok(*v);
        }
        let m = match self.template_and_window(scan.size(), f, o, p) {
            Some((tpl, w)) => scan.search(&tpl, w, &self.matching, false)?.ok(),
            None => None,
        };
        let v = self.accepted(m);
        self.found.insert(key, v);
        Ok(v)
    }
}
