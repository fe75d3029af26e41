//! Levenberg–Marquardt on the normal equations with the object points eliminated
//! (Schur complement, 3×3 point blocks), leaving the reduced camera system over exterior
//! orientations and free interior parameters. The reduced system is factorised by a
//! sparse Cholesky (faer, AMD fill-reducing ordering, symbolic analysis reused while the
//! sparsity pattern holds) or, for small blocks, a dense Cholesky.
//!
//! Assembly is parallel but deterministic: every sum is owned by one task (one object
//! point, one row of the reduced system) and adds its terms in a fixed order, so the
//! thread count never changes a bit of the result.

use super::evaluated::Evaluated;
use super::ragged::{narrow, Ragged};
use super::residual::{Loss, ResidualBlock, State};
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, LltRef, SymbolicCholesky, SymmetricOrdering,
};
use faer::sparse::{SparseColMat, Triplet};
use faer::{Conj, Par, Side};
use nalgebra::{DMatrix, Matrix3, SMatrix, SVector, Vector3};
use rayon::prelude::*;
use std::sync::Arc;

type M9 = SMatrix<f64, 9, 9>;
type M93 = SMatrix<f64, 9, 3>;
type V9 = SVector<f64, 9>;

/// Reduced systems up to this size are factorised densely.
const DENSE_MAX: usize = 400;

/// The sparsity structure: which residuals touch which camera-side block (a photo's
/// exterior orientation or a camera's interior orientation) and which object point.
pub(crate) struct Structure {
    pub n_photos: usize,
    /// Camera index → block index (cameras without free parameters have none).
    pub camera_block: Vec<Option<usize>>,
    /// Free local parameter indices per block (photo: 0..6, camera: 0..9).
    pub free: Vec<Vec<usize>>,
    pub offset: Vec<usize>,
    pub n: usize,
    /// Per block, its residuals the point-ordered pass of [`diagonal`] does not cover:
    /// those without an object point (POS and datum priors), and those of a point that
    /// couple this photo to a self-calibrated camera (their photo–camera block).
    pub block_res: Ragged<u32>,
    /// Per block, its object points with the block's place in the point's
    /// `point_blocks` (the point's coupling block W there), ascending.
    pub block_points: Ragged<(u32, u32)>,
    /// Per object point, the camera-side blocks of its residuals, ascending.
    pub point_blocks: Ragged<u32>,
    pub point_res: Ragged<u32>,
    /// Sorted blocks b2 ≥ b1 coupled to b1 in the reduced system (b1 itself included).
    pub neighbours: Vec<Vec<usize>>,
}

