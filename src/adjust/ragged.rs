//! Lists by owner (object point, camera-side block) in two flat vectors. A `Vec` of
//! `usize` per object point cost its 24-byte header, its allocation and its growth's
//! slack beside the 8 bytes an entry, for a few entries a point: with four such lists the
//! structure of the normal equations took 40 bytes an observation.

use std::ops::{Index, Range};

/// The lists of `len()` owners, each a slice of `items`.
#[derive(Debug, Clone)]
pub(crate) struct Ragged<T> {
    /// Owner k's items are `items[start[k]..start[k + 1]]`.
    start: Vec<usize>,
    items: Vec<T>,
}

impl<T: Copy + Default> Ragged<T> {
    /// Empty, to [`push`](Self::push) owners on.
    pub fn new() -> Self {
        Self {
            start: vec![0],
            items: Vec::new(),
        }
    }

    /// The lists of `n` owners from `(owner, item)` pairs, each owner's items in the
    /// pairs' order; `pairs` is called twice (counting, then filling).
    pub fn from_pairs<I>(n: usize, pairs: impl Fn() -> I) -> Self
    where
        I: Iterator<Item = (usize, T)>,
    {
        let mut start = vec![0usize; n + 1];
        for (k, _) in pairs() {
            start[k + 1] += 1;
        }
        for k in 0..n {
            start[k + 1] += start[k];
        }
        let mut next = start[..n].to_vec();
        let mut items = vec![T::default(); start[n]];
        for (k, v) in pairs() {
            items[next[k]] = v;
            next[k] += 1;
        }
        Self { start, items }
    }

    /// Appends the next owner's list.
    pub fn push(&mut self, list: impl IntoIterator<Item = T>) {
        self.items.extend(list);
        self.start.push(self.items.len());
    }

    /// Number of owners.
    pub fn len(&self) -> usize {
        self.start.len() - 1
    }

    /// The items of owners `owners`, one after another.
    pub fn span(&self, owners: Range<usize>) -> &[T] {
        &self.items[self.start[owners.start]..self.start[owners.end]]
    }
}

impl Ragged<u32> {
    /// Owner k's items as indices.
    pub fn of(&self, k: usize) -> impl Iterator<Item = usize> + '_ {
        self[k].iter().map(|&v| v as usize)
    }
}

impl<T> Index<usize> for Ragged<T> {
    type Output = [T];

    fn index(&self, k: usize) -> &[T] {
        &self.items[self.start[k]..self.start[k + 1]]
    }
}

/// An index narrowed to the four bytes the structure stores.
pub(crate) fn narrow(i: usize) -> u32 {
    u32::try_from(i).expect("index within u32")
}
