//! Progress display and run reporting: indicatif bars on a terminal, nothing
//! at all with `--quiet` or when stderr is not a TTY (scripts, CI), and peak
//! memory read from the kernel for the final one-line summaries.
//!
//! Takes: a length, a unit and a quiet flag. Gives: a cheap handle whose
//! `inc` is a no-op when hidden.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::IsTerminal;

/// Whether bars should draw: not quiet and stderr is a terminal.
pub fn visible(quiet: bool) -> bool {
    !quiet && std::io::stderr().is_terminal()
}

#[derive(Clone)]
pub struct Progress {
    bar: Option<ProgressBar>,
}

impl Progress {
    pub fn hidden() -> Progress {
        Progress { bar: None }
    }
    /// A bar counting bytes.
    pub fn bytes(len: u64, msg: &str, quiet: bool) -> Progress {
        Self::make(len, msg, quiet, "{msg:>12} [{bar:40}] {bytes}/{total_bytes} {bytes_per_sec} eta {eta}")
    }
    /// A bar counting items (triangles, nodes, records).
    pub fn items(len: u64, msg: &str, quiet: bool) -> Progress {
        Self::make(len, msg, quiet, "{msg:>12} [{bar:40}] {human_pos}/{human_len} {per_sec} eta {eta}")
    }
    fn make(len: u64, msg: &str, quiet: bool, tpl: &str) -> Progress {
        if !visible(quiet) {
            return Progress::hidden();
        }
        let bar = ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::stderr_with_hz(10));
        bar.set_style(ProgressStyle::with_template(tpl).unwrap().progress_chars("=> "));
        bar.set_message(msg.to_string());
        Progress { bar: Some(bar) }
    }
    #[inline]
    pub fn inc(&self, n: u64) {
        if let Some(b) = &self.bar {
            b.inc(n);
        }
    }
    #[inline]
    pub fn set(&self, pos: u64) {
        if let Some(b) = &self.bar {
            b.set_position(pos);
        }
    }
    pub fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}

/// Peak resident set size of this process in bytes (VmHWM), if the OS tells.
pub fn peak_rss() -> Option<u64> {
    proc_status_kb("VmHWM:").map(|kb| kb * 1024)
}

/// Current resident set size in bytes (VmRSS), if the OS tells.
pub fn current_rss() -> Option<u64> {
    proc_status_kb("VmRSS:").map(|kb| kb * 1024)
}

fn proc_status_kb(key: &str) -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with(key))?;
    line[key.len()..].trim().trim_end_matches("kB").trim().parse().ok()
}

/// Formats a byte count in the largest unit that keeps it at least 1
/// (B, KiB, MiB, GiB), one decimal: for messages where a budget may be tiny.
pub fn bytes(n: u64) -> String {
    let units = ["KiB", "MiB", "GiB", "TiB"];
    if n < 1024 {
        return format!("{n} B");
    }
    let mut x = n as f64 / 1024.0;
    let mut u = 0;
    while x >= 1024.0 && u + 1 < units.len() {
        x /= 1024.0;
        u += 1;
    }
    format!("{x:.1} {}", units[u])
}

/// Formats a byte count as MiB with one decimal.
pub fn mib(bytes: u64) -> String {
    format!("{:.1} MiB", bytes as f64 / (1024.0 * 1024.0))
}

#[cfg(test)]
mod tests {
    #[test]
    fn bytes_picks_a_unit_that_shows_the_figure() {
        assert_eq!(super::bytes(0), "0 B");
        assert_eq!(super::bytes(65536), "64.0 KiB");
        assert_eq!(super::bytes(3 << 20), "3.0 MiB");
        assert_eq!(super::bytes(5 << 30), "5.0 GiB");
    }
}