impl Structure {
    pub fn new(
        res: &[ResidualBlock],
        n_photos: usize,
        n_points: usize,
        photo_free: &[[bool; 6]],
        camera_free: &[Vec<usize>],
        camera_leader: &[usize],
    ) -> Self {
        let mut camera_block: Vec<Option<usize>> = Vec::with_capacity(camera_free.len());
        let mut free: Vec<Vec<usize>> = photo_free
            .iter()
            .map(|f| (0..6).filter(|&k| f[k]).collect())
            .collect();
        for (c, cf) in camera_free.iter().enumerate() {
            // A calibration group's cameras are one block: their Jacobians add into it and
            // its update moves each of them alike.
            let leader = camera_leader.get(c).copied().unwrap_or(c);
            if leader < c {
                camera_block.push(camera_block[leader]);
            } else if cf.is_empty() {
                camera_block.push(None);
            } else {
                camera_block.push(Some(free.len()));
                free.push(cf.clone());
            }
        }
        let nb = free.len();
        let mut offset = Vec::with_capacity(nb);
        let mut n = 0;
        for f in &free {
            offset.push(n);
            n += f.len();
        }
        let active = || res.iter().enumerate().filter(|(_, r)| r.active);
        let block_res = Ragged::from_pairs(nb, || {
            active().flat_map(|(i, r)| {
                let bs = blocks_of(r, &camera_block);
                let owners = match (r.point(), bs) {
                    (None, _) => bs,
                    (Some(_), [Some(a), Some(b)]) => [Some(a.min(b)), None],
                    _ => [None, None],
                };
                owners.into_iter().flatten().map(move |b| (b, narrow(i)))
            })
        });
        let point_res = Ragged::from_pairs(n_points, || {
            active().filter_map(|(i, r)| Some((r.point()?, narrow(i))))
        });
        let mut pairs = Pairs::new(nb);
        for (_, r) in active() {
            if let [Some(a), Some(b)] = blocks_of(r, &camera_block) {
                pairs.add(a.min(b), &[a.max(b)]);
            }
        }
        let mut point_blocks = Ragged::new();
        let mut bs = Vec::new();
        for p in 0..n_points {
            bs.clear();
            bs.extend(
                point_res
                    .of(p)
                    .flat_map(|i| blocks_of(&res[i], &camera_block))
                    .flatten(),
            );
            bs.sort_unstable();
            bs.dedup();
            for (k, &a) in bs.iter().enumerate() {
                pairs.add(a, &bs[k..]);
            }
            point_blocks.push(bs.iter().map(|&b| narrow(b)));
        }
        let block_points = Ragged::from_pairs(nb, || {
            (0..n_points).flat_map(|p| {
                point_blocks[p]
                    .iter()
                    .enumerate()
                    .map(move |(k, &a)| (a as usize, (narrow(p), narrow(k))))
            })
        });
        let pairs = pairs.finish();
        Self {
            n_photos,
            camera_block,
            free,
            offset,
            n,
            block_res,
            block_points,
            point_blocks,
            point_res,
            neighbours: pairs,
        }
    }
}

/// The reduced system's coupled block pairs as they are found, per first block: a point
/// seen by m blocks adds m(m + 1)/2 of them, most found before, so each list is sorted
/// and deduplicated whenever it has doubled rather than only at the end.
struct Pairs {
    lists: Vec<Vec<usize>>,
    unique: Vec<usize>,
}

impl Pairs {
    fn new(nb: usize) -> Self {
        Self {
            lists: (0..nb).map(|b| vec![b]).collect(),
            unique: vec![1; nb],
        }
    }

    fn add(&mut self, a: usize, bs: &[usize]) {
        let l = &mut self.lists[a];
        l.extend_from_slice(bs);
        if l.len() > 2 * self.unique[a] + 64 {
            l.sort_unstable();
            l.dedup();
            self.unique[a] = l.len();
        }
    }

    fn finish(mut self) -> Vec<Vec<usize>> {
        for l in &mut self.lists {
            l.sort_unstable();
            l.dedup();
            l.shrink_to_fit();
        }
        self.lists
    }
}

/// The camera-side blocks a residual touches: its photo, and its camera slot when that
/// has free parameters (a self-calibrated camera of an image observation, the LiDAR
/// datum of a plane and of its prior).
fn blocks_of(r: &ResidualBlock, camera_block: &[Option<usize>]) -> [Option<usize>; 2] {
    [r.photo(), r.camera().and_then(|c| camera_block[c])]
}

/// Per-point part of the normal equations after damping: V⁻¹, gradient and the
/// coupling blocks W (one per camera-side block seen by the point).
pub(crate) struct PointSys {
    pub vinv: Matrix3<f64>,
    pub g: Vector3<f64>,
    pub w: Vec<(usize, M93)>,
}

/// A point's V⁻¹ and gradient without its coupling blocks: what the precision and the
/// tests read of every point (96 bytes a point where its W took 224 an observation).
#[derive(Debug, Clone, Copy)]
pub(crate) struct PointInverse {
    pub vinv: Matrix3<f64>,
    pub g: Vector3<f64>,
}

fn damp(d: f64, lambda: f64) -> f64 {
    lambda * d.clamp(1e-6, 1e32)
}

