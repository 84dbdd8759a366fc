//! External merge sort of fixed-size byte records keyed by a little-endian
//! `u64` in their first 8 bytes, under a memory budget.
//!
//! Takes: records pushed one by one and a byte budget. Gives: the records in
//! key order, streamed to a callback. Ties are broken by push order, so the
//! output is deterministic.
//!
//! Records accumulate in one buffer; when it is full, a (key, index) array is
//! sorted in parallel with rayon and the records are gathered out in order
//! into a run file in the scratch directory (large sequential writes). At the
//! end, runs are merged with a binary heap through per-run read buffers; when
//! there are more runs than the budget allows buffers for, groups of runs are
//! merged into longer runs first (multi-pass). If everything fits in memory no
//! file is written at all. Disk access is strictly sequential per stream.

use crate::error::{IoContext, Result};
use rayon::prelude::*;
use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};

/// Smallest read buffer per run during a merge.
const MIN_RUN_BUF: usize = 4 << 10;
/// Read buffer per run we aim for when the budget allows.
const GOOD_RUN_BUF: usize = 256 << 10;
/// Bytes of sort index per buffered record: (key, sequence).
const INDEX_BYTES: usize = 16;

/// Figures about one sort, for reports and tests.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SortStats {
    pub records: u64,
    /// Run files written by the first pass.
    pub runs: u64,
    /// Merge passes over the data (0: sorted in memory; 1: one final merge).
    pub merge_passes: u32,
    /// Bytes written to scratch files (runs and intermediate merges).
    pub spilled_bytes: u64,
}

struct Run {
    path: PathBuf,
    records: u64,
}

/// An external sorter; see the module doc.
pub struct ExtSorter {
    rec: usize,
    /// Bytes for read buffers when merging (defaults to the fill budget).
    merge_mem: usize,
    cap: usize,
    buf: Vec<u8>,
    dir: PathBuf,
    runs: Vec<Run>,
    max_fan_in: usize,
    stats: SortStats,
    name: &'static str,
}

impl ExtSorter {
    /// `rec_size` bytes per record (≥ 8: the key), `mem` bytes for buffers,
    /// spill files in `dir` named after `name`.
    pub fn new(name: &'static str, rec_size: usize, mem: usize, dir: &Path) -> ExtSorter {
        assert!(rec_size >= 8);
        let cap = (mem / (rec_size + INDEX_BYTES)).max(2);
        ExtSorter {
            rec: rec_size,
            merge_mem: mem,
            cap,
            buf: Vec::new(),
            dir: dir.to_path_buf(),
            runs: Vec::new(),
            max_fan_in: usize::MAX,
            stats: SortStats::default(),
            name,
        }
    }

    /// Caps how many runs one merge reads at once (tests force multi-pass with 2).
    pub fn with_max_fan_in(mut self, k: usize) -> ExtSorter {
        self.max_fan_in = k.max(2);
        self
    }

    /// Sets the bytes the merge may use for read buffers (the run buffer is
    /// released before merging, so a caller can give that memory elsewhere).
    pub fn with_merge_mem(mut self, mem: usize) -> ExtSorter {
        self.merge_mem = mem.max(2 * MIN_RUN_BUF);
        self
    }

    /// Records held in memory before a run is spilled.
    pub fn run_capacity(&self) -> usize {
        self.cap
    }

    /// Appends one record; `fill` writes its `rec_size` bytes (key first).
    #[inline]
    pub fn push_with(&mut self, fill: impl FnOnce(&mut [u8])) -> Result<()> {
        if self.buf.len() == self.cap * self.rec {
            self.spill()?;
        }
        if self.buf.capacity() == 0 {
            self.buf.reserve_exact(self.cap * self.rec);
        }
        let at = self.buf.len();
        self.buf.resize(at + self.rec, 0);
        fill(&mut self.buf[at..]);
        self.stats.records += 1;
        Ok(())
    }

    #[inline]
    pub fn push(&mut self, rec: &[u8]) -> Result<()> {
        self.push_with(|b| b.copy_from_slice(rec))
    }

    /// Sorted order of the buffered records as indices.
    fn sorted_order(&self) -> Vec<(u64, u64)> {
        let rec = self.rec;
        let n = self.buf.len() / rec;
        let mut idx: Vec<(u64, u64)> =
            (0..n).into_par_iter().map(|i| (u64::from_le_bytes(self.buf[i * rec..i * rec + 8].try_into().unwrap()), i as u64)).collect();
        idx.par_sort_unstable();
        idx
    }

