//! A synthetic block read back as a user's inputs and, for evaluation only, as its truth:
//! an epoch's specification from `manifest.json` (the documented formats the generator
//! writes, through the one epoch builder), the true orientation of an epoch as an
//! oriented block, and navigation perturbed from a known orientation.

use crate::block::{Block, BlockCamera, Photo, PhotoId};
use crate::control::epoch::{
    block_origin, input_err, EpochCamera, EpochError, EpochInput, Navigation,
};
use crate::control::EpochSpec;
use crate::formats::pos::PosRecord;
use crate::geometry::{self, Brown, Camera, FilmCamera, Pose};
use nalgebra::Vector3;
use std::path::Path;

fn read_json(path: &Path) -> Result<serde_json::Value, EpochError> {
    let text = std::fs::read_to_string(path).map_err(|e| input_err(path, e.to_string()))?;
    serde_json::from_str(&text).map_err(|e| input_err(path, e.to_string()))
}

/// The specification of epoch `epoch` of a synthetic block, its CRS and its origin (the
/// one origin rule over the scene's area). Nothing under `truth/` is read.
pub fn synth_epoch_spec(
    dir: &Path,
    epoch: &str,
) -> Result<(EpochSpec, String, [f64; 3]), EpochError> {
    let mpath = dir.join("manifest.json");
    let m = read_json(&mpath)?;
    let crs = m["crs"]
        .as_str()
        .ok_or_else(|| input_err(&mpath, "no crs"))?
        .to_string();
    let area: [f64; 4] = serde_json::from_value(m["area"].clone())
        .map_err(|e| input_err(&mpath, format!("area: {e}")))?;
    let e = m["epochs"]
        .as_array()
        .and_then(|a| a.iter().find(|e| e["name"] == epoch))
        .ok_or_else(|| input_err(&mpath, format!("no epoch named {epoch:?}")))?;
    let field = |k: &str| {
        e[k].as_str()
            .map(|s| dir.join(s))
            .ok_or_else(|| input_err(&mpath, format!("epoch {epoch}: no {k}")))
    };
    let nav = field("navigation")?;
    let strips = nav.file_name().is_some_and(|n| n == "strips.csv");
    Ok((
        EpochSpec {
            name: epoch.to_string(),
            date: e["date"].as_str().map(str::to_string),
            photos: field("images_dir")?,
            camera: field("camera")?,
            pos: (!strips).then(|| nav.clone()),
            strips: strips.then_some(nav),
            scan_pixel_um: None,
        },
        crs,
        block_origin([[area[0], area[1]]]),
    ))
}

impl EpochInput {
    /// Epoch `epoch` of a synthetic block (formats/synth/README.md), as a user would give it.
    pub fn from_synth_epoch(dir: &Path, epoch: &str) -> Result<Self, EpochError> {
        let (spec, crs, origin) = synth_epoch_spec(dir, epoch)?;
        Self::build(&spec, &crs, origin)
    }
}

/// The true orientation of a synthetic epoch as an oriented block (block-local), its
/// photos' images set: used to export reference DCPs "as if oriented against the LiDAR"
/// and to perturb the truth for the EO-group bench. Evaluation code only.
pub fn synth_truth_block(dir: &Path, epoch: &str) -> Result<Block, EpochError> {
    let input = EpochInput::from_synth_epoch(dir, epoch)?;
    let tdir = dir.join("truth/epochs").join(epoch);
    let eo = super::truth::read_truth_eo(&tdir.join("eo.csv"))?;
    let mut block = Block {
        crs: Some(input.crs.clone()),
        origin: input.origin,
        ..Block::default()
    };
    let frame = match &input.camera {
        EpochCamera::Frame(_) => {
            let p = tdir.join("camera.json");
            Some(
                serde_json::from_value::<Camera>(read_json(&p)?)
                    .map_err(|e| input_err(&p, e.to_string()))?,
            )
        }
        EpochCamera::Film(_) => None,
    };
    let affine = match frame {
        Some(_) => Default::default(),
        None => super::truth::read_scan_affine(&tdir.join("scan_affine.csv"))?,
    };
    let origin = Vector3::from(input.origin);
    for (name, rotation, centre) in eo {
        let Some(k) = input.photos.iter().position(|p| p.name == name) else {
            continue;
        };
        let pid = k as PhotoId + 1;
        let image = &input.photos[k].image;
        let (cid, model) = match (&frame, &input.camera) {
            (Some(f), _) => (1, f.clone()),
            (None, EpochCamera::Film(def)) => {
                let io = affine.get(&name).ok_or_else(|| {
                    input_err(
                        &tdir.join("scan_affine.csv"),
                        format!("no scan affine for {name}"),
                    )
                })?;
                let (w, h) =
                    image::image_dimensions(image).map_err(|e| input_err(image, e.to_string()))?;
                let d = &def.distortion;
                (
                    pid,
                    Camera::Film(FilmCamera {
                        width: w,
                        height: h,
                        focal_mm: def.focal_mm,
                        principal_point_mm: def.principal_point_mm,
                        distortion: Brown::from_array([d.k1, d.k2, d.k3, d.p1, d.p2]),
                        interior: io.clone(),
                    }),
                )
            }
            (None, EpochCamera::Frame(_)) => unreachable!("frame epochs have a true camera"),
        };
        block.cameras.entry(cid).or_insert_with(|| BlockCamera {
            id: cid,
            name: format!("{epoch}_{cid}"),
            model,
            free_params: Vec::new(),
            calibration_group: None,
        });
        let centre = Vector3::from(centre) - origin;
        let mut photo = Photo::new(pid, name, cid, Pose::new(rotation, centre)).oriented();
        photo.date = input.date.clone();
        photo.image = Some(image.clone());
        photo.provenance = "synthetic truth".into();
        block.photos.insert(pid, photo);
    }
    Ok(block)
}

/// A POS made from known orientations perturbed by Gaussian noise of σ `center_sigma_m`
/// per centre coordinate and `attitude_sigma_rad` per angle (deterministic in `seed`),
/// stating those σ: approximate orientations of a chosen quality, e.g. the EO groups of
/// seed 001's table 1.3.
pub fn perturbed_navigation(
    block: &Block,
    center_sigma_m: f64,
    attitude_sigma_rad: f64,
    seed: u64,
) -> Navigation {
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let nc = Normal::new(0.0, center_sigma_m.max(0.0)).ok();
    let na = Normal::new(0.0, attitude_sigma_rad.max(0.0)).ok();
    let origin = Vector3::from(block.origin);
    let mut recs = Vec::new();
    for p in block.photos.values() {
        let mut draw = |n: &Option<Normal<f64>>| n.map_or(0.0, |d| d.sample(&mut rng));
        let dt = Vector3::new(draw(&na), draw(&na), draw(&na));
        let dc = Vector3::new(draw(&nc), draw(&nc), draw(&nc));
        let q = p.pose.perturbed(&dt, &dc);
        let (o, ph, k) = geometry::opk_from_matrix(&q.rotation);
        let c = q.center + origin;
        recs.push(PosRecord {
            name: p.name.clone(),
            center: [c.x, c.y, c.z],
            opk: [o, ph, k],
            sigma_xyz: Some(center_sigma_m),
            sigma_angle: Some(attitude_sigma_rad),
        });
    }
    Navigation::Pos(recs)
}