/// Object point `p`'s system, its residuals' Jacobians evaluated afresh.
pub(crate) fn point_system(ev: &Evaluated, st: &Structure, p: usize, lambda: f64) -> PointSys {
    let mut v = Matrix3::zeros();
    let mut g = Vector3::zeros();
    // In the structure's order, so that the reduced system finds a block's W by its place.
    let mut w: Vec<(usize, M93)> = st.point_blocks[p]
        .iter()
        .map(|&b| (b as usize, M93::zeros()))
        .collect();
    for i in st.point_res.of(p) {
        let Some((e, wt)) = ev.at(i) else { continue };
        let jx = e.j_point;
        v += wt * jx.transpose() * jx;
        g += wt * jx.transpose() * e.r;
        for b in blocks_of(&ev.res[i], &st.camera_block)
            .into_iter()
            .flatten()
        {
            let jb = if ev.res[i].photo() == Some(b) {
                e.j_photo
            } else {
                e.j_camera
            };
            let c = wt * jb.transpose() * jx;
            if let Some((_, m)) = w.iter_mut().find(|(k, _)| *k == b) {
                *m += c;
            }
        }
    }
    for k in 0..3 {
        v[(k, k)] += damp(v[(k, k)], lambda);
    }
    let vinv = v.try_inverse().unwrap_or_else(Matrix3::zeros);
    PointSys { vinv, g, w }
}

/// Every object point's [`PointInverse`].
pub(crate) fn point_inverses(ev: &Evaluated, st: &Structure, lambda: f64) -> Vec<PointInverse> {
    (0..st.point_res.len())
        .into_par_iter()
        .map(|p| {
            let ps = point_system(ev, st, p, lambda);
            PointInverse {
                vinv: ps.vinv,
                g: ps.g,
            }
        })
        .collect()
}

/// One row of the reduced camera system: blocks S[b1, b2] for b2 in `neighbours[b1]`.
pub(crate) struct Row {
    pub blocks: Vec<M9>,
    pub rhs: V9,
}

/// Fixed chunks of object points the block diagonal is summed over: the sum's order,
/// and so every bit of it, does not depend on the thread count.
const DIAGONAL_CHUNKS: usize = 16;

/// The diagonal blocks JᵀJ and gradients Jᵀr of every camera-side block from the
/// residuals of object points, in one pass in point order (the residuals' order in
/// memory); they do not depend on the damping, so the solver sums them once a state.
pub(crate) fn diagonal(ev: &Evaluated, st: &Structure) -> Vec<(M9, V9)> {
    let nb = st.free.len();
    let n_points = st.point_res.len();
    let per = n_points.div_ceil(DIAGONAL_CHUNKS).max(1);
    let chunks: Vec<usize> = (0..n_points).step_by(per).collect();
    let parts: Vec<Vec<(M9, V9)>> = chunks
        .into_par_iter()
        .map(|p0| {
            let mut acc = vec![(M9::zeros(), V9::zeros()); nb];
            for &i in st.point_res.span(p0..(p0 + per).min(n_points)) {
                let i = i as usize;
                let Some((e, wt)) = ev.at(i) else { continue };
                let r = &ev.res[i];
                for b in blocks_of(r, &st.camera_block).into_iter().flatten() {
                    let j = if r.photo() == Some(b) {
                        e.j_photo
                    } else {
                        e.j_camera
                    };
                    let (d, g) = &mut acc[b];
                    if b < st.n_photos {
                        let j6 = j.fixed_columns::<6>(0);
                        let mut v = d.fixed_view_mut::<6, 6>(0, 0);
                        v += wt * j6.transpose() * j6;
                        let mut g = g.fixed_rows_mut::<6>(0);
                        g += wt * j6.transpose() * e.r;
                    } else {
                        *d += wt * j.transpose() * j;
                        *g += wt * j.transpose() * e.r;
                    }
                }
            }
            acc
        })
        .collect();
    let mut parts = parts.into_iter();
    let mut sum = parts
        .next()
        .unwrap_or_else(|| vec![(M9::zeros(), V9::zeros()); nb]);
    for part in parts {
        for ((d, g), (pd, pg)) in sum.iter_mut().zip(part) {
            *d += pd;
            *g += pg;
        }
    }
    sum
}

