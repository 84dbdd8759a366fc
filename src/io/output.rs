//! Outputs that appear under their final name only when complete
//! ([`AtomicFile`], [`AtomicDir`]), and the rules for what may be replaced.
//!
//! Takes: a final path, the [`OutputKind`] written there and whether the
//! user allowed replacing (`--force`). Gives: a locked temp path in the same
//! directory ([`super::temp`]) that is moved into place on `commit()` and
//! deleted if dropped uncommitted, so a failed or interrupted run never
//! leaves partial output pretending to be complete.
//!
//! Data safety rules (README "What octolod promises"):
//! * An existing path is replaced only when it is a complete octolod output
//!   of the same kind ([`OutputKind::recognise`]: a store's index magic, a
//!   soup's magic, a render directory's marker, a PLY's exact
//!   [`PLY_MARK`] comment line) **and** `force` is set; anything else that
//!   exists is refused before any work starts.
//! * A directory output (store, render directory) is replaced only when it
//!   holds nothing but what octolod wrote there (a store: `nodes.bin`,
//!   `store.json` and its levels' packs; a render directory: the files its
//!   marker lists); a user's file inside is never deleted: the command is
//!   refused. The old output is then removed file by file, never with a
//!   recursive delete; what appeared in it meanwhile is kept under a
//!   visible name.
//! * Nothing that holds a path the running command reads ([`protect`]: its
//!   input, an opened store, a camera path) is ever replaced.
//! * A store is swapped in with one `renameat2(RENAME_EXCHANGE)`, so the
//!   final name always holds a complete store.

use super::temp::{self, parent_dir, DirLock};
use crate::error::{Error, IoContext, Result};
use std::fs::{self, File};
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// What a command writes at its final path.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutputKind {
    /// A store directory (`nodes.bin` starting with the store magic).
    Store,
    /// A PLY file whose header carries the comment line [`PLY_MARK`].
    Ply,
    /// A triangle soup file (soup magic).
    Soup,
    /// A `render` output directory (holds the [`FRAMES_MARKER`] file).
    Frames,
}

/// The first bytes of a store's `nodes.bin` ([`crate::store::MAGIC`]):
/// defined here, where outputs are recognised, so this module needs no
/// format module (they all build on it).
pub const STORE_MAGIC: [u8; 8] = *b"OCTLODIX";
/// The first bytes of a triangle soup ([`crate::soup::format::MAGIC`]).
pub const SOUP_MAGIC: [u8; 8] = *b"OCTSOUP\0";
/// The marker file every `render` output directory holds: its first line
/// is [`FRAMES_MARKER_TEXT`], the next ones list the files the render wrote.
pub const FRAMES_MARKER: &str = ".octolod-render";
const FRAMES_MARKER_TEXT: &str = "octolod render output";
/// The comment every PLY octolod writes carries, as a whole header line
/// `comment octolod-output`: recognised exactly, so a user's comment that
/// merely starts with "octolod" never makes a file replaceable.
pub const PLY_MARK: &str = "octolod-output";

