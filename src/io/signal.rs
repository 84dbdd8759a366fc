//! SIGINT, SIGTERM and SIGHUP stop a command at a safe point.
//!
//! Takes: the signals (a handler thread installed by [`install`] at the
//! start of every binary). Gives: [`check`], which the stages call between
//! units of work (a batch of records, a node, a frame) and which then
//! returns [`Error::Interrupted`]. The error unwinds the command on its own
//! threads: uncommitted outputs, temp and scratch paths are removed by
//! their owners' `Drop`, nothing is committed after the signal, and the
//! binary exits with 128 + the signal number, as a shell reports a killed
//! command. The output is therefore complete (the command committed it
//! before the signal, exit 0) or absent.
//!
//! Why not clean up in the handler: a handler thread that deletes the temp
//! directory and calls `exit()` races the threads still writing into it
//! (files re-created under a deleted directory, a partial directory
//! renamed into place, `exit()` tearing down the GPU driver under a running
//! frame: crashes and incomplete outputs in 640 signalled runs).
//!
//! A second signal, or a command that reaches no safe point within
//! [`GRACE`], stops at once: the handler removes the registered temp paths
//! and calls `_exit` (no destructors, no atexit handlers) — the promise is
//! then only "no temp paths left"; a committed output is still complete.

use crate::error::{Error, Result};
use std::sync::atomic::{AtomicI32, Ordering};
use std::time::Duration;

/// The first signal received (0: none).
static SIGNALLED: AtomicI32 = AtomicI32::new(0);

/// How long a command may take to reach a safe point after the first signal.
pub const GRACE: Duration = Duration::from_secs(10);

/// Installs the handler thread (once, at the start of a binary).
pub fn install() {
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    let Ok(mut signals) = signal_hook::iterator::Signals::new([SIGINT, SIGTERM, SIGHUP]) else { return };
    std::thread::spawn(move || {
        for sig in signals.forever() {
            if SIGNALLED.compare_exchange(0, sig, Ordering::SeqCst, Ordering::SeqCst).is_ok() {
                std::thread::spawn(move || {
                    std::thread::sleep(GRACE);
                    stop_now(sig)
                });
            } else {
                stop_now(SIGNALLED.load(Ordering::SeqCst));
            }
        }
    });
}

/// Removes this process's registered temp paths and exits at once.
fn stop_now(sig: i32) -> ! {
    super::temp::remove_live_temps();
    // SAFETY: _exit ends the process without running any user code.
    unsafe { libc::_exit(128 + sig) }
}

/// The signal that asked this process to stop, if any.
pub fn interrupted() -> Option<i32> {
    match SIGNALLED.load(Ordering::Relaxed) {
        0 => None,
        s => Some(s),
    }
}

/// A safe point: `Err(Interrupted)` once a signal asked the process to stop.
#[inline]
pub fn check() -> Result<()> {
    match interrupted() {
        None => Ok(()),
        Some(s) => Err(Error::Interrupted(s)),
    }
}

/// The exit status a binary reports for `e`: 128 + the signal for an
/// interruption (also when another error surfaced first while a signal was
/// being handled: work finding its files gone), else 1.
pub fn exit_status(e: &Error) -> u8 {
    match (e, interrupted()) {
        (&Error::Interrupted(s), _) | (_, Some(s)) => (128 + s).clamp(0, 255) as u8,
        _ => 1,
    }
}
