//! Outputs that appear under their final name only when complete
//! ([`AtomicFile`], [`AtomicDir`]), and the rules for what may be replaced.
//!
//! Takes: a final path, the [`OutputKind`] written there and whether the
//! user allowed replacing (`--force`). Gives: a locked temp path in the same
//! directory ([`super::temp`]) that is moved into place on `commit()` and
//! deleted if dropped uncommitted, so a failed or interrupted run never
//! leaves partial output pretending to be complete.
//!
//! Invariants (the data safety promises, `docs/promises.md`):
//! * An existing path is replaced only when it is a complete octolod output
//!   of the same kind ([`OutputKind::recognise`]: a store's index magic, a
//!   soup's magic, a render directory's marker, a PLY's exact [`PLY_MARK`]
//!   comment line, a glTF's `asset.extras.octolod` marker) **and** `force`
//!   is set; anything else that exists is refused before any work starts.
//! * A `.gltf`'s buffer, the `.bin` beside it ([`gltf_bin_path`]), is
//!   replaced only when the old `.gltf` is octolod's and names that `.bin`
//!   in `buffers[].uri`; both are moved into place together ([`AtomicGltfPair`]).
//! * A directory output (store, render directory) is replaced only when it
//!   holds nothing but what octolod wrote there (a store: `nodes.bin`,
//!   `store.json` and its levels' packs; a render directory: the files its
//!   marker lists); a user's file inside makes the command refuse. The old
//!   output is removed file by file, never recursively; what appeared in it
//!   meanwhile is kept under a visible name.
//! * Nothing that is, holds or lies inside a path the running command reads
//!   ([`protect`]: its input, an opened store, a camera path) is replaced
//!   (`extract s.octolod -o s.octolod/nodes.gltf --force` cannot replace the
//!   store's `nodes.bin` as the glTF's buffer).
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
    /// A `tiles` output directory, a 3D Tiles tileset (holds the
    /// [`TILES_MARKER`] file).
    Tiles,
    /// A glTF 2.0 file: a GLB, or `.gltf` JSON, whose `asset.extras` maps
    /// [`GLTF_MARK_KEY`] to [`GLTF_MARK_VALUE`]. For a path ending in
    /// `.gltf` (any case), [`check_output`] checks its `.bin` too.
    Gltf,
    /// A shard of a sharded build (`shard.state` starting with
    /// [`SHARD_MAGIC`]).
    Shard,
    /// A sharded build's plan: JSON whose `format` is `octolod-plan`.
    Plan,
}

/// The first bytes of a shard's `shard.state` ([`crate::shard`]).
pub const SHARD_MAGIC: [u8; 8] = *b"OCTSHARD";

/// The first bytes of a store's `nodes.bin` ([`crate::store::MAGIC`]):
/// defined here, where outputs are recognised, so this module needs no
/// format module (they all build on it).
pub const STORE_MAGIC: [u8; 8] = *b"OCTLODIX";
/// The first bytes of a triangle soup ([`crate::soup::format::MAGIC`]).
pub const SOUP_MAGIC: [u8; 8] = *b"OCTSOUP\0";
/// The marker file every `render` output directory holds: its first line
/// is `FRAMES_MARKER_TEXT`, the next ones list the files the render wrote.
pub const FRAMES_MARKER: &str = ".octolod-render";
const FRAMES_MARKER_TEXT: &str = "octolod render output";
/// The marker file every `tiles` output directory holds, like [`FRAMES_MARKER`].
pub const TILES_MARKER: &str = ".octolod-tiles";
const TILES_MARKER_TEXT: &str = "octolod 3D Tiles output";
/// The comment every PLY octolod writes carries, as a whole header line
/// `comment octolod-output`: recognised exactly, so a user's comment that
/// merely starts with "octolod" never makes a file replaceable.
pub const PLY_MARK: &str = "octolod-output";
/// The key in `asset.extras` of every glTF octolod writes…
pub const GLTF_MARK_KEY: &str = "octolod";
/// …and its value.
pub const GLTF_MARK_VALUE: &str = "output";
/// Largest glTF JSON read when recognising an existing output.
const GLTF_MAX_JSON: u64 = 256 << 20;