    fn spill(&mut self) -> Result<()> {
        if self.buf.is_empty() {
            return Ok(());
        }
        let path = self.dir.join(format!("{}-run{:05}.bin", self.name, self.runs.len()));
        let f = File::create(&path).ctx(&path, "create run file")?;
        let mut w = BufWriter::with_capacity(crate::io::SEQ_BUF, f);
        let n = (self.buf.len() / self.rec) as u64;
        for &(_, i) in &self.sorted_order() {
            let i = i as usize;
            w.write_all(&self.buf[i * self.rec..(i + 1) * self.rec]).ctx(&path, "write run file")?;
        }
        w.flush().ctx(&path, "write run file")?;
        self.stats.spilled_bytes += n * self.rec as u64;
        self.runs.push(Run { path, records: n });
        self.stats.runs += 1;
        self.buf.clear();
        Ok(())
    }

    /// Emits every record in key order to `out`, then deletes the scratch files.
    pub fn finish(mut self, mut out: impl FnMut(&[u8]) -> Result<()>) -> Result<SortStats> {
        if self.runs.is_empty() {
            // Everything fits: sort in memory, no disk.
            for &(_, i) in &self.sorted_order() {
                let i = i as usize;
                out(&self.buf[i * self.rec..(i + 1) * self.rec])?;
            }
            return Ok(self.stats);
        }
        self.spill()?;
        self.buf = Vec::new(); // release the run buffer before merging
                               // As many runs per merge as the budget gives good-sized read buffers for.
        let fan_in = (self.merge_mem / GOOD_RUN_BUF).clamp(2, 1024).min(self.max_fan_in);
        let mut runs = std::mem::take(&mut self.runs);
        let mut pass = 0u32;
        while runs.len() > fan_in {
            pass += 1;
            let mut next = Vec::new();
            for (g, group) in runs.chunks(fan_in).enumerate() {
                if group.len() == 1 {
                    next.push(Run { path: group[0].path.clone(), records: group[0].records });
                    continue;
                }
                let path = self.dir.join(format!("{}-p{pass}-m{g:05}.bin", self.name));
                let f = File::create(&path).ctx(&path, "create merge file")?;
                let mut w = BufWriter::with_capacity(crate::io::SEQ_BUF, f);
                let mut n = 0u64;
                merge(group, self.rec, self.merge_mem / (group.len() + 1), |r| {
                    n += 1;
                    w.write_all(r).ctx(&path, "write merge file")
                })?;
                w.flush().ctx(&path, "write merge file")?;
                for r in group {
                    let _ = std::fs::remove_file(&r.path);
                }
                self.stats.spilled_bytes += n * self.rec as u64;
                next.push(Run { path, records: n });
            }
            runs = next;
        }
        merge(&runs, self.rec, self.merge_mem / (runs.len() + 1), &mut out)?;
        for r in &runs {
            let _ = std::fs::remove_file(&r.path);
        }
        self.stats.merge_passes = pass + 1;
        Ok(self.stats)
    }
}

/// Sequential reader over one run file, buffering into a slice of the
/// merge's single arena (one large allocation, returned to the OS when the
/// merge ends, instead of many heap buffers the allocator would keep).
struct RunReader<'a> {
    file: File,
    path: PathBuf,
    buf: &'a mut [u8],
    pos: usize,
    end: usize,
    left: u64,
    rec: usize,
}

