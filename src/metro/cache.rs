//! The page cache shared by the paged operands of a comparison: what a
//! part holds in memory as a sample source or a query index, least recently
//! used first out, under a byte budget.
//!
//! Takes: a byte budget, and loads keyed by (operand, role, part). Gives:
//! shared entries, and the counters the report's `paging` object shows.

use super::paged::SrcPart;
use crate::error::Result;
use crate::geom::Bvh;
use std::collections::{BTreeMap, HashMap};
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::{Arc, Condvar, Mutex};

/// Bytes of live cache entries and reservations, and their peak.
#[derive(Debug, Default)]
pub(super) struct Acct {
    resident: AtomicU64,
    pub(super) peak: AtomicU64,
}

impl Acct {
    fn add(&self, n: u64) {
        let r = self.resident.fetch_add(n, Relaxed) + n;
        self.peak.fetch_max(r, Relaxed);
    }
    fn sub(&self, n: u64) {
        self.resident.fetch_sub(n, Relaxed);
    }
    fn resident(&self) -> u64 {
        self.resident.load(Relaxed)
    }
}

pub(super) enum Payload {
    Src(SrcPart),
    Tgt(Bvh),
}

impl Payload {
    pub(super) fn bytes(&self) -> u64 {
        match self {
            Payload::Src(s) => s.bytes(),
            Payload::Tgt(b) => b.bytes(),
        }
    }
}

/// A cache entry; its bytes count as resident until the last holder drops it.
pub(super) struct Entry {
    payload: Payload,
    bytes: u64,
    acct: Arc<Acct>,
}

impl Entry {
    pub(super) fn src(&self) -> &SrcPart {
        match &self.payload {
            Payload::Src(s) => s,
            Payload::Tgt(_) => unreachable!("a query index where a sample source was expected"),
        }
    }
    pub(super) fn bvh(&self) -> &Bvh {
        match &self.payload {
            Payload::Tgt(b) => b,
            Payload::Src(_) => unreachable!("a sample source where a query index was expected"),
        }
    }
}

impl Drop for Entry {
    fn drop(&mut self) {
        self.acct.sub(self.bytes);
    }
}

enum CacheSlot {
    Loading,
    Ready(Arc<Entry>, u64),
}

#[derive(Default)]
struct CacheState {
    map: HashMap<u64, CacheSlot>,
    /// Last-use tick → key.
    lru: BTreeMap<u64, u64>,
    tick: u64,
}

/// The page cache shared by the paged operands: node meshes and their
/// indexes, least recently used first out, under a byte budget. Resident
/// bytes are the heap bytes of live entries (cached or still held by a
/// query) plus reservations for loads in flight (the estimated peak of a
/// load: payload, decoded vertices, weld map, the structure being built),
/// swapped for the entry's real size once built.
pub struct Cache {
    pub(super) budget: u64,
    pub(super) acct: Arc<Acct>,
    state: Mutex<CacheState>,
    ready: Condvar,
    pub(super) loads: AtomicU64,
    pub(super) hits: AtomicU64,
    pub(super) evictions: AtomicU64,
    pub(super) overcommits: AtomicU64,
    pub(super) bytes_read: AtomicU64,
    pub(super) scan_bytes: AtomicU64,
}

/// Holds `bytes` of the budget until dropped.
pub(super) struct Reservation<'a>(&'a Cache, u64);

impl Drop for Reservation<'_> {
    fn drop(&mut self) {
        self.0.acct.sub(self.1);
    }
}

impl Cache {
    pub(super) fn new(budget: u64) -> Cache {
        Cache {
            budget,
            acct: Arc::new(Acct::default()),
            state: Mutex::new(CacheState::default()),
            ready: Condvar::new(),
            loads: AtomicU64::new(0),
            hits: AtomicU64::new(0),
            evictions: AtomicU64::new(0),
            overcommits: AtomicU64::new(0),
            bytes_read: AtomicU64::new(0),
            scan_bytes: AtomicU64::new(0),
        }
    }