impl OutputKind {
    pub fn describe(self) -> &'static str {
        match self {
            OutputKind::Store => "an octolod store",
            OutputKind::Ply => "a PLY written by octolod",
            OutputKind::Soup => "an octolod triangle soup",
            OutputKind::Frames => "an octolod render directory",
        }
    }

    fn is_dir(self) -> bool {
        matches!(self, OutputKind::Store | OutputKind::Frames)
    }

    /// Whether `p` is a complete output of this kind.
    pub fn recognise(self, p: &Path) -> bool {
        match self {
            OutputKind::Store => p.is_dir() && head(&p.join("nodes.bin"), 8).is_some_and(|b| b == STORE_MAGIC),
            OutputKind::Soup => p.is_file() && head(p, 8).is_some_and(|b| b == SOUP_MAGIC),
            OutputKind::Frames => {
                p.is_dir() && head(&p.join(FRAMES_MARKER), 4096).is_some_and(|b| b.starts_with(FRAMES_MARKER_TEXT.as_bytes()))
            }
            OutputKind::Ply => p.is_file() && head(p, 64 << 10).is_some_and(|b| ply_is_ours(&b)),
        }
    }

    /// The paths (relative to directory output `dir`) octolod wrote there:
    /// a store's index, manifest and level packs; a render directory's
    /// listed files (or, for a marker of an older octolod that lists none,
    /// the names a render writes).
    fn own_entries(self, dir: &Path) -> OwnEntries {
        match self {
            OutputKind::Store => {
                let levels = head(&dir.join("nodes.bin"), 24).filter(|b| b.len() == 24).map_or(0, |b| u32::from_le_bytes(b[20..24].try_into().unwrap()));
                let mut v: Vec<PathBuf> = ["nodes.bin", "store.json"].iter().map(PathBuf::from).collect();
                v.extend((0..levels.min(256)).map(|l| PathBuf::from(format!("level-{l}.pack"))));
                OwnEntries::Listed(v)
            }
            OutputKind::Frames => {
                let text = head(&dir.join(FRAMES_MARKER), 64 << 20).map(|b| String::from_utf8_lossy(&b).into_owned()).unwrap_or_default();
                let mut lines = text.lines().skip(1).filter(|l| !l.is_empty()).peekable();
                if lines.peek().is_none() {
                    return OwnEntries::RenderNames;
                }
                OwnEntries::Listed(lines.map(PathBuf::from).chain([PathBuf::from(FRAMES_MARKER)]).collect())
            }
            OutputKind::Ply | OutputKind::Soup => OwnEntries::Listed(Vec::new()),
        }
    }
}

/// What octolod wrote inside a directory output.
enum OwnEntries {
    Listed(Vec<PathBuf>),
    /// An older render directory: `frame-N.png`, `stats.csv`, `stats.json`,
    /// the marker, `reference/frame-N.png`.
    RenderNames,
    /// Every regular file (a directory this run wrote itself).
    All,
}

impl OwnEntries {
    fn holds(&self, rel: &Path) -> bool {
        match self {
            OwnEntries::Listed(v) => v.iter().any(|p| p == rel),
            OwnEntries::All => true,
            OwnEntries::RenderNames => {
                let s = rel.to_string_lossy();
                let frame = |n: &str| n.strip_prefix("frame-").and_then(|r| r.strip_suffix(".png")).is_some_and(|d| !d.is_empty() && d.bytes().all(|c| c.is_ascii_digit()));
                match s.strip_prefix("reference/") {
                    Some(r) => frame(r),
                    None => frame(&s) || s == "stats.csv" || s == "stats.json" || s == FRAMES_MARKER,
                }
            }
        }
    }
}

/// Regular files under `dir` (and in its subdirectories, for render
/// directories' `reference/`), relative; and the entries that are neither
/// octolod's nor regular files, which make the directory a user's.
fn foreign_entries(dir: &Path, own: &OwnEntries, subdirs: bool) -> (Vec<PathBuf>, Vec<PathBuf>) {
    let (mut mine, mut foreign) = (Vec::new(), Vec::new());
    let mut stack = vec![PathBuf::new()];
    while let Some(rel) = stack.pop() {
        let Ok(it) = fs::read_dir(dir.join(&rel)) else {
            foreign.push(rel);
            continue;
        };
        for e in it.flatten() {
            let r = rel.join(e.file_name());
            match e.file_type() {
                Ok(t) if t.is_file() && own.holds(&r) => mine.push(r),
                Ok(t) if t.is_dir() && subdirs && rel.as_os_str().is_empty() && r == Path::new("reference") => stack.push(r),
                _ => foreign.push(r),
            }
        }
    }
    foreign.sort();
    (mine, foreign)
}

/// Whether a PLY's first bytes hold a header with our exact mark line.
fn ply_is_ours(b: &[u8]) -> bool {
    let text = String::from_utf8_lossy(b);
    let mut lines = text.lines().map(|l| l.trim_end_matches('\r'));
    if lines.next() != Some("ply") {
        return false;
    }
    let want = format!("comment {PLY_MARK}");
    lines.take_while(|l| *l != "end_header").any(|l| l.trim_end() == want)
}

fn head(p: &Path, n: usize) -> Option<Vec<u8>> {
    let f = File::open(p).ok()?;
    if !f.metadata().ok()?.is_file() {
        return None;
    }
    let mut b = Vec::with_capacity(n.min(1 << 16));
    f.take(n as u64).read_to_end(&mut b).ok()?;
    Some(b)
}

