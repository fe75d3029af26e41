//! The report: JSON with the documented fields and the numbers of a hand-made report (per
//! checkpoint rows and the measurements rejected, film scans, warnings per epoch and per
//! run, the LiDAR's check, the run's metadata); warnings and scan rows taken from an
//! epoch's result where they were decided; and HTML that headless Chromium renders with
//! every section an operator acts on (found by element id and text in the DOM it builds,
//! plots coloured in its screenshot).

use cloudcontrol::adjust::VarianceComponent;
use cloudcontrol::control::checkpoints::RejectedMeasurement;
use cloudcontrol::lidar::clean::{OffsetModel, StripOffset};
use cloudcontrol::lidar::StripOffsetReport;
use cloudcontrol::matching::ScanOrientation;
use cloudcontrol::pipeline::project::{Outputs, Thresholds};
use cloudcontrol::pipeline::report::gather::{epoch_warnings, scan_rows};
use cloudcontrol::pipeline::report::*;
use cloudcontrol::pipeline::tie_statistics::{PhotoTies, TieStatistics};
use serde_json::{json, Value};
use std::process::Command;

fn scan(photo: &str, k: usize) -> ScanReport {
    ScanReport {
        photo: photo.into(),
        oriented: true,
        failed: None,
        marks_used: 8,
        marks_total: 8,
        rmse_um: 4.0 + k as f64,
        rmse_px: (4.0 + k as f64) / 20.0,
        max_residual_um: 7.5 + k as f64,
        pixel_um: 20.0,
        pixel_source: "given".into(),
        measured_pixel_um: 20.03,
        orientation: Some(ScanOrientation {
            rotation_deg: if k == 2 { 180 } else { 90 },
            mirrored: false,
        }),
        orientation_source: if k == 2 {
            "epoch majority (5 of 6 scans)".into()
        } else {
            "decided by the marks".into()
        },
        orientation_margin: if k == 2 { 1.3 } else { 6.25 },
        orientation_ambiguous: k == 2,
    }
}

/// A dh map of a 40 × 20 m slope with a building gone (dh −3 m) and one raised (+3 m).
fn sample_dh_map() -> Vec<u8> {
    let (w, h) = (40, 20);
    let grid = cloudcontrol::geometry::Dem::new(
        w,
        h,
        cloudcontrol::geometry::GeoTransform::north_up(0.0, 20.0, 1.0),
        (0..w * h).map(|i| (i % w) as f32 * 0.2).collect(),
    )
    .unwrap();
    let dh: Vec<f64> = (0..w * h)
        .map(|i| match (i % w, i / w) {
            (5..=12, 5..=12) => -3.0,
            (25..=32, 5..=12) => 3.0,
            _ => 0.0,
        })
        .collect();
    let terrain = cloudcontrol::change::slope_aspect(&grid);
    cloudcontrol::change::render::dh_map_png(&grid, &terrain, &dh, (0.0, 2.0), 800).unwrap()
}

#[test]
fn dh_map_is_red_where_lower_blue_where_higher_over_the_hillshade() {
    let img = image::load_from_memory(&sample_dh_map()).unwrap().to_rgb8();
    assert_eq!((img.width(), img.height()), (40, 20));
    let lower = img.get_pixel(8, 8).0;
    let higher = img.get_pixel(28, 8).0;
    let same = img.get_pixel(20, 16).0;
    assert!(lower[0] > 2 * lower[2] && lower[0] > 100, "{lower:?}");
    assert!(higher[2] > 2 * higher[0] && higher[2] > 100, "{higher:?}");
    // No change: grey, the hillshade of an east-facing 11° slope lit from the north-west.
    assert!(same[0] == same[1] && same[1] == same[2], "{same:?}");
    assert!((80..240).contains(&same[0]), "{same:?}");
}

