//! The work of oriented tie matching, photo by photo: the pairs of a block are planned
//! from the approximate orientations alone ([`plan_pairs`]: each photo with the later
//! photos it overlaps), and each photo's pairs are matched on their own
//! ([`match_photo_pairs`]: its image and its partners' prepared, each pair searched and
//! verified by its relative orientation). Where the photos' work runs is a
//! [`PairMatching`]: [`InMemory`] runs them here one after the other with one cache of
//! prepared photos; the pipeline can run each as a task on another machine. The matches
//! are then linked in photo order, so both give the same tracks.

use super::forstner::forstner;
use super::oriented::{predict_oriented_pair, BlockTieOptions, OrientedPair, OrientedPhoto};
use super::oriented::{PairReport, Surface};
use super::ties::{relative_orientation, search_candidates, PairMatches, SearchPoint, TieOptions};
use super::{invalid, MatchingError, Pyramid, Result};
use crate::block::PhotoId;
use crate::cache::Lru;
use crate::geometry::back_project;
use nalgebra::Vector3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Photo `a`'s pairs: each later photo it overlaps, with the predicted pair.
#[derive(Debug, Clone)]
pub struct PhotoPairs {
    pub a: usize,
    pub pairs: Vec<(usize, OrientedPair)>,
}

impl PhotoPairs {
    /// Whether any of the pairs is searched (the others are skipped by their predicted
    /// uncertainty alone, without an image).
    pub fn has_search(&self, opts: &BlockTieOptions) -> bool {
        self.pairs.iter().any(|(_, p)| searched(p, opts))
    }
}

fn searched(pair: &OrientedPair, opts: &BlockTieOptions) -> bool {
    pair.prediction.search_radius_px <= opts.max_radius_px
}

/// What one photo's pairs gave: the verified matches, a report per pair, and how many
/// photos were decoded and prepared for them (those a cache held already do not count).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MatchedPairs {
    pub matches: Vec<PairMatches>,
    pub reports: Vec<PairReport>,
    pub prepared: usize,
}

/// Photos prepared for tie matching (pyramid and interest points), kept between pairs
/// and bounded in bytes: pairs run in photo order, so a photo's partners in the next
/// strip are prepared once and reused by its neighbours.
pub struct PreparedPhotos(Lru<usize, Prepared>);

impl PreparedPhotos {
    pub fn new(bound_bytes: u64) -> Self {
        Self(Lru::new(bound_bytes))
    }

    /// Photos prepared so far (again after leaving the cache counts again).
    pub fn loads(&self) -> usize {
        self.0.loads()
    }

    /// Keeps only the photos of `job` (its photo and its partners): what the next photo's
    /// pairs share with them, in a process that runs one photo's pairs at a time.
    pub fn keep_job(&mut self, job: &PhotoPairs) {
        self.0
            .retain(|&k| k == job.a || job.pairs.iter().any(|(b, _)| *b == k));
    }
}

/// Where the photos' pair matching runs.
pub trait PairMatching {
    type Error;
    /// What each of `jobs` gave, in their order.
    fn match_pairs(
        &self,
        photos: &[OrientedPhoto],
        ids: &[PhotoId],
        jobs: &[PhotoPairs],
        surface: &Surface,
        opts: &BlockTieOptions,
    ) -> std::result::Result<Vec<MatchedPairs>, Self::Error>;
}

/// The photos' pairs matched here, photo after photo, with one cache of prepared photos
/// (each photo's partners prepared in parallel, each pair's search parallel).
pub struct InMemory;

impl PairMatching for InMemory {
    type Error = MatchingError;

    fn match_pairs(
        &self,
        photos: &[OrientedPhoto],
        ids: &[PhotoId],
        jobs: &[PhotoPairs],
        surface: &Surface,
        opts: &BlockTieOptions,
    ) -> Result<Vec<MatchedPairs>> {
        let mut cache = PreparedPhotos::new(opts.image_cache_bytes);
        jobs.iter()
            .map(|job| match_photo_pairs(photos, ids, job, surface, opts, &mut cache))
            .collect()
    }
}

