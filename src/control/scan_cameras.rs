//! A film epoch's scans measured once: every scan's fiducial interior orientation and,
//! where the fiducial layout leaves the scan orientation open, the other orientations that
//! fit the marks as well. A photo is oriented again in the second pass and in every round
//! of the tie pass; measuring its fiducials each time made interior orientation 11 % of a
//! small block's CPU (18 measurements for 6 scans, `perf`, seed 1).

use super::epoch::PhotoInput;
use super::photo::ScanIo;
use crate::geometry::{Brown, FilmCamera};
use crate::matching::fiducial::majority_orientation;
use crate::matching::{
    self, CameraDefinition, GreyImage, IoOptions, IoResult, MatchingError, ScanOrientation,
};
use rayon::prelude::*;
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

impl ScanCameras {
    /// Measures every scan of `photos` (in parallel, one scan per thread in memory). A scan
    /// whose marks cannot decide its orientation takes the majority of the decided scans
    /// ([`majority_orientation`]) unless `io` gives one; it is read a second time for that.
    /// A scan that cannot be read is left out: orienting it reports the read error.
    pub fn measure(def: &CameraDefinition, photos: &[PhotoInput], io: &IoOptions) -> Self {
        let first_io = IoOptions {
            fallback_orientation: None,
            ..io.clone()
        };
        type First = (Result<IoResult, MatchingError>, Option<Candidates>);
        let first: Vec<Option<First>> = photos
            .par_iter()
            .map(|ph| {
                let img = GreyImage::load(&ph.image).ok()?;
                let r = matching::interior_orientation(def, &img, &ph.name, &first_io);
                let c = match &r {
                    Err(MatchingError::OrientationUndecided { .. }) => None,
                    Err(e) => Some(Err(e.to_string())),
                    Ok(r) => Some(Ok(candidates(def, &img, &ph.name, &first_io, r))),
                };
                Some((r, c))
            })
            .collect();
        let majority = match io.orientation {
            None => majority_orientation(first.iter().flatten().map(|f| &f.0)).map(|m| m.0),
            Some(_) => None,
        };
        let undecided = IoOptions {
            fallback_orientation: majority,
            ..io.clone()
        };
        let by_photo = photos
            .par_iter()
            .zip(first)
            .filter_map(|(ph, f)| {
                let c = match f?.1 {
                    Some(c) => c,
                    None => {
                        cameras_of(def, &GreyImage::load(&ph.image).ok()?, &ph.name, &undecided)
                    }
                };
                Some((ph.name.clone(), c))
            })
            .collect();
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
    ScanIo {
        rmse_um: r.rmse_um,
        pixel_um: r.pixel_um,
        pixel_source: r.pixel_source.clone(),
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