fn sample_report() -> Report {
    let mut epochs = Vec::new();
    for (k, (name, date, gsd)) in [
        ("reference-2019", "2019-05-04", 0.1),
        ("digital-2005", "2005-08", 0.2),
        ("film-1985", "1985", 0.5),
    ]
    .iter()
    .enumerate()
    {
        let film = k == 2;
        let mut e = EpochReport {
            name: name.to_string(),
            date: date.to_string(),
            gsd_m: *gsd,
            photos_total: 12,
            photos_oriented: 12 - usize::from(film),
            photos_through_ties: 0,
            check_rmse_plan_m: 0.0,
            check_rmse_height_m: 0.0,
            check_max_m: 0.0,
            sigma0: 0.9,
            rmse_px: 0.45,
            time_s: 12.5,
            checkpoints: (0..20)
                .map(|i| CheckpointError {
                    id: format!("CP{i:02}"),
                    x: 500_000.0 + 20.0 * (i % 5) as f64,
                    y: 4_400_000.0 + 25.0 * (i / 5) as f64,
                    dx: gsd * 0.3 * ((i as f64) * 0.7).sin(),
                    dy: gsd * 0.3 * ((i as f64) * 1.3).cos(),
                    dz: gsd * 0.5 * ((i as f64) * 0.4).sin(),
                    rays: 2 + i % 3,
                })
                .collect(),
            checkpoints_not_evaluated: usize::from(film),
            checkpoint_rejections: if film {
                vec![RejectedMeasurement {
                    id: "CP07".into(),
                    photo: "film_p3".into(),
                    line: 42,
                    pixel: [1234.5, 987.4],
                    residual_px: Some(17.3),
                    reason: "data snooping: leaving it out lowers the rays' χ² by 290.1".into(),
                }]
            } else {
                Vec::new()
            },
            photos: (0..12)
                .map(|i| {
                    let oriented = !(film && i == 5);
                    PhotoSummary {
                        name: format!("{}_p{i}", &name[..name.find('-').unwrap()]),
                        x: 499_990.0 + 10.0 * (i % 4) as f64,
                        y: 4_399_995.0 + 30.0 * (i / 4) as f64,
                        oriented,
                        reason: (!oriented).then(|| {
                            "fiducial interior orientation failed: 3 of 8 marks found".into()
                        }),
                        mean_residual_px: [0.1 * (i as f64).sin(), 0.1 * (i as f64).cos()],
                        rmse_px: 0.4,
                        patches_predicted: if k == 0 { 0 } else { 20 },
                        patches_matched: if k == 0 { 0 } else { 12 + i % 8 },
                        ties: PhotoTies {
                            tie_observations: 40 + i,
                            control_observations: 12 + i % 8,
                            positions: [i % 5, 4, 4, 4, 6, 4, 4, 4, 4],
                            required: [i != 0, true, true, true, true, true, true, true, true],
                        },
                    }
                })
                .collect(),
            scans: if film {
                let mut s: Vec<ScanReport> =
                    (0..4).map(|i| scan(&format!("film_p{i}"), i)).collect();
                s.push(ScanReport {
                    failed: Some("fiducial interior orientation failed: 3 of 8 marks found".into()),
                    oriented: false,
                    ..scan("film_p5", 0)
                });
                s
            } else {
                Vec::new()
            },
            icp: if k == 0 {
                (0..8)
                    .map(|i| IcpIteration {
                        iteration: i,
                        rmse_m: 2.0 * 0.5f64.powi(i as i32) + 0.05,
                        inliers: 1000,
                    })
                    .collect()
            } else {
                Vec::new()
            },
            control: vec![if k == 0 {
                "LiDAR (tie points by ICP and plane constraints)".into()
            } else {
                "DCPs of epoch reference".into()
            }],
            ties: TieStatistics {
                points: 300,
                observations: 780,
                multiplicity: [(2, 120), (3, 150), (4, 30)].into_iter().collect(),
                control_points: 40,
                control_observations: 120,
                photos_short: 3,
                min_per_position: 3,
            },
            variance_components: vec![VarianceComponent {
                group: "image".into(),
                observations: 900,
                components: 1800,
                vtpv: 1500.0,
                redundancy: 1200.0,
                sigma0: Some(1.12),
            }],
            warnings: if film {
                vec![
                    Warning::new(
                        WarningKind::PartialEpoch,
                        "11 of 12 photos oriented; not oriented: film_p5: fiducial interior orientation failed",
                    ),
                    Warning::new(
                        WarningKind::SelfCalibrationHeld,
                        "camera 1 (rc10): k2 held at its prior value 0: its estimate was 1.2 σ from the prior",
                    ),
                ]
            } else {
                Vec::new()
            },
            surface_change: if film {
                vec![SurfaceChange {
                    against: "lidar_surface".into(),
                    shift_gsd: [0.41, -0.12, 0.05],
                    shift_plan_gsd: 0.4272,
                    shift_plan_sigma_gsd: 0.05,
                    with_tilt: Some(cloudcontrol::pipeline::change::ShiftWithTilt {
                        shift_gsd: [0.12, -0.05, 0.04],
                        shift_plan_gsd: 0.13,
                        shift_plan_sigma_gsd: 0.09,
                        shift_up_sigma_gsd: 0.02,
                        tilt_m_per_km: [0.8, -0.3],
                        tilt_over_extent_gsd: 0.31,
                    }),
                    converged: true,
                    stable_cells: 45_431,
                    median_m: -0.113,
                    nmad_m: 0.141,
                    changed_areas: 3,
                    changed_area_m2: 412.0,
                    flag: Some("shift 0.43 GSD in plan".into()),
                    map: Some("change-film_1985/dh.png".into()),
                    map_range_m: 2.0,
                    map_png: sample_dh_map(),
                }]
            } else {
                Vec::new()
            },
        };
        e.set_check_statistics();
        epochs.push(e);
    }
    Report {
        project: "demo".into(),
        crs: "EPSG:4547".into(),
        run: Some(RunInfo {
            cloudcontrol_version: cloudcontrol::VERSION.into(),
            project_sha256: Some("ab".repeat(32)),
            date_utc: utc_iso8601(1_700_000_000),
            options: RunOptions {
                thresholds: Thresholds::default(),
                outputs: Outputs::default(),
                lidar_datum_sigma_m: 0.05,
                orthophoto_sigma_m: None,
                dem_sigma_m: 0.5,
                checkpoints_crs: Some("EPSG:4326".into()),
                checkpoint_measurement_sigma_px: 1.0,
                default_self_calibration: DefaultSelfCalibration {
                    reference: Vec::new(),
                    archive_frame: vec!["fx".into(), "fy".into(), "k1".into(), "k2".into()],
                    archive_film: Vec::new(),
                },
                epochs: vec![EpochOptions {
                    name: "film-1985".into(),
                    date: "1985".into(),
                    scan_pixel_um: Some(20.0),
                    self_calibration: Some(vec!["f_mm".into()]),
                }],
            },
        }),
        warnings: vec![Warning::new(
            WarningKind::Lidar,
            "3 of 12 tiles carry no CRS (first: a.laz); assumed EPSG:4547",
        )],
        lidar_checkpoints: Some(LidarCheck {
            count: 2,
            skipped: 1,
            mean_m: 0.03,
            std_m: 0.0141,
            rmse_m: 0.0316,
            max_abs_m: 0.04,
            outliers: Vec::new(),
            rmse_without_outliers_m: 0.0316,
            radius_m: 3.0,
            k: 16,
            min_points: 6,
            rows: vec![
                LidarCheckRow {
                    id: "CP00".into(),
                    x: 500_000.0,
                    y: 4_400_000.0,
                    z: 120.0,
                    lidar_z: Some(120.02),
                    dz_m: Some(0.02),
                    neighbours: 15,
                    plane_rms_m: Some(0.011),
                    outlier: false,
                    skipped: None,
                },
                LidarCheckRow {
                    id: "CP01".into(),
                    x: 500_020.0,
                    y: 4_400_000.0,
                    z: 121.0,
                    lidar_z: Some(121.04),
                    dz_m: Some(0.04),
                    neighbours: 16,
                    plane_rms_m: Some(0.012),
                    outlier: false,
                    skipped: None,
                },
                LidarCheckRow {
                    id: "CP02".into(),
                    x: 500_040.0,
                    y: 4_400_000.0,
                    z: 122.0,
                    lidar_z: None,
                    dz_m: None,
                    neighbours: 2,
                    plane_rms_m: None,
                    outlier: false,
                    skipped: Some("2 ground points within 3 m (need 6)".into()),
                },
            ],
        }),
        lidar_strips: Some(StripOffsetReport {
            model: OffsetModel::Vertical,
            vertical_because: Some("their horizontal normals spread 0.031".into()),
            normal_spread: None,
            reference: None,
            strips: [(1, 0.031), (2, -0.031)]
                .map(|(id, dz)| StripOffset {
                    source_id: id,
                    points: 24_000,
                    offset_m: [0.0, 0.0, dz],
                    sigma_m: [0.0, 0.0, 0.0002],
                })
                .to_vec(),
            pairs: Vec::new(),
            sigma0_m: 0.055,
        }),
        epochs,
        ortho: None,
    }
}