/// Every photo's pairs (a < b), in photo order, from the approximate orientations.
pub fn plan_pairs(
    photos: &[OrientedPhoto],
    surface: &Surface,
    opts: &BlockTieOptions,
) -> Vec<PhotoPairs> {
    // Ground footprints (centre and radius) screen the pairs cheaply, so that a block of
    // thousands of photos does not transfer a grid for every one of its n² pairs.
    let footprints: Vec<Option<(Vector3<f64>, f64)>> =
        photos.par_iter().map(|p| footprint(p, surface)).collect();
    (0..photos.len())
        .into_par_iter()
        .map(|ia| {
            let mut pairs = Vec::new();
            for ib in ia + 1..photos.len() {
                if let (Some((ca, ra)), Some((cb, rb))) = (footprints[ia], footprints[ib]) {
                    if (ca.xy() - cb.xy()).norm() > ra + rb {
                        continue;
                    }
                }
                if let Some(pair) = predict_oriented_pair(photos, ia, ib, surface, opts) {
                    pairs.push((ib, pair));
                }
            }
            PhotoPairs { a: ia, pairs }
        })
        .collect()
}

/// Matches photo `job.a` with each of its partners: the photos a search needs are
/// prepared (those `cache` lacks, in parallel), each pair is searched around its
/// prediction and verified by a robust relative orientation.
pub fn match_photo_pairs(
    photos: &[OrientedPhoto],
    ids: &[PhotoId],
    job: &PhotoPairs,
    surface: &Surface,
    opts: &BlockTieOptions,
    cache: &mut PreparedPhotos,
) -> Result<MatchedPairs> {
    let t = &opts.ties;
    let ia = job.a;
    let loads = cache.loads();
    let cache = &mut cache.0;
    let mut need: Vec<usize> = job
        .pairs
        .iter()
        .filter(|(_, pair)| searched(pair, opts))
        .map(|(ib, _)| *ib)
        .collect();
    if !need.is_empty() {
        need.push(ia);
    }
    need.retain(|k| !cache.contains(k));
    let made: Vec<(usize, Result<Prepared>)> = need
        .par_iter()
        .map(|&k| (k, prepare(&photos[k], ids[k], t)))
        .collect();
    for (k, r) in made {
        let p = r?;
        cache.get_or_load(&k, || Ok::<_, MatchingError>(p.weighed()))?;
    }
    let mut matches = Vec::new();
    let mut reports = Vec::new();
    for (ib, pair) in &job.pairs {
        let ib = *ib;
        let radius = pair.prediction.search_radius_px;
        let mut report = PairReport {
            a: ids[ia],
            b: ids[ib],
            overlap: pair.overlap,
            search_radius_px: radius,
            points: 0,
            candidates: 0,
            accepted: 0,
            sigma_px: f64::NAN,
            skipped: None,
        };
        if !searched(pair, opts) {
            report.skipped = Some(format!(
                "predicted uncertainty needs a {radius:.0} px search (limit {:.0} px)",
                opts.max_radius_px
            ));
            reports.push(report);
            continue;
        }
        let mut get = |k: usize| {
            cache.get_or_load(&k, || prepare(&photos[k], ids[k], t).map(Prepared::weighed))
        };
        let (pa, pb) = (get(ia)?, get(ib)?);
        let margin = t.template_half as f64 + 2.0;
        let sp = search_points(&photos[ia], &photos[ib], surface, &pa.points, margin);
        report.points = sp.len();
        let cands = search_candidates(&pa.pyramid.levels[0], &pb.pyramid, &sp, radius, t);
        report.candidates = cands.len();
        if cands.len() < opts.min_pair_matches {
            report.skipped = Some(format!(
                "{} candidates, fewer than {} needed for a verified relative orientation",
                cands.len(),
                opts.min_pair_matches
            ));
            reports.push(report);
            continue;
        }
        match relative_orientation(ia, ib, cands, t) {
            Ok(pm) => {
                let n = pm.inliers.iter().filter(|&&i| i).count();
                report.accepted = n;
                report.sigma_px = pm.sigma_px;
                if n < opts.min_pair_matches {
                    report.skipped = Some(format!(
                        "{n} matches consistent with the relative orientation, fewer than {}",
                        opts.min_pair_matches
                    ));
                } else {
                    matches.push(pm);
                }
            }
            Err(e) => report.skipped = Some(e.to_string()),
        }
        tracing::debug!(
            a = report.a,
            b = report.b,
            radius,
            points = report.points,
            candidates = report.candidates,
            accepted = report.accepted,
            "oriented tie pair"
        );
        reports.push(report);
    }
    Ok(MatchedPairs {
        matches,
        reports,
        prepared: cache.loads() - loads,
    })
}

