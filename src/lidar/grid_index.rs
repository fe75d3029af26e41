//! Exact 3-D nearest-neighbour queries over LiDAR points bucketed on a plan (XY) grid.
//!
//! Airborne LiDAR is 2.5-D: hundreds of metres across, tens of metres high. A k-d tree that
//! splits dimensions in turn (kiddo's) cuts such data into thin slabs, and a query a metre
//! off the surface visits many of them; on our data that made nearest-neighbour queries
//! 5–10× slower than on isotropic data. Here points are sorted into plan cells of about
//! 16 points and searched ring by ring around the query's cell until the ring's lower
//! bound exceeds the k-th distance. Results are exact and deterministic (ties go to the
//! lower index). Memory: the points (24 bytes each, reordered by cell) plus 4 bytes per cell.

/// Points bucketed on a plan grid.
pub struct GridIndex {
    points: Vec<[f64; 3]>,
    x0: f64,
    y0: f64,
    cell: f64,
    nx: usize,
    ny: usize,
    /// Cell c holds points[starts[c]..starts[c + 1]] (row-major cells, y then x).
    starts: Vec<u32>,
}

/// A neighbour: index into [`GridIndex::points`] and squared distance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Neighbour {
    pub index: usize,
    pub distance2: f64,
}

impl GridIndex {
    /// Builds the index, taking the points and reordering them by cell (indices refer to
    /// [`GridIndex::points`]). `points_per_cell` sets the cell size from the mean plan density.
    pub fn new(mut points: Vec<[f64; 3]>, points_per_cell: f64) -> Self {
        assert!(
            points.len() < u32::MAX as usize,
            "at most 2^32 − 1 points per index"
        );
        let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
        for p in &points {
            x0 = x0.min(p[0]);
            y0 = y0.min(p[1]);
            x1 = x1.max(p[0]);
            y1 = y1.max(p[1]);
        }
        if points.is_empty() {
            (x0, y0, x1, y1) = (0.0, 0.0, 0.0, 0.0);
        }
        let area = ((x1 - x0) * (y1 - y0)).max(1e-6);
        let n = points.len().max(1) as f64;
        let mut cell = (points_per_cell.max(1.0) * area / n).sqrt().max(1e-3);
        // Bound the cell count (memory, and degenerate spreads) to about one per point.
        while ((x1 - x0) / cell + 1.0) * ((y1 - y0) / cell + 1.0) > n.max(1024.0) {
            cell *= 1.5;
        }
        let nx = ((x1 - x0) / cell) as usize + 1;
        let ny = ((y1 - y0) / cell) as usize + 1;
        let cell_of = |p: &[f64; 3]| {
            let cx = (((p[0] - x0) / cell) as usize).min(nx - 1);
            let cy = (((p[1] - y0) / cell) as usize).min(ny - 1);
            cy * nx + cx
        };
        let mut starts = vec![0u32; nx * ny + 1];
        for p in &points {
            starts[cell_of(p) + 1] += 1;
        }
        for i in 0..nx * ny {
            starts[i + 1] += starts[i];
        }
        // Counting sort, stable: within a cell, input order.
        let mut fill = starts.clone();
        let mut reordered = vec![[0.0; 3]; points.len()];
        for p in &points {
            let c = cell_of(p);
            reordered[fill[c] as usize] = *p;
            fill[c] += 1;
        }
        drop(fill);
        points = reordered;
        Self {
            points,
            x0,
            y0,
            cell,
            nx,
            ny,
            starts,
        }
    }

    pub fn points(&self) -> &[[f64; 3]] {
        &self.points
    }

    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    fn centre_cell(&self, q: &[f64; 3]) -> (i64, i64) {
        let cx = ((q[0] - self.x0) / self.cell).floor();
        let cy = ((q[1] - self.y0) / self.cell).floor();
        (
            (cx.max(0.0) as i64).min(self.nx as i64 - 1),
            (cy.max(0.0) as i64).min(self.ny as i64 - 1),
        )
    }

