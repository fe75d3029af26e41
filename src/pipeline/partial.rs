//! A run (or `cloudcontrol orient`) that finished with an epoch orienting fewer photos than
//! it has is *partial*: the one mechanism by which that is said rather than left in
//! `result.json`. The CLI ends such a run with exit status 3 and prints, per epoch, how
//! many photos were oriented and why the others were not; the C ABI returns
//! `CCP_STATUS_PARTIAL` with the summary; Python raises `cloudcontrol.PartialRunError`
//! carrying it (formats/project/README.md, "Exit statuses").
//!
//! Inputs a run would otherwise drop without a word (a photo without a POS or strip row,
//! a checkpoint measurement naming no surveyed checkpoint) are refused before any work
//! instead (`control::epoch::EpochInput::build`, `control::checkpoints`): a dropped input
//! is never a partial result.

use crate::block::PhotoFailure;
use crate::control::archive::EpochResult;
use crate::formats::FormatError;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// A photo an epoch did not orient, and why.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NotOriented {
    pub photo: String,
    /// The reason `result.json` gives (`block::PhotoFailure`, in words).
    pub reason: String,
}

/// An epoch that oriented fewer photos than it has.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PartialEpoch {
    pub epoch: String,
    pub oriented: usize,
    pub total: usize,
    /// Every photo not oriented, in the epoch's photo order.
    pub not_oriented: Vec<NotOriented>,
    /// The epoch's `result.json` (per-photo results), when written.
    pub result: Option<PathBuf>,
}

/// Photos listed per epoch by [`PartialEpoch::describe`]; the rest are counted.
pub const LISTED_PHOTOS: usize = 8;

impl PartialEpoch {
    /// The shortfall of epoch `epoch` from its photos (name, oriented, why not); `None`
    /// when every photo was oriented.
    pub fn of_photos(
        epoch: &str,
        photos: impl IntoIterator<Item = (String, bool, Option<String>)>,
        result: Option<PathBuf>,
    ) -> Option<Self> {
        let (mut oriented, mut total, mut not_oriented) = (0, 0, Vec::new());
        for (photo, ok, reason) in photos {
            total += 1;
            if ok {
                oriented += 1;
            } else {
                not_oriented.push(NotOriented {
                    photo,
                    reason: reason.unwrap_or_else(|| "no reason given".into()),
                });
            }
        }
        (oriented < total).then(|| Self {
            epoch: epoch.to_string(),
            oriented,
            total,
            not_oriented,
            result,
        })
    }

    /// The shortfall of an epoch's result (`cloudcontrol orient`).
    pub fn of_result(r: &EpochResult, result: Option<PathBuf>) -> Option<Self> {
        Self::of_photos(
            &r.epoch,
            r.photos.iter().map(|p| {
                (
                    p.name.clone(),
                    p.oriented,
                    p.reason.as_ref().map(|f| f.to_string()),
                )
            }),
            result,
        )
    }

    /// In words, for a terminal: `epoch E: N of M photos oriented`, then up to
    /// [`LISTED_PHOTOS`] photos with their reasons, then where the rest are.
    pub fn describe(&self) -> String {
        let mut s = format!(
            "epoch {}: {} of {} photos oriented",
            self.epoch, self.oriented, self.total
        );
        for n in self.not_oriented.iter().take(LISTED_PHOTOS) {
            s.push_str(&format!("\n  {}: {}", n.photo, n.reason));
        }
        let more = self.not_oriented.len().saturating_sub(LISTED_PHOTOS);
        if more > 0 {
            s.push_str(&format!("\n  … and {more} more photos not oriented"));
        }
        if let Some(r) = &self.result {
            s.push_str(&format!("\n  (every photo's result: {})", r.display()));
        }
        s
    }
}

/// What [`partial_epochs`] reads of an epoch stage's `result.json`.
#[derive(Deserialize)]
struct ResultFile {
    epoch: String,
    photos: Vec<PhotoResult>,
}

#[derive(Deserialize)]
struct PhotoResult {
    name: String,
    oriented: bool,
    #[serde(default)]
    reason: Option<serde_json::Value>,
}

/// The epochs of a run (their stage folders `epoch-<name>/`, in run order) that oriented
/// fewer photos than they have, read from their `result.json`.
pub fn partial_epochs(dirs: &[PathBuf]) -> Result<Vec<PartialEpoch>, FormatError> {
    let mut out = Vec::new();
    for d in dirs {
        let path = d.join("result.json");
        let r: ResultFile = super::epoch_files::read_json(&path)?;
        let photos = r.photos.into_iter().map(|p| {
            let reason = p.reason.filter(|v| !v.is_null()).map(|v| {
                PhotoFailure::deserialize(&v)
                    .map(|f| f.to_string())
                    .unwrap_or_else(|_| v.to_string())
            });
            (p.name, p.oriented, reason)
        });
        out.extend(PartialEpoch::of_photos(&r.epoch, photos, Some(path)));
    }
    Ok(out)
}

/// The summary line and per-epoch lines a partial run prints (empty when nothing is
/// partial).
pub fn describe_all(partial: &[PartialEpoch]) -> String {
    partial
        .iter()
        .map(PartialEpoch::describe)
        .collect::<Vec<_>>()
        .join("\n")
}