fn close(v: &Value, want: f64) -> bool {
    v.as_f64().is_some_and(|x| (x - want).abs() < 1e-12)
}

#[test]
fn report_json_has_the_documented_fields_and_statistics() {
    let dir = tempfile::tempdir().unwrap();
    let r = sample_report();
    write(&r, dir.path()).unwrap();
    let v: Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("report.json")).unwrap()).unwrap();
    for e in v["epochs"].as_array().unwrap() {
        for key in [
            "name",
            "gsd_m",
            "photos_total",
            "photos_oriented",
            "check_rmse_plan_m",
            "check_rmse_height_m",
            "time_s",
            "checkpoints",
            "checkpoints_not_evaluated",
            "checkpoint_rejections",
            "scans",
            "warnings",
        ] {
            assert!(e.get(key).is_some(), "{key}");
        }
    }
    // RMSE computed from the rows.
    let e = &r.epochs[0];
    let plan = (e
        .checkpoints
        .iter()
        .map(|c| c.dx * c.dx + c.dy * c.dy)
        .sum::<f64>()
        / 20.0)
        .sqrt();
    assert!((e.check_rmse_plan_m - plan).abs() < 1e-15);

    // Per checkpoint: id, dx, dy, dz (m) and the photos it was intersected from.
    let film = &v["epochs"][2];
    let cp7 = &film["checkpoints"][7];
    assert_eq!(cp7["id"], "CP07");
    assert!(close(&cp7["dx"], 0.5 * 0.3 * (4.9f64).sin()));
    assert!(close(&cp7["dy"], 0.5 * 0.3 * (9.1f64).cos()));
    assert!(close(&cp7["dz"], 0.5 * 0.5 * (2.8f64).sin()));
    assert_eq!(cp7["rays"], 3);
    assert_eq!(film["checkpoints_not_evaluated"], 1);
    assert_eq!(
        film["checkpoint_rejections"][0],
        json!({"id": "CP07", "photo": "film_p3", "line": 42, "pixel": [1234.5, 987.4],
               "residual_px": 17.3,
               "reason": "data snooping: leaving it out lowers the rays' χ² by 290.1"})
    );
    // Film interior orientation per scan.
    let s2 = &film["scans"][2];
    assert_eq!(s2["photo"], "film_p2");
    assert!(close(&s2["rmse_um"], 6.0) && close(&s2["rmse_px"], 0.3));
    assert!(close(&s2["max_residual_um"], 9.5));
    assert_eq!(
        s2["orientation"],
        json!({"rotation_deg": 180, "mirrored": false})
    );
    assert!(close(&s2["orientation_margin"], 1.3));
    assert_eq!(s2["orientation_ambiguous"], true);
    assert_eq!(s2["marks_used"], 8);
    let failed = &film["scans"][4];
    assert_eq!(failed["photo"], "film_p5");
    assert!(failed["failed"].as_str().unwrap().contains("3 of 8 marks"));
    assert_eq!(
        film["photos"][5]["reason"],
        "fiducial interior orientation failed: 3 of 8 marks found"
    );
    // Warnings per epoch and per run, each with its kind.
    assert_eq!(film["warnings"][0]["kind"], "partial_epoch");
    assert_eq!(film["warnings"][1]["kind"], "self_calibration_held");
    assert_eq!(v["warnings"][0]["kind"], "lidar");
    assert!(v["warnings"][0]["message"]
        .as_str()
        .unwrap()
        .contains("no CRS"));
    // The LiDAR against the checkpoints.
    let l = &v["lidar_checkpoints"];
    assert_eq!(l["count"], 2);
    assert_eq!(l["skipped"], 1);
    assert!(close(&l["rmse_m"], 0.0316) && close(&l["mean_m"], 0.03));
    assert!(close(&l["rows"][1]["dz_m"], 0.04));
    assert_eq!(l["rows"][2]["lidar_z"], Value::Null);
    assert_eq!(l["radius_m"], 3.0);
    // The strips' offsets, and why in height alone.
    let s = &v["lidar_strips"];
    assert_eq!(s["model"], "vertical");
    assert!(close(&s["strips"][1]["offset_m"][2], -0.031));
    assert!(s["vertical_because"].as_str().unwrap().contains("spread"));
    // The run: version, project hash, date, options and thresholds.
    let run = &v["run"];
    assert_eq!(run["cloudcontrol_version"], cloudcontrol::VERSION);
    assert_eq!(run["project_sha256"].as_str().unwrap().len(), 64);
    assert_eq!(run["date_utc"], "2023-11-14T22:13:20Z");
    assert!(close(&run["options"]["thresholds"]["reject_k"], 2.5));
    assert_eq!(
        run["options"]["epochs"][0]["self_calibration"],
        json!(["f_mm"])
    );
    assert_eq!(
        run["options"]["default_self_calibration"]["archive_frame"],
        json!(["fx", "fy", "k1", "k2"])
    );
    let back: Report = serde_json::from_value(v).unwrap();
    // The dh maps' PNG bytes are the HTML's, not the JSON's (which names the file).
    let mut epochs = r.epochs.clone();
    for c in epochs.iter_mut().flat_map(|e| e.surface_change.iter_mut()) {
        assert!(c.map.is_some() && !c.map_png.is_empty());
        c.map_png.clear();
    }
    assert_eq!(back.epochs, epochs);
    assert_eq!(back.run, r.run);
    assert_eq!(back.lidar_checkpoints, r.lidar_checkpoints);
    assert_eq!(back.warnings, r.warnings);
}