// ------------------------------------------------------------------ operands

/// Paths the running commands read: never replaced while protected.
static PROTECTED: Mutex<Vec<(u64, PathBuf)>> = Mutex::new(Vec::new());

/// A path kept safe from replacement while this guard lives.
#[must_use = "the path is protected only while the guard lives"]
pub struct Protected(u64);

impl Drop for Protected {
    fn drop(&mut self) {
        PROTECTED.lock().unwrap_or_else(|e| e.into_inner()).retain(|(id, _)| *id != self.0);
    }
}

/// Protects `p` (an input file, an opened store, a camera path) from every
/// output of this process while the guard lives: an output whose
/// replacement would delete `p` or a directory holding it is refused.
pub fn protect(p: &Path) -> Protected {
    static N: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let id = N.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let abs = fs::canonicalize(p).unwrap_or_else(|_| std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf()));
    PROTECTED.lock().unwrap_or_else(|e| e.into_inner()).push((id, abs));
    Protected(id)
}

/// A protected path at or under `dest`, if any.
fn protected_under(dest: &Path) -> Option<PathBuf> {
    let d = fs::canonicalize(dest).ok()?;
    let l = PROTECTED.lock().unwrap_or_else(|e| e.into_inner());
    l.iter().map(|(_, p)| p).find(|p| p.starts_with(&d)).cloned()
}

// -------------------------------------------------------------------- checks

/// Refuses `dest` unless it is free, or a complete output of `kind` that
/// holds only octolod's files and no protected path, and `force` is set.
/// Call before any work starts (it is checked again at commit).
pub fn check_output(dest: &Path, kind: OutputKind, force: bool) -> Result<()> {
    if !kind.is_dir() && dest.as_os_str().as_encoded_bytes().ends_with(b"/") {
        return Err(Error::Usage(format!("{}: {} is a file, but the path ends with '/'", dest.display(), kind.describe())));
    }
    let Ok(meta) = fs::symlink_metadata(dest) else { return Ok(()) };
    let what = if meta.is_dir() { "a directory" } else if meta.is_file() { "a file" } else { "something else" };
    if !(kind.recognise(dest) && !meta.file_type().is_symlink()) {
        return Err(Error::Usage(format!(
            "{} already exists and is {what} that is not {}; refusing to replace it (remove it yourself or choose another output path)",
            dest.display(),
            kind.describe()
        )));
    }
    if let Some(p) = protected_under(dest) {
        let what = if fs::canonicalize(dest).is_ok_and(|d| d == p) { "is".to_string() } else { format!("holds {},", p.display()) };
        return Err(Error::Usage(format!(
            "{} {what} an input of this command; refusing to replace it (choose another output path)",
            dest.display()
        )));
    }
    if !force {
        return Err(Error::Usage(format!("{} already exists ({}); pass --force to replace it", dest.display(), kind.describe())));
    }
    if kind.is_dir() {
        let (_, foreign) = foreign_entries(dest, &kind.own_entries(dest), kind == OutputKind::Frames);
        if !foreign.is_empty() {
            let names: Vec<String> = foreign.iter().take(3).map(|p| p.display().to_string()).collect();
            return Err(Error::Usage(format!(
                "{} is {} but also holds {}{} that octolod did not write; refusing to replace it (move {} out, or choose another output path)",
                dest.display(),
                kind.describe(),
                names.join(", "),
                if foreign.len() > 3 { format!(" and {} more", foreign.len() - 3) } else { String::new() },
                if foreign.len() == 1 { "it" } else { "them" }
            )));
        }
    }
    Ok(())
}

