//! The per-photo work of an archive epoch's global passes, as rounds.
//!
//! After its first pass, an epoch builds chip stores from its own oriented photos (the
//! second pass, the tie pass, the tie points among its photos) and looks for them in its
//! other photos. Each such step is a [`Round`]: data saying what every photo has to do
//! (cut chips, match tracks, orient from a store), and the work for one photo. Where the
//! rounds run is the caller's: [`InMemory`] runs a round's photos on this process's
//! threads; the pipeline writes a round to its task folder and runs its photos as tasks,
//! here or on other machines. A round's photos read nothing but the round, the epoch's
//! inputs ([`EpochEnv`]) and their own image, and their results are combined in the
//! round's photo order, so both give the same epoch.

use super::archive::ArchiveOptions;
use super::chips::ChipStore;
use super::epoch::EpochInput;
use super::epoch_ties::TieParams;
use super::photo::{orient_from_pose, orient_photo, KnownPose, PhotoOptions, PhotoOrientation};
use super::scan_cameras::ScanCameras;
use super::EpochError;
use crate::block::PosPrior;
use crate::geometry::Dem;
use rayon::prelude::*;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicUsize, Ordering};

/// What a photo's work in a round reads besides the round: the epoch's inputs and
/// options, the same in every process.
pub struct EpochEnv<'a> {
    pub input: &'a EpochInput,
    pub dem: &'a Dem,
    /// Approximate orientations by photo name.
    pub priors: &'a BTreeMap<String, PosPrior>,
    pub opts: PhotoOptions,
    pub ties: TieParams,
    /// A film epoch's candidate cameras of its scans (a process running one photo's work
    /// needs only that photo's).
    pub scans: Option<&'a ScanCameras>,
}

impl<'a> EpochEnv<'a> {
    pub fn new(
        input: &'a EpochInput,
        dem: &'a Dem,
        priors: &'a BTreeMap<String, PosPrior>,
        opts: PhotoOptions,
        archive: &ArchiveOptions,
        scans: Option<&'a ScanCameras>,
    ) -> Self {
        Self {
            input,
            dem,
            priors,
            opts,
            ties: TieParams::of(archive),
            scans,
        }
    }
}

/// What a round's photos do.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RoundKind {
    /// Cut chips from oriented photos.
    Cut,
    /// Find tracks of tie points in photos.
    Match,
    /// Orient photos from a chip store.
    Reorient,
}

/// One round of an epoch's global passes: per photo, one piece of work.
pub trait Round: Serialize + DeserializeOwned + Sync {
    type Output: Serialize + DeserializeOwned + Send;
    const KIND: RoundKind;
    /// The epoch photos (indices) the round has work for, in the order its outputs are
    /// combined.
    fn photos(&self) -> Vec<usize>;
    /// The work of the `k`-th of [`Round::photos`].
    fn run(&self, k: usize, env: &EpochEnv) -> Self::Output;
    /// The round as the `k`-th photo needs it, when that is a part of the whole (a process
    /// running only that photo then reads only its part); its run of that photo gives
    /// what the whole round's does. `None`: the photo needs the whole round.
    fn part(&self, _k: usize, _env: &EpochEnv) -> Option<Self>
    where
        Self: Sized,
    {
        None
    }
    /// Why a photo's work came to nothing, when that is a failure worth reporting.
    fn failure(_output: &Self::Output) -> Option<String> {
        None
    }
    /// Checks the round as a process read it from its task file, for an epoch of
    /// `photos` photos: photo indices in range, cameras, poses and sizes sane
    /// ([`super::task_checks`]). Says what is wrong; the reader names the file.
    fn check_file(&self, photos: usize) -> Result<(), String>;
    /// Checks the output of the round's `k`-th photo as read back from its task file:
    /// what the epoch indexes with it in range, its numbers finite.
    fn check_output(&self, k: usize, output: &Self::Output) -> Result<(), String>;
}

/// Where an epoch's rounds run.
pub trait EpochRounds {
    type Error: From<EpochError>;
    /// The outputs of every photo of `round`, in its photo order.
    fn run<R: Round>(&self, round: &R, env: &EpochEnv) -> Result<Vec<R::Output>, Self::Error>;
}

/// Rounds on this process's threads, one photo (and its image) per thread.
pub struct InMemory;

impl EpochRounds for InMemory {
    type Error = EpochError;

    fn run<R: Round>(&self, round: &R, env: &EpochEnv) -> Result<Vec<R::Output>, EpochError> {
        // Each photo in the caller's span (its epoch), and its end as a progress event
        // (target `cloudcontrol::progress`: the CLI's per-photo progress).
        let (photos, span, done) = (
            round.photos(),
            tracing::Span::current(),
            AtomicUsize::new(0),
        );
        Ok((0..photos.len())
            .into_par_iter()
            .map(|k| {
                let _in = span.enter();
                let out = round.run(k, env);
                tracing::info!(
                    target: "cloudcontrol::progress",
                    work = round_label(R::KIND),
                    item = %env.input.photos.get(photos[k]).map_or("", |p| p.name.as_str()),
                    done = done.fetch_add(1, Ordering::Relaxed) + 1,
                    total = photos.len(),
                );
                out
            })
            .collect())
    }
}

/// A round's work as its progress events name it.
fn round_label(kind: RoundKind) -> &'static str {
    match kind {
        RoundKind::Cut => "cut",
        RoundKind::Match => "match",
        RoundKind::Reorient => "reorient",
    }
}

/// Photos oriented from a store of chips: cut from the epoch's own oriented photos (the
/// second pass, the tie pass), or the control patches near photos the tie pass oriented.
#[derive(Serialize, Deserialize)]
pub struct OrientRound {
    pub store: ChipStore<'static>,
    pub photos: Vec<usize>,
    /// Per photo, the pose it already has and the search starts from
    /// ([`orient_from_pose`]); empty: every photo starts from its navigation.
    #[serde(default)]
    pub known: Vec<KnownPose>,
}

impl Round for OrientRound {
    type Output = PhotoOrientation;
    const KIND: RoundKind = RoundKind::Reorient;

    fn photos(&self) -> Vec<usize> {
        self.photos.clone()
    }

    fn run(&self, k: usize, env: &EpochEnv) -> PhotoOrientation {
        let ph = &env.input.photos[self.photos[k]];
        if let Some(start) = self.known.get(k) {
            return orient_from_pose(ph, start, &self.store, env.dem, &env.opts);
        }
        orient_photo(
            ph,
            &env.input.camera,
            env.priors.get(&ph.name),
            &self.store,
            env.dem,
            &env.opts,
            env.scans,
        )
    }

    fn failure(o: &PhotoOrientation) -> Option<String> {
        o.report.reason.as_ref().map(|r| r.to_string())
    }

    fn check_file(&self, photos: usize) -> Result<(), String> {
        use super::task_checks as c;
        for &n in &self.photos {
            c::index("photo", n, photos)?;
        }
        c::at_most("known poses", self.known.len(), self.photos.len())?;
        for k in &self.known {
            c::camera("known camera", &k.camera)?;
            c::pose("known pose", &k.pose)?;
            c::covariance("known covariance", &k.covariance)?;
        }
        for p in &self.store.points {
            c::control_point("store point", p)?;
        }
        Ok(())
    }

    fn check_output(&self, _k: usize, o: &PhotoOrientation) -> Result<(), String> {
        o.check(self.store.points.len())
    }
}
