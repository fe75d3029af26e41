//! One bounded least-recently-used cache for whatever is read on demand and too large to
//! hold all at once: LiDAR tiles (bounded in points), photo images (bounded in bytes).
//! Entries are shared (`Arc`), so an entry evicted while a caller still uses it stays alive
//! until that caller drops it; the bound is on what the cache itself keeps.
//!
//! The recency order is the `lru` crate's; what it lacks, a bound by the entries' weights
//! rather than their count, is the few lines here.

use std::hash::Hash;
use std::sync::Arc;

/// Default bound of the caches of decoded photos (orthophoto tiles, tie matching): 1 GiB,
/// ten 42 µm film scans in RGB or thirty 3000 × 2000 frames with their pyramids.
pub const DEFAULT_IMAGE_CACHE_BYTES: u64 = 1 << 30;

/// An LRU cache of `V` by key `K`, bounded by the sum of the entries' weights.
pub struct Lru<K: Hash + Eq, V> {
    bound: u64,
    /// Value and weight by key, in recency order.
    entries: lru::LruCache<K, (Arc<V>, u64)>,
    held: u64,
    loads: usize,
}

impl<K: Hash + Eq + Clone, V> Lru<K, V> {
    /// `bound`: total weight above which least recently used entries are dropped. An entry
    /// heavier than the bound on its own is still returned (and kept until the next load).
    pub fn new(bound: u64) -> Self {
        Self {
            bound,
            entries: lru::LruCache::unbounded(),
            held: 0,
            loads: 0,
        }
    }

    /// Total weight held.
    pub fn held(&self) -> u64 {
        self.held
    }

    /// How many entries were loaded (cache misses).
    pub fn loads(&self) -> usize {
        self.loads
    }

    /// Whether `key` is held (does not count as a use).
    pub fn contains(&self, key: &K) -> bool {
        self.entries.contains(key)
    }

    /// Drops every entry whose key `keep` refuses.
    pub fn retain(&mut self, mut keep: impl FnMut(&K) -> bool) {
        let drop: Vec<K> = self
            .entries
            .iter()
            .filter(|(k, _)| !keep(k))
            .map(|(k, _)| k.clone())
            .collect();
        for k in drop {
            if let Some((_, w)) = self.entries.pop(&k) {
                self.held -= w;
            }
        }
    }

    /// The entry of `key`, from the cache or made by `load`, which returns the value and
    /// its weight. Least recently used entries are dropped first to make room.
    pub fn get_or_load<E>(
        &mut self,
        key: &K,
        load: impl FnOnce() -> Result<(V, u64), E>,
    ) -> Result<Arc<V>, E> {
        if let Some((v, _)) = self.entries.get(key) {
            return Ok(v.clone());
        }
        let (v, weight) = load()?;
        self.loads += 1;
        let v = Arc::new(v);
        while self.held + weight > self.bound {
            let Some((_, (_, w))) = self.entries.pop_lru() else {
                break;
            };
            self.held -= w;
        }
        self.entries.put(key.clone(), (v.clone(), weight));
        self.held += weight;
        Ok(v)
    }
}
