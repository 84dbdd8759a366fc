//! File plumbing shared by the stages: outputs that appear under their final
//! name only when complete ([`AtomicFile`], [`AtomicDir`]), scratch
//! directories next to the output ([`ScratchDir`]), large sequential
//! buffers, and scratch writers that write behind the caller on another
//! thread ([`WriteBehind`], [`FileWriteBehind`]: the soup's buckets and the
//! levels' chunks, whose page-cache copies took a third of the soup's
//! time on the calling thread).
//!
//! Takes: a final path, the [`OutputKind`] written there and whether the
//! user allowed replacing (`--force`). Gives: a temp path in the same
//! directory that is renamed into place on `commit()` and deleted if dropped
//! uncommitted, so a failed or interrupted run never leaves partial output
//! pretending to be complete.
//!
//! Data safety rules (README "What octolod promises"):
//! * An existing path is replaced only when it is a complete octolod output
//!   of the same kind ([`OutputKind::recognise`]) **and** `force` is set;
//!   anything else that exists is refused before any work starts. A store is
//!   swapped in with one `renameat2(RENAME_EXCHANGE)`, so the final name
//!   always holds a complete store.
//! * Temp and scratch paths are named `.NAME.octolod-tmp-PID-START-N` (START:
//!   the owner's start time in clock ticks since boot, so a reused PID is not
//!   mistaken for the owner). Creating one first removes the stale ones in
//!   the same directory whose owner process is gone (killed with SIGKILL, or
//!   a crash), and every live one is listed in a process-wide registry that
//!   [`remove_live_temps`] empties — the binaries call it on SIGINT, SIGTERM
//!   and SIGHUP before exiting.

use crate::error::{Error, IoContext, Result};
use std::fs::{self, File};
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

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

/// The marker between a temp path's name and its owner.
const TMP_TAG: &str = ".octolod-tmp-";

/// What a command writes at its final path.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutputKind {
    /// A store directory (`nodes.bin` starting with the store magic).
    Store,
    /// A PLY file whose header carries a comment starting with `octolod`.
    Ply,
    /// A triangle soup file (soup magic).
    Soup,
    /// A `render` output directory (holds the `.octolod-render` marker).
    Frames,
    /// A file inside one of our own temp directories (never pre-exists).
    Inner,
}

/// The first bytes of a store's `nodes.bin` ([`crate::store::MAGIC`]):
/// defined here, where outputs are recognised, so this module needs no
/// format module (they all build on it).
pub const STORE_MAGIC: [u8; 8] = *b"OCTLODIX";
/// The first bytes of a triangle soup ([`crate::soup::format::MAGIC`]).
pub const SOUP_MAGIC: [u8; 8] = *b"OCTSOUP\0";

/// The marker file every `render` output directory holds.
pub const FRAMES_MARKER: &str = ".octolod-render";

impl OutputKind {
    pub fn describe(self) -> &'static str {
        match self {
            OutputKind::Store => "an octolod store",
            OutputKind::Ply => "a PLY written by octolod",
            OutputKind::Soup => "an octolod triangle soup",
            OutputKind::Frames => "an octolod render directory",
            OutputKind::Inner => "an octolod file",
        }
    }

    /// Whether `p` is a complete output of this kind.
    pub fn recognise(self, p: &Path) -> bool {
        let head = |p: &Path, n: usize| -> Option<Vec<u8>> {
            let mut b = Vec::with_capacity(n);
            File::open(p).ok()?.take(n as u64).read_to_end(&mut b).ok()?;
            Some(b)
        };
        match self {
            OutputKind::Store => {
                p.is_dir() && head(&p.join("nodes.bin"), 8).is_some_and(|b| b == STORE_MAGIC)
            }
            OutputKind::Soup => p.is_file() && head(p, 8).is_some_and(|b| b == SOUP_MAGIC),
            OutputKind::Frames => p.is_dir() && p.join(FRAMES_MARKER).is_file(),
            OutputKind::Ply => {
                if !p.is_file() {
                    return false;
                }
                let Some(b) = head(p, 64 << 10) else { return false };
                let text = String::from_utf8_lossy(&b);
                let mut lines = text.lines();
                lines.next().map(str::trim_end) == Some("ply")
                    && lines
                        .take_while(|l| l.trim_end() != "end_header")
                        .any(|l| l.strip_prefix("comment ").is_some_and(|c| c.starts_with("octolod")))
            }
            OutputKind::Inner => false,
        }
    }
}

