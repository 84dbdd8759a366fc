//! Temp and scratch paths: where a command writes before its output is
//! complete, and how a later run tells a dead run's leftovers from a live
//! run's work.
//!
//! Takes: the final path an output or scratch area belongs next to. Gives:
//! a fresh sibling named `.NAME.octolod-tmp-PID-START-N` (NAME cut so the
//! whole name fits 255 bytes) that its owner holds **locked** (`flock`) for
//! as long as it lives: a temp file is locked itself, a temp directory
//! through its lock file [`LOCK_FILE`]. Creating one first sweeps the same
//! directory: a temp path whose lock can be taken has no live owner and is
//! removed (while holding the lock). So a live run is never swept by
//! another, even one in another PID namespace or on another host sharing
//! the directory (containers, network file systems), where a PID says
//! nothing. A temp directory without a lock file (an older octolod's, or
//! one caught between its creation and its lock) is removed only when it
//! is over an hour old and its PID (with START, its start time, against
//! PID reuse) is gone.
//!
//! Every live temp path is also listed in a process-wide registry that
//! [`remove_live_temps`] empties when a signal must stop the process at once
//! (see [`super::signal`]).

use crate::error::{IoContext, Result};
use std::ffi::OsString;
use std::fs::{self, File, OpenOptions};
use std::os::unix::ffi::{OsStrExt, OsStringExt};
use std::os::unix::fs::MetadataExt;
use std::os::unix::io::AsRawFd;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Duration;

/// The marker between a temp path's name and its owner.
pub(crate) const TMP_TAG: &str = ".octolod-tmp-";
/// The lock file inside a temp or scratch directory.
pub const LOCK_FILE: &str = ".octolod-lock";
/// Longest file name (Linux `NAME_MAX`).
const NAME_MAX: usize = 255;
/// Age after which an unlocked temp directory of a gone PID is removed.
const UNLOCKED_AGE: Duration = Duration::from_secs(3600);

/// Takes `f`'s exclusive lock without waiting: `Ok(false)` when another
/// open file holds it.
fn try_lock(f: &File) -> std::io::Result<bool> {
    // SAFETY: flock on a valid open descriptor.
    if unsafe { libc::flock(f.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } == 0 {
        return Ok(true);
    }
    let e = std::io::Error::last_os_error();
    if e.raw_os_error() == Some(libc::EWOULDBLOCK) {
        Ok(false)
    } else {
        Err(e)
    }
}

/// This process's start time (clock ticks since boot), 0 when unknown.
pub(crate) fn own_start() -> u64 {
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

/// Whether the owner (pid, start) of a temp path is gone by its PID.
/// Unknown (no /proc) counts as alive.
fn owner_gone(pid: u32, start: u64) -> bool {
    if !Path::new("/proc/self/stat").exists() {
        return false;
    }
    match process_start(pid) {
        None => true,
        Some(s) => start != 0 && s != start,
    }
}

/// The owner of a temp name (`.…octolod-tmp-PID-START-N`), if it is one.
fn temp_owner(name: &str) -> Option<(u32, u64)> {
    if !name.starts_with('.') {
        return None;
    }
    let at = name.rfind(TMP_TAG)?;
    let mut f = name[at + TMP_TAG.len()..].split('-');
    let (pid, start, n) = (f.next()?.parse().ok()?, f.next()?.parse().ok()?, f.next()?);
    if f.next().is_some() || n.parse::<u64>().is_err() {
        return None;
    }
    Some((pid, start))
}

/// Removes the temp and scratch paths in `dir` that no live process holds
/// (see the module doc). Returns how many were removed.
pub fn remove_stale_temps(dir: &Path) -> usize {
    let Ok(entries) = fs::read_dir(dir) else { return 0 };
    let mut n = 0;
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some((pid, start)) = temp_owner(&name) else { continue };
        let p = e.path();
        let Ok(meta) = fs::symlink_metadata(&p) else { continue };
        let removed = if meta.is_dir() {
            match OpenOptions::new().read(true).write(true).open(p.join(LOCK_FILE)) {
                // Removed while we hold its lock: no owner can take it meanwhile.
                Ok(lock) => matches!(try_lock(&lock), Ok(true)) && remove_path(&p),
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                    let old = meta.modified().ok().and_then(|m| m.elapsed().ok()).is_some_and(|a| a > UNLOCKED_AGE);
                    old && owner_gone(pid, start) && remove_path(&p)
                }
                Err(_) => false,
            }
        } else if meta.is_file() {
            match OpenOptions::new().read(true).write(true).open(&p) {
                Ok(f) => matches!(try_lock(&f), Ok(true)) && fs::remove_file(&p).is_ok(),
                Err(_) => false,
            }
        } else {
            false
        };
        n += removed as usize;
    }
    n
}