    /// Visits the cells of Chebyshev ring `r` around (cx, cy) that lie in the grid.
    #[inline]
    fn ring(&self, cx: i64, cy: i64, r: i64, mut f: impl FnMut(usize, usize)) {
        let (nx, ny) = (self.nx as i64, self.ny as i64);
        let mut visit = |x: i64, y: i64| {
            if x >= 0 && y >= 0 && x < nx && y < ny {
                f(x as usize, y as usize);
            }
        };
        if r == 0 {
            visit(cx, cy);
            return;
        }
        for x in cx - r..=cx + r {
            visit(x, cy - r);
            visit(x, cy + r);
        }
        for y in cy - r + 1..cy + r {
            visit(cx - r, y);
            visit(cx + r, y);
        }
    }

    /// Squared plan distance from q to cell (x, y).
    #[inline]
    fn cell_gap2(&self, q: &[f64; 3], x: usize, y: usize) -> f64 {
        let lx = self.x0 + x as f64 * self.cell;
        let ly = self.y0 + y as f64 * self.cell;
        let dx = (lx - q[0]).max(q[0] - lx - self.cell).max(0.0);
        let dy = (ly - q[1]).max(q[1] - ly - self.cell).max(0.0);
        dx * dx + dy * dy
    }

    /// Searches rings outward; `bound()` is the current pruning distance², `scan` sees
    /// every point of every cell that may hold a closer point.
    fn search(
        &self,
        q: &[f64; 3],
        mut bound: impl FnMut() -> f64,
        mut scan: impl FnMut(usize, f64),
    ) {
        if self.points.is_empty() {
            return;
        }
        let (cx, cy) = self.centre_cell(q);
        let max_r = self.nx.max(self.ny) as i64;
        for r in 0..=max_r {
            // Any cell of ring r ≥ 1 is at least (r − 1) cells away along one axis.
            let lb = ((r - 1).max(0) as f64) * self.cell;
            if lb * lb > bound() {
                break;
            }
            self.ring(cx, cy, r, |x, y| {
                if self.cell_gap2(q, x, y) > bound() {
                    return;
                }
                let c = y * self.nx + x;
                for i in self.starts[c] as usize..self.starts[c + 1] as usize {
                    let p = &self.points[i];
                    let d = (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2);
                    scan(i, d);
                }
            });
        }
    }

    /// The nearest point (lowest index among equals), None for an empty index.
    pub fn nearest_one(&self, q: &[f64; 3]) -> Option<Neighbour> {
        let best = std::cell::Cell::new((f64::INFINITY, usize::MAX));
        self.search(
            q,
            || best.get().0,
            |i, d| {
                let b = best.get();
                if d < b.0 || (d == b.0 && i < b.1) {
                    best.set((d, i));
                }
            },
        );
        let (d, i) = best.get();
        (i != usize::MAX).then_some(Neighbour {
            index: i,
            distance2: d,
        })
    }

    /// The k nearest points, nearest first (ties: lower index first), into `out`.
    pub fn nearest_k(&self, q: &[f64; 3], k: usize, out: &mut Vec<Neighbour>) {
        out.clear();
        if k == 0 {
            return;
        }
        let list = std::cell::RefCell::new(std::mem::take(out));
        self.search(
            q,
            || {
                let l = list.borrow();
                if l.len() < k {
                    f64::INFINITY
                } else {
                    l[k - 1].distance2
                }
            },
            |i, d| {
                let mut l = list.borrow_mut();
                if l.len() == k {
                    let last = l[k - 1];
                    if d > last.distance2 || (d == last.distance2 && i > last.index) {
                        return;
                    }
                }
                let pos = l
                    .iter()
                    .position(|n| d < n.distance2 || (d == n.distance2 && i < n.index))
                    .unwrap_or(l.len());
                l.insert(
                    pos,
                    Neighbour {
                        index: i,
                        distance2: d,
                    },
                );
                l.truncate(k);
            },
        );
        *out = list.into_inner();
    }
}
