//! File plumbing shared by the stages: outputs that appear under their final
//! name only when complete ([`AtomicFile`], [`AtomicDir`]), scratch
//! directories next to the output, and large sequential buffers.
//!
//! Takes: a final path. Gives: a temp path in the same directory that is
//! renamed into place on `commit()` and deleted if dropped uncommitted, so a
//! failed or interrupted run never leaves partial output pretending to be
//! complete.

use crate::error::{IoContext, Result};
use std::fs::{self, File};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// Buffer size for large sequential reads and writes.
pub const SEQ_BUF: usize = 1 << 20;

fn temp_sibling(final_path: &Path, tag: &str) -> PathBuf {
    let name = final_path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "out".into());
    let dir = parent_dir(final_path);
    dir.join(format!(".{name}.{tag}-{}-{}.tmp", std::process::id(), unique()))
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

/// A file written under a temporary name and renamed to its final name on commit.
pub struct AtomicFile {
    tmp: PathBuf,
    dest: PathBuf,
    writer: Option<BufWriter<File>>,
}

impl AtomicFile {
    /// Creates the temp file, and the destination's directory if missing.
    pub fn create(dest: impl AsRef<Path>) -> Result<AtomicFile> {
        let dest = dest.as_ref().to_path_buf();
        ensure_parent(&dest)?;
        let tmp = temp_sibling(&dest, "partial");
        let f = File::create(&tmp).ctx(&tmp, "create")?;
        Ok(AtomicFile { tmp, dest, writer: Some(BufWriter::with_capacity(SEQ_BUF, f)) })
    }
    pub fn writer(&mut self) -> &mut BufWriter<File> {
        self.writer.as_mut().expect("writer taken")
    }
    pub fn dest(&self) -> &Path {
        &self.dest
    }
    /// Flush, sync and rename into place.
    pub fn commit(mut self) -> Result<()> {
        let w = self.writer.take().expect("writer taken");
        let f = w.into_inner().map_err(|e| e.into_error()).ctx(&self.tmp, "write")?;
        f.sync_all().ctx(&self.tmp, "sync")?;
        drop(f);
        fs::rename(&self.tmp, &self.dest).ctx(&self.dest, "rename into place")?;
        Ok(())
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
        }
    }
}

/// A directory built under a temporary name and renamed into place on commit.
/// An existing directory at the final name is replaced only on commit.
pub struct AtomicDir {
    tmp: PathBuf,
    dest: PathBuf,
    done: bool,
}

impl AtomicDir {
    /// Creates the temp directory, and the destination's parent if missing.
    pub fn create(dest: impl AsRef<Path>) -> Result<AtomicDir> {
        let dest = dest.as_ref().to_path_buf();
        ensure_parent(&dest)?;
        let tmp = temp_sibling(&dest, "partial");
        fs::create_dir_all(&tmp).ctx(&tmp, "create directory")?;
        Ok(AtomicDir { tmp, dest, done: false })
    }
    /// The directory to write into.
    pub fn path(&self) -> &Path {
        &self.tmp
    }
    pub fn dest(&self) -> &Path {
        &self.dest
    }
    pub fn commit(mut self) -> Result<()> {
        if self.dest.exists() {
            let old = temp_sibling(&self.dest, "old");
            fs::rename(&self.dest, &old).ctx(&self.dest, "move old output aside")?;
            fs::rename(&self.tmp, &self.dest).ctx(&self.dest, "rename into place")?;
            let _ = fs::remove_dir_all(&old);
        } else {
            fs::rename(&self.tmp, &self.dest).ctx(&self.dest, "rename into place")?;
        }
        self.done = true;
        Ok(())
    }
}

impl Drop for AtomicDir {
    fn drop(&mut self) {
        if !self.done {
            let _ = fs::remove_dir_all(&self.tmp);
        }
    }
}

/// A scratch directory for spill files next to `near` (same filesystem as the
/// output, so large temp data does not land on a small /tmp). Removed on drop.
pub fn scratch_dir(near: &Path) -> Result<tempfile::TempDir> {
    ensure_parent(near)?;
    let dir = parent_dir(near);
    tempfile::Builder::new().prefix(".octolod-scratch-").tempdir_in(&dir).ctx(&dir, "create scratch directory")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uncommitted_file_leaves_nothing() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("x.bin");
        {
            let mut f = AtomicFile::create(&p).unwrap();
            f.write_all(b"partial").unwrap();
        }
        assert!(!p.exists());
        assert_eq!(fs::read_dir(d.path()).unwrap().count(), 0);
        let mut f = AtomicFile::create(&p).unwrap();
        f.write_all(b"whole").unwrap();
        f.commit().unwrap();
        assert_eq!(fs::read(&p).unwrap(), b"whole");
        assert_eq!(fs::read_dir(d.path()).unwrap().count(), 1);
    }

    #[test]
    fn outputs_create_their_directory() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("a/b/x.bin");
        let mut f = AtomicFile::create(&p).unwrap();
        f.write_all(b"1").unwrap();
        f.commit().unwrap();
        assert!(p.exists());
        AtomicDir::create(d.path().join("c/s.octolod")).unwrap().commit().unwrap();
        assert!(d.path().join("c/s.octolod").is_dir());
    }

    #[test]
    fn uncommitted_dir_leaves_nothing_and_commit_replaces() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("s.octolod");
        fs::create_dir(&p).unwrap();
        fs::write(p.join("old"), b"1").unwrap();
        {
            let a = AtomicDir::create(&p).unwrap();
            fs::write(a.path().join("new"), b"2").unwrap();
        }
        assert!(p.join("old").exists());
        let a = AtomicDir::create(&p).unwrap();
        fs::write(a.path().join("new"), b"2").unwrap();
        a.commit().unwrap();
        assert!(p.join("new").exists() && !p.join("old").exists());
        assert_eq!(fs::read_dir(d.path()).unwrap().count(), 1);
    }
}
