//! Local planes over LiDAR points: exact nearest-neighbour queries (plan-grid index), PCA
//! plane fits of the k nearest points, the coplanarity λmin/Σλ and a weight from it (seed 000 §2.2 (2)).

use super::grid_index::{GridIndex, Neighbour};
use super::{LidarError, Result};
use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::RwLock;

/// Plane-fit settings.
#[derive(Debug, Clone, Copy)]
pub struct PlaneOptions {
    /// Neighbours per PCA fit.
    pub k: usize,
    /// Neighbourhoods with λmin/Σλ above this are not planar (vegetation, edges, noise)
    /// and give no constraint. A perfect plane gives 0, isotropic scatter 1/3.
    pub max_coplanarity: f64,
    /// Neighbourhoods wider than this (metres, farthest neighbour) are rejected: a plane
    /// bridging a data gap is not a measured surface.
    pub max_radius: f64,
}

impl Default for PlaneOptions {
    fn default() -> Self {
        Self {
            k: 12,
            max_coplanarity: 0.02,
            max_radius: 3.0,
        }
    }
}

/// A local plane fitted to LiDAR points, in the index's local frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalPlane {
    /// Centroid of the neighbourhood (local frame).
    pub centroid: Vector3<f64>,
    /// Unit normal, oriented upward (n_z ≥ 0) so signed distances are comparable.
    pub normal: Vector3<f64>,
    /// λmin / (λ1+λ2+λ3).
    pub coplanarity: f64,
    /// Weight in (0, 1]: 1 on a perfect plane, falling to 0 at `max_coplanarity`.
    pub weight: f64,
}

impl LocalPlane {
    /// Signed distance of a local-frame point along the normal.
    #[inline]
    pub fn distance(&self, p: &Vector3<f64>) -> f64 {
        self.normal.dot(&(p - self.centroid))
    }
}

/// Slot states of the plane cache; a fitted plane is stored as its arena index + FIRST.
const UNKNOWN: u32 = 0;
const NOT_PLANAR: u32 = 1;
const FIRST: u32 = 2;

/// LiDAR points in a local frame with a k-d tree; plane fits are cached per LiDAR point
/// (the neighbourhood of the nearest LiDAR point), so ICP iterations that land on the same
/// surface patch never refit it. The cache costs 4 bytes per LiDAR point plus 64 bytes per
/// plane actually fitted (only the points queries land on), so memory stays near the
/// points and the tree.
pub struct PlaneIndex {
    origin: Vector3<f64>,
    /// Points in the local frame, bucketed for exact nearest-neighbour queries.
    grid: GridIndex,
    options: PlaneOptions,
    slots: Vec<AtomicU32>,
    arena: RwLock<Vec<LocalPlane>>,
}

impl PlaneIndex {
    /// Builds the index from world coordinates; `origin` is subtracted before anything else.
    pub fn new(world: &[[f64; 3]], origin: Vector3<f64>, options: PlaneOptions) -> Result<Self> {
        let local = world
            .iter()
            .map(|p| [p[0] - origin.x, p[1] - origin.y, p[2] - origin.z])
            .collect();
        Self::from_local(local, origin, options)
    }

