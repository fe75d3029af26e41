//! Plan (XY) queries over control points: which points of one or more DCP packages lie
//! in a photo's footprint.

use super::dcp::DcpPackage;
use kiddo::{KdTree, SquaredEuclidean};

/// Plan (XY) index over points, for footprint queries.
pub struct PlanIndex {
    tree: KdTree<f64, 2>,
    xy: Vec<[f64; 2]>,
}

impl PlanIndex {
    pub fn new(xy: Vec<[f64; 2]>) -> Self {
        let mut tree = KdTree::new();
        for (i, p) in xy.iter().enumerate() {
            tree.add(p, i as u64);
        }
        Self { tree, xy }
    }

    pub fn len(&self) -> usize {
        self.xy.len()
    }

    pub fn is_empty(&self) -> bool {
        self.xy.is_empty()
    }

    /// Indices of the points inside a polygon (any orientation), in increasing order.
    pub fn query_polygon(&self, polygon: &[[f64; 2]]) -> Vec<usize> {
        if polygon.len() < 3 || self.is_empty() {
            return Vec::new();
        }
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for p in polygon {
            for a in 0..2 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        let c = [(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0];
        let r2 = ((hi[0] - lo[0]).powi(2) + (hi[1] - lo[1]).powi(2)) / 4.0 * (1.0 + 1e-12);
        let mut hits: Vec<usize> = self
            .tree
            .within_unsorted::<SquaredEuclidean>(&c, r2)
            .into_iter()
            .map(|n| n.item as usize)
            .filter(|&i| point_in_polygon(self.xy[i], polygon))
            .collect();
        hits.sort_unstable();
        hits
    }
}

/// Spatial index over the control points of one or more packages (world XY).
pub struct DcpIndex {
    index: PlanIndex,
    entries: Vec<(usize, usize)>,
}

impl DcpIndex {
    pub fn new(packages: &[DcpPackage]) -> Self {
        let mut entries = Vec::new();
        let mut xy = Vec::new();
        for (k, pkg) in packages.iter().enumerate() {
            for (i, p) in pkg.points_xy() {
                entries.push((k, i));
                xy.push(p);
            }
        }
        Self {
            index: PlanIndex::new(xy),
            entries,
        }
    }

    pub fn len(&self) -> usize {
        self.entries.len()
    }

    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// (package, point) indices inside a polygon (world XY, any orientation), in a
    /// deterministic order.
    pub fn query_polygon(&self, polygon: &[[f64; 2]]) -> Vec<(usize, usize)> {
        self.index
            .query_polygon(polygon)
            .into_iter()
            .map(|i| self.entries[i])
            .collect()
    }
}

/// Even–odd rule.
pub fn point_in_polygon(p: [f64; 2], poly: &[[f64; 2]]) -> bool {
    let mut inside = false;
    let mut j = poly.len() - 1;
    for i in 0..poly.len() {
        let (a, b) = (poly[i], poly[j]);
        if (a[1] > p[1]) != (b[1] > p[1])
            && p[0] < (b[0] - a[0]) * (p[1] - a[1]) / (b[1] - a[1]) + a[0]
        {
            inside = !inside;
        }
        j = i;
    }
    inside
}