/// Observations of the object points whose systems are held at once while the reduced
/// system is assembled: their W blocks (224 bytes an observation) for all points were a
/// quarter of the peak memory.
const BATCH_OBSERVATIONS: usize = 1 << 17;

/// The reduced camera system at damping `lambda`, `diag` from [`diagonal`]. Each row
/// adds its points' terms in ascending point order as before, a batch of point systems
/// at a time: the same sums in the same order, so the same bits.
pub(crate) fn reduced_rows(
    ev: &Evaluated,
    st: &Structure,
    diag: &[(M9, V9)],
    lambda: f64,
) -> Vec<Row> {
    let mut rows: Vec<Row> = (0..st.free.len())
        .into_par_iter()
        .map(|b1| row_start(ev, st, &diag[b1], b1, lambda))
        .collect();
    // Per row, its next entry of `block_points`.
    let mut next = vec![0usize; rows.len()];
    let n_points = st.point_res.len();
    let mut p0 = 0;
    while p0 < n_points {
        let mut p1 = p0;
        let mut n = 0;
        while p1 < n_points && (p1 == p0 || n < BATCH_OBSERVATIONS) {
            n += st.point_res[p1].len();
            p1 += 1;
        }
        let batch: Vec<PointSys> = (p0..p1)
            .into_par_iter()
            .map(|p| point_system(ev, st, p, lambda))
            .collect();
        rows.par_iter_mut()
            .zip(next.par_iter_mut())
            .enumerate()
            .for_each(|(b1, (row, next))| {
                let nbr = &st.neighbours[b1];
                let slot = |b2: usize| nbr.binary_search(&b2).expect("pattern holds b2");
                let photo1 = b1 < st.n_photos;
                let bp = &st.block_points[b1];
                while let Some(&(p, k1)) = bp.get(*next).filter(|(p, _)| (*p as usize) < p1) {
                    *next += 1;
                    let (p, k1) = (p as usize, k1 as usize);
                    let ps = &batch[p - p0];
                    let w1v = ps.w[k1].1 * ps.vinv;
                    row.rhs += w1v * ps.g;
                    // The point's blocks ascend: b2 ≥ b1 from b1's own place on.
                    for (b2, w2) in &ps.w[k1..] {
                        let blk = &mut row.blocks[slot(*b2)];
                        if photo1 && *b2 < st.n_photos {
                            subtract_eo_outer(blk, &w1v, w2);
                        } else {
                            *blk -= w1v * w2.transpose();
                        }
                    }
                }
            });
        p0 = p1;
    }
    rows
}

/// Row `b1` before its object points' terms: its diagonal, the residuals without a point
/// and the photo–camera couplings, damped.
fn row_start(ev: &Evaluated, st: &Structure, diag: &(M9, V9), b1: usize, lambda: f64) -> Row {
    let nbr = &st.neighbours[b1];
    let slot = |b2: usize| nbr.binary_search(&b2).expect("pattern holds b2");
    let mut blocks = vec![M9::zeros(); nbr.len()];
    let (d, g) = diag;
    blocks[0] = *d;
    let mut rhs = -g;
    for i in st.block_res.of(b1) {
        let Some((e, wt)) = ev.at(i) else { continue };
        let r = &ev.res[i];
        let j1 = if r.photo() == Some(b1) {
            e.j_photo
        } else {
            e.j_camera
        };
        if r.point().is_none() {
            if b1 < st.n_photos {
                let j6 = j1.fixed_columns::<6>(0);
                let mut v = blocks[0].fixed_view_mut::<6, 6>(0, 0);
                v += wt * j6.transpose() * j6;
                let mut g = rhs.fixed_rows_mut::<6>(0);
                g -= wt * j6.transpose() * e.r;
            } else {
                blocks[0] += wt * j1.transpose() * j1;
                rhs -= wt * j1.transpose() * e.r;
            }
        }
        if let [Some(p), Some(c)] = blocks_of(r, &st.camera_block) {
            if p == b1 && c > b1 {
                blocks[slot(c)] += wt * j1.transpose() * e.j_camera;
            }
        }
    }
    for k in 0..9 {
        let d = blocks[0][(k, k)];
        blocks[0][(k, k)] += damp(d, lambda);
    }
    Row { blocks, rhs }
}

