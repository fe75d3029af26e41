//! Scan orientation hypotheses: the eight ways a film can lie on the scanner (the square's
//! rotations and reflections), how well each explains the scan, and the orientation an
//! epoch shares.
//!
//! A hypothesis assigns the measured marks to fiducial numbers. Its cost multiplies three
//! cues, each compared between hypotheses only as a ratio:
//! * geometry: the RMS residual (µm) of the calibrated layout after the fitted transform,
//!   a mark the hypothesis could not use counting as a residual at the rejection limit.
//!   Calibrated layouts are symmetric only to tens of µm, many times the measuring
//!   precision, so the wrong assignment of a near-symmetric layout fits far worse;
//! * look: the product over marks of the variance the template leaves unexplained
//!   (1 − ρ², ρ the mark's NCC; 1 for a mark not used), which a distinct mark shape
//!   changes by several times wherever the hypothesis puts the wrong shape;
//! * data strip: the reciprocal of the grey-value spread where the hypothesis puts the
//!   camera's data strip (text on one side, uniform opaque frame on the others).

use super::{CameraDefinition, IoOptions, IoResult, MarkResult};
use crate::geometry::InteriorOrientation;
use crate::matching::{GreyImage, MatchingError, Result};
use nalgebra::Matrix2;
use serde::{Deserialize, Serialize};

/// How the scan lies relative to the fiducial system: the ideal map pixel → mm
/// (x = col·s, y = −row·s about the centre) is rotated counter-clockwise by
/// `rotation_deg` and, when `mirrored`, reflected in the y axis first.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct ScanOrientation {
    pub rotation_deg: u16,
    pub mirrored: bool,
}

impl std::fmt::Display for ScanOrientation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}°{}",
            self.rotation_deg,
            if self.mirrored { " mirrored" } else { "" }
        )
    }
}

/// "0", "90", "180" or "270", with "m" appended when mirrored (command lines, files).
impl std::str::FromStr for ScanOrientation {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        let mirrored = s.ends_with('m');
        s.trim_end_matches('m')
            .parse::<u16>()
            .ok()
            .filter(|r| r % 90 == 0 && *r < 360)
            .map(|rotation_deg| ScanOrientation {
                rotation_deg,
                mirrored,
            })
            .ok_or_else(|| format!("{s:?}: expected 0, 90, 180 or 270, optionally followed by m"))
    }
}

impl ScanOrientation {
    pub fn all() -> Vec<Self> {
        let mut v = Vec::new();
        for mirrored in [false, true] {
            for rotation_deg in [0, 90, 180, 270] {
                v.push(Self {
                    rotation_deg,
                    mirrored,
                });
            }
        }
        v
    }

    /// Linear map from a pixel offset (col, row) to an mm offset, for pixel size `s`.
    pub fn linear(&self, s: f64) -> Matrix2<f64> {
        let base = Matrix2::new(s, 0.0, 0.0, -s);
        let m = if self.mirrored {
            Matrix2::new(-1.0, 0.0, 0.0, 1.0)
        } else {
            Matrix2::identity()
        };
        let (c, si) = match self.rotation_deg % 360 {
            90 => (0.0, 1.0),
            180 => (-1.0, 0.0),
            270 => (0.0, -1.0),
            _ => (1.0, 0.0),
        };
        Matrix2::new(c, -si, si, c) * m * base
    }
}

/// Smallest margin (cost of the second-best hypothesis over the best) at which the scan
/// orientation counts as decided. For the geometric cue alone this is an RMS ratio of 2,
/// an F ratio of 4: with the 10 redundant coordinates of 8 marks, noise alone reaches it
/// in about 2 % of cases, while the wrong assignment of a real (near-symmetric) layout
/// scores 4–40 times worse at 42–21 µm scan pixels.
pub const ORIENTATION_MIN_MARGIN: f64 = 2.0;

/// Margin reported when no other hypothesis measured enough marks to be compared.
pub const ORIENTATION_MARGIN_CAP: f64 = 1000.0;

/// Unexplained variance credited to a mark however well it matches: NCC above ≈ 0.87
/// (a good real mark) is taken as a perfect match. The same physical mark correlates a
/// few % differently with the template drawn through each hypothesis' similarity (at
/// 100 µm pixels, 1 − ρ² of 0.171 against 0.179 over eight marks made a 1.4× cost
/// difference); a wrong mark shape (ρ < 0.7, 1 − ρ² > 0.5) still weighs twice or more.
const UNEXPLAINED_FLOOR: f64 = 0.25;

/// How well one orientation hypothesis explains the scan.
#[derive(Debug, Clone, Serialize)]
pub struct OrientationScore {
    pub orientation: ScanOrientation,
    /// Marks used in its transform.
    pub marks_used: usize,
    /// RMS residual of its used marks (µm).
    pub rmse_um: f64,
    /// Geometric cue: RMS residual per redundant coordinate with every mark it could not
    /// use counted at the rejection limit (µm).
    pub geometry_um: f64,
    /// Look cue: geometric mean over the marks of the unexplained variance 1 − ρ²
    /// (floored at 0.25; 1 for a mark not used).
    pub unexplained: f64,
    /// Data-strip cue: grey-value standard deviation where it puts the data strip
    /// (None without a data strip in the camera definition or inside the scan).
    pub strip_std: Option<f64>,
    /// geometry_um × unexplained^marks ÷ (1 + strip_std): only ratios between
    /// hypotheses mean anything.
    pub cost: f64,
}

