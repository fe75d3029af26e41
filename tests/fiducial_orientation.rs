//! Scan orientation of film scans found from the fiducial marks, never guessed: synthetic
//! RC10-like scans (crosshair-and-ring marks at the calibrated positions of USGS report
//! RT-R/427, a data strip on the left, a scanner affine with scale difference and shear)
//! at 21 and 42 µm, upright, rotated and mirrored; a perfectly symmetric layout (an error
//! naming the scan, or the given orientation used); a data strip as the only cue; a plain
//! cross described as a cross; real mark crops (NAGAP notch and triangle, USGS
//! EarthExplorer block) as image templates of a camera definition; and scan files, of
//! which only windows around the marks are read.
//!
//! The scans are drawn here from the mark geometry (not through the library's shapes), by
//! 5×5 supersampling of the true pixel → mm affine.

use cloudcontrol::matching::fiducial::{
    interior_orientation, interior_orientation_epoch, interior_orientation_file, CameraDefinition,
    IoOptions, IoResult, ScanOrientation,
};
use cloudcontrol::matching::{GreyImage, MatchingError};
use nalgebra::{Matrix2, Vector2};
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// RT-R/427 (Wild RC10 s/n 1945) fiducials, mm, x right, y up.
const RC10: [(&str, f64, f64); 8] = [
    ("1", -105.983, -106.005),
    ("2", 105.996, 106.006),
    ("3", -105.998, 105.985),
    ("4", 106.001, -106.005),
    ("5", -110.004, -0.009),
    ("6", 110.013, 0.024),
    ("7", -0.003, 109.999),
    ("8", 0.009, -109.992),
];

/// The same layout made exactly symmetric.
const SYMMETRIC: [(&str, f64, f64); 8] = [
    ("1", -106.0, -106.0),
    ("2", 106.0, 106.0),
    ("3", -106.0, 106.0),
    ("4", 106.0, -106.0),
    ("5", -110.0, 0.0),
    ("6", 110.0, 0.0),
    ("7", 0.0, 110.0),
    ("8", 0.0, -110.0),
];

/// Data strip of the test cameras (mm): left of the format, on its lower half.
const STRIP_X: [f64; 2] = [-121.0, -116.0];
const STRIP_Y: [f64; 2] = [-100.0, -20.0];

/// How a test mark looks (mm).
#[derive(Clone, Copy)]
enum Mark {
    /// Crosshair of span `span`, bar width `line`, in a ring (outer diameter `ring`,
    /// width `line`), with a central dot.
    CrossRingDot {
        span: f64,
        line: f64,
        ring: f64,
        dot: f64,
    },
    /// Plain cross, optionally with a central dot.
    Cross {
        span: f64,
        line: f64,
        dot: Option<f64>,
    },
}

const RC10_MARK: Mark = Mark::CrossRingDot {
    span: 2.0,
    line: 0.1,
    ring: 1.4,
    dot: 0.25,
};

fn on_mark(m: Mark, x: f64, y: f64) -> bool {
    let r = x.hypot(y);
    let bar = |span: f64, line: f64| {
        (x.abs() <= span / 2.0 && y.abs() <= line / 2.0)
            || (y.abs() <= span / 2.0 && x.abs() <= line / 2.0)
    };
    match m {
        Mark::CrossRingDot {
            span,
            line,
            ring,
            dot,
        } => bar(span, line) || (r <= ring / 2.0 && r >= ring / 2.0 - line) || r <= dot / 2.0,
        Mark::Cross { span, line, dot } => bar(span, line) || dot.is_some_and(|d| r <= d / 2.0),
    }
}