#[test]
fn report_dates_are_iso_8601() {
    assert_eq!(utc_iso8601(0), "1970-01-01T00:00:00Z");
    assert_eq!(utc_iso8601(951_782_400), "2000-02-29T00:00:00Z");
    assert_eq!(utc_iso8601(-86_400), "1969-12-31T00:00:00Z");
    assert_eq!(decimal_year("1985"), Some(1985.5));
    assert!((decimal_year("2000-12-31").unwrap() - (2000.0 + 365.5 / 366.0)).abs() < 1e-12);
    assert!((decimal_year("1978-06").unwrap() - (1978.0 + (151.0 + 15.0) / 365.0)).abs() < 1e-12);
    assert_eq!(decimal_year("1985-13-01"), None);
    assert_eq!(decimal_year("autumn"), None);
}

/// An epoch's result as `result.json` holds it: one film scan measured with an undecided
/// orientation and a warning of its own, one whose marks were not found, and an
/// adjustment that held one parameter, left one undetermined, tested against the first
/// solution's σ0 and scaled the control σ.
fn film_result() -> cloudcontrol::control::archive::EpochResult {
    let io = |rmse: f64, ambiguous: bool| {
        json!({"rmse_um": rmse, "pixel_um": 20.0, "pixel_source": "given",
               "measured_pixel_um": 20.5, "marks_used": 7, "marks_total": 8,
               "max_residual_um": 2.0 * rmse,
               "orientation": {"rotation_deg": 270, "mirrored": true},
               "orientation_source": if ambiguous { "epoch majority (3 of 4 scans)" } else { "decided by the marks" },
               "orientation_margin": if ambiguous { 1.2 } else { 1000.0 },
               "orientation_ambiguous": ambiguous,
               "warnings": if ambiguous { vec!["given scan pixel size 20.000 µm, but the fiducial marks measure 20.500 µm"] } else { vec![] }})
    };
    let photo = |name: &str, io: Value, reason: Value| {
        json!({"name": name, "oriented": reason.is_null(), "reason": reason, "iterations": [],
               "control_matches": 9, "sigma_px": 0.5, "io": io, "predicted": 12,
               "matching": {"offered": 0, "no_chip": 0, "textureless": 0, "rejected": 0, "accepted": 0},
               "relaxed": false, "second_pass": false, "tie_pass": false})
    };
    let photos = vec![
        photo("s1", io(5.0, false), Value::Null),
        photo("s2", io(8.0, true), Value::Null),
        photo(
            "s3",
            Value::Null,
            json!({"kind": "interior_orientation", "message": "3 of 8 marks found"}),
        ),
    ];
    let cal = |param: &str, fixed: bool, held: Value, t: Value, determinable: bool| {
        json!({"camera": 1, "param": param, "value": 0.0, "sigma": 0.0, "max_correlation": 0.97,
               "correlated_with": "photo 2 z", "determinable": determinable, "fixed": fixed,
               "held_because": held, "t_prior": t})
    };
    let adjustment = json!({
        "sigma0": 1.1, "rejection_test": "baarda_data_snooping alpha=0.001 sigma=first_round 1.83",
        "control_sigma_scale": 4.2, "rmse_px": 0.6, "iterations": 7, "rounds": 2, "converged": true,
        "datum": "control", "photos": 2, "points": 100, "observations": 400, "redundancy": 200,
        "rejected": {"count": 0, "list": []}, "time_s": 0.1, "photo_precision": [],
        "calibration": [cal("k2", true, json!("not_significant"), json!(1.2), true),
                        cal("f_mm", false, Value::Null, Value::Null, false)],
        "check": null, "residuals": []
    });
    cloudcontrol::control::archive::EpochResult {
        epoch: "film".into(),
        block: Default::default(),
        photos: serde_json::from_value(Value::Array(photos)).unwrap(),
        adjustment: Some(serde_json::from_value(adjustment).unwrap()),
        gsd_m: 0.5,
        time_s: 1.0,
    }
}

