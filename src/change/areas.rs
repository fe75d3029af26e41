//! Changed areas: the connected cells (4-neighbours) whose dh departs from the stable
//! terrain's median by more than the level of detection, kept when they cover
//! `min_area_m2`; each with its area, volume change (Σ dh × cell area, relative to the
//! stable median) and outline, traced along cell edges into GeoJSON polygons (outer ring
//! counter-clockwise, holes clockwise, as RFC 7946 asks).
//!
//! The level of detection varies by cell where the surfaces say how well each cell is
//! known (Wheaton et al. 2010, "minimum level of detection" of a DoD):
//! `max(min_dh_m, k_nmad · sqrt(NMAD² + σ²))`, NMAD that of dh on stable terrain and σ the
//! cell's own 1σ (e.g. the spread of the pairs a fused DSM took its median of). A cell
//! whose pairs disagree — a building edge seen half as roof and half as ground, a
//! mismatch one pair made — is not called changed on a difference its own spread explains.

use super::{ChangeError, Result};
use crate::geometry::Dem;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct AreaOptions {
    pub k_nmad: f64,
    /// Least |dh − median| (m) of a changed cell, whatever the NMAD: a surface measured
    /// to a few centimetres still does not change by them.
    pub min_dh_m: f64,
    pub min_area_m2: f64,
}

impl Default for AreaOptions {
    fn default() -> Self {
        Self {
            k_nmad: 3.0,
            min_dh_m: 1.0,
            min_area_m2: 25.0,
        }
    }
}

/// One changed area.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ChangedArea {
    pub cells: usize,
    pub area_m2: f64,
    /// Σ (dh − median) × cell area (m³): positive where B stands higher (built, grown).
    pub volume_m3: f64,
    pub mean_dh_m: f64,
    /// Rings of world coordinates, closed (first point repeated): the outer boundary
    /// first, then any holes.
    pub rings: Vec<Vec<[f64; 2]>>,
}

/// The changed areas of `dh` (per cell of `grid`, NaN without data) against the stable
/// terrain's `median` and `nmad`; `cell_sigma` (per cell, m; NaN or absent: unknown, 0)
/// raises the level of detection where a cell is known worse than the stable terrain.
pub fn changed_areas(
    dh: &[f64],
    grid: &Dem,
    (median, nmad): (f64, f64),
    cell_sigma: Option<&[f64]>,
    options: &AreaOptions,
) -> Result<Vec<ChangedArea>> {
    let (w, h) = (grid.width, grid.height);
    for (what, n) in [
        ("dh", Some(dh.len())),
        ("cell σ", cell_sigma.map(<[f64]>::len)),
    ] {
        if let Some(n) = n.filter(|&n| n != w * h) {
            return Err(ChangeError::InvalidInput {
                what: what.into(),
                message: format!("{n} values for a grid of {w}×{h}"),
            });
        }
    }
    let changed: Vec<bool> = dh
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let s = cell_sigma.map_or(0.0, |s| if s[i].is_finite() { s[i] } else { 0.0 });
            let limit = (options.k_nmad * nmad.hypot(s)).max(options.min_dh_m);
            v.is_finite() && (v - median).abs() > limit
        })
        .collect();
    let cell_area = grid.transform.0[1] * -grid.transform.0[5];
    let mut label = vec![usize::MAX; w * h];
    let mut areas = Vec::new();
    let mut stack = Vec::new();
    for start in 0..w * h {
        if !changed[start] || label[start] != usize::MAX {
            continue;
        }
        let id = areas.len();
        let mut members = Vec::new();
        label[start] = id;
        crate::geometry::region::grow_region((w, h), start, &mut members, &mut stack, |_, q| {
            let joins = changed[q] && label[q] == usize::MAX;
            if joins {
                label[q] = id;
            }
            joins
        });
        areas.push(members);
    }
    let mut out = Vec::new();
    for (id, members) in areas.iter().enumerate() {
        let area = members.len() as f64 * cell_area;
        if area < options.min_area_m2 {
            continue;
        }
        let sum: f64 = members.iter().map(|&i| dh[i] - median).sum();
        let rings = outline(members, &label, id, w, h)
            .into_iter()
            .map(|ring| {
                ring.into_iter()
                    .map(|(c, r)| {
                        let (x, y) = grid.transform.pixel_to_world(c as f64, r as f64);
                        [x, y]
                    })
                    .collect()
            })
            .collect();
        out.push(ChangedArea {
            cells: members.len(),
            area_m2: area,
            volume_m3: sum * cell_area,
            mean_dh_m: sum / members.len() as f64 + median,
            rings,
        });
    }
    Ok(out)
}