impl OutputKind {
    pub fn describe(self) -> &'static str {
        match self {
            OutputKind::Store => "an octolod store",
            OutputKind::Ply => "a PLY written by octolod",
            OutputKind::Soup => "an octolod triangle soup",
            OutputKind::Frames => "an octolod render directory",
            OutputKind::Tiles => "an octolod tileset directory",
            OutputKind::Gltf => "a glTF written by octolod",
            OutputKind::Shard => "an octolod shard directory",
            OutputKind::Plan => "an octolod plan",
        }
    }

    fn is_dir(self) -> bool {
        matches!(self, OutputKind::Store | OutputKind::Frames | OutputKind::Tiles | OutputKind::Shard)
    }

    /// A listing directory's marker file, its first line and the one
    /// subdirectory it may hold.
    fn marker(self) -> Option<(&'static str, &'static str, &'static str)> {
        match self {
            OutputKind::Frames => Some((FRAMES_MARKER, FRAMES_MARKER_TEXT, "reference")),
            OutputKind::Tiles => Some((TILES_MARKER, TILES_MARKER_TEXT, "t")),
            _ => None,
        }
    }

    /// Whether `p` is a complete output of this kind.
    pub fn recognise(self, p: &Path) -> bool {
        match self {
            OutputKind::Store => p.is_dir() && head(&p.join("nodes.bin"), 8).is_some_and(|b| b == STORE_MAGIC),
            OutputKind::Soup => p.is_file() && head(p, 8).is_some_and(|b| b == SOUP_MAGIC),
            OutputKind::Shard => p.is_dir() && head(&p.join("shard.state"), 8).is_some_and(|b| b == SHARD_MAGIC),
            OutputKind::Plan => p.is_file() && head(p, 4096).is_some_and(|b| String::from_utf8_lossy(&b).contains("\"format\": \"octolod-plan\"")),
            OutputKind::Frames | OutputKind::Tiles => {
                let (name, text, _) = self.marker().expect("a listing kind");
                p.is_dir() && head(&p.join(name), 4096).is_some_and(|b| b.starts_with(text.as_bytes()))
            }
            OutputKind::Ply => p.is_file() && head(p, 64 << 10).is_some_and(|b| ply_is_ours(&b)),
            OutputKind::Gltf => is_octolod_gltf(p),
        }
    }

    /// The paths (relative to directory output `dir`) octolod wrote there:
    /// a store's index, manifest and level packs; a render directory's
    /// listed files (or, for a marker of an older octolod that lists none,
    /// the names a render writes).
    fn own_entries(self, dir: &Path) -> OwnEntries {
        match self {
            OutputKind::Store => {
                // The header's levels (bytes 20..24) and pack parts (36..40).
                let h = head(&dir.join("nodes.bin"), 40).unwrap_or_default();
                let at = |o: usize| h.get(o..o + 4).map_or(0, |b| u32::from_le_bytes(b.try_into().unwrap()));
                OwnEntries::Store { levels: at(20).min(256), parts: at(crate::store::HEADER_PARTS_AT).min(crate::store::MAX_PARTS) }
            }
            OutputKind::Shard => {
                // The state's byte 24: the level the shard stopped before.
                let levels = head(&dir.join("shard.state"), 25).filter(|b| b.len() == 25).map_or(0, |b| b[24]);
                let mut v: Vec<PathBuf> = ["shard.state", "shard.json", "chunks.bin"].iter().map(PathBuf::from).collect();
                v.extend((0..levels).map(|l| PathBuf::from(format!("level-{l}.pack"))));
                OwnEntries::Listed(v)
            }
            OutputKind::Frames | OutputKind::Tiles => {
                let (name, _, _) = self.marker().expect("a listing kind");
                let text = head(&dir.join(name), 64 << 20).map(|b| String::from_utf8_lossy(&b).into_owned()).unwrap_or_default();
                let mut lines = text.lines().skip(1).filter(|l| !l.is_empty()).peekable();
                if lines.peek().is_none() && self == OutputKind::Frames {
                    return OwnEntries::RenderNames;
                }
                OwnEntries::Listed(lines.map(PathBuf::from).chain([PathBuf::from(name)]).collect())
            }
            OutputKind::Ply | OutputKind::Soup | OutputKind::Gltf | OutputKind::Plan => OwnEntries::Listed(Vec::new()),
        }
    }
}