impl<'a> RunReader<'a> {
    fn open(run: &Run, rec: usize, buf: &'a mut [u8]) -> Result<RunReader<'a>> {
        let file = File::open(&run.path).ctx(&run.path, "open run file")?;
        Ok(RunReader { file, path: run.path.clone(), buf, pos: 0, end: 0, left: run.records, rec })
    }

    /// The current record, refilling when needed; None when the run is done.
    fn current(&mut self) -> Result<Option<&[u8]>> {
        if self.pos == self.end {
            if self.left == 0 {
                return Ok(None);
            }
            // Each refill is a safe point for signals.
            crate::io::signal::check()?;
            let want = ((self.left as usize).min(self.buf.len() / self.rec)) * self.rec;
            self.file.read_exact(&mut self.buf[..want]).ctx(&self.path, "read run file")?;
            self.pos = 0;
            self.end = want;
            self.left -= (want / self.rec) as u64;
        }
        Ok(Some(&self.buf[self.pos..self.pos + self.rec]))
    }
}

fn key_of(r: &[u8]) -> u64 {
    u64::from_le_bytes(r[..8].try_into().unwrap())
}

/// k-way merge of sorted runs. Ties go to the earlier run, which holds the
/// earlier-pushed records, so the merge is stable.
fn merge(runs: &[Run], rec: usize, buf_bytes: usize, mut out: impl FnMut(&[u8]) -> Result<()>) -> Result<()> {
    let per = (buf_bytes.max(MIN_RUN_BUF) / rec).max(1) * rec;
    let mut arena = vec![0u8; per * runs.len()];
    let mut readers = runs.iter().zip(arena.chunks_mut(per)).map(|(r, b)| RunReader::open(r, rec, b)).collect::<Result<Vec<_>>>()?;
    let mut heap = BinaryHeap::with_capacity(readers.len());
    for (i, r) in readers.iter_mut().enumerate() {
        if let Some(b) = r.current()? {
            heap.push(Reverse((key_of(b), i)));
        }
    }
    while let Some(Reverse((_, i))) = heap.pop() {
        let r = &mut readers[i];
        out(&r.buf[r.pos..r.pos + rec])?;
        r.pos += rec;
        // Drain this run while it stays the smallest: avoids heap traffic on presorted input.
        while let Some(b) = r.current()? {
            let k = key_of(b);
            match heap.peek() {
                Some(Reverse((top, j))) if (*top, *j) < (k, i) => {
                    heap.push(Reverse((k, i)));
                    break;
                }
                _ => {
                    out(&r.buf[r.pos..r.pos + rec])?;
                    r.pos += rec;
                }
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check(n: usize, mem: usize, fan: usize, key_range: u64) -> SortStats {
        let dir = tempfile::tempdir().unwrap();
        let mut s = ExtSorter::new("t", 12, mem, dir.path()).with_max_fan_in(fan).with_merge_mem(64 << 20);
        let mut rng = crate::geom::Rng::new(7);
        let mut expect = Vec::new();
        for i in 0..n as u32 {
            let k = (rng.next_u64() >> 33) % key_range;
            expect.push((k, i));
            s.push_with(|b| {
                b[..8].copy_from_slice(&k.to_le_bytes());
                b[8..].copy_from_slice(&i.to_le_bytes());
            })
            .unwrap();
        }
        expect.sort(); // stable by (key, push order)
        let mut got = Vec::new();
        let st = s
            .finish(|r| {
                got.push((key_of(r), u32::from_le_bytes(r[8..12].try_into().unwrap())));
                Ok(())
            })
            .unwrap();
        assert_eq!(got, expect);
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "scratch files left behind");
        assert_eq!(st.records, n as u64);
        st
    }

    #[test]
    fn in_memory_when_it_fits() {
        let st = check(10_000, 1 << 20, 1024, u64::MAX);
        assert_eq!((st.runs, st.merge_passes, st.spilled_bytes), (0, 0, 0));
    }

    #[test]
    fn single_merge_pass() {
        let st = check(10_000, 28 * 500, 1024, 1000);
        assert_eq!(st.runs, 20);
        assert_eq!(st.merge_passes, 1);
    }

    #[test]
    fn multi_pass_merge_is_exact_and_stable() {
        let st = check(5_000, 28 * 100, 3, 50);
        assert_eq!(st.runs, 50);
        // 50 runs, fan-in 3: 50 -> 17 -> 6 -> 2, then the final merge.
        assert_eq!(st.merge_passes, 4);
        assert!(st.spilled_bytes > 3 * 5_000 * 12);
    }

    #[test]
    fn merge_fan_in_follows_the_budget() {
        // 2 MiB of merge memory gives 8 runs of 256 KiB buffers per merge: 50 -> 7 -> final.
        let dir = tempfile::tempdir().unwrap();
        let mut s = ExtSorter::new("t", 12, 28 * 100, dir.path()).with_merge_mem(2 << 20);
        for i in 0..5_000u64 {
            s.push_with(|b| b[..8].copy_from_slice(&((i * 7919) % 5_000).to_le_bytes())).unwrap();
        }
        let mut last = 0;
        let st = s
            .finish(|r| {
                assert!(key_of(r) >= last);
                last = key_of(r);
                Ok(())
            })
            .unwrap();
        assert_eq!((st.runs, st.merge_passes), (50, 2));
    }

    #[test]
    fn empty_input() {
        let st = check(0, 1 << 10, 4, 10);
        assert_eq!(st.records, 0);
    }
}