/// blk[..6, ..6] −= a[..6, :] · b[..6, :]ᵀ: the photo–photo coupling of one object point,
/// the bulk of the reduced camera system, where only the exterior orientations' 6×6
/// corner is populated; written out over the column-major storage of both.
#[inline]
fn subtract_eo_outer(blk: &mut M9, a: &M93, b: &M93) {
    let (a, b) = (a.as_slice(), b.as_slice());
    let out = blk.as_mut_slice();
    for j in 0..6 {
        let (b0, b1, b2) = (b[j], b[9 + j], b[18 + j]);
        let col = &mut out[9 * j..9 * j + 6];
        for (i, o) in col.iter_mut().enumerate() {
            *o -= a[i] * b0 + a[9 + i] * b1 + a[18 + i] * b2;
        }
    }
}

/// faer runs sequentially inside the solver: with its rayon parallelism (the default)
/// beside ours on 2 cores, `cloudcontrol adjust` took 0.71 s instead of 0.57 on the
/// 200-photo bench block and 4.1 s instead of 3.3 on the 800-photo one (interleaved runs);
/// the assembly around the factorisations is where the parallel work is.
const FAER_PAR: Par = Par::Seq;

/// A factorised reduced camera system.
pub(crate) enum Factor {
    /// The dense lower Cholesky factor L (its upper triangle unused).
    Dense(faer::Mat<f64>),
    Sparse {
        symbolic: Arc<SymbolicCholesky<usize>>,
        values: Vec<f64>,
    },
}

impl Factor {
    /// How the system was ordered before it was factorised.
    pub fn ordering(&self) -> &'static str {
        match self {
            Factor::Dense(_) => "dense",
            Factor::Sparse { .. } => "AMD",
        }
    }

    /// Stored entries of the factor (a dense one counted as its lower triangle).
    pub fn nonzeros(&self) -> usize {
        match self {
            Factor::Dense(m) => m.nrows() * (m.nrows() + 1) / 2,
            Factor::Sparse { values, .. } => values.len(),
        }
    }

    /// Solves in place on the column-major storage of `x` (no copy either way).
    pub fn solve_in_place(&self, x: &mut DMatrix<f64>) {
        let (r, c) = x.shape();
        let rhs = faer::MatMut::from_column_major_slice_mut(x.as_mut_slice(), r, c);
        match self {
            Factor::Dense(l) => {
                let req = llt::solve::solve_in_place_scratch::<f64>(r, c, FAER_PAR);
                llt::solve::solve_in_place_with_conj(
                    l.as_ref(),
                    Conj::No,
                    rhs,
                    FAER_PAR,
                    MemStack::new(&mut MemBuffer::new(req)),
                );
            }
            Factor::Sparse { symbolic, values } => {
                let req = symbolic.solve_in_place_scratch::<f64>(c, FAER_PAR);
                LltRef::new(symbolic, values).solve_in_place_with_conj(
                    Conj::No,
                    rhs,
                    FAER_PAR,
                    MemStack::new(&mut MemBuffer::new(req)),
                );
            }
        }
    }

    /// The whole inverse (both triangles) of a dense factor; None for a sparse one.
    pub fn dense_inverse(&self) -> Option<faer::Mat<f64>> {
        let Factor::Dense(l) = self else {
            return None;
        };
        let n = l.nrows();
        let mut inv = faer::Mat::<f64>::zeros(n, n);
        let req = llt::inverse::inverse_scratch::<f64>(n, FAER_PAR);
        llt::inverse::inverse(
            inv.as_mut(),
            l.as_ref(),
            FAER_PAR,
            MemStack::new(&mut MemBuffer::new(req)),
        );
        // faer fills the lower triangle.
        for j in 0..n {
            for i in 0..j {
                inv[(i, j)] = inv[(j, i)];
            }
        }
        Some(inv)
    }
}