/// What octolod wrote inside a directory output.
enum OwnEntries {
    Listed(Vec<PathBuf>),
    /// A store's index, manifest, level packs and pack parts (a merged
    /// sharded store's links to its shards' packs).
    Store {
        levels: u32,
        parts: u32,
    },
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
            OwnEntries::Store { levels, parts } => {
                let s = rel.to_string_lossy();
                let num = |d: &str| {
                    (!d.is_empty() && d.len() < 10 && d.bytes().all(|c| c.is_ascii_digit()) && !(d.len() > 1 && d.starts_with('0')))
                        .then(|| d.parse::<u32>().ok())
                        .flatten()
                };
                let pack = s.strip_prefix("level-").and_then(|r| r.strip_suffix(".pack")).map(|r| match r.split_once(".part-") {
                    Some((l, p)) => num(l).is_some_and(|l| l < *levels) && num(p).is_some_and(|p| p >= 1 && p <= *parts),
                    None => num(r).is_some_and(|l| l < *levels),
                });
                // Textures copied from the input (`texture-K[.EXT]`).
                let texture = s.strip_prefix("texture-").is_some_and(|r| {
                    let (k, ext) = r.split_once('.').unwrap_or((r, "x"));
                    num(k).is_some_and(|k| k < 1 << 16) && !ext.is_empty() && ext.len() <= 5 && ext.bytes().all(|c| c.is_ascii_alphanumeric())
                });
                s == "nodes.bin" || s == "store.json" || pack == Some(true) || texture
            }
            OwnEntries::All => true,
            OwnEntries::RenderNames => {
                let s = rel.to_string_lossy();
                let frame = |n: &str| {
                    n.strip_prefix("frame-").and_then(|r| r.strip_suffix(".png")).is_some_and(|d| !d.is_empty() && d.bytes().all(|c| c.is_ascii_digit()))
                };
                match s.strip_prefix("reference/") {
                    Some(r) => frame(r),
                    None => frame(&s) || s == "stats.csv" || s == "stats.json" || s == FRAMES_MARKER,
                }
            }
        }
    }
}

/// Regular files under `dir` (and in its one subdirectory `sub`, a render
/// directory's `reference/` or a tileset's `t/`), relative; and the entries
/// that are neither octolod's nor regular files, which make the directory
/// a user's.
fn foreign_entries(dir: &Path, own: &OwnEntries, sub: Option<&str>) -> (Vec<PathBuf>, Vec<PathBuf>) {
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
                Ok(t) if t.is_dir() && rel.as_os_str().is_empty() && sub.is_some_and(|s| r == Path::new(s)) => stack.push(r),
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

// ---------------------------------------------------------------------- glTF

/// Whether `path` is a glTF octolod wrote: a regular file holding a GLB (by
/// its magic) or glTF JSON whose `asset.extras.octolod` is `"output"`.
pub fn is_octolod_gltf(path: &Path) -> bool {
    gltf_json(path).is_some_and(|v| gltf_is_ours(&v))
}

fn gltf_is_ours(v: &serde_json::Value) -> bool {
    v["asset"]["extras"][GLTF_MARK_KEY] == GLTF_MARK_VALUE
}

/// The `.bin` that holds the buffer of the `.gltf` at `gltf` (same stem).
pub fn gltf_bin_path(gltf: &Path) -> PathBuf {
    gltf.with_extension("bin")
}

/// Whether a glTF output at `p` is `.gltf` JSON with a `.bin` beside it
/// (by the extension, any case), not a GLB.
fn is_gltf_pair(p: &Path) -> bool {
    p.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("gltf"))
}

/// The JSON of a GLB or `.gltf` at `path` (a regular file), if it parses.
fn gltf_json(path: &Path) -> Option<serde_json::Value> {
    const GLB_MAGIC: &[u8; 4] = b"glTF";
    let mut f = File::open(path).ok()?;
    let meta = f.metadata().ok()?;
    if !meta.is_file() {
        return None;
    }
    let mut head = [0u8; 20];
    let n = read_full(&mut f, &mut head).ok()?;
    let bytes = if n == 20 && &head[..4] == GLB_MAGIC {
        let word = |k: usize| u32::from_le_bytes(head[k..k + 4].try_into().unwrap());
        if word(4) != 2 || &head[16..20] != b"JSON" || word(12) as u64 > GLTF_MAX_JSON {
            return None;
        }
        let mut b = vec![0u8; word(12) as usize];
        f.read_exact(&mut b).ok()?;
        b
    } else {
        if meta.len() > GLTF_MAX_JSON {
            return None;
        }
        let mut b = head[..n].to_vec();
        f.read_to_end(&mut b).ok()?;
        b
    };
    let text = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(&bytes);
    serde_json::from_slice(text).ok()
}

fn read_full(f: &mut File, b: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < b.len() {
        match f.read(&mut b[n..])? {
            0 => break,
            k => n += k,
        }
    }
    Ok(n)
}

/// A relative URI reference's bytes, percent-decoded; `None` when it is not
/// a bare file name (a scheme, a query, a path, a bad escape).
fn uri_file_name(uri: &str) -> Option<Vec<u8>> {
    if uri.is_empty() || uri.contains(['/', '\\', ':', '?', '#']) {
        return None;
    }
    let b = uri.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut k = 0;
    while k < b.len() {
        if b[k] == b'%' {
            let hex = std::str::from_utf8(b.get(k + 1..k + 3)?).ok()?;
            out.push(u8::from_str_radix(hex, 16).ok()?);
            k += 3;
        } else {
            out.push(b[k]);
            k += 1;
        }
    }
    Some(out)
}

