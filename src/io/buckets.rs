//! Distribution by dense keys through bucket files: records are appended
//! to the file of their key range, then each file is read back
//! sequentially and its records placed in memory ([`SlotBuckets`]) or
//! joined with a table slab (the soup's vertex slabs, an OBJ's corner
//! tables). Nothing is compared or merged; the disk is read and written in
//! sequence.
//!
//! Takes: fixed-size or varint-coded records and a byte budget. Gives:
//! [`BucketFiles`] (append per bucket, written behind the caller),
//! [`read_records`] and [`read_varying`], LEB128 varints ([`put_varint`],
//! [`get_varint`]), and [`SlotBuckets`] (records by dense slot, emitted in
//! slot order; its records delta-coded, as the soup's corner records: the
//! external path is bound by the bytes it writes, `docs/ply-and-soup.md`).

use super::{WriteBehind, SEQ_BUF};
use crate::error::{Error, IoContext, Location, Result};
use rayon::prelude::*;
use std::fs::File;
use std::io::Read;
use std::path::{Path, PathBuf};

/// Append-only bucket files of records of at most `rec` bytes (fixed:
/// [`BucketFiles::record`]; varying: [`BucketFiles::room`]), one write buffer of
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

    /// Room for a record of at most `max` bytes (at most the record size
    /// the files were made with) at the end of bucket `b`;
    /// [`BucketFiles::commit`] then says how many bytes it took.
    #[inline]
    pub(crate) fn room(&mut self, b: usize, max: usize) -> Result<&mut [u8]> {
        debug_assert!(max <= self.rec);
        if self.fill[b] + max > self.region {
            self.flush(b)?;
        }
        let at = self.fill[b];
        Ok(&mut self.bufs[b][at..at + max])
    }

    /// The record just written into [`BucketFiles::room`] took `len` bytes.
    #[inline]
    pub(crate) fn commit(&mut self, b: usize, len: usize) {
        self.counts[b] += 1;
        self.fill[b] += len;
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

/// Reads the `records` variable-length records of the file at `path`
/// (each at most `max_rec` bytes) through `chunk` (at least `max_rec`
/// bytes): `each` is given a record's index and the bytes from its start
/// (at least `max_rec` of them, or all that are left) and returns the
/// record's length. Gives the bytes read; an error naming the file when
/// it holds another number of records (a damaged scratch file).
pub(crate) fn read_varying(path: &Path, max_rec: usize, records: u64, chunk: &mut [u8], mut each: impl FnMut(u64, &[u8]) -> Result<usize>) -> Result<u64> {
    assert!(chunk.len() >= max_rec && max_rec > 0);
    let mut f = File::open(path).ctx(path, "open bucket file")?;
    let total = f.metadata().ctx(path, "read bucket file")?.len();
    let mut left = total;
    let (mut lo, mut hi, mut seen) = (0usize, 0usize, 0u64);
    loop {
        if left > 0 && hi - lo < max_rec {
            chunk.copy_within(lo..hi, 0);
            hi -= lo;
            lo = 0;
            let want = ((chunk.len() - hi) as u64).min(left) as usize;
            f.read_exact(&mut chunk[hi..hi + want]).ctx(path, "read bucket file")?;
            hi += want;
            left -= want as u64;
        }
        if lo == hi {
            break;
        }
        while lo < hi && (hi - lo >= max_rec || left == 0) {
            let n = each(seen, &chunk[lo..hi])?;
            debug_assert!(n > 0 && n <= hi - lo);
            lo += n;
            seen += 1;
        }
    }
    if seen != records {
        let at = Location { file: path.to_path_buf(), ..Default::default() };
        return Err(Error::input(at, format!("damaged scratch file: {seen} records read, {records} written")));
    }
    Ok(total)
}

/// A signed difference as an unsigned varint's value (zigzag: 0, -1, 1,
/// -2, ... as 0, 1, 2, 3, ...), so small differences of either sign are
/// short.
#[inline]
pub(crate) fn zigzag(d: i64) -> u64 {
    ((d << 1) ^ (d >> 63)) as u64
}

/// The difference [`zigzag`] coded.
#[inline]
pub(crate) fn unzigzag(z: u64) -> i64 {
    (z >> 1) as i64 ^ -((z & 1) as i64)
}

/// Writes `x` as a LEB128 varint (7 bits a byte, low first) at the start
/// of `out` (room for 10 bytes); gives its length.
#[inline]
pub(crate) fn put_varint(out: &mut [u8], mut x: u64) -> usize {
    if x < 0x80 {
        out[0] = x as u8;
        return 1;
    }
    let mut i = 0;
    while x >= 0x80 {
        out[i] = x as u8 | 0x80;
        x >>= 7;
        i += 1;
    }
    out[i] = x as u8;
    i + 1
}

/// The LEB128 varint at the start of `b` and its length; None when `b`
/// ends inside it or it runs past 10 bytes.
#[inline]
pub(crate) fn get_varint(b: &[u8]) -> Option<(u64, usize)> {
    match b.first() {
        Some(&c) if c < 0x80 => return Some((c as u64, 1)),
        None => return None,
        _ => {}
    }
    // Up to 8 bytes at once, without a branch per byte (a corner record's
    // index difference takes 1 to 3 bytes in no predictable order, and the
    // per-byte loop's exits were a fifth of phase 2's reading thread): the
    // first byte whose top bit is clear ends it; byte i's 7 bits go to bit
    // 7i. The same value and length as the loop below.
    if let Some(w) = b.get(..8) {
        let w = u64::from_le_bytes(w.try_into().expect("8 bytes"));
        let stops = !w & 0x8080_8080_8080_8080;
        if stops != 0 {
            let n = stops.trailing_zeros() / 8 + 1;
            let mut x = 0;
            for i in 0..8 {
                x |= (w >> i) & (0x7f << (7 * i));
            }
            return Some((x & ((1u64 << (7 * n)) - 1), n as usize));
        }
    }
    let mut x = 0u64;
    for (i, &c) in b.iter().enumerate().take(10) {
        x |= ((c & 0x7f) as u64) << (7 * i);
        if c < 0x80 {
            return Some((x, i + 1));
        }
    }
    None
}

/// The longest varint of a slot record's slot difference (33 bits).
const MAX_SLOT_VARINT: usize = 5;

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
    /// Buckets placed at once (one per thread of half the pool; two groups
    /// exist at once), each in its share of the placing memory.
    group: usize,
    /// Records, when spilling: the slot within the bucket as the zigzag
    /// varint of its difference from the bucket's previous record's (1 or
    /// 2 bytes where corners come in order; a fixed u32 took 4), then the
    /// vertex bytes.
    files: Option<BucketFiles>,
    /// Each bucket's last slot within it.
    prev: Vec<u32>,
    /// The single in-memory bucket, when everything fits.
    mem: Option<Vec<u8>>,
    placed: u64,
}