/// Cache of the symbolic sparse factorisation (AMD ordering and elimination tree),
/// valid while the structure does not change.
#[derive(Default)]
pub(crate) struct SymbolicCache {
    pub symbolic: Option<Arc<SymbolicCholesky<usize>>>,
}

pub(crate) fn factorize(st: &Structure, rows: &[Row], cache: &mut SymbolicCache) -> Option<Factor> {
    let n = st.n;
    if n == 0 {
        return None;
    }
    if n <= DENSE_MAX {
        // faer's blocked dense Cholesky: nalgebra's unblocked one took 0.9 ms of each
        // 50-photo iteration's 4 ms (n = 293).
        let mut m = faer::Mat::<f64>::zeros(n, n);
        for (b1, row) in rows.iter().enumerate() {
            for (s, &b2) in st.neighbours[b1].iter().enumerate() {
                for (i1, &k1) in st.free[b1].iter().enumerate() {
                    for (i2, &k2) in st.free[b2].iter().enumerate() {
                        let (g1, g2) = (st.offset[b1] + i1, st.offset[b2] + i2);
                        // b2 ≥ b1: the upper triangle, stored as its transpose.
                        m[(g2.max(g1), g2.min(g1))] = row.blocks[s][(k1, k2)];
                    }
                }
            }
        }
        let req = llt::factor::cholesky_in_place_scratch::<f64>(n, FAER_PAR, Default::default());
        llt::factor::cholesky_in_place(
            m.as_mut(),
            Default::default(),
            FAER_PAR,
            MemStack::new(&mut MemBuffer::new(req)),
            Default::default(),
        )
        .ok()?;
        return Some(Factor::Dense(m));
    }
    let mat = reduced_upper(st, rows)?;
    if cache.symbolic.is_none() {
        cache.symbolic = factorize_symbolic_cholesky(
            mat.symbolic(),
            Side::Upper,
            SymmetricOrdering::Amd,
            Default::default(),
        )
        .ok()
        .map(Arc::new);
    }
    let symbolic = cache.symbolic.clone()?;
    let mut values = vec![0.0; symbolic.len_val()];
    let req = symbolic.factorize_numeric_llt_scratch::<f64>(FAER_PAR, Default::default());
    symbolic
        .factorize_numeric_llt(
            &mut values,
            mat.as_ref(),
            Side::Upper,
            Default::default(),
            FAER_PAR,
            MemStack::new(&mut MemBuffer::new(req)),
            Default::default(),
        )
        .ok()?;
    Some(Factor::Sparse { symbolic, values })
}

/// Entries of the reduced camera system's upper triangle that its structure makes
/// non-zero (counted as [`reduced_upper`] stores them).
pub(crate) fn reduced_nonzeros(st: &Structure) -> usize {
    (0..st.free.len())
        .map(|b1| {
            let n1 = st.free[b1].len();
            st.neighbours[b1]
                .iter()
                .map(|&b2| {
                    if b1 == b2 {
                        n1 * (n1 + 1) / 2
                    } else {
                        n1 * st.free[b2].len()
                    }
                })
                .sum::<usize>()
        })
        .sum()
}

/// The upper triangle of the reduced camera system as a sparse matrix.
pub(crate) fn reduced_upper(st: &Structure, rows: &[Row]) -> Option<SparseColMat<usize, f64>> {
    let mut trip = Vec::new();
    for (b1, row) in rows.iter().enumerate() {
        for (s, &b2) in st.neighbours[b1].iter().enumerate() {
            for (i1, &k1) in st.free[b1].iter().enumerate() {
                for (i2, &k2) in st.free[b2].iter().enumerate() {
                    if b1 == b2 && i2 < i1 {
                        continue;
                    }
                    let (g1, g2) = (st.offset[b1] + i1, st.offset[b2] + i2);
                    trip.push(Triplet::new(g1, g2, row.blocks[s][(k1, k2)]));
                }
            }
        }
    }
    SparseColMat::<usize, f64>::try_new_from_triplets(st.n, st.n, &trip).ok()
}