/// A photo ready for tie matching: its pyramid (level 0 is the image) and its Förstner
/// points.
struct Prepared {
    pyramid: Pyramid,
    points: Vec<[f64; 2]>,
}

impl Prepared {
    /// With its weight in the cache: the bytes it holds.
    fn weighed(self) -> (Self, u64) {
        let bytes =
            self.pyramid.bytes() + (self.points.len() * std::mem::size_of::<[f64; 2]>()) as u64;
        (self, bytes)
    }
}

/// Decodes a photo (checking its size against the camera) and prepares it.
fn prepare(p: &OrientedPhoto, id: PhotoId, t: &TieOptions) -> Result<Prepared> {
    let img = p.image.get()?;
    let (w, h) = p.camera.image_size();
    if (w as usize, h as usize) != (img.width, img.height) {
        return Err(invalid(
            format!("photo {id}"),
            format!(
                "image is {}×{} px but its camera is {w}×{h} px",
                img.width, img.height
            ),
        ));
    }
    let points = forstner(&img, &t.forstner)
        .iter()
        .map(|q| [q.x, q.y])
        .collect();
    Ok(Prepared {
        pyramid: Pyramid::from_image(img.into_owned(), 6, 32),
        points,
    })
}

/// Search points of photo a for photo b: each point's own transfer through the surface
/// and the local shape of the transfer (central differences over ±2 px).
fn search_points(
    a: &OrientedPhoto,
    b: &OrientedPhoto,
    surface: &Surface,
    points: &[[f64; 2]],
    margin: f64,
) -> Vec<SearchPoint> {
    let (wb, hb) = b.size();
    points
        .par_iter()
        .filter_map(|&p| {
            let q = a.transfer(b, surface, p)?;
            if q[0] < margin || q[1] < margin || q[0] > wb - margin || q[1] > hb - margin {
                return None;
            }
            const D: f64 = 2.0;
            let xp = a.transfer(b, surface, [p[0] + D, p[1]])?;
            let xm = a.transfer(b, surface, [p[0] - D, p[1]])?;
            let yp = a.transfer(b, surface, [p[0], p[1] + D])?;
            let ym = a.transfer(b, surface, [p[0], p[1] - D])?;
            let s = 1.0 / (2.0 * D);
            Some(SearchPoint {
                a: p,
                predicted_b: q,
                affine: Some([
                    (xp[0] - xm[0]) * s,
                    (yp[0] - ym[0]) * s,
                    (xp[1] - xm[1]) * s,
                    (yp[1] - ym[1]) * s,
                ]),
            })
        })
        .collect()
}

/// Ground centre of a photo and the radius that contains its footprint (image centre and
/// corners carried onto the surface); `None` when a ray misses the surface (the pair is
/// then judged by the grid transfer alone).
fn footprint(p: &OrientedPhoto, surface: &Surface) -> Option<(Vector3<f64>, f64)> {
    let (w, h) = p.size();
    let ground = |q: [f64; 2]| {
        back_project(p.camera, &p.pose, q)
            .ok()
            .and_then(|r| surface.intersect(&r))
    };
    let c = ground([w / 2.0, h / 2.0])?;
    let mut r: f64 = 0.0;
    for q in [[0.0, 0.0], [w, 0.0], [0.0, h], [w, h]] {
        r = r.max((ground(q)?.xy() - c.xy()).norm());
    }
    Some((c, r))
}
