//! File plumbing shared by the stages.
//!
//! * [`output`]: outputs that appear under their final name only when
//!   complete ([`AtomicFile`], [`AtomicDir`], [`AtomicGltfPair`]) and the
//!   rules of what may be replaced (`--force`, [`protect`]ed inputs, foreign
//!   files).
//! * [`temp`]: locked temp and scratch paths next to the output
//!   ([`ScratchDir`]), and the sweep of dead runs' leftovers.
//! * [`signal`]: SIGINT/SIGTERM/SIGHUP stop work at safe points.
//! * `buckets`: distribution by dense keys through bucket files (the
//!   soup's slabs and slots, an OBJ's corners out of core).
//! * Here: large sequential buffers, and scratch writers that write behind
//!   the caller on another thread ([`WriteBehind`], [`FileWriteBehind`]:
//!   the soup's buckets and the levels' chunks, whose page-cache copies took
//!   a third of the soup's time on the calling thread).

pub(crate) mod buckets;
pub(crate) mod relay;
mod seq;
pub(crate) use seq::SeqInput;
pub mod output;
pub mod signal;
pub mod temp;

pub use output::{
    check_output, gltf_bin_path, is_octolod_gltf, protect, AtomicDir, AtomicFile, AtomicGltfPair, OutputKind, Protected, FRAMES_MARKER, GLTF_MARK_KEY,
    GLTF_MARK_VALUE, PLY_MARK, SHARD_MAGIC, SOUP_MAGIC, STORE_MAGIC, TILES_MARKER,
};
pub use temp::{parent_dir, remove_stale_temps, scratch_dir, scratch_in, ScratchDir};

use crate::error::{Error, IoContext, Result};
use std::fs::File;
use std::io::Write;
use std::path::PathBuf;
use std::sync::Mutex;

/// Opens `path` for reading, refusing what is not a regular file (see
/// [`regular_file_len`]); gives the file and its length. The open itself
/// does not wait: a FIFO with no writer is refused, not waited on.
pub fn open_regular(path: &std::path::Path, op: &'static str) -> Result<(File, u64)> {
    use std::os::unix::fs::OpenOptionsExt;
    let f = std::fs::OpenOptions::new().read(true).custom_flags(libc::O_NONBLOCK).open(path).ctx(path, op)?;
    let len = regular_file_len(path, &f)?;
    // A regular file reads the same either way; clear the flag all the same.
    // SAFETY: fcntl on an open descriptor.
    unsafe {
        use std::os::unix::io::AsRawFd;
        let fl = libc::fcntl(f.as_raw_fd(), libc::F_GETFL);
        libc::fcntl(f.as_raw_fd(), libc::F_SETFL, fl & !libc::O_NONBLOCK);
    }
    Ok((f, len))
}

/// The whole of regular file `path`, refused (naming it as `what`, e.g.
/// "a manifest") when it is longer than `max` bytes, which are all that is
/// read: small metadata files (manifests, plans, shard states).
pub fn read_bounded(path: &std::path::Path, max: u64, what: &str) -> Result<Vec<u8>> {
    use std::io::Read;
    let (f, len) = open_regular(path, "open")?;
    if len > max {
        return Err(crate::error::Error::input(
            crate::error::Location { file: path.to_path_buf(), ..Default::default() },
            format!("{what} of {len} bytes (at most {max} are read)"),
        ));
    }
    let mut b = Vec::with_capacity(len as usize);
    f.take(max).read_to_end(&mut b).ctx(path, "read")?;
    Ok(b)
}

/// The length of `f` (opened from `path`), refusing what is not a regular
/// file: a FIFO, a device (`/dev/zero`) or a directory would hang, never
/// end, or fail late, since inputs and stores are read more than once and
/// by position.
pub fn regular_file_len(path: &std::path::Path, f: &File) -> Result<u64> {
    use std::os::unix::fs::FileTypeExt;
    let m = f.metadata().ctx(path, "stat")?;
    if m.is_file() {
        return Ok(m.len());
    }
    let t = m.file_type();
    let what = if t.is_fifo() {
        "a FIFO (named pipe)"
    } else if t.is_dir() {
        "a directory"
    } else if t.is_char_device() || t.is_block_device() {
        "a device"
    } else if t.is_socket() {
        "a socket"
    } else {
        "something else"
    };
    Err(Error::input(
        crate::error::Location { file: path.to_path_buf(), ..Default::default() },
        format!("is {what}, not a regular file: octolod reads its inputs more than once and by position (save it to a file first)"),
    ))
}

