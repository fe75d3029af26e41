//! The real kite block of Coal Oil Point (12 photos, COLMAP model computed from the real
//! images) adjusted with its OpenDroneMap GCP file as given: heights all 0.0 (unknown),
//! one GCP measured in a single photo, one measurement copied from another point.

use std::path::{Path, PathBuf};
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_cloudcontrol");

pub(crate) fn data() -> PathBuf {
    let local = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/copr_kap_2009");
    if local.exists() {
        local
    } else {
        PathBuf::from("/work/shared/data/copr_kap_2009")
    }
}

/// A rejected observation as `--observations` lists it.
#[derive(serde::Deserialize)]
pub(crate) struct RejectedRow {
    #[serde(rename = "type")]
    pub kind: String,
    pub photo: Option<i64>,
    pub point: Option<i64>,
    pub status: String,
    pub with_point: Option<bool>,
}

/// `cloudcontrol adjust` of COLMAP model `model` with the block's ODM GCP file as given
/// and 0.5 px: the JSON report and every rejected observation (`--observations`; the
/// report lists only the 100 largest). The report's count agrees with the listing's.
fn adjust(model: &Path) -> (serde_json::Value, Vec<RejectedRow>) {
    let dir = tempfile::tempdir().unwrap();
    let report = dir.path().join("report.json");
    let listing = dir.path().join("observations.csv");
    let out = Command::new(BIN)
        .args(["-q", "adjust", "--model"])
        .arg(model)
        .arg("--gcp")
        .arg(data().join("gcp_list_subset.txt"))
        .args(["--sigma-px", "0.5", "--out"])
        .arg(dir.path().join("out"))
        .arg("--report")
        .arg(&report)
        .arg("--observations")
        .arg(&listing)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    let rejected: Vec<RejectedRow> = csv::Reader::from_path(&listing)
        .unwrap()
        .deserialize()
        .map(|row| row.unwrap())
        .filter(|row: &RejectedRow| row.status == "rejected")
        .collect();
    assert_eq!(r["rejected"]["count"], rejected.len());
    assert_eq!(r["rejected"]["listed"], rejected.len().min(100));
    (r, rejected)
}

#[test]
fn kite_block_adjusts_with_its_odm_gcp_file_as_given() {
    let (r, rejected) = adjust(&data().join("colmap_sparse/txt"));
    let g = &r["georeference"];
    // Six GCPs: five fix the similarity, gcp00 (one photo) constrains its photo alone;
    // none is rejected as a whole.
    assert_eq!(g["control_used"].as_array().unwrap().len(), 5, "{g}");
    assert_eq!(g["single_ray"], serde_json::json!(["gcp00"]));
    assert!(g["rejected_points"].as_array().unwrap().is_empty(), "{g}");
    // The measurement of gcp04 in IMG_0031 sits on gcp00's mark (3484, 729): a copied
    // measurement, thousands of pixels from gcp04's other rays; it is named as that
    // measurement with its residual.
    let meas = g["rejected_measurements"].as_array().unwrap();
    let copied = meas
        .iter()
        .find(|m| m["name"] == "gcp04" && m["photo_name"] == "IMG_0031.jpg")
        .unwrap_or_else(|| panic!("{meas:#?}"));
    assert!(copied["residual_px"].as_f64().unwrap() > 1000.0);
    assert!(meas.len() <= 2, "{meas:#?}");
    for m in meas {
        assert!(
            m["residual_px"].as_f64().unwrap() > 0.0 && !m["reason"].as_str().unwrap().is_empty()
        );
    }
    // The adjustment after it. The GCP file states no σ (5 cm assumed); its points fit
    // their rays at decimetres (coordinates to the centimetre, heights unknown), so the
    // control group is re-weighted on the first solution and all six stay in.
    let scale = r["control_sigma_scale"].as_f64().expect("control σ scaled");
    assert!(scale > 3.0 && scale < 20.0, "control σ × {scale}");
    let other: Vec<(&str, Option<i64>, Option<i64>)> = rejected
        .iter()
        .filter(|x| x.kind != "image")
        .map(|x| (x.kind.as_str(), x.photo, x.point))
        .collect();
    assert!(other.is_empty(), "{other:?}");
    let control = r["variance_components"]
        .as_array()
        .unwrap()
        .iter()
        .find(|v| v["group"] == "control")
        .unwrap();
    assert_eq!(control["observations"], 6, "{control}");
    // σ0 of the image group for the a-priori 0.5 px: COLMAP's own solution of this model
    // has an RMS of 0.43 px per component.
    let s0 = r["sigma0"].as_f64().unwrap();
    assert!(s0 > 0.7 && s0 < 1.1, "σ0 {s0}");
    assert_eq!(
        r["rejection_test"].as_str().unwrap().split(',').next(),
        Some("baarda_data_snooping alpha=0.001 sigma=a_priori")
    );
    // Rejected tie observations: the issue asks for fewer than 1 %. The block's tie points
    // differ in precision (a ray's squared residual correlates at 0.49 with its point's
    // other rays'), so each ray is tested against its own point's other rays with the
    // fitted prior (d0 ≈ 3, s0² ≈ 0.5); data snooping against one 0.5 px σ rejected
    // 3.0 % here (1.4 % with three-ray points removed whole).
    let prior = &r["tie_point_prior"];
    let d0 = prior["dof"].as_f64().expect("a tie point prior");
    assert!((2.0..=5.0).contains(&d0), "{prior}");
    let ties = 35_172.0;
    let n = rejected.len() as f64;
    let alone = rejected
        .iter()
        .filter(|x| x.with_point == Some(false))
        .count() as f64;
    eprintln!(
        "kite: σ0 {s0:.3}, control σ × {scale:.2}, {n} rejected ({:.2} %, {:.2} % as themselves), test {}",
        100.0 * n / ties,
        100.0 * alone / ties,
        r["rejection_test"]
    );
    assert!(n / ties < 0.006, "{n} rejected"); // measured 0.37 %
}

