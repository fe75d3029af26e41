//! A film epoch's scans measured once: every scan's fiducial interior orientation and,
//! where the fiducial layout leaves the scan orientation open, the other orientations that
//! fit the marks as well. A photo is oriented again in the second pass and in every round
//! of the tie pass; measuring its fiducials each time made interior orientation 11 % of a
//! small block's CPU (18 measurements for 6 scans, `perf`, seed 1).

use super::epoch::PhotoInput;
use super::photo::ScanIo;
use crate::geometry::{Brown, FilmCamera};
use crate::matching::fiducial::majority_of_votes;
use crate::matching::{
    self, CameraDefinition, GreyImage, IoOptions, IoResult, MatchingError, ScanOrientation,
};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;

/// A scan's candidate cameras, best first, or why its interior orientation failed.
pub type Candidates = Result<Vec<(FilmCamera, ScanIo)>, String>;

/// The candidate film cameras of each scan of an epoch, by photo name.
#[derive(Debug, Clone, Default)]
pub struct ScanCameras {
    by_photo: HashMap<String, Candidates>,
    /// The orientation the undecided scans took: the epoch's majority, when there is one.
    pub majority: Option<ScanOrientation>,
}

/// One scan's first measurement, made without any epoch fallback orientation: its vote
/// for the epoch's majority, and its candidate cameras unless its marks left the scan
/// orientation undecided (then the majority decides, [`resolve_scan`]). A per-scan task
/// of a distributed run returns exactly this.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ScanMeasure {
    /// The orientation the marks decided (not ambiguous): this scan's majority vote.
    pub vote: Option<ScanOrientation>,
    /// `None`: orientation undecided, to be resolved with the epoch's majority.
    pub candidates: Option<Candidates>,
}

/// Measures one scan's fiducials (the first of [`ScanCameras::measure`]'s two steps).
/// `None`: the scan cannot be read (orienting it reports the read error).
pub fn measure_scan(
    def: &CameraDefinition,
    photo: &PhotoInput,
    io: &IoOptions,
) -> Option<ScanMeasure> {
    let first_io = IoOptions {
        fallback_orientation: None,
        ..io.clone()
    };
    let img = GreyImage::load(&photo.image).ok()?;
    let r = matching::interior_orientation(def, &img, &photo.name, &first_io);
    let vote = match &r {
        Ok(r) if !r.orientation_ambiguous => Some(r.orientation),
        _ => None,
    };
    let candidates = match &r {
        Err(MatchingError::OrientationUndecided { .. }) => None,
        Err(e) => Some(Err(e.to_string())),
        Ok(r) => Some(Ok(candidates(def, &img, &photo.name, &first_io, r))),
    };
    Some(ScanMeasure { vote, candidates })
}

/// The epoch's majority orientation from its scans' votes, unless `io` fixes one.
pub fn epoch_majority<'a>(
    measures: impl IntoIterator<Item = &'a ScanMeasure>,
    io: &IoOptions,
) -> Option<ScanOrientation> {
    match io.orientation {
        None => majority_of_votes(measures.into_iter().map(|m| m.vote)).map(|m| m.0),
        Some(_) => None,
    }
}

/// A scan's candidates (the second step): its own, or for an undecided scan those the
/// epoch's `majority` gives (the scan is read a second time for that). `None`: the scan
/// cannot be read.
pub fn resolve_scan(
    def: &CameraDefinition,
    photo: &PhotoInput,
    measure: &ScanMeasure,
    majority: Option<ScanOrientation>,
    io: &IoOptions,
) -> Option<Candidates> {
    if let Some(c) = &measure.candidates {
        return Some(c.clone());
    }
    let undecided = IoOptions {
        fallback_orientation: majority,
        ..io.clone()
    };
    let img = GreyImage::load(&photo.image).ok()?;
    Some(cameras_of(def, &img, &photo.name, &undecided))
}