/// Refuses `dest` unless it is free, or a complete output of `kind` and
/// `force` is set. Call before any work starts.
pub fn check_output(dest: &Path, kind: OutputKind, force: bool) -> Result<()> {
    let Ok(meta) = fs::symlink_metadata(dest) else { return Ok(()) };
    let what = if meta.is_dir() { "a directory" } else if meta.is_file() { "a file" } else { "something else" };
    if kind.recognise(dest) && !meta.file_type().is_symlink() {
        if force {
            return Ok(());
        }
        return Err(Error::Usage(format!(
            "{} already exists ({}); pass --force to replace it",
            dest.display(),
            kind.describe()
        )));
    }
    Err(Error::Usage(format!(
        "{} already exists and is {what} that is not {}; refusing to replace it (remove it yourself or choose another output path)",
        dest.display(),
        kind.describe()
    )))
}

/// This process's start time (clock ticks since boot), 0 when unknown.
fn own_start() -> u64 {
    static START: std::sync::OnceLock<u64> = std::sync::OnceLock::new();
    *START.get_or_init(|| process_start(std::process::id()).unwrap_or(0))
}

/// Field 22 of `/proc/PID/stat`: the start time in clock ticks since boot.
fn process_start(pid: u32) -> Option<u64> {
    let s = fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // The command name (field 2) may hold spaces; it ends at the last ')'.
    let rest = &s[s.rfind(')')? + 1..];
    rest.split_whitespace().nth(19)?.parse().ok()
}

/// Whether the owner (pid, start) of a temp path is gone. Unknown (no
/// /proc) counts as alive: never delete what might be in use.
fn owner_gone(pid: u32, start: u64) -> bool {
    if !Path::new("/proc/self/stat").exists() {
        return false;
    }
    match process_start(pid) {
        None => true,
        Some(s) => start != 0 && s != start,
    }
}

/// The owner of a temp name (`...octolod-tmp-PID-START-N`), if it is one.
fn temp_owner(name: &str) -> Option<(u32, u64)> {
    let at = name.rfind(TMP_TAG)?;
    let mut f = name[at + TMP_TAG.len()..].split('-');
    let (pid, start, n) = (f.next()?.parse().ok()?, f.next()?.parse().ok()?, f.next()?);
    if f.next().is_some() || n.parse::<u64>().is_err() {
        return None;
    }
    Some((pid, start))
}

/// Removes the temp and scratch paths in `dir` whose owner process is
/// gone. Returns how many were removed.
pub fn remove_stale_temps(dir: &Path) -> usize {
    let Ok(entries) = fs::read_dir(dir) else { return 0 };
    let mut n = 0;
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some((pid, start)) = temp_owner(&name) else { continue };
        if !name.starts_with('.') || !owner_gone(pid, start) {
            continue;
        }
        if remove_path(&e.path()) {
            n += 1;
        }
    }
    n
}

fn remove_path(p: &Path) -> bool {
    match fs::symlink_metadata(p) {
        Ok(m) if m.is_dir() => fs::remove_dir_all(p).is_ok(),
        Ok(_) => fs::remove_file(p).is_ok(),
        Err(_) => false,
    }
}

/// Temp paths this process owns now (removed by [`remove_live_temps`]).
static LIVE: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

fn register(p: &Path) {
    LIVE.lock().unwrap_or_else(|e| e.into_inner()).push(p.to_path_buf());
}

fn unregister(p: &Path) {
    let mut l = LIVE.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(i) = l.iter().rposition(|x| x == p) {
        l.swap_remove(i);
    }
}