    /// Evicts least recently used entries nobody holds until `need` more
    /// bytes fit (or nothing more can go: counted as an overcommit).
    fn make_room(&self, st: &mut CacheState, need: u64) {
        while self.acct.resident() + need > self.budget {
            let victim = st.lru.iter().find(|(_, k)| matches!(st.map.get(k), Some(CacheSlot::Ready(e, _)) if Arc::strong_count(e) == 1)).map(|(&t, &k)| (t, k));
            let Some((t, k)) = victim else {
                self.overcommits.fetch_add(1, Relaxed);
                return;
            };
            st.lru.remove(&t);
            st.map.remove(&k);
            self.evictions.fetch_add(1, Relaxed);
        }
    }

    pub(super) fn reserve(&self, bytes: u64) -> Reservation<'_> {
        let mut st = self.state.lock().unwrap();
        self.make_room(&mut st, bytes);
        self.acct.add(bytes);
        Reservation(self, bytes)
    }

    /// The entry for `key`, loading it with `load` (which returns the
    /// payload and the bytes it read) under a reservation of `estimate`
    /// bytes if absent. Concurrent requests for the same key wait for one load.
    pub(super) fn get(&self, key: u64, estimate: u64, load: impl FnOnce() -> Result<(Payload, u64)>) -> Result<Arc<Entry>> {
        let mut st = self.state.lock().unwrap();
        loop {
            match st.map.get(&key) {
                Some(CacheSlot::Ready(e, t)) => {
                    let (e, t) = (e.clone(), *t);
                    st.tick += 1;
                    let now = st.tick;
                    st.lru.remove(&t);
                    st.lru.insert(now, key);
                    st.map.insert(key, CacheSlot::Ready(e.clone(), now));
                    self.hits.fetch_add(1, Relaxed);
                    return Ok(e);
                }
                Some(CacheSlot::Loading) => st = self.ready.wait(st).unwrap(),
                None => break,
            }
        }
        self.make_room(&mut st, estimate);
        self.acct.add(estimate);
        st.map.insert(key, CacheSlot::Loading);
        drop(st);
        let loaded = load();
        let mut st = self.state.lock().unwrap();
        st.map.remove(&key);
        let out = match loaded {
            Ok((payload, read)) => {
                let bytes = payload.bytes();
                if bytes > estimate {
                    self.acct.add(bytes - estimate);
                } else {
                    self.acct.sub(estimate - bytes);
                }
                let e = Arc::new(Entry { payload, bytes, acct: self.acct.clone() });
                st.tick += 1;
                let now = st.tick;
                st.lru.insert(now, key);
                st.map.insert(key, CacheSlot::Ready(e.clone(), now));
                self.loads.fetch_add(1, Relaxed);
                self.bytes_read.fetch_add(read, Relaxed);
                Ok(e)
            }
            Err(err) => {
                self.acct.sub(estimate);
                Err(err)
            }
        };
        drop(st);
        self.ready.notify_all();
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::random_mesh;

    #[test]
    fn cache_evicts_least_recently_used_and_keeps_held_entries() {
        let bvh = |n: usize| {
            let m = random_mesh(n, n as u64);
            Payload::Tgt(Bvh::build(&m, false))
        };
        let size = bvh(3).bytes();
        assert!(size > 0 && size <= Bvh::bytes_bound(3), "{size}");
        // Room for four entries.
        let budget = 4 * size + size / 2;
        let cache = Cache::new(budget);
        let held = cache.get(0, size, || Ok((bvh(3), 10))).unwrap();
        for k in 1..8u64 {
            let _ = cache.get(k, size, || Ok((bvh(3), 10))).unwrap();
            assert!(cache.acct.resident() <= budget);
        }
        assert!(cache.evictions.load(Relaxed) > 0);
        // Entry 0 was held all along: still cached, a hit.
        let again = cache.get(0, size, || panic!("held entries stay")).unwrap();
        assert!(Arc::ptr_eq(&held, &again));
        // Entry 1 was the least recently used of the others: gone.
        let mut reloaded = false;
        let _ = cache.get(1, size, || {
            reloaded = true;
            Ok((bvh(3), 10))
        });
        assert!(reloaded);
        assert!(cache.acct.peak.load(Relaxed) <= budget);
        assert_eq!(cache.overcommits.load(Relaxed), 0);
        drop((held, again));
        // A reservation larger than what can be freed is an overcommit.
        let r = cache.reserve(2 * budget);
        assert!(cache.overcommits.load(Relaxed) > 0);
        drop(r);
    }
}