/// Solves for the camera-side update and back-substitutes the points, their systems
/// evaluated again as [`reduced_rows`] did (the same bits).
pub(crate) fn solve_step(
    ev: &Evaluated,
    st: &Structure,
    rows: &[Row],
    factor: &Factor,
    lambda: f64,
) -> (Vec<V9>, Vec<Vector3<f64>>) {
    let mut x = DMatrix::zeros(st.n, 1);
    for (b, row) in rows.iter().enumerate() {
        for (i, &k) in st.free[b].iter().enumerate() {
            x[(st.offset[b] + i, 0)] = row.rhs[k];
        }
    }
    factor.solve_in_place(&mut x);
    let dblocks: Vec<V9> = (0..st.free.len())
        .map(|b| {
            let mut v = V9::zeros();
            for (i, &k) in st.free[b].iter().enumerate() {
                v[k] = x[(st.offset[b] + i, 0)];
            }
            v
        })
        .collect();
    let dpoints = (0..st.point_res.len())
        .into_par_iter()
        .map(|p| {
            let ps = point_system(ev, st, p, lambda);
            let mut r = -ps.g;
            for (b, w) in &ps.w {
                r -= w.transpose() * dblocks[*b];
            }
            ps.vinv * r
        })
        .collect();
    (dblocks, dpoints)
}

/// Applies an update to a copy of the state.
pub(crate) fn apply(
    st: &Structure,
    state: &State,
    dblocks: &[V9],
    dpoints: &[Vector3<f64>],
) -> State {
    let mut s = state.clone();
    for (i, pose) in s.poses.iter_mut().enumerate() {
        let d = &dblocks[i];
        *pose = pose.perturbed(
            &Vector3::new(d[0], d[1], d[2]),
            &Vector3::new(d[3], d[4], d[5]),
        );
    }
    for (c, cam) in s.cameras.iter_mut().enumerate() {
        if let Some(b) = st.camera_block[c] {
            let mut p = cam.params();
            for &k in &st.free[b] {
                p[k] += dblocks[b][k];
            }
            if cam.set_params(&p).is_err() {
                continue;
            }
        }
    }
    // The camera slot after the cameras is the LiDAR datum's, when it is adjusted.
    if let Some(Some(b)) = st.camera_block.get(s.cameras.len()) {
        for &k in &st.free[*b] {
            s.lidar_shift[k] += dblocks[*b][k];
        }
    }
    for (x, d) in s.points.iter_mut().zip(dpoints) {
        *x += d;
    }
    s
}

/// Outcome of a Levenberg–Marquardt run.
#[derive(Debug, Clone)]
pub(crate) struct LmOutcome {
    pub iterations: usize,
    pub initial_cost: f64,
    pub final_cost: f64,
    pub converged: bool,
    /// The loss weighs every evaluated residual fully at the solution (its cost is the
    /// least-squares cost about it).
    pub fully_weighted: bool,
}

#[derive(Debug, Clone)]
pub(crate) struct LmOptions {
    pub max_iterations: usize,
    /// Stop when the relative cost decrease falls below this.
    pub function_tolerance: f64,
    /// Stop when the largest update (radians, metres, interior units) falls below this.
    pub parameter_tolerance: f64,
    /// Stop when the camera-side update's squared length in units of its own precision,
    /// δᵀSδ with S the reduced camera system (see [`camera_decrement`]), falls below this;
    /// 0 leaves it to the other two.
    pub camera_tolerance: f64,
}