impl SlotBuckets {
    pub(crate) fn new(dir: &Path, name: &str, n_slots: u64, vsize: usize, place_mem: usize, write_mem: usize) -> Result<SlotBuckets> {
        let total = n_slots * vsize as u64;
        if total <= write_mem as u64 {
            let mem = Some(vec![0u8; total as usize]);
            return Ok(SlotBuckets { vsize, n_slots, per: n_slots.max(3), group: 1, files: None, prev: Vec::new(), mem, placed: 0 });
        }
        // Half the threads place a group of buckets while the caller takes
        // the previous group's triangles: two groups are in memory at once.
        let group = (rayon::current_num_threads() / 2).max(1);
        let per = ((place_mem / (2 * group) / vsize) as u64 / 3 * 3).clamp(3, u32::MAX as u64 / 3 * 3);
        let n = n_slots.div_ceil(per) as usize;
        let files = Some(BucketFiles::create(dir, name, n, MAX_SLOT_VARINT + vsize, write_mem)?);
        Ok(SlotBuckets { vsize, n_slots, per, group, files, prev: vec![0; n], mem: None, placed: 0 })
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
        let (b, i) = ((slot / self.per) as usize, (slot % self.per) as u32);
        let r = files.room(b, MAX_SLOT_VARINT + s)?;
        let d = i as i64 - self.prev[b] as i64;
        self.prev[b] = i;
        let n = put_varint(r, zigzag(d));
        r[n..n + s].copy_from_slice(vertex);
        files.commit(b, n + s);
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
        let rec = MAX_SLOT_VARINT + s;
        // Flush every bucket first: the write buffers must not sit in
        // memory beside the buckets being placed.
        let buckets = self.files.expect("slot buckets spill or place in memory").finish()?;
        // Their buffers, freed, back to the system before the placing.
        crate::mem::trim();
        // `group` buckets are placed at once (each read and placed by its
        // own thread) on a placing thread, while this one hands the group
        // before to `out`: placing and what the caller does with the
        // triangles (the build's routing to level 0's cells) overlap, and
        // at most two groups exist (the placer waits for the hand-over).
        let numbered: Vec<(usize, (PathBuf, u64))> = buckets.into_iter().enumerate().collect();
        let (per, n_slots, group) = (self.per, self.n_slots, self.group);
        // Buffers of written buckets, for the next ones (at most a group).
        let spare: std::sync::Mutex<Vec<Vec<u8>>> = std::sync::Mutex::new(Vec::new());
        let place = |(b, (path, records)): &(usize, (PathBuf, u64))| -> Result<(Vec<u8>, u64)> {
            let first = *b as u64 * per;
            let n = (n_slots - first).min(per) as usize;
            assert_eq!(*records, n as u64, "bucket {b} misses corners");
            let mut chunk = vec![0u8; SEQ_BUF.max(rec)];
            // One buffer per bucket, a written group's taken again: a new
            // one per bucket (tens of MB, past glibc's mmap threshold or
            // trimmed after each group) was faulted in page by page every
            // time, a third of a build's page faults.
            let mut placed = spare.lock().expect("placing buffers").pop().unwrap_or_default();
            placed.clear();
            placed.resize(n * s, 0);
            let mut prev = 0i64;
            let bytes = read_varying(path, rec, *records, &mut chunk, |k, c| {
                let bad = || {
                    Error::input(
                        Location { file: path.clone(), element: Some("slot record".into()), record: Some(k), ..Default::default() },
                        "damaged scratch slot record",
                    )
                };
                let (z, len) = get_varint(c).ok_or_else(bad)?;
                let i = prev + unzigzag(z);
                if !(0..n as i64).contains(&i) || c.len() < len + s {
                    return Err(bad());
                }
                prev = i;
                let i = i as usize;
                placed[i * s..(i + 1) * s].copy_from_slice(&c[len..len + s]);
                Ok(len + s)
            })?;
            let _ = std::fs::remove_file(path);
            Ok((placed, bytes))
        };
        std::thread::scope(|sc| -> Result<()> {
            let (tx, rx) = std::sync::mpsc::sync_channel::<Vec<Result<(Vec<u8>, u64)>>>(0);
            sc.spawn(move || {
                for g in numbered.chunks(group) {
                    let placed: Vec<Result<(Vec<u8>, u64)>> = g.par_iter().map(place).collect();
                    if tx.send(placed).is_err() {
                        break; // the caller stopped
                    }
                }
            });
            for placed in rx {
                for p in placed {
                    let (p, bytes) = p?;
                    spilled += bytes;
                    out(&p)?;
                    spare.lock().expect("placing buffers").push(p);
                }
                // The group's other buffers (its read chunks) are freed;
                // below glibc's mmap threshold (it grows to 32 MiB) they
                // stay in the heap and arenas, and the next group's come
                // beside them: a 2 × 10^7 soup at --mem 64M peaked at 86
                // MiB without this, 63.7 with it.
                crate::mem::trim();
            }
            Ok(())
        })?;
        Ok(spilled)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn varints_read_eight_at_once_as_byte_by_byte() {
        // Every length 1..=10, with and without bytes after the varint (the
        // eight-byte path needs eight readable bytes).
        let mut b = [0xffu8; 24];
        for bits in 0..64 {
            for x in [1u64 << bits, (1u64 << bits) - 1, (1u64 << bits) | 0x55, u64::MAX >> bits] {
                let n = put_varint(&mut b, x);
                for tail in [0usize, 3, 12] {
                    assert_eq!(get_varint(&b[..n + tail]), Some((x, n)), "{x} with {tail} bytes after");
                }
            }
        }
        // Eleven continuation bytes: too long either way.
        assert_eq!(get_varint(&[0x80; 16]), None);
    }

    #[test]
    fn varints_round_trip_and_cut_ones_are_refused() {
        let mut b = [0u8; 10];
        for x in [0u64, 1, 127, 128, 300, u32::MAX as u64, u32::MAX as u64 + 1, u64::MAX] {
            let n = put_varint(&mut b, x);
            assert_eq!(get_varint(&b[..n]), Some((x, n)), "{x}");
            assert_eq!(get_varint(&b[..n - 1]), None, "{x} cut");
        }
        assert_eq!(put_varint(&mut b, u64::MAX), 10);
    }

    #[test]
    fn varying_records_straddling_chunks_are_read_whole() {
        let d = tempfile::tempdir().unwrap();
        let mut files = BucketFiles::create(d.path(), "v", 2, 10, 8 << 10).unwrap();
        let xs: Vec<u64> = (0..20_000u64).map(|i| (i * 2_654_435_761) >> (i % 60)).collect();
        for (i, &x) in xs.iter().enumerate() {
            let r = files.room(i % 2, 10).unwrap();
            let n = put_varint(r, x);
            files.commit(i % 2, n);
        }
        let buckets = files.finish().unwrap();
        for (b, (path, records)) in buckets.iter().enumerate() {
            assert_eq!(*records, 10_000);
            let mut got = Vec::new();
            // A chunk of 13 bytes: most records straddle two reads.
            let mut chunk = vec![0u8; 13];
            let bytes = read_varying(path, 10, *records, &mut chunk, |_, r| {
                let (x, n) = get_varint(r).unwrap();
                got.push(x);
                Ok(n)
            })
            .unwrap();
            assert_eq!(bytes, std::fs::metadata(path).unwrap().len());
            let want: Vec<u64> = xs.iter().skip(b).step_by(2).copied().collect();
            assert_eq!(got, want);
            // A count the file does not hold is a damaged file.
            let e = read_varying(path, 10, *records + 1, &mut chunk, |_, r| Ok(get_varint(r).unwrap().1)).unwrap_err();
            assert!(e.to_string().contains("10000 records read, 10001 written"), "{e}");
        }
    }

    #[test]
    fn zigzag_round_trips_small_differences_short() {
        for d in [0i64, -1, 1, -2, 63, -64, i64::MAX, i64::MIN] {
            assert_eq!(unzigzag(zigzag(d)), d);
        }
        assert_eq!([0, -1, 1, -2].map(zigzag), [0, 1, 2, 3]);
    }
}