/// Removes an old directory output of `kind` (moved aside to `old`, once
/// at `dest`) file by file: only what octolod wrote. Anything else found
/// in it (added while this run worked) is kept, under a visible name next
/// to `dest`.
fn remove_old_output(old: &Path, dest: &Path, own: &OwnEntries, kind: OutputKind) {
    let (mine, _) = foreign_entries(old, own, kind == OutputKind::Frames);
    for rel in &mine {
        let _ = fs::remove_file(old.join(rel));
    }
    let _ = fs::remove_dir(old.join("reference"));
    if fs::remove_dir(old).is_ok() {
        temp::unregister(old);
        return;
    }
    for n in 0.. {
        let keep = PathBuf::from(format!("{}.octolod-kept-{n}", dest.display()));
        if fs::symlink_metadata(&keep).is_err() {
            if fs::rename(old, &keep).is_ok() {
                eprintln!(
                    "octolod: warning: files appeared in {} while it was being replaced; the old output with them is kept at {}",
                    dest.display(),
                    keep.display()
                );
            }
            break;
        }
    }
    temp::unregister(old);
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
/// output of `kind` that may be replaced (see [`check_output`]), refusing
/// anything else that exists.
fn place(tmp: &Path, dest: &Path, kind: OutputKind, force: bool) -> Result<()> {
    // Re-checked at commit: the path may have changed while we worked.
    super::signal::check()?;
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
    if !kind.is_dir() {
        return fs::rename(tmp, dest).ctx(dest, "rename into place");
    }
    // An existing output directory of the same kind, --force given.
    let own = kind.own_entries(dest);
    match exchange(tmp, dest) {
        // `tmp` now holds the old output (our own, being replaced).
        Ok(()) => remove_old_output(tmp, dest, &own, kind),
        Err(_) => {
            let old = temp::temp_name(dest);
            temp::register(&old);
            fs::rename(dest, &old).ctx(dest, "move old output aside")?;
            fs::rename(tmp, dest).ctx(dest, "rename into place")?;
            remove_old_output(&old, dest, &own, kind);
        }
    }
    Ok(())
}

/// A file written under a temporary name and renamed to its final name on commit.
pub struct AtomicFile {
    tmp: PathBuf,
    dest: PathBuf,
    kind: OutputKind,
    force: bool,
    /// The temp file (locked while open, see [`super::temp`]).
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
        let (tmp, f) = temp::create_temp_file(&dest)?;
        Ok(AtomicFile { tmp, dest, kind, force, writer: Some(BufWriter::with_capacity(super::SEQ_BUF, f)), sync: true })
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
            // Still open (and locked) while it is moved.
            let r = place(&self.tmp, &self.dest, self.kind, self.force);
            drop(f);
            r
        })();
        if res.is_err() {
            let _ = fs::remove_file(&self.tmp);
        }
        temp::unregister(&self.tmp);
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
            let _ = fs::remove_file(&self.tmp);
            self.writer.take();
            temp::unregister(&self.tmp);
        }
    }
}

/// A directory built under a temporary name and moved into place on commit.
pub struct AtomicDir {
    tmp: PathBuf,
    dest: PathBuf,
    kind: OutputKind,
    force: bool,
    lock: Option<DirLock>,
}

impl AtomicDir {
    /// Checks `dest` (see [`check_output`]), then creates the temp
    /// directory, and the destination's parent if missing.
    pub fn create(dest: impl AsRef<Path>, kind: OutputKind, force: bool) -> Result<AtomicDir> {
        let dest = dest.as_ref().to_path_buf();
        check_output(&dest, kind, force)?;
        ensure_parent(&dest)?;
        let (tmp, lock) = temp::create_temp_dir(&dest)?;
        Ok(AtomicDir { tmp, dest, kind, force, lock: Some(lock) })
    }
    /// The directory to write into.
    pub fn path(&self) -> &Path {
        &self.tmp
    }
    pub fn dest(&self) -> &Path {
        &self.dest
    }
    pub fn commit(mut self) -> Result<()> {
        let lock = self.lock.as_ref().expect("committed once");
        lock.remove_file()?;
        if self.kind == OutputKind::Frames {
            // The marker lists every file the render wrote, so a later
            // `--force` replaces exactly those.
            let (mine, _) = foreign_entries(&self.tmp, &OwnEntries::All, true);
            let mut text = format!("{FRAMES_MARKER_TEXT}\n");
            for p in mine.iter().filter(|p| *p != Path::new(FRAMES_MARKER)) {
                text.push_str(&p.to_string_lossy());
                text.push('\n');
            }
            let m = self.tmp.join(FRAMES_MARKER);
            fs::write(&m, text).ctx(&m, "write")?;
        }
        place(&self.tmp, &self.dest, self.kind, self.force)?;
        self.lock = None;
        temp::unregister(&self.tmp);
        Ok(())
    }
}

