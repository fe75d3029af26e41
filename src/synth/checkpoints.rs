//! Surveyed checkpoints (as a field crew delivers them: 5 cm noise) and the truth files
//! that go with them and with the LiDAR strips.

use super::lidar::LidarStrip;
use super::{Scene, SynthError, ORIGIN};
use crate::formats;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::fmt::Write;
use std::path::Path;

/// Survey precision of the checkpoints (m, 1σ), in plan and height.
pub const SURVEY_SIGMA: f64 = 0.05;

pub(crate) fn write_checkpoints(
    scene: &Scene,
    out: &Path,
    rng: &mut ChaCha8Rng,
) -> Result<(), SynthError> {
    let n = Normal::new(0.0, SURVEY_SIGMA).expect("sigma");
    let mut surveyed = String::from("id,x,y,z,sigma_xy,sigma_z\n");
    let mut truth = String::from("id,x,y,z\n");
    for t in &scene.targets {
        let w = [
            t.center[0] + ORIGIN[0],
            t.center[1] + ORIGIN[1],
            t.center[2] + ORIGIN[2],
        ];
        let _ = writeln!(truth, "{},{:.4},{:.4},{:.4}", t.id, w[0], w[1], w[2]);
        let _ = writeln!(
            surveyed,
            "{},{:.3},{:.3},{:.3},{SURVEY_SIGMA:.3},{SURVEY_SIGMA:.3}",
            t.id,
            w[0] + n.sample(rng),
            w[1] + n.sample(rng),
            w[2] + n.sample(rng)
        );
    }
    formats::write_bytes_atomically(&out.join("checkpoints.csv"), surveyed.as_bytes())?;
    formats::write_bytes_atomically(&out.join("truth/checkpoints.csv"), truth.as_bytes())?;
    Ok(())
}

/// One visible checkpoint in one photo: (epoch, photo, id, col, row).
pub(crate) type CheckpointImage = (String, String, String, f64, f64);

pub(crate) fn write_image_truth(rows: &[CheckpointImage], out: &Path) -> Result<(), SynthError> {
    let mut s = String::from("epoch,photo,id,col,row\n");
    for (e, p, id, c, r) in rows {
        let _ = writeln!(s, "{e},{p},{id},{c:.4},{r:.4}");
    }
    formats::write_bytes_atomically(&out.join("truth/checkpoint_images.csv"), s.as_bytes())?;
    Ok(())
}

pub(crate) fn write_lidar_truth(strips: &[LidarStrip], out: &Path) -> Result<(), SynthError> {
    let mut s = String::from("point_source_id,dx,dy,dz,center_x,swath_m,points\n");
    for st in strips {
        let _ = writeln!(
            s,
            "{},{:.4},{:.4},{:.4},{:.3},{:.1},{}",
            st.point_source_id,
            st.offset[0],
            st.offset[1],
            st.offset[2],
            st.center_x + ORIGIN[0],
            st.swath_m,
            st.points
        );
    }
    formats::write_bytes_atomically(&out.join("truth/lidar_strips.csv"), s.as_bytes())?;
    Ok(())
}