/// A measured hypothesis: its marks and fitted transform.
pub(super) struct Hypothesis {
    pub orientation: ScanOrientation,
    pub marks: Vec<MarkResult>,
    pub io: InteriorOrientation,
    pub rmse_plain: f64,
    pub score: OrientationScore,
}

/// Scores a hypothesis from its fit (without the data-strip cue, added by [`rank`]).
pub(super) fn score(
    orientation: ScanOrientation,
    marks: &[MarkResult],
    ss: f64,
    rmse_plain: f64,
    dof: usize,
    max_res_um: f64,
    floor_um: f64,
) -> OrientationScore {
    let n = marks.len();
    let unused = marks.iter().filter(|m| !m.used).count();
    let redundant = (2 * n).saturating_sub(dof).max(1);
    let geometry_um = ((ss + unused as f64 * max_res_um * max_res_um) / redundant as f64)
        .sqrt()
        .max(floor_um);
    let ln_u: f64 = marks
        .iter()
        .map(|m| {
            if m.used {
                (1.0 - m.ncc * m.ncc).max(UNEXPLAINED_FLOOR).ln()
            } else {
                0.0
            }
        })
        .sum();
    OrientationScore {
        orientation,
        marks_used: n - unused,
        rmse_um: rmse_plain,
        geometry_um,
        unexplained: (ln_u / n as f64).exp(),
        strip_std: None,
        cost: geometry_um * ln_u.exp(),
    }
}

/// Adds the data-strip cue (`strip_stds`: the grey-value spread where each hypothesis puts
/// the data strip, [`super::patches::Patches::strip_std`]; empty without a data strip),
/// when every hypothesis can see the strip, and sorts the hypotheses best first; returns
/// the margin of the best over the second.
pub(super) fn rank(hyps: &mut [Hypothesis], strip_stds: &[Option<f64>]) -> f64 {
    if !strip_stds.is_empty() && strip_stds.iter().all(Option::is_some) {
        for (h, s) in hyps.iter_mut().zip(strip_stds) {
            let s = s.unwrap_or_default();
            h.score.strip_std = Some(s);
            h.score.cost /= 1.0 + s;
        }
    }
    hyps.sort_by(|a, b| a.score.cost.total_cmp(&b.score.cost));
    match hyps {
        [best, second, ..] => (second.score.cost / best.score.cost).min(ORIENTATION_MARGIN_CAP),
        _ => ORIENTATION_MARGIN_CAP,
    }
}

/// The orientation an epoch's undecided scans take: the one a strict majority of its
/// confidently decided scans (Ok and not `orientation_ambiguous`: the marks put the
/// orientation at least the confidence margin ahead of any other) has; with the number of votes and of decided scans. None without such a majority.
pub fn majority_orientation<'a>(
    results: impl IntoIterator<Item = &'a Result<IoResult>>,
) -> Option<(ScanOrientation, usize, usize)> {
    majority_of_votes(results.into_iter().map(|r| match r {
        Ok(r) if !r.orientation_ambiguous => Some(r.orientation),
        _ => None,
    }))
}

/// The majority rule of [`majority_orientation`] over votes already taken: `Some` is a
/// scan whose marks decided its orientation, `None` one that did not vote. Returns the
/// orientation more than half the deciding scans found, with its votes and the number of
/// deciding scans (per-scan tasks vote in separate processes).
pub fn majority_of_votes(
    votes: impl IntoIterator<Item = Option<ScanOrientation>>,
) -> Option<(ScanOrientation, usize, usize)> {
    let mut tally: Vec<(ScanOrientation, usize)> = Vec::new();
    let mut decided = 0;
    for o in votes.into_iter().flatten() {
        decided += 1;
        match tally.iter_mut().find(|v| v.0 == o) {
            Some(v) => v.1 += 1,
            None => tally.push((o, 1)),
        }
    }
    let (o, n) = tally.into_iter().max_by_key(|v| v.1)?;
    (2 * n > decided).then_some((o, n, decided))
}

/// Fiducial interior orientation of an epoch's scans, the orientation found per scan:
/// a scan whose orientation the marks cannot decide
/// ([`MatchingError::OrientationUndecided`]) takes the majority orientation of the
/// epoch's decided scans ([`majority_orientation`]), its `orientation_source` saying so;
/// without a majority it keeps the error. `load` gives a scan's name and image; scans are
/// loaded one at a time (twice for an undecided one), so a large epoch never holds more
/// than one scan in memory. With `opts.orientation` given, every scan takes it.
pub fn interior_orientation_epoch<S>(
    cam: &CameraDefinition,
    scans: &[S],
    load: impl Fn(&S) -> Result<(String, GreyImage)>,
    opts: &IoOptions,
) -> Vec<Result<IoResult>> {
    let run = |s: &S, o: &IoOptions| -> Result<IoResult> {
        let (name, img) = load(s)?;
        super::interior_orientation(cam, &img, &name, o)
    };
    let mut out: Vec<Result<IoResult>> = scans.iter().map(|s| run(s, opts)).collect();
    let Some((o, votes, decided)) = majority_orientation(&out) else {
        return out;
    };
    let fixed = IoOptions {
        fallback_orientation: Some(o),
        ..opts.clone()
    };
    for (s, r) in scans.iter().zip(out.iter_mut()) {
        if matches!(r, Err(MatchingError::OrientationUndecided { .. })) {
            *r = run(s, &fixed).map(|mut io| {
                io.orientation_source = format!(
                    "epoch majority ({votes} of {decided} decided scans lie {o}); this scan's \
                     marks could not decide"
                );
                io
            });
        }
    }
    out
}