#[test]
fn epoch_warnings_and_scans_come_from_the_result() {
    let result = film_result();
    let scans = scan_rows(&result);
    assert_eq!(scans.len(), 3);
    assert!((scans[1].rmse_um - 8.0).abs() < 1e-12 && (scans[1].rmse_px - 0.4).abs() < 1e-12);
    assert!((scans[1].max_residual_um - 16.0).abs() < 1e-12);
    assert_eq!(
        scans[1].orientation,
        Some(ScanOrientation {
            rotation_deg: 270,
            mirrored: true
        })
    );
    assert!(scans[1].orientation_ambiguous && (scans[1].orientation_margin - 1.2).abs() < 1e-12);
    assert_eq!((scans[0].marks_used, scans[0].marks_total), (7, 8));
    assert!((scans[0].measured_pixel_um - 20.5).abs() < 1e-12);
    assert_eq!(
        scans[2].failed.as_deref(),
        Some("fiducial interior orientation failed: 3 of 8 marks found")
    );
    let mut rep: EpochReport = serde_json::from_value(json!({
        "name": "film", "date": "1985", "gsd_m": 0.5, "photos_total": 3, "photos_oriented": 2,
        "check_rmse_plan_m": null, "check_rmse_height_m": null, "check_max_m": null,
        "sigma0": 1.1, "rmse_px": 0.6, "time_s": 1.0, "checkpoints_not_evaluated": 2
    }))
    .unwrap();
    rep.checkpoint_rejections = vec![RejectedMeasurement {
        id: "C1".into(),
        photo: "s2".into(),
        line: 3,
        pixel: [10.0, 20.0],
        residual_px: Some(25.0),
        reason: "data snooping".into(),
    }];
    let w = epoch_warnings(&result, &rep);
    let kinds: Vec<WarningKind> = w.iter().map(|w| w.kind).collect();
    let text = |k: WarningKind| -> Vec<&str> {
        w.iter()
            .filter(|w| w.kind == k)
            .map(|w| w.message.as_str())
            .collect()
    };
    assert_eq!(
        text(WarningKind::PartialEpoch),
        ["2 of 3 photos oriented; not oriented: s3: fiducial interior orientation failed: 3 of 8 marks found"]
    );
    assert_eq!(
        text(WarningKind::SelfCalibrationHeld),
        ["camera 1: k2 held at its prior value 0: its estimate was 1.2 σ from the prior: not significant at 5 %"]
    );
    assert_eq!(text(WarningKind::SelfCalibrationNotDeterminable).len(), 1);
    assert!(text(WarningKind::SelfCalibrationNotDeterminable)[0].contains("f_mm"));
    let adj = text(WarningKind::Adjustment);
    assert!(
        adj.iter().any(|m| m.contains("first solution's σ0 1.83")),
        "{adj:?}"
    );
    assert!(adj.iter().any(|m| m.contains("×4.20")), "{adj:?}");
    let scan_w = text(WarningKind::ScanInteriorOrientation);
    assert_eq!(scan_w.len(), 2, "{scan_w:?}");
    assert!(scan_w[0].starts_with("scan s2: the fiducial marks alone do not decide"));
    assert!(scan_w[1].contains("the fiducial marks measure 20.500 µm"));
    let cps = text(WarningKind::Checkpoints);
    assert!(cps[0].starts_with("2 checkpoint(s) not evaluated"));
    assert!(cps[1].starts_with("1 checkpoint measurement(s) rejected (photos s2)"));
    assert_eq!(kinds[0], WarningKind::PartialEpoch);
}