/// δᵀ(S + λD)δ = δᵀb of the camera-side update δ solved from the reduced system's rows
/// (right-hand sides b): the squared Mahalanobis length of the step in the orientations
/// at unit variance (σ0 = 1), an upper bound of δᵀSδ. Every function f of the orientations
/// moves by at most √(δᵀSδ) times its own standard deviation, since
/// |∇fᵀδ| ≤ √(δᵀSδ)·√(∇fᵀS⁻¹∇f).
fn camera_decrement(st: &Structure, rows: &[Row], dblocks: &[V9]) -> f64 {
    rows.iter()
        .zip(dblocks)
        .zip(&st.free)
        .map(|((row, d), free)| free.iter().map(|&k| d[k] * row.rhs[k]).sum::<f64>())
        .sum()
}

/// The damping each run starts at, relative to the normal equations' diagonal.
const LAMBDA_START: f64 = 1e-4;

pub(crate) fn levenberg_marquardt(
    st: &Structure,
    res: &[ResidualBlock],
    state: &mut State,
    loss: Loss,
    opts: &LmOptions,
) -> LmOutcome {
    let mut cache = SymbolicCache::default();
    let mut cur = Evaluated::new(res, state, loss).cost();
    let initial_cost = cur.cost;
    let mut lambda = LAMBDA_START;
    let mut iterations = 0;
    let mut converged = false;
    while iterations < opts.max_iterations {
        iterations += 1;
        let mut taken = None;
        let mut decrement = f64::NAN;
        {
            let ev = Evaluated::new(res, state, loss);
            let t = std::time::Instant::now();
            let diag = diagonal(&ev, st);
            tracing::debug!(t_diagonal = t.elapsed().as_secs_f64(), "diagonal blocks");
            while lambda < 1e12 {
                let t = std::time::Instant::now();
                let rows = reduced_rows(&ev, st, &diag, lambda);
                let t_rows = t.elapsed().as_secs_f64();
                let factor = factorize(st, &rows, &mut cache);
                tracing::debug!(
                    t_rows,
                    t_factor = t.elapsed().as_secs_f64() - t_rows,
                    n = st.n,
                    "normal equations"
                );
                let Some(f) = factor else {
                    lambda *= 10.0;
                    continue;
                };
                let (db, dp) = solve_step(&ev, st, &rows, &f, lambda);
                decrement = camera_decrement(st, &rows, &db);
                let step_max = db
                    .iter()
                    .map(|v| v.amax())
                    .chain(dp.iter().map(|v| v.amax() * 1e-3))
                    .fold(0.0f64, f64::max);
                let trial = apply(st, state, &db, &dp);
                let t = std::time::Instant::now();
                let c = Evaluated::new(res, &trial, loss).cost();
                tracing::debug!(t_eval = t.elapsed().as_secs_f64(), "trial residuals");
                if c.cost.is_finite() && c.failed <= cur.failed && c.cost <= cur.cost {
                    let rel = (cur.cost - c.cost) / cur.cost.max(f64::MIN_POSITIVE);
                    // A strongly damped step is short for the damping's sake, not because
                    // the orientations are there.
                    let settled = lambda <= LAMBDA_START && decrement < opts.camera_tolerance;
                    taken = Some((trial, c));
                    lambda = (lambda / 3.0).max(1e-12);
                    if rel < opts.function_tolerance
                        || step_max < opts.parameter_tolerance
                        || settled
                    {
                        converged = true;
                    }
                    break;
                }
                lambda *= 10.0;
            }
        }
        let accepted = taken.is_some();
        if let Some((trial, c)) = taken {
            *state = trial;
            cur = c;
        }
        tracing::debug!(
            iterations,
            cost = cur.cost,
            lambda,
            camera_decrement = decrement,
            "bundle adjustment iteration"
        );
        if !accepted {
            // No step lowers the cost any more: we are at the minimum to machine precision.
            converged = true;
            break;
        }
        if converged {
            break;
        }
    }
    LmOutcome {
        iterations,
        initial_cost,
        final_cost: cur.cost,
        converged,
        fully_weighted: cur.fully_weighted,
    }
}