pub(crate) fn remove_path(p: &Path) -> bool {
    match fs::symlink_metadata(p) {
        Ok(m) if m.is_dir() => fs::remove_dir_all(p).is_ok(),
        Ok(_) => fs::remove_file(p).is_ok(),
        Err(_) => false,
    }
}

/// Temp paths this process owns now (removed by [`remove_live_temps`]).
static LIVE: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

pub(crate) fn register(p: &Path) {
    LIVE.lock().unwrap_or_else(|e| e.into_inner()).push(p.to_path_buf());
}

pub(crate) fn unregister(p: &Path) {
    let mut l = LIVE.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(i) = l.iter().rposition(|x| x == p) {
        l.swap_remove(i);
    }
}

/// Removes every temp and scratch path this process owns (for a stop at
/// once: call, then `_exit`). Worker threads may still be writing into a
/// temp directory, so a directory is retried a few times.
pub fn remove_live_temps() {
    let paths: Vec<PathBuf> = std::mem::take(&mut *LIVE.lock().unwrap_or_else(|e| e.into_inner()));
    for p in paths {
        for _ in 0..5 {
            if remove_path(&p) || fs::symlink_metadata(&p).is_err() {
                break;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

/// A fresh temp name next to `final_path` (no sweep, nothing created).
pub(crate) fn temp_name(final_path: &Path) -> PathBuf {
    static N: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n = N.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let name = final_path.file_name().map(|n| n.as_bytes().to_vec()).unwrap_or_else(|| b"out".to_vec());
    let tail = format!("{TMP_TAG}{}-{}-{n}", std::process::id(), own_start());
    // `.` + as much of the name as fits + the tail.
    let keep = name.len().min(NAME_MAX - 1 - tail.len());
    let mut b = Vec::with_capacity(NAME_MAX);
    b.push(b'.');
    b.extend_from_slice(&name[..keep]);
    b.extend_from_slice(tail.as_bytes());
    parent_dir(final_path).join(OsString::from_vec(b))
}

/// The directory a path lives in (`.` for a bare file name).
pub fn parent_dir(p: &Path) -> PathBuf {
    match p.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// A live temp directory's lock: held while the value lives.
pub(crate) struct DirLock {
    _file: File,
    dir: PathBuf,
}

impl DirLock {
    /// Removes the lock file (the directory is about to be renamed into
    /// place as an output, which must not hold it); the lock stays held
    /// on the open file until `self` drops.
    pub(crate) fn remove_file(&self) -> Result<()> {
        let p = self.dir.join(LOCK_FILE);
        fs::remove_file(&p).ctx(&p, "remove lock file")
    }
}

/// Tries a few fresh names (a name can be taken, or swept between its
/// creation and its lock: the module doc's sweep removes only what it
/// could lock, so a creator that gets its lock owns the path).
const TRIES: usize = 16;

/// Creates and locks a temp file next to `final_path`, after sweeping its
/// directory; registered as live.
pub(crate) fn create_temp_file(final_path: &Path) -> Result<(PathBuf, File)> {
    remove_stale_temps(&parent_dir(final_path));
    let mut last = None;
    for _ in 0..TRIES {
        let tmp = temp_name(final_path);
        let f = match OpenOptions::new().read(true).write(true).create_new(true).open(&tmp) {
            Ok(f) => f,
            Err(e) => {
                last = Some((tmp, e));
                continue;
            }
        };
        // Locked, and still the file at that name (not swept meanwhile).
        let same = |f: &File| Some(fs::metadata(&tmp).ok()?.ino() == f.metadata().ok()?.ino());
        if matches!(try_lock(&f), Ok(true)) && same(&f) == Some(true) {
            register(&tmp);
            return Ok((tmp, f));
        }
    }
    let (tmp, e) = last.unwrap_or_else(|| (temp_name(final_path), std::io::Error::other("swept while being created")));
    Err(crate::error::Error::io(tmp, "create", e))
}

/// Creates and locks a temp directory next to `final_path`, after
/// sweeping its directory; registered as live.
pub(crate) fn create_temp_dir(final_path: &Path) -> Result<(PathBuf, DirLock)> {
    remove_stale_temps(&parent_dir(final_path));
    let mut last = None;
    for _ in 0..TRIES {
        let tmp = temp_name(final_path);
        if let Err(e) = fs::create_dir(&tmp) {
            last = Some((tmp, e));
            continue;
        }
        let lock = OpenOptions::new().read(true).write(true).create_new(true).open(tmp.join(LOCK_FILE));
        match lock {
            Ok(f) if matches!(try_lock(&f), Ok(true)) => {
                register(&tmp);
                return Ok((tmp.clone(), DirLock { _file: f, dir: tmp }));
            }
            Ok(_) => continue,
            Err(e) => last = Some((tmp, e)),
        }
    }
    let (tmp, e) = last.unwrap_or_else(|| (temp_name(final_path), std::io::Error::other("swept while being created")));
    Err(crate::error::Error::io(tmp, "create directory", e))
}

/// A scratch directory for spill files (named, locked and registered like
/// every temp path); removed on drop.
pub struct ScratchDir {
    path: PathBuf,
    _lock: DirLock,
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

/// Creates a [`ScratchDir`] in the directory of `near` (the same file
/// system as the output, so large temp data does not land on a small /tmp),
/// creating that directory if missing.
pub fn scratch_dir(near: &Path) -> Result<ScratchDir> {
    let dir = parent_dir(near);
    fs::create_dir_all(&dir).ctx(&dir, "create output directory")?;
    scratch_in(&dir)
}

/// Creates a [`ScratchDir`] inside directory `dir`.
pub fn scratch_in(dir: &Path) -> Result<ScratchDir> {
    let (path, lock) = create_temp_dir(&dir.join("octolod-scratch"))?;
    Ok(ScratchDir { path, _lock: lock })
}

#[cfg(test)]
mod tests {
    use super::super::tests::names;
    use super::*;

    #[test]
    fn unlocked_temps_are_swept_and_locked_ones_kept_whatever_their_pid_says() {
        let d = tempfile::tempdir().unwrap();
        // A dead owner's file (no lock held), and a file whose PID is not
        // visible here (another namespace or host) but whose owner holds it.
        let dead = d.path().join(format!(".o.ply{TMP_TAG}4194305-1-0"));
        fs::write(&dead, b"x").unwrap();
        let elsewhere = d.path().join(format!(".p.ply{TMP_TAG}4194306-1-0"));
        fs::write(&elsewhere, b"x").unwrap();
        let held = File::options().read(true).write(true).open(&elsewhere).unwrap();
        // flock locks belong to the open file: another open of the same
        // file in this process conflicts like another process would.
        assert!(try_lock(&held).unwrap());
        // A dead owner's directory with its lock file, one held elsewhere.
        let dead_dir = d.path().join(format!(".s.octolod{TMP_TAG}4194305-1-1"));
        fs::create_dir(&dead_dir).unwrap();
        fs::write(dead_dir.join(LOCK_FILE), b"").unwrap();
        fs::write(dead_dir.join("level-0.pack"), b"x").unwrap();
        let live_dir = d.path().join(format!(".t.octolod{TMP_TAG}4194306-1-1"));
        fs::create_dir(&live_dir).unwrap();
        fs::write(live_dir.join(LOCK_FILE), b"").unwrap();
        let dir_lock = File::options().read(true).write(true).open(live_dir.join(LOCK_FILE)).unwrap();
        assert!(try_lock(&dir_lock).unwrap());
        // A fresh directory with no lock file (an older octolod's): kept
        // for an hour even though its PID is gone.
        let legacy = d.path().join(format!(".u.octolod{TMP_TAG}4194305-1-2"));
        fs::create_dir(&legacy).unwrap();
        let user = d.path().join(".hidden-user-file-1-2-3");
        fs::write(&user, b"x").unwrap();
        assert_eq!(remove_stale_temps(d.path()), 2);
        assert!(!dead.exists() && !dead_dir.exists());
        assert!(elsewhere.exists() && live_dir.exists() && legacy.exists() && user.exists());
        drop((held, dir_lock));
        assert_eq!(remove_stale_temps(d.path()), 2, "unlocked once their owners are gone");
        assert!(legacy.exists() && user.exists());
    }

    #[test]
    fn our_own_temps_are_kept_by_a_sweep_until_dropped() {
        let d = tempfile::tempdir().unwrap();
        let s = scratch_dir(&d.path().join("out.soup")).unwrap();
        let (f, file) = create_temp_file(&d.path().join("x.ply")).unwrap();
        assert_eq!(remove_stale_temps(d.path()), 0);
        assert!(s.path().is_dir() && f.is_file());
        let sp = s.path().to_path_buf();
        drop(s);
        assert!(!sp.exists());
        drop(file);
        assert_eq!(remove_stale_temps(d.path()), 1);
        assert!(names(d.path()).is_empty());
    }

    #[test]
    fn temp_names_fit_the_file_name_limit() {
        let long = "n".repeat(250) + ".ply";
        let t = temp_name(&Path::new("/x").join(&long));
        let name = t.file_name().unwrap().as_bytes();
        assert!(name.len() <= NAME_MAX, "{}", name.len());
        assert!(temp_owner(&String::from_utf8_lossy(name)).is_some());
        // Names that are not UTF-8 keep their bytes.
        let odd = OsString::from_vec(b"caf\xe9.ply".to_vec());
        let t = temp_name(&Path::new("/x").join(&odd));
        assert!(t.file_name().unwrap().as_bytes().starts_with(b".caf\xe9.ply.octolod-tmp-"));
    }
}
