//! Unit tests of `adjust::selinv`: the selected inverse against a dense inverse.

mod tests {
    use cloudcontrol::adjust::selinv::SelectedInverse;
    use faer::sparse::{SparseColMat, Triplet};
    use nalgebra::DMatrix;
    use rand::{Rng, SeedableRng};

    /// A block-banded SPD matrix like a reduced camera system of strips: 6×6 blocks, each
    /// coupled to the next `band` blocks and to the block `stride` ahead (the next
    /// strip), with random couplings and a dominant diagonal.
    fn system(blocks: usize, band: usize, stride: usize, seed: u64) -> DMatrix<f64> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let n = 6 * blocks;
        let mut m = DMatrix::<f64>::zeros(n, n);
        for b in 0..blocks {
            let mut others: Vec<usize> = (b + 1..(b + 1 + band).min(blocks)).collect();
            if b + stride < blocks {
                others.push(b + stride);
            }
            for c in std::iter::once(b).chain(others) {
                for i in 0..6 {
                    for j in 0..6 {
                        let v: f64 = rng.gen_range(-1.0..1.0);
                        m[(6 * b + i, 6 * c + j)] += v;
                        m[(6 * c + j, 6 * b + i)] += v;
                    }
                }
            }
        }
        for i in 0..n {
            let row: f64 = (0..n).map(|j| m[(i, j)].abs()).sum();
            m[(i, i)] = row + 1.0;
        }
        m
    }

    fn upper(m: &DMatrix<f64>) -> SparseColMat<usize, f64> {
        let n = m.nrows();
        let mut trip = Vec::new();
        for j in 0..n {
            for i in 0..=j {
                if m[(i, j)] != 0.0 {
                    trip.push(Triplet::new(i, j, m[(i, j)]));
                }
            }
        }
        SparseColMat::try_new_from_triplets(n, n, &trip).unwrap()
    }

    #[test]
    fn diagonal_blocks_equal_the_dense_inverse() {
        for (blocks, band, stride, seed) in [(40, 2, 7, 1), (120, 3, 11, 2), (7, 1, 3, 3)] {
            let m = system(blocks, band, stride, seed);
            let dense = m.clone().try_inverse().unwrap();
            let z = SelectedInverse::new(upper(&m).as_ref()).expect("SPD");
            let mut worst = 0.0f64;
            for b in 0..blocks {
                for i in 0..6 {
                    for j in 0..6 {
                        let (g, h) = (6 * b + i, 6 * b + j);
                        let got = z.get(g, h).expect("on the pattern");
                        worst = worst.max((got - dense[(g, h)]).abs() / dense[(g, g)].abs());
                    }
                }
            }
            // Every entry of the matrix is on the factor's pattern too.
            let (g, h) = (0, 6 * stride.min(blocks - 1));
            if m[(g, h)] != 0.0 {
                let got = z.get(g, h).expect("an entry of S is on the pattern");
                worst = worst.max((got - dense[(g, h)]).abs() / dense[(g, g)].abs());
            }
            assert!(worst < 1e-10, "{blocks} blocks: relative error {worst:e}");
        }
    }

    #[test]
    fn an_indefinite_matrix_has_none() {
        let mut m = system(10, 2, 4, 5);
        m[(13, 13)] = -50.0;
        assert!(SelectedInverse::new(upper(&m).as_ref()).is_none());
    }
}
