//! The residuals of one state under a loss, evaluated where each pass needs them rather
//! than stored: the Jacobians of every observation (a 552-byte `Eval` each) were two
//! thirds of the adjustment's peak memory, 3.5 GB at 6.5 million observations, while a
//! projection with its Jacobians costs less than reading them back from memory did.

use super::residual::{Eval, Loss, ResidualBlock, State};
use nalgebra::Vector3;
use rayon::prelude::*;

/// Residual blocks per parallel chunk of an in-order pass: bounds its buffer to a few
/// MB however large the block, with chunks long enough to keep both cores busy.
const CHUNK: usize = 1 << 16;

/// The residual blocks `res` at `state`, weighed by `loss`.
#[derive(Clone, Copy)]
pub(crate) struct Evaluated<'a> {
    pub res: &'a [ResidualBlock],
    pub state: &'a State,
    pub loss: Loss,
}

/// The cost of a state and what it says about its residuals.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Cost {
    /// Σρ over the evaluated active blocks, summed in block order.
    pub cost: f64,
    /// Active blocks that could not be evaluated (a point behind its camera).
    pub failed: usize,
    /// The loss weighs every evaluated block fully (its IRLS weight is 1).
    pub fully_weighted: bool,
}

impl<'a> Evaluated<'a> {
    pub fn new(res: &'a [ResidualBlock], state: &'a State, loss: Loss) -> Self {
        Self { res, state, loss }
    }

    /// Block `i`'s whitened residual and Jacobians with its IRLS weight; `None` when it
    /// is rejected or cannot be evaluated.
    pub fn at(&self, i: usize) -> Option<(Eval, f64)> {
        let r = &self.res[i];
        if !r.active {
            return None;
        }
        let e = r.evaluate(self.state)?;
        let w = self.loss.rho(e.norm_sq()).1;
        Some((e, w))
    }

    /// Block `i`'s whitened residual alone (the same bits as [`Self::at`]'s), `None` as
    /// there.
    pub fn residual(&self, i: usize) -> Option<Vector3<f64>> {
        let r = &self.res[i];
        if !r.active {
            return None;
        }
        r.residual(self.state)
    }

    /// Visits every block in order with its [`residual`](Self::residual), evaluated in
    /// parallel chunks: for the sums whose order fixes their bits.
    pub fn for_each_residual(&self, mut f: impl FnMut(usize, Option<&Vector3<f64>>)) {
        let mut buf = Vec::with_capacity(CHUNK.min(self.res.len()));
        for start in (0..self.res.len()).step_by(CHUNK) {
            let end = (start + CHUNK).min(self.res.len());
            (start..end)
                .into_par_iter()
                .map(|i| self.residual(i))
                .collect_into_vec(&mut buf);
            for (k, v) in buf.iter().enumerate() {
                f(start + k, v.as_ref());
            }
        }
    }

    /// The cost of the state. Residuals without Jacobians: a trial step needs no more,
    /// and an accepted one's cost is the same bits.
    pub fn cost(&self) -> Cost {
        let mut c = Cost {
            cost: 0.0,
            failed: 0,
            fully_weighted: true,
        };
        self.for_each_residual(|i, v| match v {
            Some(v) => {
                let (rho, w) = self.loss.rho(v.norm_squared());
                c.cost += rho;
                c.fully_weighted &= w == 1.0;
            }
            None if self.res[i].active => c.failed += 1,
            None => {}
        });
        c
    }
}