/// The scan's true pixel → mm affine: the orientation's ideal map with a 0.2 % scale
/// difference, 0.15 % shear and a 0.23° rotation of the film on the platen; the frame
/// centre off the scan centre.
fn truth(o: ScanOrientation, pixel_mm: f64, size: usize) -> (Matrix2<f64>, Vector2<f64>) {
    let a = 0.004f64;
    let rot = Matrix2::new(a.cos(), -a.sin(), a.sin(), a.cos());
    let lin = rot * o.linear(pixel_mm) * Matrix2::new(1.002, 0.0015, 0.0, 0.9985);
    (
        lin,
        Vector2::new(size as f64 / 2.0 + 3.3, size as f64 / 2.0 - 2.7),
    )
}

/// Cheap deterministic grain in [−1, 1] (sum of two hashed uniforms).
fn grain(col: usize, row: usize, seed: u64) -> f32 {
    let mut h = (col as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (row as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ seed.wrapping_mul(0x1656_67B1_9E37_79F9);
    h ^= h >> 29;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 32;
    ((h & 0xFFFF) as f32 + ((h >> 16) & 0xFFFF) as f32) / 65535.0 - 1.0
}

/// What a scan carries besides the frame.
struct Scene<'a> {
    marks: Vec<(f64, f64, Mark)>,
    /// Real mark crops: (x_mm, y_mm, crop, crop pixel mm), centred on the position.
    crops: Vec<(f64, f64, &'a GreyImage, f64)>,
    strip: bool,
}

/// Renders a scan of `size`² pixels: dark opaque frame with grain, a smooth photograph
/// inside ±100 mm, bright marks, the data strip's "text" (bright blocks).
fn render(scene: &Scene, o: ScanOrientation, pixel_mm: f64, size: usize, seed: u64) -> GreyImage {
    let (lin, origin) = truth(o, pixel_mm, size);
    let inv = lin.try_inverse().unwrap();
    let mut data = vec![0f32; size * size];
    data.par_chunks_mut(size)
        .enumerate()
        .for_each(|(row, line)| {
            for (col, v) in line.iter_mut().enumerate() {
                let p = Vector2::new(col as f64 + 0.5, row as f64 + 0.5) - origin;
                let mm = lin * p;
                let mut base = 30.0;
                if mm.x.abs() < 100.0 && mm.y.abs() < 100.0 {
                    base = 120.0 + 50.0 * ((mm.x / 3.1).sin() * (mm.y / 4.7).cos()) as f32;
                }
                if scene.strip
                    && (STRIP_X[0]..STRIP_X[1]).contains(&mm.x)
                    && (STRIP_Y[0]..STRIP_Y[1]).contains(&mm.y)
                {
                    // Characters 1.5 mm apart, 1 mm tall blocks, some lit.
                    let (cx, cy) = ((mm.x / 1.5).floor() as i64, (mm.y / 1.5).floor() as i64);
                    let lit = (cx * 7 + cy * 13).rem_euclid(5) < 2;
                    if lit && (mm.x / 1.5).fract().abs() < 0.7 && (mm.y / 1.5).fract().abs() < 0.7 {
                        base = 200.0;
                    }
                }
                *v = base + 6.0 * grain(col, row, seed);
            }
        });
    let mut img = GreyImage::new(size, size, data).unwrap();
    for &(x, y, m) in &scene.marks {
        let c = origin + inv * Vector2::new(x, y);
        let r = (1.2 / pixel_mm).ceil() as i64 + 2;
        for row in (c.y as i64 - r).max(0)..(c.y as i64 + r).min(size as i64) {
            for col in (c.x as i64 - r).max(0)..(c.x as i64 + r).min(size as i64) {
                let mut hit = 0;
                for sy in 0..5 {
                    for sx in 0..5 {
                        let q = Vector2::new(
                            col as f64 + (sx as f64 + 0.5) / 5.0,
                            row as f64 + (sy as f64 + 0.5) / 5.0,
                        );
                        let d = lin * (q - origin) - Vector2::new(x, y);
                        hit += on_mark(m, d.x, d.y) as u32;
                    }
                }
                img.data[row as usize * size + col as usize] += 170.0 * hit as f32 / 25.0;
            }
        }
    }
    for &(x, y, crop, tp) in &scene.crops {
        let c = origin + inv * Vector2::new(x, y);
        let (hw, hh) = (crop.width as f64 / 2.0, crop.height as f64 / 2.0);
        let r = (hw.max(hh) * tp / pixel_mm * 1.5).ceil() as i64 + 2;
        for row in (c.y as i64 - r).max(0)..(c.y as i64 + r).min(size as i64) {
            for col in (c.x as i64 - r).max(0)..(c.x as i64 + r).min(size as i64) {
                let (mut sum, mut n) = (0.0, 0);
                for sy in 0..SS {
                    for sx in 0..SS {
                        let q = Vector2::new(
                            col as f64 + (sx as f64 + 0.5) / SS as f64,
                            row as f64 + (sy as f64 + 0.5) / SS as f64,
                        );
                        let d = lin * (q - origin) - Vector2::new(x, y);
                        let (u, v) = (hw + d.x / tp, hh - d.y / tp);
                        // The scan goes on beyond the crop: its border is continued for
                        // 3 crop pixels, so no hard cut falls under the template's edge.
                        let (w, h) = (crop.width as f64, crop.height as f64);
                        if u > -3.0 && v > -3.0 && u < w + 3.0 && v < h + 3.0 {
                            let uc = u.clamp(0.5, w - 0.5);
                            let vc = v.clamp(0.5, h - 0.5);
                            sum += bilinear(crop, uc, vc).unwrap_or(0.0);
                            n += 1;
                        }
                    }
                }
                if n == SS * SS {
                    img.data[row as usize * size + col as usize] =
                        (sum / n as f64) as f32 + 2.0 * grain(col as usize, row as usize, seed + 1);
                }
            }
        }
    }
    img
}

/// Supersampling of a crop per scan pixel.
const SS: usize = 4;

/// Bilinear sample of an image at (u, v) (corner origin), None outside its pixel centres.
fn bilinear(img: &GreyImage, u: f64, v: f64) -> Option<f64> {
    let (x, y) = (u - 0.5, v - 0.5);
    if x < 0.0 || y < 0.0 || x > (img.width - 1) as f64 || y > (img.height - 1) as f64 {
        return None;
    }
    let (i, j) = (
        (x as usize).min(img.width - 2),
        (y as usize).min(img.height - 2),
    );
    let (fx, fy) = (x - i as f64, y - j as f64);
    let g = |a: usize, b: usize| img.at(a, b) as f64;
    Some(
        (1.0 - fy) * ((1.0 - fx) * g(i, j) + fx * g(i + 1, j))
            + fy * ((1.0 - fx) * g(i, j + 1) + fx * g(i + 1, j + 1)),
    )
}

/// A camera definition written as formats/cameras/README.md specifies it.
fn camera_json(layout: &[(&str, f64, f64)], shape: &str, strip: bool) -> String {
    let fids: Vec<String> = layout
        .iter()
        .map(|(id, x, y)| {
            format!(r#"{{"id": "{id}", "x_mm": {x}, "y_mm": {y}, "shape": {shape}}}"#)
        })
        .collect();
    let strip = if strip {
        format!(
            r#", "data_strip": {{"x_mm": [{}, {}], "y_mm": [{}, {}]}}"#,
            STRIP_X[0], STRIP_X[1], STRIP_Y[0], STRIP_Y[1]
        )
    } else {
        String::new()
    };
    format!(
        r#"{{"name": "RC10-like test camera", "source": "test", "focal_mm": 152.865,
            "principal_point_mm": [-0.03, -0.001], "format_mm": [230, 230],
            "fiducials": [{}]{strip}}}"#,
        fids.join(", ")
    )
}

const RC10_SHAPE: &str =
    r#"{"type": "cross", "size_mm": 2.0, "line_mm": 0.1, "ring_mm": 1.4, "dot_mm": 0.25}"#;

fn camera(json: &str) -> CameraDefinition {
    let c: CameraDefinition = serde_json::from_str(json).unwrap();
    c.validate().unwrap();
    c
}

const UPRIGHT: ScanOrientation = ScanOrientation {
    rotation_deg: 0,
    mirrored: false,
};

fn orientations() -> Vec<ScanOrientation> {
    let o = |rotation_deg, mirrored| ScanOrientation {
        rotation_deg,
        mirrored,
    };
    vec![
        o(0, false),
        o(90, false),
        o(180, false),
        o(270, false),
        o(0, true),
        o(90, true),
        o(180, true),
        o(270, true),
    ]
}

/// Worst distance (px) of the measured marks from their true pixel centres; every mark
/// must be used and carry the right number.
fn worst_mark_px(
    io: &IoResult,
    layout: &[(&str, f64, f64)],
    o: ScanOrientation,
    pixel_mm: f64,
    size: usize,
) -> f64 {
    let (lin, origin) = truth(o, pixel_mm, size);
    let inv = lin.try_inverse().unwrap();
    let mut worst: f64 = 0.0;
    for (id, x, y) in layout {
        let m = io.marks.iter().find(|m| m.id == *id).unwrap();
        assert!(m.used, "mark {id}: {:?}", m.reason);
        let c = origin + inv * Vector2::new(*x, *y);
        let e = (m.x - c.x).hypot(m.y - c.y);
        if e > 0.1 {
            eprintln!(
                "mark {id}: off by ({:.3}, {:.3}) px, ncc {:.3}, σ {:.3} px",
                m.x - c.x,
                m.y - c.y,
                m.ncc,
                m.sigma_px
            );
        }
        worst = worst.max(e);
    }
    worst
}

/// The RC10-like scans at one resolution, every orientation: the marks decide.
fn rc10_scans(pixel_um: f64) {
    let cam = camera(&camera_json(&RC10, RC10_SHAPE, true));
    let pixel_mm = pixel_um / 1000.0;
    let size = (244.0 / pixel_mm) as usize;
    let scene = Scene {
        marks: RC10.iter().map(|(_, x, y)| (*x, *y, RC10_MARK)).collect(),
        crops: vec![],
        strip: true,
    };
    for o in orientations() {
        let scan = render(&scene, o, pixel_mm, size, 7);
        let name = format!("rc10_{pixel_um}um_{}", o.to_string().replace(' ', "_"));
        let io = interior_orientation(&cam, &scan, &name, &IoOptions::default())
            .unwrap_or_else(|e| panic!("{e}"));
        let worst = worst_mark_px(&io, &RC10, io.orientation, pixel_mm, size);
        let second = &io.orientation_hypotheses[1];
        eprintln!(
            "| {pixel_um} µm | {o} | {} | {:.1} (vs {}) | {worst:.3} px | RMSE {:.2} µm; geometry best/second {:.2}/{:.2} µm, strip σ {:?}/{:?} |",
            io.orientation,
            io.orientation_margin,
            second.orientation,
            io.rmse_um,
            io.orientation_hypotheses[0].geometry_um,
            second.geometry_um,
            io.orientation_hypotheses[0].strip_std.map(|v| v.round()),
            second.strip_std.map(|v| v.round()),
        );
        assert_eq!(io.orientation, o, "{name}");
        assert!(!io.orientation_ambiguous && io.orientation_margin >= 2.0);
        assert_eq!(io.orientation_source, "decided by the marks");
        assert!(worst <= 0.1, "{name}: worst mark {worst:.3} px");
        // The geometry alone tells the wrong assignment: several times the right one's
        // residuals.
        let wrong_geometry = io
            .orientation_hypotheses
            .iter()
            .filter(|h| h.orientation != o)
            .map(|h| h.geometry_um)
            .fold(f64::INFINITY, f64::min);
        assert!(
            wrong_geometry > 3.0 * io.orientation_hypotheses[0].geometry_um,
            "{name}: {wrong_geometry} µm"
        );
    }
}

#[test]
fn rc10_scan_orientation_found_at_42_um() {
    rc10_scans(42.0);
}

#[test]
fn rc10_scan_orientation_found_at_21_um() {
    rc10_scans(21.0);
}

#[test]
fn symmetric_layout_without_cue_is_an_error_naming_the_scan_or_takes_the_given_orientation() {
    let cam = camera(&camera_json(&SYMMETRIC, RC10_SHAPE, false));
    let (pixel_mm, size) = (0.042, 5800);
    let scene = Scene {
        marks: SYMMETRIC
            .iter()
            .map(|(_, x, y)| (*x, *y, RC10_MARK))
            .collect(),
        crops: vec![],
        strip: false,
    };
    let o = ScanOrientation {
        rotation_deg: 90,
        mirrored: false,
    };
    let scan = render(&scene, o, pixel_mm, size, 3);
    let e = interior_orientation(&cam, &scan, "frame_0412.tif", &IoOptions::default()).unwrap_err();
    assert!(
        matches!(&e, MatchingError::OrientationUndecided { scan, margin, .. }
            if scan == "frame_0412.tif" && *margin < 1.2),
        "{e}"
    );
    assert!(e.to_string().contains("frame_0412.tif"), "{e}");
    eprintln!("{e}");
    // Given, the orientation is used and the marks land on their numbers.
    let opts = IoOptions {
        orientation: Some(o),
        ..IoOptions::default()
    };
    let io = interior_orientation(&cam, &scan, "frame_0412.tif", &opts).unwrap();
    assert_eq!(io.orientation, o);
    assert_eq!(io.orientation_source, "given");
    assert!(io.orientation_ambiguous);
    let worst = worst_mark_px(&io, &SYMMETRIC, o, pixel_mm, size);
    assert!(worst <= 0.1, "worst {worst}");
    // A fallback (an epoch's majority) is taken only because the marks cannot decide.
    let opts = IoOptions {
        fallback_orientation: Some(o),
        ..IoOptions::default()
    };
    let io = interior_orientation(&cam, &scan, "frame_0412.tif", &opts).unwrap();
    assert_eq!(io.orientation, o);
    assert!(
        io.orientation_source.starts_with("fallback 90°"),
        "{}",
        io.orientation_source
    );
    assert!(io.orientation_ambiguous);
    assert!(worst_mark_px(&io, &SYMMETRIC, o, pixel_mm, size) <= 0.1);
    // An epoch fixes it: two scans decided by their data strip (another camera
    // definition would be needed for that), here the epoch of undecided scans alone has
    // no majority and keeps the error.
    let scans = [0u64, 1];
    let out = interior_orientation_epoch(
        &cam,
        &scans,
        |&k| Ok((format!("frame_{k}.tif"), scan.clone())),
        &IoOptions::default(),
    );
    assert!(out
        .iter()
        .all(|r| matches!(r, Err(MatchingError::OrientationUndecided { .. }))));
}

#[test]
fn data_strip_decides_a_symmetric_layout_and_the_epoch_majority_fixes_the_rest() {
    let with_strip = camera(&camera_json(&SYMMETRIC, RC10_SHAPE, true));
    let (pixel_mm, size) = (0.042, 5900);
    let scene = |strip| Scene {
        marks: SYMMETRIC
            .iter()
            .map(|(_, x, y)| (*x, *y, RC10_MARK))
            .collect(),
        crops: vec![],
        strip,
    };
    for o in orientations() {
        let scan = render(&scene(true), o, pixel_mm, size, 5);
        let io = interior_orientation(&with_strip, &scan, "strip", &IoOptions::default())
            .unwrap_or_else(|e| panic!("{o}: {e}"));
        eprintln!(
            "data strip, {o}: chose {} margin {:.1}, strip σ {:?} vs {:?}",
            io.orientation,
            io.orientation_margin,
            io.orientation_hypotheses[0].strip_std,
            io.orientation_hypotheses[1].strip_std
        );
        assert_eq!(io.orientation, o);
        assert!(worst_mark_px(&io, &SYMMETRIC, o, pixel_mm, size) <= 0.1);
    }
    // An epoch of three scans lying 180°: two show their data strip, one has it cut off
    // (scanned without the margin): that one takes the majority.
    let o = ScanOrientation {
        rotation_deg: 180,
        mirrored: false,
    };
    let scans = [true, true, false];
    let out = interior_orientation_epoch(
        &with_strip,
        &scans,
        |&strip| {
            Ok((
                format!("strip_{strip}"),
                render(&scene(strip), o, pixel_mm, size, 9),
            ))
        },
        &IoOptions::default(),
    );
    for r in &out {
        let io = r.as_ref().unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(io.orientation, o);
    }
    let last = out[2].as_ref().unwrap();
    assert!(
        last.orientation_source
            .starts_with("epoch majority (2 of 2"),
        "{}",
        last.orientation_source
    );
    assert!(worst_mark_px(last, &SYMMETRIC, o, pixel_mm, size) <= 0.1);
}

#[test]
fn cross_described_as_a_cross_is_found_with_and_without_dot() {
    let (pixel_mm, size) = (0.042, 5800);
    for (dot, shape) in [
        (
            Some(0.3),
            r#"{"type": "cross", "size_mm": 1.6, "line_mm": 0.1, "dot_mm": 0.3}"#,
        ),
        (None, r#"{"type": "cross", "size_mm": 1.6, "line_mm": 0.1}"#),
    ] {
        let cam = camera(&camera_json(&RC10, shape, true));
        let m = Mark::Cross {
            span: 1.6,
            line: 0.1,
            dot,
        };
        let scene = Scene {
            marks: RC10.iter().map(|(_, x, y)| (*x, *y, m)).collect(),
            crops: vec![],
            strip: true,
        };
        for o in [UPRIGHT, orientations()[1]] {
            let scan = render(&scene, o, pixel_mm, size, 11);
            let io = interior_orientation(&cam, &scan, "cross", &IoOptions::default())
                .unwrap_or_else(|e| panic!("dot {dot:?} {o}: {e}"));
            let worst = worst_mark_px(&io, &RC10, o, pixel_mm, size);
            eprintln!(
                "cross dot {dot:?} {o}: margin {:.1}, worst {worst:.3} px",
                io.orientation_margin
            );
            assert_eq!(io.orientation, o);
            assert!(worst <= 0.1, "worst {worst}");
        }
    }
    // A crosshair with a central gap (open centre) around a dot.
    let gap = r#"{"type": "cross", "size_mm": 1.6, "line_mm": 0.1, "gap_mm": 0.6, "dot_mm": 0.2}"#;
    let cam = camera(&camera_json(&RC10, gap, true));
    let shape = &cam.fiducials[0].shape;
    assert!(!shape.covers(0.2, 0.0) && shape.covers(0.5, 0.0) && shape.covers(0.05, 0.05));
}

fn templates_root() -> PathBuf {
    let local =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/fiducial_templates_nagap_ee");
    if local.exists() {
        local
    } else {
        PathBuf::from("/work/shared/data/fiducial_templates_nagap_ee")
    }
}

/// A camera whose four midside marks are real crops: the crops copied next to a camera
/// JSON in a fresh folder, placed at the LMK 1000 (OSL/1785) midside positions of a
/// synthetic frame scanned at 40 µm, upright and rotated 90°.
fn template_kind(style: &str, ext: &str, limit_px: f64) {
    let dir = std::env::temp_dir().join(format!(
        "cc_fid_tpl_{}_{}",
        style.replace('/', "_"),
        std::process::id()
    ));
    std::fs::create_dir_all(dir.join("marks")).unwrap();
    let layout = [
        ("L", -111.998, -0.004),
        ("R", 112.004, 0.0),
        ("T", 0.014, 111.993),
        ("B", 0.0, -112.002),
    ];
    let tp = 0.02;
    let mut crops = Vec::new();
    let mut fids = Vec::new();
    for (id, x, y) in layout {
        let src = templates_root().join(style).join(format!("{id}.{ext}"));
        std::fs::copy(&src, dir.join("marks").join(format!("{id}.{ext}"))).unwrap();
        crops.push((x, y, GreyImage::load(&src).unwrap(), tp));
        fids.push(format!(
            r#"{{"id": "{id}", "x_mm": {x}, "y_mm": {y},
                "shape": {{"type": "template", "file": "marks/{id}.{ext}", "pixel_mm": {tp}}}}}"#
        ));
    }
    let json = format!(
        r#"{{"name": "{style} test camera", "source": "test", "focal_mm": 152.299,
            "principal_point_mm": [0, 0], "format_mm": [230, 230], "fiducials": [{}]}}"#,
        fids.join(", ")
    );
    std::fs::write(dir.join("camera.json"), &json).unwrap();
    let cam = CameraDefinition::load(&dir.join("camera.json")).unwrap();
    // A template path leaving the camera's folder is refused.
    std::fs::write(dir.join("escape.json"), json.replace("marks/L", "../L")).unwrap();
    let e = CameraDefinition::load(&dir.join("escape.json")).unwrap_err();
    assert!(
        e.to_string().contains("inside the camera file's folder"),
        "{e}"
    );
    let (pixel_mm, size) = (0.04, 6000);
    let scene = Scene {
        marks: vec![],
        crops: crops.iter().map(|(x, y, c, t)| (*x, *y, c, *t)).collect(),
        strip: false,
    };
    for o in [UPRIGHT, orientations()[1]] {
        let scan = render(&scene, o, pixel_mm, size, 13);
        let io = interior_orientation(&cam, &scan, style, &IoOptions::default())
            .unwrap_or_else(|e| panic!("{style} {o}: {e}"));
        let worst = worst_mark_px(&io, &layout, o, pixel_mm, size);
        eprintln!(
            "template {style} {o}: chose {}, margin {:.1}, worst {worst:.3} px, RMSE {:.2} µm",
            io.orientation, io.orientation_margin, io.rmse_um
        );
        assert_eq!(io.orientation, o);
        assert!(worst <= limit_px, "{style} {o}: worst {worst:.3} px");
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn template_nagap_notch() {
    template_kind("nagap/notch", "jpg", 0.1);
}

#[test]
fn template_nagap_triangle() {
    template_kind("nagap/triangle", "jpg", 0.1);
}

#[test]
fn template_ee_block() {
    template_kind("ee/block", "jpg", 0.1);
}

/// The largest resident set (VmHWM) the running child `pid` reached, read from /proc while
/// it runs: the child's own (wait4's peak would count the pages of this test process,
/// whose memory the child shares until it executes).
#[cfg(target_os = "linux")]
fn peak_while_running(child: &mut std::process::Child) -> u64 {
    let status = format!("/proc/{}/status", child.id());
    let mut peak = 0;
    while child.try_wait().unwrap().is_none() {
        let kib = std::fs::read_to_string(&status)
            .unwrap_or_default()
            .lines()
            .find_map(|l| l.strip_prefix("VmHWM:"))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok());
        peak = peak.max(kib.unwrap_or(0) * 1024);
        std::thread::sleep(std::time::Duration::from_millis(1));
    }
    peak
}

