//! The adjustment report as files: the JSON summary keeps every field of the report but
//! the per-observation residuals, its lists stay at 100 whatever the block, and the CSV
//! listings hold every observation and photo.

use cloudcontrol::adjust::synthetic::{generate, SyntheticOptions};
use cloudcontrol::adjust::{adjust, AdjustOptions, AdjustReport, ObservationRef};
use cloudcontrol::formats::adjust_report::{self, LISTED};
use std::collections::BTreeSet;

/// A 4 × 10 photo block with 3 % of its image observations displaced 20 px.
fn adjusted() -> (AdjustReport, cloudcontrol::block::Block) {
    let o = SyntheticOptions {
        strips: 4,
        photos_per_strip: 10,
        tie_points: 4000,
        seed: 7,
        ..SyntheticOptions::default()
    };
    let mut b = generate(&o).start;
    let mut k = 0usize;
    for p in b.points.values_mut() {
        for obs in p.observations.iter_mut() {
            k += 1;
            if k % 33 == 0 {
                obs.pixel[0] += 20.0;
            }
        }
    }
    let rep = adjust(&mut b, &[], None, &AdjustOptions::default()).unwrap();
    (rep, b)
}

fn keys(v: &serde_json::Value) -> BTreeSet<String> {
    v.as_object().unwrap().keys().cloned().collect()
}

#[test]
fn summary_keeps_every_field_but_the_residuals_and_bounds_its_lists() {
    let (rep, block) = adjusted();
    assert!(
        rep.rejected.count > LISTED,
        "{} rejected",
        rep.rejected.count
    );
    let full = serde_json::to_value(&rep).unwrap();
    let summary = serde_json::to_value(adjust_report::summary(&rep)).unwrap();
    // A field added to the report and forgotten here would be dropped from the file.
    let mut expected = keys(&full);
    expected.remove("residuals");
    assert_eq!(keys(&summary), expected);
    for k in expected {
        if k != "rejected" && k != "photo_precision" {
            assert_eq!(summary[&k], full[&k], "{k}");
        }
    }
    // The largest rejections, in decreasing order, and how many there are.
    let r = &summary["rejected"];
    assert_eq!(r["count"], rep.rejected.count);
    assert_eq!(r["listed"], LISTED);
    let listed: Vec<f64> = r["list"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x["standardized_residual"].as_f64().unwrap())
        .collect();
    assert_eq!(listed.len(), LISTED);
    assert!(listed.windows(2).all(|w| w[0] >= w[1]));
    let mut all: Vec<f64> = rep
        .rejected
        .list
        .iter()
        .map(|x| x.standardized_residual)
        .collect();
    all.sort_by(|a, b| b.total_cmp(a));
    assert_eq!(listed, all[..LISTED]);
    // The photos' precision: medians and maxima over all 40, the weakest first.
    let p = &summary["photo_precision"];
    assert_eq!(p["photos"], 40);
    let mut z: Vec<f64> = rep
        .photo_precision
        .iter()
        .map(|x| x.sigma_center_m[2])
        .collect();
    z.sort_by(f64::total_cmp);
    assert_eq!(p["max_sigma_center_m"][2].as_f64().unwrap(), z[39]);
    assert_eq!(p["median_sigma_center_m"][2].as_f64().unwrap(), z[20]);
    let worst = |x: &serde_json::Value| {
        (0..3)
            .map(|k| x["sigma_center_m"][k].as_f64().unwrap())
            .fold(0.0, f64::max)
    };
    let weakest = p["weakest"].as_array().unwrap();
    assert_eq!(weakest.len(), 40);
    assert!(weakest.windows(2).all(|w| worst(&w[0]) >= worst(&w[1])));

    // The listings: every kept observation with its residual, every rejected one.
    let dir = tempfile::tempdir().unwrap();
    let obs = dir.path().join("observations.csv");
    let n = adjust_report::write_observations_csv(&obs, &rep, &block).unwrap();
    assert_eq!(n, rep.residuals.len() + rep.rejected.list.len());
    let rows: Vec<csv::StringRecord> = csv::Reader::from_path(&obs)
        .unwrap()
        .records()
        .map(|r| r.unwrap())
        .collect();
    assert_eq!(rows.len(), n);
    let rejected: BTreeSet<(u64, u32)> = rows
        .iter()
        .filter(|r| &r[5] == "rejected")
        .map(|r| (r[3].parse().unwrap(), r[1].parse().unwrap()))
        .collect();
    let truth: BTreeSet<(u64, u32)> = rep
        .rejected
        .list
        .iter()
        .filter_map(|x| match x.observation {
            ObservationRef::Image { point, photo } => Some((point, photo)),
            _ => None,
        })
        .collect();
    assert_eq!(rejected, truth);
    // A kept image observation: its residual to the bit as the report holds it.
    let first = rows
        .iter()
        .find(|r| &r[5] == "used" && &r[0] == "image")
        .unwrap();
    let res = rep
        .residuals
        .iter()
        .find(|x| {
            x.observation
                == ObservationRef::Image {
                    point: first[3].parse().unwrap(),
                    photo: first[1].parse().unwrap(),
                }
        })
        .unwrap();
    assert_eq!(first[7].parse::<f64>().unwrap(), res.residual[0]);
    assert_eq!(first[2], block.photos[&first[1].parse().unwrap()].name);
    let photos = dir.path().join("photos.csv");
    assert_eq!(adjust_report::write_photos_csv(&photos, &rep).unwrap(), 40);
}

#[test]
fn summary_size_does_not_grow_with_the_block() {
    let (rep, _) = adjusted();
    let size = |r: &AdjustReport| {
        serde_json::to_vec_pretty(&adjust_report::summary(r))
            .unwrap()
            .len()
    };
    let base = size(&rep);
    // The same report with 100 × its photos and rejections (a 4,000-photo block's lists).
    let mut big = rep.clone();
    for k in 0..100 {
        big.photo_precision
            .extend(rep.photo_precision.iter().cloned().map(|mut p| {
                p.photo += 1000 * (k + 1);
                p
            }));
        big.rejected.list.extend(rep.rejected.list.iter().cloned());
        big.residuals.extend(rep.residuals.iter().cloned());
    }
    big.rejected.count = big.rejected.list.len();
    let grown = size(&big);
    eprintln!(
        "summary {base} B, with 100 × the lists {grown} B, the whole report {} B",
        serde_json::to_vec_pretty(&big).unwrap().len()
    );
    assert!(grown < base + base / 2, "{base} → {grown} B");
}