/// The same block with 2 % of its tie observations displaced 3–30 px (seeded): the test
/// against each point's own rays must still find the displaced rays, not take them for an
/// imprecise point (a factor estimated from all of a point's rays, the ray under test
/// among them, found 11.7 % of such displacements).
#[test]
fn kite_block_finds_displaced_tie_observations() {
    use rand::{Rng, SeedableRng};
    use std::collections::BTreeSet;
    let d = data();
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("model");
    std::fs::create_dir(&model).unwrap();
    for f in ["cameras.txt", "points3D.txt"] {
        std::fs::copy(d.join("colmap_sparse/txt").join(f), model.join(f)).unwrap();
    }
    let text = std::fs::read_to_string(d.join("colmap_sparse/txt/images.txt")).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(16);
    let mut displaced = BTreeSet::new();
    let mut out = Vec::new();
    let mut lines = text.lines();
    let mut observations = 0usize;
    while let Some(l) = lines.next() {
        out.push(l.to_string());
        if l.starts_with('#') || l.trim().is_empty() {
            continue;
        }
        let image: i64 = l.split_whitespace().next().unwrap().parse().unwrap();
        let obs: Vec<&str> = lines.next().unwrap().split_whitespace().collect();
        let mut row = Vec::new();
        for o in obs.chunks(3) {
            let (mut x, mut y): (f64, f64) = (o[0].parse().unwrap(), o[1].parse().unwrap());
            let point: i64 = o[2].parse().unwrap();
            if point >= 0 {
                observations += 1;
                if rng.gen::<f64>() < 0.02 {
                    let (a, m) = (
                        rng.gen_range(0.0..std::f64::consts::TAU),
                        rng.gen_range(3.0..30.0),
                    );
                    x += m * a.cos();
                    y += m * a.sin();
                    displaced.insert((point, image));
                }
            }
            row.push(format!("{x:.4} {y:.4} {point}"));
        }
        out.push(row.join(" "));
    }
    std::fs::write(model.join("images.txt"), out.join("\n") + "\n").unwrap();
    let (_, rows) = adjust(&model);
    let rejected: BTreeSet<(i64, i64)> = rows
        .iter()
        .filter(|x| x.kind == "image")
        .map(|x| (x.point.unwrap(), x.photo.unwrap()))
        .collect();
    let found = rejected.intersection(&displaced).count() as f64;
    let false_ = rejected.difference(&displaced).count() as f64;
    let good = (observations - displaced.len()) as f64;
    eprintln!(
        "kite displaced: {} displaced, {found} found ({:.1} %), {false_} good rejected ({:.2} %)",
        displaced.len(),
        100.0 * found / displaced.len() as f64,
        100.0 * false_ / good
    );
    // Measured: 94.9 % found, 0.63 % of the others rejected (against one σ: 98.6 % and
    // 3.2 % on another draw). Most misses are displacements below 8 px in three-ray
    // points, where the prior's spread makes an imprecise point as likely; the issue's
    // bound for false rejections is 1 %.
    assert!(found / displaced.len() as f64 > 0.9);
    assert!(false_ / good < 0.01);
}