    /// Builds the index from points already in the local frame (world = local + origin),
    /// taking ownership so that no second copy of the points is made.
    pub fn from_local(
        points: Vec<[f64; 3]>,
        origin: Vector3<f64>,
        options: PlaneOptions,
    ) -> Result<Self> {
        if options.k < 3 {
            return Err(LidarError::InvalidOption(format!(
                "plane fit needs k >= 3 neighbours, got {}",
                options.k
            )));
        }
        if !(options.max_coplanarity > 0.0 && options.max_radius > 0.0) {
            return Err(LidarError::InvalidOption(
                "max_coplanarity and max_radius must be positive".into(),
            ));
        }
        if points.len() < options.k {
            return Err(LidarError::TooFewPoints {
                what: "LiDAR points".into(),
                got: points.len(),
                need: options.k,
            });
        }
        if let Some(i) = points.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
            return Err(LidarError::NonFinite {
                what: "LiDAR points".into(),
                index: i,
            });
        }
        if !(origin.iter().all(|v| v.is_finite())) {
            return Err(LidarError::InvalidOption("origin is not finite".into()));
        }
        let slots = (0..points.len()).map(|_| AtomicU32::new(UNKNOWN)).collect();
        let grid = GridIndex::new(points, 8.0);
        Ok(Self {
            origin,
            grid,
            options,
            slots,
            arena: RwLock::new(Vec::new()),
        })
    }

    pub fn options(&self) -> PlaneOptions {
        self.options
    }

    /// Planes fitted so far (cache size).
    pub fn fitted_planes(&self) -> usize {
        self.arena.read().map(|a| a.len()).unwrap_or(0)
    }

    pub fn origin(&self) -> Vector3<f64> {
        self.origin
    }

    pub fn len(&self) -> usize {
        self.grid.len()
    }

    pub fn is_empty(&self) -> bool {
        self.grid.is_empty()
    }

    /// The plane for a local-frame query point, or None where the surface is not planar.
    pub fn plane_at(&self, q: &Vector3<f64>) -> Option<LocalPlane> {
        let idx = self.grid.nearest_one(&[q.x, q.y, q.z])?.index;
        match self.slots[idx].load(Ordering::Acquire) {
            NOT_PLANAR => return None,
            UNKNOWN => {}
            k => {
                if let Ok(a) = self.arena.read() {
                    return Some(a[(k - FIRST) as usize]);
                }
            }
        }
        // Two threads may fit the same neighbourhood at once: the fit is deterministic, so
        // whichever slot value wins holds the same plane.
        let plane = self.fit(idx);
        let state = match plane {
            None => NOT_PLANAR,
            Some(pl) => match self.arena.write() {
                Ok(mut a) if a.len() < (u32::MAX - FIRST) as usize => {
                    a.push(pl);
                    (a.len() - 1) as u32 + FIRST
                }
                _ => return plane,
            },
        };
        self.slots[idx].store(state, Ordering::Release);
        plane
    }

    fn fit(&self, idx: usize) -> Option<LocalPlane> {
        thread_local! {
            static NBRS: std::cell::RefCell<Vec<Neighbour>> = const { std::cell::RefCell::new(Vec::new()) };
        }
        NBRS.with(|buf| {
            let mut nbrs = buf.borrow_mut();
            let pts = self.grid.points();
            self.grid.nearest_k(&pts[idx], self.options.k, &mut nbrs);
            self.fit_neighbours(pts, &nbrs)
        })
    }

    fn fit_neighbours(&self, points: &[[f64; 3]], nbrs: &[Neighbour]) -> Option<LocalPlane> {
        if nbrs.len() < 3 {
            return None;
        }
        let far = nbrs.iter().map(|n| n.distance2).fold(0.0, f64::max).sqrt();
        if far > self.options.max_radius {
            return None;
        }
        let mut c = Vector3::zeros();
        for n in nbrs {
            let p = points[n.index];
            c += Vector3::new(p[0], p[1], p[2]);
        }
        c /= nbrs.len() as f64;
        let mut cov = Matrix3::zeros();
        for n in nbrs {
            let p = points[n.index];
            let d = Vector3::new(p[0], p[1], p[2]) - c;
            cov += d * d.transpose();
        }
        let eig = SymmetricEigen::new(cov);
        let sum = eig.eigenvalues.sum();
        if sum <= 0.0 {
            return None;
        }
        let (imin, lmin) =
            eig.eigenvalues
                .iter()
                .enumerate()
                .fold(
                    (0, f64::INFINITY),
                    |a, (i, &l)| if l < a.1 { (i, l) } else { a },
                );
        let coplanarity = lmin.max(0.0) / sum;
        if coplanarity > self.options.max_coplanarity {
            return None;
        }
        let mut normal: Vector3<f64> = eig.eigenvectors.column(imin).into_owned().normalize();
        if normal.z < 0.0 {
            normal = -normal;
        }
        let weight = (1.0 - coplanarity / self.options.max_coplanarity).max(1e-3);
        Some(LocalPlane {
            centroid: c,
            normal,
            coplanarity,
            weight,
        })
    }
}