impl ScanCameras {
    /// Measures every scan of `photos` (in parallel, one scan per thread in memory). A scan
    /// whose marks cannot decide its orientation takes the majority of the decided scans
    /// ([`majority_of_votes`]) unless `io` gives one; it is read a second time for that.
    /// A scan that cannot be read is left out: orienting it reports the read error.
    pub fn measure(def: &CameraDefinition, photos: &[PhotoInput], io: &IoOptions) -> Self {
        let first: Vec<Option<ScanMeasure>> = photos
            .par_iter()
            .map(|ph| measure_scan(def, ph, io))
            .collect();
        let majority = epoch_majority(first.iter().flatten(), io);
        let by_photo = photos
            .par_iter()
            .zip(first)
            .filter_map(|(ph, m)| {
                Some((ph.name.clone(), resolve_scan(def, ph, &m?, majority, io)?))
            })
            .collect();
        Self { by_photo, majority }
    }

    /// The scans of an epoch measured elsewhere (per-scan tasks): each photo's resolved
    /// candidates and the majority they were resolved with.
    pub fn from_parts(
        by_photo: HashMap<String, Candidates>,
        majority: Option<ScanOrientation>,
    ) -> Self {
        Self { by_photo, majority }
    }

    /// The measured candidates of photo `name`, if it was measured.
    pub fn of(&self, name: &str) -> Option<&Candidates> {
        self.by_photo.get(name)
    }
}

/// Film cameras of one scan: the best fiducial interior orientation first, then, when the
/// fiducial layout is symmetric, every other scan orientation whose marks fit within
/// twice the best RMSE (plus 10 µm).
pub fn cameras_of(
    def: &CameraDefinition,
    img: &GreyImage,
    name: &str,
    io: &IoOptions,
) -> Candidates {
    let r = matching::interior_orientation(def, img, name, io).map_err(|e| e.to_string())?;
    Ok(candidates(def, img, name, io, &r))
}

fn candidates(
    def: &CameraDefinition,
    img: &GreyImage,
    name: &str,
    io: &IoOptions,
    r: &IoResult,
) -> Vec<(FilmCamera, ScanIo)> {
    let mut out = vec![(film_from_io(def, img, r), scan_io(r))];
    if r.orientation_ambiguous && io.orientation.is_none() {
        for o in ScanOrientation::all() {
            if o == r.orientation {
                continue;
            }
            let forced = IoOptions {
                orientation: Some(o),
                ..io.clone()
            };
            if let Ok(r2) = matching::interior_orientation(def, img, name, &forced) {
                if r2.rmse_um <= 2.0 * r.rmse_um + 10.0 {
                    out.push((film_from_io(def, img, &r2), scan_io(&r2)));
                }
            }
        }
    }
    out
}

fn scan_io(r: &IoResult) -> ScanIo {
    let finite = |v: f64| v.is_finite().then_some(v);
    let used = r.marks.iter().filter(|m| m.used);
    ScanIo {
        rmse_um: r.rmse_um,
        pixel_um: r.pixel_um,
        pixel_source: r.pixel_source.clone(),
        measured_pixel_um: finite(r.pixel_mm * 1000.0),
        marks_used: used.clone().count(),
        marks_total: r.marks.len(),
        max_residual_um: used
            .map(|m| m.residual_norm_um)
            .filter(|v| v.is_finite())
            .reduce(f64::max),
        orientation: Some(r.orientation),
        orientation_source: r.orientation_source.clone(),
        orientation_margin: finite(r.orientation_margin),
        orientation_ambiguous: r.orientation_ambiguous,
        warnings: r.warnings.clone(),
    }
}

fn film_from_io(def: &CameraDefinition, img: &GreyImage, r: &IoResult) -> FilmCamera {
    let d = &def.distortion;
    FilmCamera {
        width: img.width as u32,
        height: img.height as u32,
        focal_mm: def.focal_mm,
        principal_point_mm: def.principal_point_mm,
        distortion: Brown::from_array([d.k1, d.k2, d.k3, d.p1, d.p2]),
        interior: r.transform.clone(),
    }
}