impl Drop for AtomicDir {
    fn drop(&mut self) {
        if self.lock.is_some() {
            let _ = fs::remove_dir_all(&self.tmp);
            temp::unregister(&self.tmp);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::names;
    use super::*;

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
        // Magic, then version, attributes, flags and 1 level (u32 each).
        let mut b = STORE_MAGIC.to_vec();
        for x in [2u32, 0, 0, 1] {
            b.extend_from_slice(&x.to_le_bytes());
        }
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
        fs::write(&ours, "ply\nformat ascii 1.0\ncomment octolod-output\ncomment octolod level 2 of x\nend_header\n").unwrap();
        let theirs = d.path().join("b.ply");
        fs::write(&theirs, "ply\nformat ascii 1.0\ncomment VCGLIB generated\nend_header\n").unwrap();
        assert!(OutputKind::Ply.recognise(&ours));
        assert!(!OutputKind::Ply.recognise(&theirs));
        assert!(AtomicFile::create(&ours, OutputKind::Ply, false).is_err());
        let mut f = AtomicFile::create(&ours, OutputKind::Ply, true).unwrap();
        f.write_all(b"ply\ncomment octolod-output\ncomment new\nend_header\n").unwrap();
        f.commit().unwrap();
        assert!(fs::read_to_string(&ours).unwrap().contains("new"));
        let e = AtomicFile::create(&theirs, OutputKind::Ply, true).err().unwrap();
        assert!(e.to_string().contains("refusing"), "{e}");
    }

    #[test]
    fn a_comment_that_merely_starts_with_octolod_is_not_our_mark() {
        let d = tempfile::tempdir().unwrap();
        for (name, text, ours) in [
            ("lodge.ply", "ply\nformat ascii 1.0\ncomment octolodge scanner export\nend_header\n", false),
            ("bare.ply", "ply\nformat ascii 1.0\ncomment octolod\nend_header\n", false),
            ("prefix.ply", "ply\nformat ascii 1.0\ncomment octolod-output by a user tool\nend_header\n", false),
            ("after.ply", "ply\nformat ascii 1.0\nend_header\ncomment octolod-output\n", false),
            ("crlf.ply", "ply\r\nformat ascii 1.0\r\ncomment octolod-output\r\nend_header\r\n", true),
        ] {
            let p = d.path().join(name);
            fs::write(&p, text).unwrap();
            assert_eq!(OutputKind::Ply.recognise(&p), ours, "{name}");
            if !ours {
                assert!(AtomicFile::create(&p, OutputKind::Ply, true).is_err(), "{name}");
            }
        }
    }

    #[test]
    fn a_store_holding_a_user_file_is_refused_and_kept_whole() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("s.octolod");
        fake_store(&p, b"old");
        fs::write(p.join("NOTES.txt"), b"mine").unwrap();
        fs::create_dir(p.join("extracted")).unwrap();
        let e = AtomicDir::create(&p, OutputKind::Store, true).err().expect("must refuse");
        let msg = e.to_string();
        assert!(msg.contains("NOTES.txt") && msg.contains("extracted") && msg.contains("did not write"), "{msg}");
        assert_eq!(names(&p), ["NOTES.txt", "extracted", "nodes.bin"]);
        // Only octolod's files: replaced.
        fs::remove_file(p.join("NOTES.txt")).unwrap();
        fs::remove_dir(p.join("extracted")).unwrap();
        fs::write(p.join("store.json"), b"{}").unwrap();
        fs::write(p.join("level-0.pack"), b"").unwrap();
        let a = AtomicDir::create(&p, OutputKind::Store, true).unwrap();
        fake_store(a.path(), b"new");
        a.commit().unwrap();
        assert_eq!(names(&p), ["nodes.bin"]);
        assert_eq!(names(d.path()), ["s.octolod"]);
    }