/// The boundary of the cells labelled `id` as closed rings of cell-corner positions
/// (column, row): every cell edge between a member and a non-member, directed so the
/// member lies on its left in world coordinates (rows run south), linked end to start.
/// Where two members touch only at a corner, the ring turns left (keeps them apart, as
/// 4-neighbour components are). The outer ring comes first.
fn outline(
    members: &[usize],
    label: &[usize],
    id: usize,
    w: usize,
    h: usize,
) -> Vec<Vec<(usize, usize)>> {
    let inside = |c: isize, r: isize| {
        c >= 0
            && r >= 0
            && (c as usize) < w
            && (r as usize) < h
            && label[r as usize * w + c as usize] == id
    };
    // Directed edges start → end, in corner coordinates. World: x = c, y = −r; the member
    // on the left of each edge walking it means counter-clockwise around the region.
    let mut next: HashMap<(usize, usize), Vec<(usize, usize)>> = HashMap::new();
    for &i in members {
        let (c, r) = ((i % w) as isize, (i / w) as isize);
        let (cu, ru) = (c as usize, r as usize);
        // South edge (row r + 1) walked east, north edge walked west, east edge walked
        // north, west edge walked south: counter-clockwise in world coordinates.
        if !inside(c, r + 1) {
            next.entry((cu, ru + 1)).or_default().push((cu + 1, ru + 1));
        }
        if !inside(c + 1, r) {
            next.entry((cu + 1, ru + 1)).or_default().push((cu + 1, ru));
        }
        if !inside(c, r - 1) {
            next.entry((cu + 1, ru)).or_default().push((cu, ru));
        }
        if !inside(c - 1, r) {
            next.entry((cu, ru)).or_default().push((cu, ru + 1));
        }
    }
    let mut rings = Vec::new();
    let mut starts: Vec<(usize, usize)> = next.keys().copied().collect();
    starts.sort_unstable();
    for s in starts {
        while next.get(&s).is_some_and(|v| !v.is_empty()) {
            let mut ring = vec![s];
            let mut prev = s;
            let mut at = pop_left(&mut next, s, None);
            while let Some(p) = at {
                ring.push(p);
                if p == s {
                    break;
                }
                let dir = (
                    p.0 as isize - prev.0 as isize,
                    p.1 as isize - prev.1 as isize,
                );
                prev = p;
                at = pop_left(&mut next, p, Some(dir));
            }
            rings.push(ring);
        }
    }
    // The outer ring has the largest area (counter-clockwise, positive in world terms).
    rings.sort_by(|a, b| signed_area(b).total_cmp(&signed_area(a)));
    rings
}

/// Takes the edge leaving `at` that turns most to the left of the incoming direction
/// `dir` (corner coordinates: column east, row south).
fn pop_left(
    next: &mut HashMap<(usize, usize), Vec<(usize, usize)>>,
    at: (usize, usize),
    dir: Option<(isize, isize)>,
) -> Option<(usize, usize)> {
    let out = next.get_mut(&at)?;
    if out.is_empty() {
        return None;
    }
    let k = match (dir, out.len()) {
        (Some((dx, dy)), n) if n > 1 => {
            // Left of (dx, dy) in world (x east, y north = −row): rotate counter-clockwise.
            let left = (dy, -dx);
            out.iter()
                .position(|&(c, r)| {
                    (c as isize - at.0 as isize, r as isize - at.1 as isize) == left
                })
                .unwrap_or(0)
        }
        _ => 0,
    };
    Some(out.swap_remove(k))
}

/// Shoelace area of a ring of corners in world orientation (y = −row): positive when
/// counter-clockwise.
fn signed_area(ring: &[(usize, usize)]) -> f64 {
    ring.windows(2)
        .map(|p| {
            let (x0, y0) = (p[0].0 as f64, -(p[0].1 as f64));
            let (x1, y1) = (p[1].0 as f64, -(p[1].1 as f64));
            x0 * y1 - x1 * y0
        })
        .sum::<f64>()
        / 2.0
}

/// The areas as a GeoJSON FeatureCollection (coordinates in the rasters' CRS, named by
/// `crs_name` in a `crs` member, as GDAL writes it for projected data).
pub fn areas_geojson(areas: &[ChangedArea], crs_name: Option<&str>) -> serde_json::Value {
    let features: Vec<serde_json::Value> = areas
        .iter()
        .enumerate()
        .map(|(k, a)| {
            serde_json::json!({
                "type": "Feature",
                "properties": {
                    "id": k + 1,
                    "cells": a.cells,
                    "area_m2": a.area_m2,
                    "volume_m3": a.volume_m3,
                    "mean_dh_m": a.mean_dh_m,
                },
                "geometry": {"type": "Polygon", "coordinates": a.rings},
            })
        })
        .collect();
    let mut fc = serde_json::json!({"type": "FeatureCollection", "features": features});
    if let Some(name) = crs_name {
        fc["crs"] = serde_json::json!({"type": "name", "properties": {"name": name}});
    }
    fc
}