fn chromium() -> Option<&'static str> {
    ["chromium", "chromium-browser", "google-chrome"]
        .into_iter()
        .find(|c| {
            Command::new(c)
                .arg("--version")
                .output()
                .is_ok_and(|o| o.status.success())
        })
}

/// Chromium with a throwaway profile on `page`: `--dump-dom` (the DOM it built) or
/// `--screenshot=…`.
fn chromium_on(dir: &std::path::Path, page: &std::path::Path, what: &str) -> std::process::Output {
    let browser = chromium().expect("chromium is installed by setup.sh");
    Command::new(browser)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--hide-scrollbars",
            "--window-size=1400,2400",
        ])
        .arg(format!("--user-data-dir={}", dir.join("profile").display()))
        .arg(what)
        .arg(format!("file://{}", page.display()))
        .output()
        .unwrap()
}

/// The markup of the element with `id` in `dom`, up to its closing tag (the report
/// nests no element in one of its own tag that a test looks into).
fn element<'d>(dom: &'d str, id: &str) -> &'d str {
    let at = dom
        .find(&format!(" id=\"{id}\""))
        .unwrap_or_else(|| panic!("no element #{id} in the page"));
    let open = dom[..at].rfind('<').unwrap();
    let tag = dom[open + 1..at].split(' ').next().unwrap();
    let end = dom[at..]
        .find(&format!("</{tag}>"))
        .unwrap_or_else(|| panic!("#{id} is not closed"));
    &dom[open..at + end]
}

/// Whether `markup` holds an element whose whole text is `t` (an SVG `<text>` holds its
/// text between line breaks).
fn has_text(markup: &str, t: &str) -> bool {
    markup.contains(&format!(">{t}<")) || markup.contains(&format!(">\n{t}\n<"))
}