    #[test]
    fn a_user_file_that_appears_during_the_run_is_kept_under_a_visible_name() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("s.octolod");
        fake_store(&p, b"old");
        let a = AtomicDir::create(&p, OutputKind::Store, true).unwrap();
        fake_store(a.path(), b"new");
        // Refused at commit too: the old store now holds a user's file.
        fs::write(p.join("late.txt"), b"mine").unwrap();
        assert!(a.commit().is_err());
        assert_eq!(fs::read(p.join("late.txt")).unwrap(), b"mine");
        assert_eq!(names(d.path()), ["s.octolod"]);
        // Appearing after the check: the removal takes only our files.
        fs::remove_file(p.join("late.txt")).unwrap();
        let old = d.path().join("old-copy");
        fake_store(&old, b"old");
        fs::write(old.join("late.txt"), b"mine").unwrap();
        remove_old_output(&old, &p, &OutputKind::Store.own_entries(&p), OutputKind::Store);
        assert_eq!(fs::read(d.path().join("s.octolod.octolod-kept-0/late.txt")).unwrap(), b"mine");
        assert!(!d.path().join("s.octolod.octolod-kept-0/nodes.bin").exists());
    }

    #[test]
    fn a_render_directory_is_replaced_only_with_the_files_it_lists() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("shots");
        let a = AtomicDir::create(&p, OutputKind::Frames, false).unwrap();
        fs::write(a.path().join("frame-00000.png"), b"1").unwrap();
        fs::create_dir(a.path().join("reference")).unwrap();
        fs::write(a.path().join("reference/frame-00000.png"), b"1").unwrap();
        a.commit().unwrap();
        let marker = fs::read_to_string(p.join(FRAMES_MARKER)).unwrap();
        assert_eq!(marker, "octolod render output\nframe-00000.png\nreference/frame-00000.png\n");
        // A store kept inside: refused, with --force.
        fake_store(&p.join("s.octolod"), b"x");
        let e = AtomicDir::create(&p, OutputKind::Frames, true).err().expect("must refuse").to_string();
        assert!(e.contains("s.octolod"), "{e}");
        fs::remove_dir_all(p.join("s.octolod")).unwrap();
        let a = AtomicDir::create(&p, OutputKind::Frames, true).unwrap();
        fs::write(a.path().join("frame-00000.png"), b"2").unwrap();
        a.commit().unwrap();
        assert_eq!(names(&p), [".octolod-render", "frame-00000.png"]);
        // An older render directory (a marker listing nothing): its names.
        fs::write(p.join(FRAMES_MARKER), "octolod render output\n").unwrap();
        fs::write(p.join("stats.json"), b"{}").unwrap();
        assert!(check_output(&p, OutputKind::Frames, true).is_ok());
        fs::write(p.join("frame-1.png.bak"), b"{}").unwrap();
        assert!(check_output(&p, OutputKind::Frames, true).is_err());
    }

    #[test]
    fn nothing_holding_a_protected_input_is_replaced() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("s.octolod");
        fake_store(&p, b"old");
        let input = p.join("level-0.pack");
        fs::write(&input, b"an input that happens to be named like ours").unwrap();
        {
            let _g = protect(&input);
            let e = AtomicDir::create(&p, OutputKind::Store, true).err().expect("must refuse").to_string();
            assert!(e.contains("an input of this command"), "{e}");
            // Through another spelling of the same directory.
            let other = d.path().join(".").join("s.octolod");
            assert!(AtomicDir::create(&other, OutputKind::Store, true).is_err());
        }
        // The guard dropped: replaceable again.
        assert!(AtomicDir::create(&p, OutputKind::Store, true).is_ok());
        // The output is the input itself.
        let ply = d.path().join("o.ply");
        fs::write(&ply, "ply\nformat ascii 1.0\ncomment octolod-output\nend_header\n").unwrap();
        let _g = protect(&ply);
        let e = AtomicFile::create(&ply, OutputKind::Ply, true).err().expect("must refuse").to_string();
        assert!(e.contains("is an input of this command"), "{e}");
    }

    #[test]
    fn a_file_output_path_ending_in_a_slash_is_refused_before_work() {
        let d = tempfile::tempdir().unwrap();
        let p = format!("{}/x.ply/", d.path().display());
        let e = AtomicFile::create(&p, OutputKind::Ply, false).err().expect("must refuse").to_string();
        assert!(e.contains("ends with '/'"), "{e}");
        assert!(names(d.path()).is_empty());
    }
}