/// Whether the `.gltf` at `gltf` is a regular file octolod wrote whose
/// `buffers[].uri` names `bin` (a file beside it).
fn gltf_names_bin(gltf: &Path, bin: &Path) -> bool {
    use std::os::unix::ffi::OsStrExt;
    if !fs::symlink_metadata(gltf).is_ok_and(|m| m.is_file()) || parent_dir(gltf) != parent_dir(bin) {
        return false;
    }
    let Some(name) = bin.file_name() else { return false };
    gltf_json(gltf).is_some_and(|v| {
        gltf_is_ours(&v)
            && v["buffers"].as_array().is_some_and(|bufs| bufs.iter().any(|b| b["uri"].as_str().and_then(uri_file_name).is_some_and(|n| n == name.as_bytes())))
    })
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
/// replacement would delete `p`, a directory holding it or a file inside it
/// is refused.
pub fn protect(p: &Path) -> Protected {
    static N: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let id = N.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let abs = fs::canonicalize(p).unwrap_or_else(|_| std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf()));
    PROTECTED.lock().unwrap_or_else(|e| e.into_inner()).push((id, abs));
    Protected(id)
}

/// A protected path at or under `dest`, or a protected directory holding
/// `dest`, if any; and `dest` canonical.
fn protected_near(dest: &Path) -> Option<(PathBuf, PathBuf)> {
    let d = fs::canonicalize(dest).ok()?;
    let l = PROTECTED.lock().unwrap_or_else(|e| e.into_inner());
    let p = l.iter().map(|(_, p)| p).find(|p| p.starts_with(&d) || d.starts_with(p)).cloned()?;
    Some((p, d))
}

/// Refuses `dest` when replacing it would touch a protected path.
fn check_protected(dest: &Path) -> Result<()> {
    let Some((p, d)) = protected_near(dest) else { return Ok(()) };
    let what = if d == p {
        "is".to_string()
    } else if d.starts_with(&p) {
        format!("is inside {},", p.display())
    } else {
        format!("holds {},", p.display())
    };
    Err(Error::Usage(format!("{} {what} an input of this command; refusing to replace it (choose another output path)", dest.display())))
}

fn what_is(meta: &fs::Metadata) -> &'static str {
    if meta.is_dir() {
        "a directory"
    } else if meta.is_file() {
        "a file"
    } else {
        "something else"
    }
}

// -------------------------------------------------------------------- checks

/// Refuses `dest` unless it is free, or a complete output of `kind` that
/// holds only octolod's files and no protected path, and `force` is set.
/// For a `.gltf` ([`OutputKind::Gltf`]), its `.bin` ([`gltf_bin_path`]) too:
/// free, or named by the old `.gltf`, which is octolod's. Call before any
/// work starts (it is checked again at commit).
pub fn check_output(dest: &Path, kind: OutputKind, force: bool) -> Result<()> {
    if !kind.is_dir() && dest.as_os_str().as_encoded_bytes().ends_with(b"/") {
        return Err(Error::Usage(format!("{}: {} is a file, but the path ends with '/'", dest.display(), kind.describe())));
    }
    if kind == OutputKind::Gltf && is_gltf_pair(dest) {
        // Refusals first (they hold with --force too), then the want of --force.
        let bin = gltf_bin_path(dest);
        let main = refusal(dest, kind)?;
        let old_bin = bin_refusal(&bin, dest)?;
        if main {
            needs_force(dest, kind, force)?;
        }
        if old_bin && !force {
            return Err(Error::Usage(format!("{} already exists (the buffer of a glTF written by octolod); pass --force to replace it", bin.display())));
        }
        return Ok(());
    }
    if refusal(dest, kind)? {
        needs_force(dest, kind, force)?;
    }
    Ok(())
}

/// What refuses `dest` whatever `--force` says: something there that is not
/// a complete output of `kind`, or that touches a protected path. Gives
/// whether `dest` exists.
fn refusal(dest: &Path, kind: OutputKind) -> Result<bool> {
    let Ok(meta) = fs::symlink_metadata(dest) else { return Ok(false) };
    if meta.file_type().is_symlink() || !kind.recognise(dest) {
        return Err(Error::Usage(format!(
            "{} already exists and is {} that is not {}; refusing to replace it (remove it yourself or choose another output path)",
            dest.display(),
            what_is(&meta),
            kind.describe()
        )));
    }
    check_protected(dest)?;
    Ok(true)
}