/// Buffer size for large sequential reads and writes.
pub const SEQ_BUF: usize = 1 << 20;

/// Writes behind the caller: filled buffers are handed to one writer
/// thread, which appends them to their files (the kernel's copy into the
/// page cache then runs on another core, beside the caller's work), and
/// come back to be filled again. Each file gets its buffers in the order
/// they were handed over. At most `depth` buffers are in flight.
pub struct WriteBehind {
    tx: Option<std::sync::mpsc::SyncSender<(usize, Vec<u8>, usize)>>,
    /// (In a mutex only so that a holder can be shared between threads.)
    back: Mutex<std::sync::mpsc::Receiver<Vec<u8>>>,
    thread: Option<std::thread::JoinHandle<Result<()>>>,
    /// Buffers that may still be allocated rather than waited for.
    fresh: usize,
}

impl WriteBehind {
    /// Writes to `files` (with their paths, for errors, and `what` is
    /// written, e.g. "write bucket file").
    pub fn new(files: Vec<(PathBuf, File)>, depth: usize, what: &'static str) -> WriteBehind {
        let depth = depth.max(1);
        let (tx, rx) = std::sync::mpsc::sync_channel::<(usize, Vec<u8>, usize)>(depth);
        let (back_tx, back) = std::sync::mpsc::channel();
        let thread = std::thread::spawn(move || {
            let mut files = files;
            for (f, buf, len) in rx {
                let (path, file) = &mut files[f];
                file.write_all(&buf[..len]).ctx(path, what)?;
                let _ = back_tx.send(buf);
            }
            Ok(())
        });
        WriteBehind { tx: Some(tx), back: Mutex::new(back), thread: Some(thread), fresh: depth }
    }

    /// Appends `buf[..len]` to file `f`; gives a buffer of `buf`'s length
    /// to fill next (a returned one, or a new one while fewer than `depth`
    /// are in flight).
    pub fn write(&mut self, f: usize, buf: Vec<u8>, len: usize) -> Result<Vec<u8>> {
        let size = buf.len();
        self.write_last(f, buf, len)?;
        if self.fresh > 0 {
            self.fresh -= 1;
            return Ok(vec![0u8; size]);
        }
        let back = self.back.get_mut().unwrap_or_else(|e| e.into_inner()).recv();
        match back {
            Ok(b) => Ok(b),
            Err(_) => Err(self.stop()),
        }
    }

    /// Appends `buf[..len]` to file `f`, wanting no buffer back (the last
    /// of a file; [`WriteBehind::write`] then asks for one).
    pub fn write_last(&mut self, f: usize, buf: Vec<u8>, len: usize) -> Result<()> {
        if self.tx.as_ref().expect("writer finished").send((f, buf, len)).is_err() {
            return Err(self.stop());
        }
        Ok(())
    }

    /// Waits for every write; the first error, if any.
    pub fn finish(mut self) -> Result<()> {
        self.tx = None;
        match self.thread.take().map(|t| t.join()) {
            Some(Ok(r)) => r,
            Some(Err(p)) => std::panic::resume_unwind(p),
            None => Ok(()),
        }
    }

    /// The writer stopped early: its error.
    fn stop(&mut self) -> Error {
        self.tx = None;
        match self.thread.take().map(|t| t.join()) {
            Some(Ok(Err(e))) => e,
            Some(Err(p)) => std::panic::resume_unwind(p),
            _ => Error::Usage("the background writer stopped".into()),
        }
    }
}

