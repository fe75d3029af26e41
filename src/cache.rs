//! One bounded least-recently-used cache for whatever is read on demand and too large to
//! hold all at once: LiDAR tiles (bounded in points), photo images (bounded in bytes).
//! Entries are shared (`Arc`), so an entry evicted while a caller still uses it stays alive
//! until that caller drops it; the bound is on what the cache itself keeps.

use std::sync::Arc;

/// Default bound of the caches of decoded photos (orthophoto tiles, tie matching): 1 GiB,
/// ten 42 µm film scans in RGB or thirty 3000 × 2000 frames with their pyramids.
pub const DEFAULT_IMAGE_CACHE_BYTES: u64 = 1 << 30;

/// An LRU cache of `V` by key `K`, bounded by the sum of the entries' weights.
pub struct Lru<K, V> {
    bound: u64,
    /// (key, value, weight), most recently used last. A linear scan: the caches hold tens
    /// of entries, each costing a file read of milliseconds to seconds.
    entries: Vec<(K, Arc<V>, u64)>,
    loads: usize,
}

impl<K: PartialEq + Clone, V> Lru<K, V> {
    /// `bound`: total weight above which least recently used entries are dropped. An entry
    /// heavier than the bound on its own is still returned (and kept until the next load).
    pub fn new(bound: u64) -> Self {
        Self {
            bound,
            entries: Vec::new(),
            loads: 0,
        }
    }

    /// Total weight held.
    pub fn held(&self) -> u64 {
        self.entries.iter().map(|e| e.2).sum()
    }

    /// How many entries were loaded (cache misses).
    pub fn loads(&self) -> usize {
        self.loads
    }

    /// Whether `key` is held (does not count as a use).
    pub fn contains(&self, key: &K) -> bool {
        self.entries.iter().any(|e| e.0 == *key)
    }

    /// Drops every entry whose key `keep` refuses.
    pub fn retain(&mut self, mut keep: impl FnMut(&K) -> bool) {
        self.entries.retain(|e| keep(&e.0));
    }

    /// The entry of `key`, from the cache or made by `load`, which returns the value and
    /// its weight. Least recently used entries are dropped first to make room.
    pub fn get_or_load<E>(
        &mut self,
        key: &K,
        load: impl FnOnce() -> Result<(V, u64), E>,
    ) -> Result<Arc<V>, E> {
        if let Some(pos) = self.entries.iter().position(|e| e.0 == *key) {
            let e = self.entries.remove(pos);
            let v = e.1.clone();
            self.entries.push(e);
            return Ok(v);
        }
        let (v, weight) = load()?;
        self.loads += 1;
        let v = Arc::new(v);
        let mut held = self.held();
        while held + weight > self.bound && !self.entries.is_empty() {
            held -= self.entries.remove(0).2;
        }
        self.entries.push((key.clone(), v.clone(), weight));
        Ok(v)
    }
}