/// The rest of [`check_output`] for an existing output of `kind`: `force`,
/// and (directories) nothing in it but octolod's files.
fn needs_force(dest: &Path, kind: OutputKind, force: bool) -> Result<()> {
    if !force {
        return Err(Error::Usage(format!("{} already exists ({}); pass --force to replace it", dest.display(), kind.describe())));
    }
    if kind.is_dir() {
        let (_, foreign) = foreign_entries(dest, &kind.own_entries(dest), kind.marker().map(|m| m.2));
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

/// [`refusal`] for the `.bin` of the `.gltf` at `gltf`: it may be replaced
/// only when it is a regular file that the old `.gltf`, octolod's, names.
/// Gives whether `bin` exists.
fn bin_refusal(bin: &Path, gltf: &Path) -> Result<bool> {
    let Ok(meta) = fs::symlink_metadata(bin) else { return Ok(false) };
    if !(meta.is_file() && gltf_names_bin(gltf, bin)) {
        return Err(Error::Usage(format!(
            "{} already exists and is {} that is not the buffer of a glTF octolod wrote at {}; refusing to replace it (remove it yourself or choose another output path)",
            bin.display(),
            what_is(&meta),
            gltf.display()
        )));
    }
    check_protected(bin)?;
    Ok(true)
}

/// Removes an old directory output of `kind` (moved aside to `old`, once
/// at `dest`) file by file: only what octolod wrote. Anything else found
/// in it (added while this run worked) is kept, under a visible name next
/// to `dest`.
fn remove_old_output(old: &Path, dest: &Path, own: &OwnEntries, kind: OutputKind) {
    let sub = kind.marker().map(|m| m.2);
    let (mine, _) = foreign_entries(old, own, sub);
    for rel in &mine {
        let _ = fs::remove_file(old.join(rel));
    }
    if let Some(s) = sub {
        let _ = fs::remove_dir(old.join(s));
    }
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
    if !kind.is_dir() {
        return place_file(tmp, dest);
    }
    if fs::symlink_metadata(dest).is_err() {
        // No-replace semantics: a directory rename fails onto a non-empty one.
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

/// Moves file `tmp` to `dest`: a hard link when `dest` is free (which
/// fails, rather than replace, when the name was taken meanwhile), a rename
/// over the checked old output otherwise.
fn place_file(tmp: &Path, dest: &Path) -> Result<()> {
    if fs::symlink_metadata(dest).is_err() {
        fs::hard_link(tmp, dest).ctx(dest, "move into place")?;
        return fs::remove_file(tmp).ctx(tmp, "remove temp file");
    }
    fs::rename(tmp, dest).ctx(dest, "rename into place")
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
    /// so it never waits for the file's writeback (the build's soup, when
    /// it writes one).
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

/// A `.gltf` and the `.bin` beside it ([`gltf_bin_path`]), written as one
/// output: each under a temp name next to it (locked, registered and swept
/// like every temp path, see [`super::temp`]), both removed if dropped
/// uncommitted, and on [`AtomicGltfPair::commit`] moved into place only
/// once both are completely written and synced: the `.bin` first, so a new
/// `.gltf` under its final name always has its whole buffer beside it.
/// What may be replaced: see [`check_output`] ([`OutputKind::Gltf`]).
pub struct AtomicGltfPair {
    json: AtomicFile,
    bin: AtomicFile,
}

impl AtomicGltfPair {
    /// Checks `gltf` and its `.bin` (see [`check_output`]), then creates
    /// both temp files, and their directory if missing.
    pub fn create(gltf: impl AsRef<Path>, force: bool) -> Result<AtomicGltfPair> {
        let gltf = gltf.as_ref();
        if !is_gltf_pair(gltf) {
            return Err(Error::Usage(format!("{}: a glTF with its buffer beside it ends in .gltf", gltf.display())));
        }
        let json = AtomicFile::create(gltf, OutputKind::Gltf, force)?;
        let dest = gltf_bin_path(gltf);
        let (tmp, f) = temp::create_temp_file(&dest)?;
        let bin = AtomicFile { tmp, dest, kind: OutputKind::Gltf, force, writer: Some(BufWriter::with_capacity(super::SEQ_BUF, f)), sync: true };
        Ok(AtomicGltfPair { json, bin })
    }
    /// The `.gltf`'s JSON.
    pub fn json(&mut self) -> &mut BufWriter<File> {
        self.json.writer()
    }
    /// The `.bin`'s bytes.
    pub fn bin(&mut self) -> &mut BufWriter<File> {
        self.bin.writer()
    }
    pub fn dest(&self) -> &Path {
        &self.json.dest
    }
    pub fn bin_dest(&self) -> &Path {
        &self.bin.dest
    }

    /// Flushes and syncs both, checks both paths again, then moves the
    /// `.bin` and the `.gltf` into place. When the `.gltf` cannot be placed
    /// (its path changed while we worked), the old `.bin` is put back.
    pub fn commit(mut self) -> Result<()> {
        let r = self.commit_both();
        for f in [&mut self.json, &mut self.bin] {
            // Writers taken: Drop leaves the temp names to this.
            f.writer = None;
            let _ = fs::remove_file(&f.tmp);
            temp::unregister(&f.tmp);
        }
        r
    }

    fn commit_both(&mut self) -> Result<()> {
        let finish = |f: &mut AtomicFile| -> Result<File> {
            let w = f.writer.take().expect("writer taken");
            let file = w.into_inner().map_err(|e| e.into_error()).ctx(&f.tmp, "write")?;
            file.sync_all().ctx(&f.tmp, "sync")?;
            Ok(file)
        };
        // Still open (and locked) until moved.
        let _json_file = finish(&mut self.json)?;
        let bin_file = finish(&mut self.bin)?;
        super::signal::check()?;
        let (gltf, bin, force) = (self.json.dest.clone(), self.bin.dest.clone(), self.json.force);
        // Both again, as before the work: either may have changed since.
        check_output(&gltf, OutputKind::Gltf, force)?;
        // POSIX renames one name at a time. The old buffer stays reachable
        // (a hard link under a locked temp name) until the new .gltf is in
        // place, so a failure to place the .gltf puts it back. What remains
        // is the window between the two renames (no safe point in it: a
        // signal waits for the end): a crash, power cut or SIGKILL there
        // leaves the new .bin beside the old .gltf. If octolod wrote that
        // .gltf (it names this .bin), a reader sees a buffer of another
        // layout (usually of another byteLength, which loaders reject), and
        // `--force` replaces the pair; without an old .gltf, a lone new .bin
        // that no .gltf names, which later runs refuse to replace (remove it
        // by hand). Directories are not synced: a power cut may also lose
        // either rename, as for every output.
        let aside = if fs::symlink_metadata(&bin).is_ok() { Some(Aside::keep(&bin)?) } else { None };
        let moved = match &aside {
            Some(_) => fs::rename(&self.bin.tmp, &bin).ctx(&bin, "rename into place"),
            None => fs::hard_link(&self.bin.tmp, &bin).ctx(&bin, "move into place"),
        };
        if let Err(e) = moved {
            if let Some(a) = aside {
                a.discard();
            }
            return Err(e);
        }
        #[cfg(test)]
        tests::BETWEEN.with(|h| h.borrow_mut().take().map(|f| f(&gltf)));
        let placed = refusal(&gltf, OutputKind::Gltf)
            .and_then(|old| if old { needs_force(&gltf, OutputKind::Gltf, force) } else { Ok(()) })
            .and_then(|()| place_file(&self.json.tmp, &gltf));
        match (placed, aside) {
            (Ok(()), aside) => {
                if let Some(a) = aside {
                    a.discard();
                }
                Ok(())
            }
            (Err(e), Some(a)) => {
                a.restore(&bin);
                Err(e)
            }
            (Err(e), None) => {
                use std::os::unix::fs::MetadataExt;
                // Ours (the same file) still: taken back.
                let ours = |m: fs::Metadata| bin_file.metadata().is_ok_and(|f| f.ino() == m.ino() && f.dev() == m.dev());
                if fs::symlink_metadata(&bin).is_ok_and(ours) {
                    let _ = fs::remove_file(&bin);
                }
                Err(e)
            }
        }
    }
}

/// An old output file kept under a locked temp name while its replacement
/// is committed.
struct Aside {
    path: PathBuf,
    _lock: File,
}

impl Aside {
    fn keep(p: &Path) -> Result<Aside> {
        let f = File::open(p).ctx(p, "open")?;
        // Locked, so another run's sweep keeps it (best effort: the sweep
        // also keeps what it cannot open).
        // SAFETY: flock on a valid open descriptor.
        unsafe {
            use std::os::unix::io::AsRawFd;
            libc::flock(f.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB);
        }
        let path = temp::temp_name(p);
        temp::register(&path);
        if let Err(e) = fs::hard_link(p, &path) {
            temp::unregister(&path);
            return Err(Error::io(path, "keep the old file", e));
        }
        Ok(Aside { path, _lock: f })
    }
    fn discard(self) {
        let _ = fs::remove_file(&self.path);
        temp::unregister(&self.path);
    }
    fn restore(self, p: &Path) {
        if fs::rename(&self.path, p).is_err() {
            let _ = fs::remove_file(&self.path);
        }
        temp::unregister(&self.path);
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
        if let Some((name, first, sub)) = self.kind.marker() {
            // The marker lists every file the command wrote, so a later
            // `--force` replaces exactly those.
            let (mut mine, _) = foreign_entries(&self.tmp, &OwnEntries::All, Some(sub));
            mine.sort();
            let mut text = format!("{first}\n");
            for p in mine.iter().filter(|p| *p != Path::new(name)) {
                text.push_str(&p.to_string_lossy());
                text.push('\n');
            }
            let m = self.tmp.join(name);
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

    /// A merged store's pack parts are its own up to its header's part
    /// number; a part beyond it, or a name like one, is not.
    #[test]
    fn a_merged_stores_pack_parts_are_its_own() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("s.octolod");
        fake_store(&p, b"old");
        let mut b = fs::read(p.join("nodes.bin")).unwrap();
        b.resize(40, 0);
        b[20..24].copy_from_slice(&2u32.to_le_bytes());
        b[36..40].copy_from_slice(&3u32.to_le_bytes());
        fs::write(p.join("nodes.bin"), b).unwrap();
        for f in ["level-0.part-1.pack", "level-1.part-3.pack", "level-1.pack"] {
            fs::write(p.join(f), b"").unwrap();
        }
        let own = OutputKind::Store.own_entries(&p);
        for (f, mine) in [
            ("level-1.part-3.pack", true),
            ("level-1.part-4.pack", false),
            ("level-2.part-1.pack", false),
            ("level-0.part-0.pack", false),
            ("level-0.part-01.pack", false),
            ("level-0.part-.pack", false),
            ("level-1.pack", true),
            ("level-2.pack", false),
        ] {
            assert_eq!(own.holds(Path::new(f)), mine, "{f}");
        }
        fs::write(p.join("level-0.part-9.pack"), b"mine").unwrap();
        assert!(AtomicDir::create(&p, OutputKind::Store, true).is_err());
        fs::remove_file(p.join("level-0.part-9.pack")).unwrap();
        let a = AtomicDir::create(&p, OutputKind::Store, true).unwrap();
        fake_store(a.path(), b"new");
        a.commit().unwrap();
        assert_eq!(names(&p), ["nodes.bin"]);
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

    type Hook = Option<Box<dyn FnOnce(&Path)>>;

    thread_local! {
        /// Run between the placements of a glTF pair's `.bin` and `.gltf`.
        pub(super) static BETWEEN: std::cell::RefCell<Hook> = const { std::cell::RefCell::new(None) };
    }

    #[test]
    fn a_gltf_that_cannot_be_placed_after_its_bin_puts_the_old_bin_back() {
        let d = tempfile::tempdir().unwrap();
        let g = d.path().join("m.gltf");
        let bin = d.path().join("m.bin");
        write_pair(&g, false, "m.bin", b"old").unwrap();
        let old_json = fs::read(&g).unwrap();
        // The old .gltf turns into a user's file once the .bin is placed.
        BETWEEN.with(|h| *h.borrow_mut() = Some(Box::new(|g: &Path| fs::write(g, "user's").unwrap())));
        let e = write_pair(&g, true, "m.bin", b"new").unwrap_err().to_string();
        assert!(e.contains("refusing"), "{e}");
        assert_eq!(fs::read(&bin).unwrap(), b"old", "the old buffer is back");
        assert_eq!(fs::read(&g).unwrap(), b"user's");
        assert_eq!(names(d.path()), ["m.bin", "m.gltf"]);
        // A fresh pair: the new .bin is taken back.
        fs::write(&g, &old_json).unwrap();
        let g2 = d.path().join("n.gltf");
        BETWEEN.with(|h| *h.borrow_mut() = Some(Box::new(|g: &Path| fs::create_dir(g).unwrap())));
        assert!(write_pair(&g2, false, "n.bin", b"new").is_err());
        assert_eq!(names(d.path()), ["m.bin", "m.gltf", "n.gltf"]);
        assert!(d.path().join("n.gltf").is_dir());
    }

    /// glTF JSON of ours (or not) naming `uri` as its buffer.
    fn gltf_text(ours: bool, uri: &str) -> String {
        let mark = if ours { r#","extras":{"octolod":"output"}"# } else { "" };
        format!(r#"{{"asset":{{"version":"2.0"{mark}}},"buffers":[{{"uri":"{uri}","byteLength":3}}]}}"#)
    }

    fn write_pair(g: &Path, force: bool, uri: &str, bin: &[u8]) -> Result<()> {
        let mut p = AtomicGltfPair::create(g, force)?;
        p.json().write_all(gltf_text(true, uri).as_bytes()).unwrap();
        p.bin().write_all(bin).unwrap();
        p.commit()
    }

    #[test]
    fn gltf_outputs_are_recognised_by_their_marker() {
        let d = tempfile::tempdir().unwrap();
        let (ours, theirs, glb) = (d.path().join("a.gltf"), d.path().join("b.gltf"), d.path().join("c.glb"));
        fs::write(&ours, gltf_text(true, "a.bin")).unwrap();
        fs::write(&theirs, gltf_text(false, "b.bin")).unwrap();
        // A GLB: header, then the JSON chunk.
        let json = br#"{"asset":{"version":"2.0","extras":{"octolod":"output"}}}  "#;
        let mut b = b"glTF".to_vec();
        for x in [2u32, 20 + json.len() as u32, json.len() as u32] {
            b.extend_from_slice(&x.to_le_bytes());
        }
        b.extend_from_slice(b"JSON");
        b.extend_from_slice(json);
        fs::write(&glb, &b).unwrap();
        assert!(OutputKind::Gltf.recognise(&ours) && OutputKind::Gltf.recognise(&glb));
        assert!(!OutputKind::Gltf.recognise(&theirs) && !OutputKind::Gltf.recognise(d.path()));
        assert!(gltf_names_bin(&ours, &d.path().join("a.bin")) && !gltf_names_bin(&ours, &d.path().join("b.bin")));
        assert_eq!(uri_file_name("a%20b.bin").unwrap(), b"a b.bin");
        assert!(uri_file_name("../a.bin").is_none() && uri_file_name("data:,x").is_none() && uri_file_name("a%2").is_none());
    }

    #[test]
    fn a_gltf_pair_is_placed_together_and_its_bin_only_when_the_old_gltf_names_it() {
        let d = tempfile::tempdir().unwrap();
        let g = d.path().join("m.gltf");
        let bin = d.path().join("m.bin");
        {
            let mut p = AtomicGltfPair::create(&g, false).unwrap();
            p.json().write_all(b"partial").unwrap();
            p.bin().write_all(b"partial").unwrap();
        }
        assert!(names(d.path()).is_empty(), "dropped: nothing left");
        write_pair(&g, false, "m.bin", b"one").unwrap();
        assert_eq!(names(d.path()), ["m.bin", "m.gltf"]);
        let e = write_pair(&g, false, "m.bin", b"two").unwrap_err().to_string();
        assert!(e.contains("--force"), "{e}");
        write_pair(&g, true, "m.bin", b"two").unwrap();
        assert_eq!(fs::read(&bin).unwrap(), b"two");
        // Percent-encoded, the same name.
        fs::write(&g, gltf_text(true, "m%2Ebin")).unwrap();
        write_pair(&g, true, "m.bin", b"three").unwrap();
        assert_eq!(names(d.path()), ["m.bin", "m.gltf"]);
        // A .bin the old .gltf does not name, or a .gltf of another tool.
        for text in [gltf_text(true, "other.bin"), gltf_text(false, "m.bin")] {
            fs::write(&g, &text).unwrap();
            for force in [false, true] {
                let e = AtomicGltfPair::create(&g, force).err().expect("must refuse").to_string();
                assert!(e.contains("refusing"), "{e}");
            }
        }
        assert_eq!(fs::read(&bin).unwrap(), b"three");
        // A .bin appearing while a fresh pair is written: refused at commit,
        // kept, and nothing of ours left.
        let g2 = d.path().join("n.gltf");
        let mut p = AtomicGltfPair::create(&g2, true).unwrap();
        p.json().write_all(gltf_text(true, "n.bin").as_bytes()).unwrap();
        p.bin().write_all(b"ours").unwrap();
        fs::write(d.path().join("n.bin"), b"user's").unwrap();
        assert!(p.commit().unwrap_err().to_string().contains("refusing"));
        assert_eq!(fs::read(d.path().join("n.bin")).unwrap(), b"user's");
        assert_eq!(names(d.path()), ["m.bin", "m.gltf", "n.bin"]);
        // A protected .bin (the file alone): refused, even named by ours.
        fs::write(&g, gltf_text(true, "m.bin")).unwrap();
        {
            let _guard = protect(&bin);
            let e = AtomicGltfPair::create(&g, true).err().expect("must refuse").to_string();
            assert!(e.contains("m.bin is an input of this command"), "{e}");
        }
        write_pair(&g, true, "m.bin", b"four").unwrap();
        assert_eq!(fs::read(&bin).unwrap(), b"four");
    }

    #[test]
    fn nothing_inside_a_protected_directory_is_replaced() {
        let d = tempfile::tempdir().unwrap();
        let dir = d.path().join("in");
        fs::create_dir(&dir).unwrap();
        let ply = dir.join("o.ply");
        fs::write(&ply, "ply\nformat ascii 1.0\ncomment octolod-output\nend_header\n").unwrap();
        let _g = protect(&dir);
        let e = AtomicFile::create(&ply, OutputKind::Ply, true).err().expect("must refuse").to_string();
        assert!(e.contains("is inside") && e.contains("an input of this command"), "{e}");
        // A new file there is no replacement.
        assert!(AtomicFile::create(dir.join("new.ply"), OutputKind::Ply, false).is_ok());
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
