//! Process-wide memos of values that depend only on sizes and angles (FFT plans, spreading
//! weights, the sub-directions of a tilted camera), so that rendering many images pays for them
//! once. Values are built outside the lock (two threads may build the same one; both results are
//! equal, the first one stored wins), so a slow build never blocks unrelated lookups.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

/// A memo keyed by `K`.
pub(crate) struct Memo<K, V> {
    map: Mutex<BTreeMap<K, Arc<V>>>,
}

impl<K: Ord + Copy, V> Memo<K, V> {
    /// An empty memo (usable in a `static`).
    pub(crate) const fn new() -> Self {
        Self {
            map: Mutex::new(BTreeMap::new()),
        }
    }

    /// The value for `key`, built by `make` the first time.
    pub(crate) fn get(&'static self, key: K, make: impl FnOnce() -> V) -> Arc<V> {
        // A poisoned lock only means another thread panicked while inserting; the map itself
        // holds complete values, so keep using it.
        if let Some(v) = self.map.lock().unwrap_or_else(|e| e.into_inner()).get(&key) {
            return v.clone();
        }
        let v = Arc::new(make());
        self.map
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .entry(key)
            .or_insert(v)
            .clone()
    }
}
