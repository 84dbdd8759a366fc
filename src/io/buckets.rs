//! Distribution by dense keys through bucket files: records are appended
//! to the file of their key range, then each file is read back
//! sequentially and its records placed in memory ([`SlotBuckets`]) or
//! joined with a table slab (the soup's vertex slabs, an OBJ's corner
//! tables). Nothing is compared or merged; the disk is read and written in
//! sequence.
//!
//! Takes: fixed-size records and a byte budget. Gives: [`BucketFiles`]
//! (append per bucket, written behind the caller), [`read_records`], and
//! [`SlotBuckets`] (records by dense slot, emitted in slot order).

use super::{WriteBehind, SEQ_BUF};
use crate::error::{IoContext, Result};
use rayon::prelude::*;
use std::fs::File;
use std::io::Read;
use std::path::{Path, PathBuf};

/// Append-only bucket files of fixed-size records, one write buffer of
/// `region` bytes per bucket, filled up to `fill[b]`; a full buffer is
/// written behind ([`WriteBehind`]: the kernel's copy runs on another core
/// while the next records are made) and replaced by an empty one.
pub(crate) struct BucketFiles {
    rec: usize,
    paths: Vec<PathBuf>,
    bufs: Vec<Vec<u8>>,
    region: usize,
    fill: Vec<usize>,
    /// Records per bucket.
    counts: Vec<u64>,
    writer: WriteBehind,
}

/// Buffers in flight to a bucket set's writer.
const WRITE_DEPTH: usize = 4;

impl BucketFiles {
    /// `n` files named `{name}-{b}.bin` in `dir`, with write buffers of
    /// about `mem` bytes in all (at least 4 KiB, at most [`SEQ_BUF`] each).
    pub(crate) fn create(dir: &Path, name: &str, n: usize, rec: usize, mem: usize) -> Result<BucketFiles> {
        let region = ((mem / n.max(1)).clamp(4 << 10, SEQ_BUF) / rec).max(1) * rec;
        let mut files = Vec::with_capacity(n);
        for b in 0..n {
            let path = dir.join(format!("{name}-{b:05}.bin"));
            let f = File::create(&path).ctx(&path, "create bucket file")?;
            files.push((path, f));
        }
        let paths = files.iter().map(|f| f.0.clone()).collect();
        Ok(BucketFiles {
            rec,
            paths,
            bufs: (0..n).map(|_| vec![0u8; region]).collect(),
            region,
            fill: vec![0; n],
            counts: vec![0; n],
            writer: WriteBehind::new(files, WRITE_DEPTH, "write bucket file"),
        })
    }

    pub(crate) fn len(&self) -> usize {
        self.paths.len()
    }

    /// Bytes of the write buffers in the caller's hands (those in flight to
    /// the writer add at most [`WRITE_DEPTH`] more).
    pub(crate) fn buffer_bytes(&self) -> u64 {
        (self.region * self.len()) as u64
    }

    /// The bytes of a new record appended to bucket `b`, to be filled.
    #[inline]
    pub(crate) fn record(&mut self, b: usize) -> Result<&mut [u8]> {
        if self.fill[b] + self.rec > self.region {
            self.flush(b)?;
        }
        self.counts[b] += 1;
        let at = self.fill[b];
        self.fill[b] += self.rec;
        Ok(&mut self.bufs[b][at..at + self.rec])
    }

    fn flush(&mut self, b: usize) -> Result<()> {
        if self.fill[b] > 0 {
            let full = std::mem::take(&mut self.bufs[b]);
            self.bufs[b] = self.writer.write(b, full, self.fill[b])?;
            self.fill[b] = 0;
        }
        Ok(())
    }

    /// Writes out every buffer and frees them; gives each bucket's path and record count.
    pub(crate) fn finish(self) -> Result<Vec<(PathBuf, u64)>> {
        let BucketFiles { paths, bufs, fill, counts, mut writer, .. } = self;
        for (b, buf) in bufs.into_iter().enumerate() {
            writer.write_last(b, buf, fill[b])?;
        }
        writer.finish()?;
        Ok(paths.into_iter().zip(counts).collect())
    }
}

/// Reads `records` records of `rec` bytes from `path` through `chunk` (a
/// multiple of `rec` bytes) and hands each to `each`.
pub(crate) fn read_records(path: &Path, rec: usize, records: u64, chunk: &mut [u8], mut each: impl FnMut(&[u8]) -> Result<()>) -> Result<()> {
    let mut f = File::open(path).ctx(path, "open bucket file")?;
    let mut left = records * rec as u64;
    while left > 0 {
        let want = (left as usize).min(chunk.len());
        f.read_exact(&mut chunk[..want]).ctx(path, "read bucket file")?;
        for r in chunk[..want].chunks_exact(rec) {
            each(r)?;
        }
        left -= want as u64;
    }
    Ok(())
}