/// Removes every temp and scratch path this process owns (for signal
/// handlers: call, then exit). Worker threads may still be writing into a
/// temp directory, so a directory is retried a few times.
pub fn remove_live_temps() {
    let paths: Vec<PathBuf> = std::mem::take(&mut *LIVE.lock().unwrap_or_else(|e| e.into_inner()));
    for p in paths {
        for _ in 0..5 {
            if remove_path(&p) || fs::symlink_metadata(&p).is_err() {
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
    }
}

/// On SIGINT, SIGTERM or SIGHUP: remove this process's temp and scratch
/// paths, then exit with 128 + the signal number, as a shell reports a
/// killed command. For binaries, called once at start.
pub fn clean_up_on_signals() {
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    if let Ok(mut signals) = signal_hook::iterator::Signals::new([SIGINT, SIGTERM, SIGHUP]) {
        std::thread::spawn(move || {
            if let Some(sig) = signals.forever().next() {
                SIGNALLED.store(sig, std::sync::atomic::Ordering::SeqCst);
                remove_live_temps();
                std::process::exit(128 + sig);
            }
        });
    }
}

/// The signal being handled by [`clean_up_on_signals`] (0: none).
static SIGNALLED: std::sync::atomic::AtomicI32 = std::sync::atomic::AtomicI32::new(0);

/// For a binary's error exit: when a signal is being handled, its handler
/// is removing the temp paths and will exit with 128 + the signal, and the
/// error is only work finding its files gone: wait for that exit rather
/// than report the error and exit 1 first. Returns at once otherwise.
pub fn yield_to_signal_handler() {
    if SIGNALLED.load(std::sync::atomic::Ordering::SeqCst) != 0 {
        loop {
            std::thread::park();
        }
    }
}

/// A fresh temp name next to `final_path`, after removing stale ones there.
fn temp_sibling(final_path: &Path) -> PathBuf {
    let name = final_path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "out".into());
    let dir = parent_dir(final_path);
    remove_stale_temps(&dir);
    dir.join(format!(".{name}{TMP_TAG}{}-{}-{}", std::process::id(), own_start(), unique()))
}

fn unique() -> u64 {
    use std::sync::atomic::{AtomicU64, Ordering};
    static N: AtomicU64 = AtomicU64::new(0);
    N.fetch_add(1, Ordering::Relaxed)
}

/// The directory a path lives in (`.` for a bare file name).
pub fn parent_dir(p: &Path) -> PathBuf {
    match p.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

fn ensure_parent(dest: &Path) -> Result<()> {
    let dir = parent_dir(dest);
    fs::create_dir_all(&dir).ctx(&dir, "create output directory")
}

/// Swaps two paths atomically (Linux `renameat2(RENAME_EXCHANGE)`).
#[cfg(target_os = "linux")]
fn exchange(a: &Path, b: &Path) -> std::io::Result<()> {
    use std::ffi::CString;
    use std::os::unix::ffi::OsStrExt;
    let ca = CString::new(a.as_os_str().as_bytes())?;
    let cb = CString::new(b.as_os_str().as_bytes())?;
    // SAFETY: two valid NUL-terminated paths; the call reads them only.
    let r = unsafe { libc::renameat2(libc::AT_FDCWD, ca.as_ptr(), libc::AT_FDCWD, cb.as_ptr(), libc::RENAME_EXCHANGE) };
    if r == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

#[cfg(not(target_os = "linux"))]
fn exchange(_a: &Path, _b: &Path) -> std::io::Result<()> {
    Err(std::io::Error::from(std::io::ErrorKind::Unsupported))
}

/// Moves `tmp` to `dest`: atomically replacing it when it is a complete
/// output of `kind` and `force` is set, refusing anything else that exists.
fn place(tmp: &Path, dest: &Path, kind: OutputKind, force: bool) -> Result<()> {
    // Re-checked at commit: the path may have changed while we worked.
    check_output(dest, kind, force)?;
    let exists = fs::symlink_metadata(dest).is_ok();
    if !exists {
        // No-replace semantics: a file is hard-linked (fails if the name was
        // taken meanwhile); a directory rename fails onto a non-empty one.
        if fs::metadata(tmp).map(|m| m.is_file()).unwrap_or(false) {
            fs::hard_link(tmp, dest).ctx(dest, "move into place")?;
            return fs::remove_file(tmp).ctx(tmp, "remove temp file");
        }
        return fs::rename(tmp, dest).ctx(dest, "rename into place");
    }
    if fs::metadata(dest).map(|m| m.is_file()).unwrap_or(false) {
        return fs::rename(tmp, dest).ctx(dest, "rename into place");
    }
    // An existing output directory of the same kind, --force given.
    match exchange(tmp, dest) {
        Ok(()) => {
            // `tmp` now holds the old output (our own, being replaced).
            remove_path(tmp);
            Ok(())
        }
        Err(_) => {
            let old = temp_sibling(dest);
            register(&old);
            fs::rename(dest, &old).ctx(dest, "move old output aside")?;
            fs::rename(tmp, dest).ctx(dest, "rename into place")?;
            remove_path(&old);
            unregister(&old);
            Ok(())
        }
    }
}

/// A file written under a temporary name and renamed to its final name on commit.
pub struct AtomicFile {
    tmp: PathBuf,
    dest: PathBuf,
    kind: OutputKind,
    force: bool,
    writer: Option<BufWriter<File>>,
    /// Sync to disk before moving into place (false: scratch, see [`AtomicFile::scratch`]).
    sync: bool,
}

impl AtomicFile {
    /// Checks `dest` (see [`check_output`]), then creates the temp file,
    /// and the destination's directory if missing.
    pub fn create(dest: impl AsRef<Path>, kind: OutputKind, force: bool) -> Result<AtomicFile> {
        let dest = dest.as_ref().to_path_buf();
        check_output(&dest, kind, force)?;
        ensure_parent(&dest)?;
        let tmp = temp_sibling(&dest);
        register(&tmp);
        let f = match File::create(&tmp).ctx(&tmp, "create") {
            Ok(f) => f,
            Err(e) => {
                unregister(&tmp);
                return Err(e);
            }
        };
        Ok(AtomicFile { tmp, dest, kind, force, writer: Some(BufWriter::with_capacity(SEQ_BUF, f)), sync: true })
    }
    /// Not synced to disk on commit: for a command's own scratch, removed
    /// before the command ends (a crash loses the command's output anyway),
    /// so it never waits for the file's writeback (the build's soup: 4 GB
    /// at 120 M triangles).
    pub fn scratch(mut self) -> AtomicFile {
        self.sync = false;
        self
    }
    pub fn writer(&mut self) -> &mut BufWriter<File> {
        self.writer.as_mut().expect("writer taken")
    }
    pub fn dest(&self) -> &Path {
        &self.dest
    }
    /// Flush, sync and move into place.
    pub fn commit(mut self) -> Result<()> {
        let w = self.writer.take().expect("writer taken");
        let res = (|| {
            let f = w.into_inner().map_err(|e| e.into_error()).ctx(&self.tmp, "write")?;
            if self.sync {
                f.sync_all().ctx(&self.tmp, "sync")?;
            }
            drop(f);
            place(&self.tmp, &self.dest, self.kind, self.force)
        })();
        if res.is_err() {
            let _ = fs::remove_file(&self.tmp);
        }
        unregister(&self.tmp);
        res
    }
}

impl Write for AtomicFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.writer().write(buf)
    }
    fn write_all(&mut self, buf: &[u8]) -> std::io::Result<()> {
        self.writer().write_all(buf)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.writer().flush()
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        if self.writer.is_some() {
            self.writer.take();
            let _ = fs::remove_file(&self.tmp);
            unregister(&self.tmp);
        }
    }
}

/// A directory built under a temporary name and moved into place on commit.
pub struct AtomicDir {
    tmp: PathBuf,
    dest: PathBuf,
    kind: OutputKind,
    force: bool,
    done: bool,
}

impl AtomicDir {
    /// Checks `dest` (see [`check_output`]), then creates the temp
    /// directory, and the destination's parent if missing.
    pub fn create(dest: impl AsRef<Path>, kind: OutputKind, force: bool) -> Result<AtomicDir> {
        let dest = dest.as_ref().to_path_buf();
        check_output(&dest, kind, force)?;
        ensure_parent(&dest)?;
        let tmp = temp_sibling(&dest);
        register(&tmp);
        if let Err(e) = fs::create_dir_all(&tmp).ctx(&tmp, "create directory") {
            unregister(&tmp);
            return Err(e);
        }
        Ok(AtomicDir { tmp, dest, kind, force, done: false })
    }
    /// The directory to write into.
    pub fn path(&self) -> &Path {
        &self.tmp
    }
    pub fn dest(&self) -> &Path {
        &self.dest
    }
    pub fn commit(mut self) -> Result<()> {
        if self.kind == OutputKind::Frames {
            let m = self.tmp.join(FRAMES_MARKER);
            fs::write(&m, b"octolod render output\n").ctx(&m, "write")?;
        }
        place(&self.tmp, &self.dest, self.kind, self.force)?;
        self.done = true;
        unregister(&self.tmp);
        Ok(())
    }
}

impl Drop for AtomicDir {
    fn drop(&mut self) {
        if !self.done {
            let _ = fs::remove_dir_all(&self.tmp);
            unregister(&self.tmp);
        }
    }
}

/// A scratch directory for spill files next to `near` (same filesystem as
/// the output, so large temp data does not land on a small /tmp), named and
/// registered like every temp path; removed on drop.
pub struct ScratchDir {
    path: PathBuf,
}

impl ScratchDir {
    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for ScratchDir {
    fn drop(&mut self) {
        let _ = fs::remove_dir_all(&self.path);
        unregister(&self.path);
    }
}

/// Creates a [`ScratchDir`] in the directory of `near`.
pub fn scratch_dir(near: &Path) -> Result<ScratchDir> {
    ensure_parent(near)?;
    let path = temp_sibling(&parent_dir(near).join("octolod-scratch"));
    register(&path);
    if let Err(e) = fs::create_dir(&path).ctx(&path, "create scratch directory") {
        unregister(&path);
        return Err(e);
    }
    Ok(ScratchDir { path })
}

#[cfg(test)]
mod tests {
    use super::*;

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

    fn names(d: &Path) -> Vec<String> {
        let mut v: Vec<String> = fs::read_dir(d).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        v.sort();
        v
    }

    #[test]
    fn uncommitted_file_leaves_nothing() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("x.soup");
        {
            let mut f = AtomicFile::create(&p, OutputKind::Soup, false).unwrap();
            f.write_all(b"partial").unwrap();
        }
        assert!(!p.exists());
        assert!(names(d.path()).is_empty());
        let mut f = AtomicFile::create(&p, OutputKind::Soup, false).unwrap();
        f.write_all(b"whole").unwrap();
        f.commit().unwrap();
        assert_eq!(fs::read(&p).unwrap(), b"whole");
        assert_eq!(names(d.path()), ["x.soup"]);
    }

    #[test]
    fn outputs_create_their_directory() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("a/b/x.ply");
        let mut f = AtomicFile::create(&p, OutputKind::Ply, false).unwrap();
        f.write_all(b"1").unwrap();
        f.commit().unwrap();
        assert!(p.exists());
        AtomicDir::create(d.path().join("c/s.octolod"), OutputKind::Store, false).unwrap().commit().unwrap();
        assert!(d.path().join("c/s.octolod").is_dir());
    }

    fn fake_store(p: &Path, tag: &[u8]) {
        fs::create_dir_all(p).unwrap();
        let mut b = STORE_MAGIC.to_vec();
        b.extend_from_slice(tag);
        fs::write(p.join("nodes.bin"), b).unwrap();
    }

    #[test]
    fn a_user_directory_is_never_replaced_even_with_force() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("proj");
        fs::create_dir(&p).unwrap();
        fs::write(p.join("input.ply"), b"precious").unwrap();
        for force in [false, true] {
            let e = AtomicDir::create(&p, OutputKind::Store, force).err().expect("must refuse");
            assert!(e.to_string().contains("not an octolod store"), "{e}");
        }
        // Refused before anything was created next to it.
        assert_eq!(names(d.path()), ["proj"]);
        assert_eq!(fs::read(p.join("input.ply")).unwrap(), b"precious");
        // A regular file in the way of a store, a directory in the way of a file.
        let f = d.path().join("x.octolod");
        fs::write(&f, b"user file").unwrap();
        assert!(AtomicDir::create(&f, OutputKind::Store, true).is_err());
        assert!(AtomicFile::create(&p, OutputKind::Ply, true).is_err());
        assert_eq!(fs::read(&f).unwrap(), b"user file");
    }

    #[test]
    fn a_directory_that_becomes_a_user_directory_while_we_work_is_kept() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("s.octolod");
        let a = AtomicDir::create(&p, OutputKind::Store, true).unwrap();
        fs::create_dir(&p).unwrap();
        fs::write(p.join("mine"), b"1").unwrap();
        assert!(a.commit().is_err());
        assert_eq!(fs::read(p.join("mine")).unwrap(), b"1");
        assert_eq!(names(d.path()), ["s.octolod"]);
    }

    #[test]
    fn a_store_is_replaced_only_with_force_and_atomically() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("s.octolod");
        fake_store(&p, b"old");
        let e = AtomicDir::create(&p, OutputKind::Store, false).err().expect("needs --force");
        assert!(e.to_string().contains("--force"), "{e}");
        let a = AtomicDir::create(&p, OutputKind::Store, true).unwrap();
        fake_store(a.path(), b"new");
        a.commit().unwrap();
        assert!(fs::read(p.join("nodes.bin")).unwrap().ends_with(b"new"));
        assert_eq!(names(d.path()), ["s.octolod"]);
    }

    #[test]
    fn our_ply_is_recognised_by_its_comment() {
        let d = tempfile::tempdir().unwrap();
        let ours = d.path().join("a.ply");
        fs::write(&ours, "ply\nformat ascii 1.0\ncomment octolod level 2 of x\nend_header\n").unwrap();
        let theirs = d.path().join("b.ply");
        fs::write(&theirs, "ply\nformat ascii 1.0\ncomment VCGLIB generated\nend_header\n").unwrap();
        assert!(OutputKind::Ply.recognise(&ours));
        assert!(!OutputKind::Ply.recognise(&theirs));
        assert!(AtomicFile::create(&ours, OutputKind::Ply, false).is_err());
        let mut f = AtomicFile::create(&ours, OutputKind::Ply, true).unwrap();
        f.write_all(b"ply\ncomment octolod new\nend_header\n").unwrap();
        f.commit().unwrap();
        assert!(fs::read_to_string(&ours).unwrap().contains("new"));
        let e = AtomicFile::create(&theirs, OutputKind::Ply, true).err().unwrap();
        assert!(e.to_string().contains("refusing"), "{e}");
    }

    #[test]
    fn stale_temps_of_dead_owners_are_removed_and_live_ones_kept() {
        let d = tempfile::tempdir().unwrap();
        // A PID that cannot be running (above pid_max) and ours with a wrong start time.
        let dead = d.path().join(format!(".s.octolod{TMP_TAG}4194305-1-0"));
        fs::create_dir(&dead).unwrap();
        fs::write(dead.join("level-0.pack"), b"x").unwrap();
        let reused = d.path().join(format!(".o.ply{TMP_TAG}{}-{}-3", std::process::id(), own_start() + 1));
        fs::write(&reused, b"x").unwrap();
        let live = d.path().join(format!(".o.ply{TMP_TAG}{}-{}-99999", std::process::id(), own_start()));
        fs::write(&live, b"x").unwrap();
        let user = d.path().join(".hidden-user-file-1-2-3");
        fs::write(&user, b"x").unwrap();
        let s = scratch_dir(&d.path().join("out.soup")).unwrap();
        assert!(!dead.exists() && !reused.exists());
        assert!(live.exists() && user.exists() && s.path().is_dir());
        let sp = s.path().to_path_buf();
        drop(s);
        assert!(!sp.exists());
    }
}
