//! COLMAP camera models (`colmap/src/colmap/sensor/models.h`) and their mapping onto our
//! [`FrameCamera`]: exact both ways for the models that are a subset of Brown; the others
//! are refused by name rather than approximated.

use crate::geometry::{Brown, FrameCamera};

/// COLMAP camera models that map onto [`FrameCamera`]: (id, name, number of parameters).
const MODELS: [(i32, &str, usize); 5] = [
    (0, "SIMPLE_PINHOLE", 3),
    (1, "PINHOLE", 4),
    (2, "SIMPLE_RADIAL", 4),
    (3, "RADIAL", 5),
    (4, "OPENCV", 8),
];
const FULL_OPENCV: (i32, &str, usize) = (6, "FULL_OPENCV", 12);

/// All COLMAP model names by id, to name unsupported ones in errors.
const ALL_MODEL_NAMES: [&str; 18] = [
    "SIMPLE_PINHOLE",
    "PINHOLE",
    "SIMPLE_RADIAL",
    "RADIAL",
    "OPENCV",
    "OPENCV_FISHEYE",
    "FULL_OPENCV",
    "FOV",
    "SIMPLE_RADIAL_FISHEYE",
    "RADIAL_FISHEYE",
    "THIN_PRISM_FISHEYE",
    "RAD_TAN_THIN_PRISM_FISHEYE",
    "SIMPLE_DIVISION",
    "DIVISION",
    "SIMPLE_FISHEYE",
    "FISHEYE",
    "EUCM",
    "EQUIRECTANGULAR",
];

pub(super) fn model_by_name(name: &str) -> Option<(i32, usize)> {
    MODELS
        .iter()
        .chain(std::iter::once(&FULL_OPENCV))
        .find(|m| m.1 == name)
        .map(|m| (m.0, m.2))
        .or_else(|| {
            ALL_MODEL_NAMES
                .iter()
                .position(|n| *n == name)
                .map(|i| (i as i32, usize::MAX))
        })
}

pub(super) fn model_name(id: i32) -> String {
    usize::try_from(id)
        .ok()
        .and_then(|i| ALL_MODEL_NAMES.get(i))
        .map(|s| s.to_string())
        .unwrap_or_else(|| format!("model id {id}"))
}

pub(super) fn num_params(id: i32) -> Option<usize> {
    MODELS
        .iter()
        .chain(std::iter::once(&FULL_OPENCV))
        .find(|m| m.0 == id)
        .map(|m| m.2)
}

/// The error for a COLMAP model we do not map (fisheye, FOV, thin prism, …).
pub(super) fn unsupported(model: &str) -> String {
    format!(
        "camera model {model} is not supported (supported: SIMPLE_PINHOLE, PINHOLE, \
         SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV)"
    )
}

/// Our frame camera from a COLMAP model's parameters.
pub(super) fn camera_from_colmap(
    model: i32,
    width: u64,
    height: u64,
    p: &[f64],
) -> std::result::Result<FrameCamera, String> {
    let size = |v: u64, what: &str| {
        u32::try_from(v)
            .ok()
            .filter(|&v| v > 0)
            .ok_or_else(|| format!("{what} {v} is not a valid image size"))
    };
    let (width, height) = (size(width, "width")?, size(height, "height")?);
    if p.iter().any(|v| !v.is_finite()) {
        return Err("a parameter is not finite".into());
    }
    let d = |k1, k2, k3, p1, p2| Brown { k1, k2, k3, p1, p2 };
    let (fx, fy, cx, cy, distortion) = match model {
        0 => (p[0], p[0], p[1], p[2], Brown::default()),
        1 => (p[0], p[1], p[2], p[3], Brown::default()),
        2 => (p[0], p[0], p[1], p[2], d(p[3], 0.0, 0.0, 0.0, 0.0)),
        3 => (p[0], p[0], p[1], p[2], d(p[3], p[4], 0.0, 0.0, 0.0)),
        4 => (p[0], p[1], p[2], p[3], d(p[4], p[5], 0.0, p[6], p[7])),
        6 => {
            if p[9] != 0.0 || p[10] != 0.0 || p[11] != 0.0 {
                return Err(format!(
                    "FULL_OPENCV with rational radial terms k4..k6 = ({}, {}, {}) has no Brown \
                     equivalent; only k4 = k5 = k6 = 0 is supported",
                    p[9], p[10], p[11]
                ));
            }
            (p[0], p[1], p[2], p[3], d(p[4], p[5], p[8], p[6], p[7]))
        }
        _ => return Err(unsupported(&model_name(model))),
    };
    if fx <= 0.0 || fy <= 0.0 {
        return Err(format!(
            "focal length must be positive (fx = {fx}, fy = {fy})"
        ));
    }
    Ok(FrameCamera {
        width,
        height,
        fx,
        fy,
        cx,
        cy,
        distortion,
    })
}

/// The smallest COLMAP model that holds the camera exactly, and its parameters.
pub(super) fn camera_to_colmap(c: &FrameCamera) -> (i32, &'static str, Vec<f64>) {
    let d = &c.distortion;
    let square = c.fx == c.fy;
    let tangential = d.p1 != 0.0 || d.p2 != 0.0;
    if d.is_zero() {
        if square {
            (0, "SIMPLE_PINHOLE", vec![c.fx, c.cx, c.cy])
        } else {
            (1, "PINHOLE", vec![c.fx, c.fy, c.cx, c.cy])
        }
    } else if square && !tangential && d.k3 == 0.0 && d.k2 == 0.0 {
        (2, "SIMPLE_RADIAL", vec![c.fx, c.cx, c.cy, d.k1])
    } else if square && !tangential && d.k3 == 0.0 {
        (3, "RADIAL", vec![c.fx, c.cx, c.cy, d.k1, d.k2])
    } else if d.k3 == 0.0 {
        (
            4,
            "OPENCV",
            vec![c.fx, c.fy, c.cx, c.cy, d.k1, d.k2, d.p1, d.p2],
        )
    } else {
        (
            6,
            "FULL_OPENCV",
            vec![
                c.fx, c.fy, c.cx, c.cy, d.k1, d.k2, d.p1, d.p2, d.k3, 0.0, 0.0, 0.0,
            ],
        )
    }
}
