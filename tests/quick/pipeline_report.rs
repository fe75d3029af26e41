//! The report: JSON with the documented fields, and HTML whose plots render in headless
//! Chromium (a screenshot with the plots' colours in it).

use cloudcontrol::adjust::VarianceComponent;
use cloudcontrol::pipeline::report::*;
use cloudcontrol::pipeline::tie_statistics::{PhotoTies, TieStatistics};
use std::process::Command;

fn sample_report() -> Report {
    let mut epochs = Vec::new();
    for (k, (name, gsd)) in [("reference-2019", 0.1), ("film-1985", 0.5)]
        .iter()
        .enumerate()
    {
        let mut e = EpochReport {
            name: name.to_string(),
            date: if k == 0 {
                "2019-05-04".into()
            } else {
                "1985".into()
            },
            gsd_m: *gsd,
            photos_total: 12,
            photos_oriented: 12 - k,
            photos_through_ties: 0,
            check_rmse_plan_m: 0.0,
            check_rmse_height_m: 0.0,
            check_max_m: 0.0,
            sigma0: 0.9,
            rmse_px: 0.45,
            time_s: 12.5,
            checkpoints: (0..20)
                .map(|i| CheckpointError {
                    id: format!("CP{i}"),
                    x: 500_000.0 + 20.0 * (i % 5) as f64,
                    y: 4_400_000.0 + 25.0 * (i / 5) as f64,
                    dx: gsd * 0.3 * ((i as f64) * 0.7).sin(),
                    dy: gsd * 0.3 * ((i as f64) * 1.3).cos(),
                    dz: gsd * 0.5 * ((i as f64) * 0.4).sin(),
                    rays: 3,
                })
                .collect(),
            checkpoints_not_evaluated: 0,
            checkpoint_rejections: Vec::new(),
            photos: (0..12)
                .map(|i| PhotoSummary {
                    name: format!("p{i}"),
                    x: 499_990.0 + 10.0 * (i % 4) as f64,
                    y: 4_399_995.0 + 30.0 * (i / 4) as f64,
                    oriented: !(k == 1 && i == 5),
                    mean_residual_px: [0.1 * (i as f64).sin(), 0.1 * (i as f64).cos()],
                    rmse_px: 0.4,
                    patches_predicted: 20,
                    patches_matched: 12 + i % 8,
                    ties: PhotoTies {
                        tie_observations: 40 + i,
                        control_observations: 12 + i % 8,
                        positions: [i % 5, 4, 4, 4, 6, 4, 4, 4, 4],
                        required: [i != 0, true, true, true, true, true, true, true, true],
                    },
                })
                .collect(),
            icp: (0..8)
                .map(|i| IcpIteration {
                    iteration: i,
                    rmse_m: 2.0 * 0.5f64.powi(i as i32) + 0.05,
                    inliers: 1000,
                })
                .collect(),
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
        };
        e.set_check_statistics();
        epochs.push(e);
    }
    Report {
        project: "demo".into(),
        crs: "EPSG:4547".into(),
        epochs,
        ortho: None,
    }
}

#[test]
fn report_json_has_the_documented_fields_and_statistics() {
    let dir = tempfile::tempdir().unwrap();
    let r = sample_report();
    write(&r, dir.path()).unwrap();
    let v: serde_json::Value =
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
    let back: Report = serde_json::from_value(v).unwrap();
    assert_eq!(back.epochs, r.epochs);
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

#[test]
fn html_report_renders_in_headless_chromium() {
    let dir = tempfile::tempdir().unwrap();
    write(&sample_report(), dir.path()).unwrap();
    let html = std::fs::read_to_string(dir.path().join("report.html")).unwrap();
    assert!(
        html.matches("<svg").count() >= 8,
        "map + 2 epochs × (histogram, residuals, matching, ICP)"
    );
    // Each epoch says what controlled it.
    assert!(html.contains("<td>LiDAR (tie points by ICP and plane constraints)</td>"));
    assert!(html.contains("<td>DCPs of epoch reference</td>"));
    // Tie statistics: points × photos, σ0 of each group, and the standard positions short
    // of points (i % 5 < 3 at top-left for photos 1, 2, 5, 6, 7, 10, 11: photo 0's is not
    // required) marked, in both epochs.
    assert!(html.contains("<td>120×2, 150×3, 30×4</td>"));
    assert!(html.contains("<td>image</td><td>900</td><td>1200.0</td><td>1.12</td>"));
    assert_eq!(html.matches("background:#f4b6b6").count(), 2 * 7);
    assert_eq!(html.matches("color:#999").count(), 2);
    let browser = chromium().expect("chromium is installed by setup.sh");
    let shot = dir.path().join("shot.png");
    let profile = dir.path().join("profile");
    let out = Command::new(browser)
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
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg(format!("--screenshot={}", shot.display()))
        .arg(format!(
            "file://{}",
            dir.path().join("report.html").display()
        ))
        .output()
        .unwrap();
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
    // Plot colours: the blue of the plan histogram/ICP line, the red of the height bars and residual vectors.
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