#[test]
fn html_report_renders_in_headless_chromium() {
    let dir = tempfile::tempdir().unwrap();
    write(&sample_report(), dir.path()).unwrap();
    if let Ok(d) = std::env::var("TMP_REPORT_SAMPLE") {
        write(&sample_report(), std::path::Path::new(&d)).unwrap();
    }
    let page = dir.path().join("report.html");
    let html = std::fs::read_to_string(&page).unwrap();
    assert!(
        html.matches("<svg").count() >= 10,
        "map + accuracy by date + 3 epochs × (histogram, residuals) + 2 × matching + ICP"
    );
    // Each epoch says what controlled it.
    assert!(html.contains("<td>LiDAR (tie points by ICP and plane constraints)</td>"));
    // The film epoch's surface against the LiDAR, flagged.
    assert!(html.contains(
        "<tr class=\"bad\"><td>film-1985</td><td>1985</td><td>lidar_surface</td><td>0.41</td>"
    ));
    // Beside Nuth & Kääb's plan shift, the shift and tilt fitted together.
    assert!(html.contains(
        "<td>0.43 ± 0.05</td><td>0.13 ± 0.09</td><td>0.04 ± 0.02</td><td>0.80, -0.30</td>"
    ));
    assert!(html.contains("<td>DCPs of epoch reference</td>"));
    // Tie statistics: points × photos, σ0 of each group, and the standard positions short
    // of points (i % 5 < 3 at top-left for photos 1, 2, 5, 6, 7, 10, 11: photo 0's is not
    // required) marked, in every epoch.
    assert!(html.contains("<td>120×2, 150×3, 30×4</td>"));
    assert!(html.contains("<td>image</td><td>900</td><td>1200.0</td><td>1.12</td>"));
    assert_eq!(html.matches("background:#f4b6b6").count(), 3 * 7);
    assert_eq!(html.matches("color:#999").count(), 3);

    // The DOM Chromium builds holds every section an operator acts on.
    let out = chromium_on(dir.path(), &page, "--dump-dom");
    let dom = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        dom.contains("</html>"),
        "no DOM: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    // Run metadata.
    let run = element(&dom, "run-info");
    assert!(run.contains(cloudcontrol::VERSION));
    assert!(run.contains(&"ab".repeat(32)));
    assert!(run.contains("2023-11-14T22:13:20Z"));
    assert!(run.contains("reject_k = 2.5"));
    assert!(run.contains("self-calibration f_mm"));
    // Warnings of the run and of the epochs.
    let w = element(&dom, "warnings");
    assert!(w.contains("Warnings (3)"));
    assert!(w.contains("tiles carry no CRS"));
    assert!(w.contains("k2 held at its prior value"));
    assert!(element(&dom, "warnings-film-1985").contains("11 of 12 photos oriented"));
    // Accuracy by epoch date: both panels, every epoch named, years on the axis.
    let acc = element(&dom, "accuracy-by-date");
    for t in [
        "checkpoint RMSE (m)",
        "checkpoint RMSE (GSD)",
        "film-1985",
        "digital-2005",
        "reference-2019",
        "1990",
        "2010",
    ] {
        assert!(acc.contains(t), "accuracy plot lacks {t:?}");
    }
    // The LiDAR's check, one row per checkpoint.
    let l = element(&dom, "lidar-check");
    assert!(l.contains("<td>+0.020</td>") && l.contains("<td>120.020</td>"));
    assert!(l.contains("skipped: 2 ground points within 3 m (need 6)"));
    let s = element(&dom, "lidar-strips");
    assert!(s.contains("a height offset per strip") && s.contains("spread 0.031"));
    assert!(s.contains("<td>2</td><td>24000</td><td>+0.000</td><td>+0.000</td><td>-0.031</td>"));
    // Per-checkpoint table: id, dx, dy, dz in m and GSD, photos.
    let e = &sample_report().epochs[2];
    let c = &e.checkpoints[7];
    let row = format!(
        "<td>CP07</td><td>{:+.3}</td><td>{:+.3}</td><td>{:+.3}</td><td>{:.3}</td><td>{:+.2}</td><td>{:+.2}</td><td>{:+.2}</td><td>3</td>",
        c.dx,
        c.dy,
        c.dz,
        c.dx.hypot(c.dy),
        c.dx / 0.5,
        c.dy / 0.5,
        c.dz / 0.5
    );
    assert!(
        element(&dom, "checkpoints-film-1985").contains(&row),
        "{row}"
    );
    assert!(element(&dom, "checkpoints-reference-2019").contains("<td>CP19</td>"));
    // Checkpoint measurements rejected.
    let rej = element(&dom, "checkpoint-rejections-film-1985");
    assert!(rej.contains("<td>film_p3</td><td>42</td><td>1234.5, 987.4</td><td>17.3</td>"));
    // Film interior orientation per scan: residuals in µm and px, orientation, margin.
    let scans = element(&dom, "scans-film-1985");
    assert!(scans.contains(
        "<td>film_p2</td><td>8/8</td><td>6.0</td><td>0.30</td><td>9.5</td><td>180°</td>"
    ));
    assert!(scans.contains("epoch majority (5 of 6 scans)</td><td>1.30</td>"));
    assert!(scans.contains("no interior orientation: fiducial interior orientation failed"));
    // Photo names on the matching bar chart.
    let m = element(&dom, "matching-digital-2005");
    assert!(has_text(m, "digital_p0") && has_text(m, "digital_p11"));
    // The residual plot's scale: axis units, the stated factor, a scale arrow's label.
    let r = element(&dom, "residuals-film-1985");
    assert!(r.contains("E (m)") && r.contains("N (m)"));
    assert!(r.contains("(arrows: 1 px = ") && has_text(r, "0.1 px"));
    // The epoch's checkpoint map: plan error arrows with their factor and a scale arrow
    // (the largest plan error 0.2 × 0.3 × √2 m, rounded down), height circles.
    let m = element(&dom, "checkpoint-map-digital-2005");
    assert!(m.contains("plan error (arrows ×") && has_text(m, "0.05 m"));
    assert!(m.contains("height error (circles):"));
    // The time series' dh maps: the film epoch's, inline, with its colour range.
    let maps = element(&dom, "dh-maps");
    assert!(maps.contains("<img") && maps.contains("data:image/png;base64,"));
    assert!(
        maps.contains("full colour at ±2.0 m from the median -0.11 m"),
        "{maps}"
    );

    let shot = dir.path().join("shot.png");
    let out = chromium_on(
        dir.path(),
        &page,
        &format!("--screenshot={}", shot.display()),
    );
    assert!(
        shot.exists(),
        "no screenshot: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let img = image::open(&shot).unwrap().to_rgb8();
    let total = (img.width() * img.height()) as usize;
    let non_white = img
        .pixels()
        .filter(|p| p.0.iter().any(|&c| c < 240))
        .count();
    // Plot colours: the blue of the plan series, the red of the height series.
    let blue = img
        .pixels()
        .filter(|p| p.0[2] > 150 && p.0[0] < 120 && p.0[1] < 120)
        .count();
    let red = img
        .pixels()
        .filter(|p| p.0[0] > 150 && p.0[1] < 120 && p.0[2] < 120)
        .count();
    assert!(
        non_white > total / 50,
        "page looks blank: {non_white} of {total} pixels drawn"
    );
    assert!(
        blue > 500 && red > 500,
        "plots not rendered (blue {blue}, red {red})"
    );
}

/// The samples of formats/workflow/: `epoch.json`'s warnings, scans and reasons are what
/// the code derives from `result.json`.
#[test]
fn workflow_sample_warnings_are_derived_from_its_result() {
    let sample = |name: &str| -> Value {
        let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("formats/workflow")
            .join(name);
        serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap()
    };
    let mut r = sample("result.json");
    // A photo without a resection has σ NaN, written null, which PhotoReport does not read
    // back (nothing in cloudcontrol reads result.json); the warnings do not use it.
    for p in r["photos"].as_array_mut().unwrap() {
        if p["sigma_px"].is_null() {
            p["sigma_px"] = json!(0.0);
        }
    }
    let result = cloudcontrol::control::archive::EpochResult {
        epoch: r["epoch"].as_str().unwrap().into(),
        block: serde_json::from_value(sample("block.json")).unwrap(),
        photos: serde_json::from_value(r["photos"].clone()).unwrap(),
        adjustment: serde_json::from_value(r["adjustment"].clone()).unwrap(),
        gsd_m: r["gsd_m"].as_f64().unwrap(),
        time_s: r["time_s"].as_f64().unwrap(),
    };
    let epoch: EpochReport = serde_json::from_value(sample("epoch.json")).unwrap();
    assert_eq!(epoch.warnings, epoch_warnings(&result, &epoch));
    assert_eq!(epoch.scans, scan_rows(&result));
    for (p, q) in epoch.photos.iter().zip(&result.photos) {
        assert_eq!(
            p.reason,
            q.reason.as_ref().map(|f| f.to_string()),
            "{}",
            p.name
        );
    }
    assert_eq!(epoch.warnings[0].kind, WarningKind::PartialEpoch);
}