/// Phases 2–3 of the external path: a one-pass distribution sort by slot.
///
/// Slots are dense (0..3·triangles), so instead of a comparison sort the
/// joined corners are appended to bucket files, each covering a slot range
/// whose vertex bytes fit the budget; each bucket is then read back
/// sequentially, its corners placed at their slot in memory, and written out
/// in order. When all corners fit in half the budget no file is written.
pub(crate) struct SlotBuckets {
    vsize: usize,
    n_slots: u64,
    /// Slots per bucket (a multiple of 3, so no triangle straddles two buckets).
    per: u64,
    /// Buckets placed at once (one per thread), each in its share of the placing memory.
    group: usize,
    /// Records (slot within the bucket: u32, vertex bytes), when spilling.
    files: Option<BucketFiles>,
    /// The single in-memory bucket, when everything fits.
    mem: Option<Vec<u8>>,
    placed: u64,
}

impl SlotBuckets {
    pub(crate) fn new(dir: &Path, name: &str, n_slots: u64, vsize: usize, place_mem: usize, write_mem: usize) -> Result<SlotBuckets> {
        let total = n_slots * vsize as u64;
        if total <= write_mem as u64 {
            let mem = Some(vec![0u8; total as usize]);
            return Ok(SlotBuckets { vsize, n_slots, per: n_slots.max(3), group: 1, files: None, mem, placed: 0 });
        }
        let group = rayon::current_num_threads().max(1);
        let per = ((place_mem / group / vsize) as u64 / 3 * 3).clamp(3, u32::MAX as u64 / 3 * 3);
        let n = n_slots.div_ceil(per) as usize;
        let files = Some(BucketFiles::create(dir, name, n, 4 + vsize, write_mem)?);
        Ok(SlotBuckets { vsize, n_slots, per, group, files, mem: None, placed: 0 })
    }

    /// Bucket files (0: placed in memory).
    pub(crate) fn len(&self) -> u64 {
        self.files.as_ref().map_or(0, |f| f.len() as u64)
    }

    #[inline]
    pub(crate) fn push(&mut self, slot: u64, vertex: &[u8]) -> Result<()> {
        let s = self.vsize;
        if let Some(m) = &mut self.mem {
            m[slot as usize * s..(slot as usize + 1) * s].copy_from_slice(vertex);
            self.placed += 1;
            return Ok(());
        }
        let files = self.files.as_mut().expect("slot buckets spill or place in memory");
        let r = files.record((slot / self.per) as usize)?;
        r[..4].copy_from_slice(&((slot % self.per) as u32).to_le_bytes());
        r[4..].copy_from_slice(vertex);
        Ok(())
    }

    /// Emits every triangle (3 corners) in slot order, several at a time;
    /// returns bytes spilled to bucket files.
    pub(crate) fn finish(self, mut out: impl FnMut(&[u8]) -> Result<()>) -> Result<u64> {
        let s = self.vsize;
        if let Some(m) = self.mem {
            debug_assert_eq!(self.placed, self.n_slots);
            out(&m)?;
            return Ok(0);
        }
        let mut spilled = 0;
        let rec = 4 + s;
        // Flush every bucket first: the write buffers must not sit in
        // memory beside the buckets being placed.
        let buckets = self.files.expect("slot buckets spill or place in memory").finish()?;
        // Their buffers, freed, back to the system before the placing.
        crate::mem::trim();
        // `group` buckets are placed at once (each read and placed by its
        // own thread), then written out in order.
        let numbered: Vec<(usize, (PathBuf, u64))> = buckets.into_iter().enumerate().collect();
        for group in numbered.chunks(self.group) {
            let placed: Vec<Result<Vec<u8>>> = group
                .par_iter()
                .map(|(b, (path, records))| {
                    let first = *b as u64 * self.per;
                    let n = (self.n_slots - first).min(self.per) as usize;
                    assert_eq!(*records, n as u64, "bucket {b} misses corners");
                    let mut chunk = vec![0u8; (SEQ_BUF / rec).max(1) * rec];
                    // A single large allocation per bucket, freed once written.
                    let mut placed = vec![0u8; n * s];
                    read_records(path, rec, *records, &mut chunk, |c| {
                        let i = u32::from_le_bytes(c[..4].try_into().unwrap()) as usize;
                        placed[i * s..(i + 1) * s].copy_from_slice(&c[4..]);
                        Ok(())
                    })?;
                    let _ = std::fs::remove_file(path);
                    Ok(placed)
                })
                .collect();
            for p in placed {
                let p = p?;
                spilled += (p.len() / s * rec) as u64;
                out(&p)?;
            }
            // The group's buffers are freed; below glibc's mmap threshold
            // (it grows to 32 MiB) they stay in the heap and arenas, and the
            // next group's come beside them: a 2 × 10^7 soup at --mem 64M
            // peaked at 86 MiB without this, 63.7 with it.
            crate::mem::trim();
        }
        Ok(spilled)
    }
}