/// A sequential file written behind the caller ([`WriteBehind`]) through
/// [`SEQ_BUF`]-sized buffers: a `BufWriter` whose writes run on another thread.
pub struct FileWriteBehind {
    buf: Vec<u8>,
    fill: usize,
    w: WriteBehind,
}

impl FileWriteBehind {
    pub fn new(path: PathBuf, file: File, what: &'static str) -> FileWriteBehind {
        FileWriteBehind { buf: vec![0u8; SEQ_BUF], fill: 0, w: WriteBehind::new(vec![(path, file)], 2, what) }
    }

    pub fn write_all(&mut self, mut bytes: &[u8]) -> Result<()> {
        while !bytes.is_empty() {
            let n = bytes.len().min(self.buf.len() - self.fill);
            self.buf[self.fill..self.fill + n].copy_from_slice(&bytes[..n]);
            self.fill += n;
            bytes = &bytes[n..];
            if self.fill == self.buf.len() {
                let full = std::mem::take(&mut self.buf);
                self.buf = self.w.write(0, full, self.fill)?;
                self.fill = 0;
            }
        }
        Ok(())
    }

    /// Writes what is buffered and waits for every write.
    pub fn finish(mut self) -> Result<()> {
        let last = std::mem::take(&mut self.buf);
        self.w.write_last(0, last, self.fill)?;
        self.w.finish()
    }
}

impl Drop for WriteBehind {
    fn drop(&mut self) {
        // Not finished (an error elsewhere): let the writer end before the
        // files are removed.
        self.tx = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Raises this process's soft limit of open files to its hard limit (as
/// Go's runtime does): a store merged from many shards opens one pack part
/// per shard and level (`store::Store::open` keeps every pack open), more
/// than the usual soft limit of 1024 with a thousand shards.
pub fn raise_open_files() {
    let mut r = libc::rlimit { rlim_cur: 0, rlim_max: 0 };
    // SAFETY: getrlimit/setrlimit read and write the struct passed only.
    unsafe {
        if libc::getrlimit(libc::RLIMIT_NOFILE, &mut r) == 0 && r.rlim_cur < r.rlim_max {
            r.rlim_cur = r.rlim_max;
            libc::setrlimit(libc::RLIMIT_NOFILE, &r);
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use std::fs;

    /// The sorted names in directory `d`.
    pub(crate) fn names(d: &std::path::Path) -> Vec<String> {
        let mut v: Vec<String> = fs::read_dir(d).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        v.sort();
        v
    }

    #[test]
    fn writes_behind_land_in_order_and_their_errors_name_the_file() {
        let d = tempfile::tempdir().unwrap();
        let (a, b) = (d.path().join("a.bin"), d.path().join("b.bin"));
        let files = vec![(a.clone(), File::create(&a).unwrap()), (b.clone(), File::create(&b).unwrap())];
        let mut w = WriteBehind::new(files, 2, "write test file");
        let mut buf = vec![0u8; 4];
        for i in 0..10u8 {
            buf.fill(i);
            buf = w.write((i % 2) as usize, buf, 1 + (i % 4) as usize).unwrap();
            assert_eq!(buf.len(), 4);
        }
        w.write_last(1, vec![9; 4], 2).unwrap();
        w.finish().unwrap();
        let want = |k: u8| (0..10u8).filter(|i| i % 2 == k).flat_map(|i| std::iter::repeat_n(i, 1 + (i % 4) as usize)).collect::<Vec<u8>>();
        assert_eq!(fs::read(&a).unwrap(), want(0));
        assert_eq!(fs::read(&b).unwrap(), [want(1), vec![9, 9]].concat());

        // A file that cannot be written: the error comes back, naming it.
        let ro = File::open(&a).unwrap();
        let mut w = FileWriteBehind::new(a.clone(), ro, "write test file");
        let r = w.write_all(&vec![1u8; 3 * SEQ_BUF]).and_then(|_| w.finish());
        let e = r.expect_err("writing a read-only handle must fail").to_string();
        assert!(e.contains("a.bin") && e.contains("write test file"), "{e}");
    }
}