/// A 21 µm RC10-like scan of 11 600² pixels written as an 8-bit TIFF (what a scanner
/// writes, read straight from the file) and a 42 µm one as an LZW TIFF (read through
/// GDAL): the interior orientation of the file reads a few per cent of its pixels and
/// measures the marks of the whole scan held in memory, to the same bits; `cloudcontrol
/// io` peaks at less than half the 8-bit scan's bytes (the whole scan's grey copy and
/// pyramid took 5.3 bytes a pixel); the marks lie within 0.1 px of the truth.
#[test]
fn a_scan_file_is_read_by_windows_with_the_marks_of_the_whole_scan() {
    let cam_json = camera_json(&RC10, RC10_SHAPE, true);
    let cam = camera(&cam_json);
    let scene = Scene {
        marks: RC10.iter().map(|(_, x, y)| (*x, *y, RC10_MARK)).collect(),
        crops: vec![],
        strip: true,
    };
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("camera.json"), &cam_json).unwrap();
    let o = ScanOrientation {
        rotation_deg: 270,
        mirrored: true,
    };
    for (pixel_um, lzw) in [(21.0, false), (42.0, true)] {
        let pixel_mm = pixel_um / 1000.0;
        let size = (244.0 / pixel_mm) as usize;
        // The grey values a file of 8-bit samples holds.
        let mut scan = render(&scene, o, pixel_mm, size, 17);
        scan.data
            .iter_mut()
            .for_each(|v| *v = v.round().clamp(0.0, 255.0));
        let path = dir.path().join(format!("scan_{pixel_um}um.tif"));
        if lzw {
            let driver = cloudcontrol::formats::gdal::Driver::by_name("GTiff").unwrap();
            let ds = driver
                .create::<u8>(&path, (size, size), 1, &["COMPRESS=LZW"])
                .unwrap();
            let bytes: Vec<u8> = scan.data.iter().map(|&v| v as u8).collect();
            ds.rasterband(1)
                .unwrap()
                .write((0, 0), (size, size), &bytes)
                .unwrap();
        } else {
            scan.save(&path, false).unwrap();
        }
        let name = path.display().to_string();
        let held = interior_orientation(&cam, &scan, &name, &IoOptions::default()).unwrap();
        drop(scan);
        let file = interior_orientation_file(&cam, &path, &IoOptions::default()).unwrap();
        assert_eq!(file.orientation, o);
        for (a, b) in file.marks.iter().zip(&held.marks) {
            assert_eq!(
                (a.x.to_bits(), a.y.to_bits()),
                (b.x.to_bits(), b.y.to_bits())
            );
        }
        assert_eq!(file.rmse_um.to_bits(), held.rmse_um.to_bits());
        let worst = worst_mark_px(&file, &RC10, o, pixel_mm, size);
        let pixels = (size * size) as u64;
        let read = file.scan_pixels_read as f64 / pixels as f64;
        eprintln!(
            "{pixel_um} µm ({}): {:.2} % of the scan read, worst mark {worst:.3} px",
            if lzw { "LZW, GDAL" } else { "uncompressed" },
            100.0 * read
        );
        assert!(read < 0.1, "{:.1} % of the scan read", 100.0 * read);
        assert!(worst <= 0.1, "worst mark {worst:.3} px");
        #[cfg(target_os = "linux")]
        if !lzw {
            let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_cloudcontrol"))
                .args(["io", "--camera"])
                .arg(dir.path().join("camera.json"))
                .arg(&path)
                .arg("--out")
                .arg(dir.path().join("io.json"))
                .stdout(std::process::Stdio::null())
                .spawn()
                .unwrap();
            let peak = peak_while_running(&mut child);
            assert!(child.wait().unwrap().success());
            eprintln!(
                "cloudcontrol io of the {} MiB scan: peak {} MiB",
                pixels >> 20,
                peak >> 20
            );
            assert!(peak > 0 && peak < pixels / 2, "peak {} MiB", peak >> 20);
        }
    }
}
