//! Signal sweep (issue 37, item 5): `build`, `simplify`, `extract` and
//! `render` interrupted by SIGINT, SIGTERM or SIGHUP at many moments of
//! their run, from before their first output to after their last. Every
//! run must end without a crash (no SIGSEGV/SIGABRT, no panic), with exit
//! status 0 and a complete output, or 128 + the signal and no output at
//! all; and no temp or scratch path may be left behind.
//!
//! The `render` case needs a Vulkan (or GL) adapter (Mesa lavapipe in CI);
//! it is skipped only with OCTOLOD_SKIP_GPU_TESTS=1.

use crate::common::cli::{bin, gen_with, names, octolod_ok, s, wait_or_fail};
use std::os::unix::process::ExitStatusExt;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Instant;

/// How one command's output is checked when it exists.
#[derive(Clone, Copy)]
enum Out {
    Store,
    Ply(u64),
    #[cfg(feature = "view")]
    Frames(usize),
}

fn complete(out: &Path, kind: Out) -> Result<(), String> {
    match kind {
        Out::Store => {
            let st = octolod::store::Store::open(out).map_err(|e| e.to_string())?;
            for l in 0..=st.top_level() {
                let cut = st.level_cut(l);
                for m in st.cut_meshes(&cut) {
                    m.map_err(|e| e.to_string())?;
                }
            }
            Ok(())
        }
        Out::Ply(tris) => {
            let (_, m, _) = octolod::ply::read::read_all(out).map_err(|e| e.to_string())?;
            if tris != 0 && m.triangles.len() as u64 != tris {
                return Err(format!("{} triangles, {tris} expected", m.triangles.len()));
            }
            Ok(())
        }
        #[cfg(feature = "view")]
        Out::Frames(n) => {
            let frames = names(out).iter().filter(|n| n.starts_with("frame-") && n.ends_with(".png")).count();
            let stats: serde_json::Value =
                serde_json::from_slice(&std::fs::read(out.join("stats.json")).map_err(|e| e.to_string())?).map_err(|e| e.to_string())?;
            let listed = stats["frames_rendered"].as_u64().unwrap_or(0) as usize;
            if frames < n || frames != listed || !out.join(".octolod-render").is_file() {
                return Err(format!("{frames} frames on disk, {listed} in stats.json, at least {n} expected"));
            }
            Ok(())
        }
    }
}

/// Runs `args` once to time it, then `runs` times with a signal sent at
/// moments spread from 0 to 1.2 × that time; checks every outcome.
fn sweep(dir: &Path, args: &[&str], out: &Path, kind: Out, runs: usize) -> (usize, usize) {
    let t = Instant::now();
    octolod_ok(args);
    let full = t.elapsed();
    complete(out, kind).unwrap_or_else(|e| panic!("{args:?}: the uninterrupted output is incomplete: {e}"));
    let rm = |p: &Path| {
        if p.is_dir() {
            std::fs::remove_dir_all(p).unwrap()
        } else if p.exists() {
            std::fs::remove_file(p).unwrap()
        }
    };
    rm(out);
    let before = names(dir);
    let (mut finished, mut stopped) = (0, 0);
    for k in 0..runs {
        let (sig, name) = [(libc::SIGINT, "INT"), (libc::SIGTERM, "TERM"), (libc::SIGHUP, "HUP")][k % 3];
        let at = full.mul_f64(1.2 * k as f64 / (runs - 1).max(1) as f64);
        let mut child = Command::new(bin()).args(args).stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
        std::thread::sleep(at);
        // SAFETY: signalling our own child.
        unsafe { libc::kill(child.id() as i32, sig) };
        wait_or_fail(&mut child, 60, &format!("{args:?}, SIG{name},"));
        let o = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        let what = format!("{args:?}, SIG{name} at {:.0} ms of {:.0}: {:?} {err}", at.as_secs_f64() * 1e3, full.as_secs_f64() * 1e3, o.status);
        assert!(!err.contains("panicked"), "{what}");
        match (o.status.code(), o.status.signal()) {
            (Some(0), _) => {
                finished += 1;
                complete(out, kind).unwrap_or_else(|e| panic!("{what}: exit 0 with an incomplete output: {e}"));
            }
            (Some(c), _) if c == 128 + sig => {
                stopped += 1;
                assert!(!out.exists(), "{what}: interrupted, yet {} exists", out.display());
            }
            // Killed before its handler was installed (the process's first
            // instants): nothing was written yet.
            (None, Some(s)) if s == sig => {
                stopped += 1;
                assert!(!out.exists(), "{what}");
            }
            _ => panic!("{what}: neither complete (0) nor interrupted (128 + {sig})"),
        }
        assert_eq!(
            names(dir).iter().filter(|n| !before.contains(n)).filter(|n| **n != out.file_name().unwrap().to_string_lossy()).count(),
            0,
            "{what}: left {:?}",
            names(dir)
        );
        rm(out);
    }
    (finished, stopped)
}

const RUNS: usize = 12;

fn input(dir: &Path, tris: u64) -> std::path::PathBuf {
    let ply = dir.join("in.ply");
    gen_with("sphere", tris, &ply, &["--normals"]);
    ply
}

fn check_both(what: &str, (finished, stopped): (usize, usize)) {
    // The sweep spans the whole run: some signals land before the end.
    assert!(stopped > 0, "{what}: no run was interrupted ({finished} finished)");
}

#[test]
fn build_and_simplify_interrupted_anywhere_leave_a_complete_output_or_none() {
    let d = tempfile::tempdir().unwrap();
    let ply = input(d.path(), 400_000);
    let st = d.path().join("s.octolod");
    let r = sweep(d.path(), &["build", s(&ply), "-o", s(&st), "--mem", "16M", "--quiet"], &st, Out::Store, RUNS);
    check_both("build", r);
    let out = d.path().join("o.ply");
    let r = sweep(d.path(), &["simplify", s(&ply), "-o", s(&out), "--target-tris", "20000", "--mem", "16M", "--quiet"], &out, Out::Ply(0), RUNS);
    check_both("simplify", r);
}

#[test]
fn extract_interrupted_anywhere_leaves_a_complete_output_or_none() {
    let d = tempfile::tempdir().unwrap();
    let ply = input(d.path(), 600_000);
    let st = d.path().join("s.octolod");
    octolod_ok(&["build", s(&ply), "-o", s(&st), "--quiet"]);
    let out = d.path().join("l0.ply");
    let store = octolod::store::Store::open(&st).unwrap();
    let tris = store.level_cut(0).triangles(&store);
    drop(store);
    let r = sweep(d.path(), &["extract", s(&st), "--level", "0", "-o", s(&out)], &out, Out::Ply(tris), RUNS);
    check_both("extract", r);
}

#[test]
#[cfg(feature = "view")]
fn render_interrupted_anywhere_leaves_a_complete_output_or_none() {
    if crate::common::gpu_tests_skipped() {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let ply = input(d.path(), 200_000);
    let st = d.path().join("s.octolod");
    octolod_ok(&["build", s(&ply), "-o", s(&st), "--quiet"]);
    let out = d.path().join("shots");
    let r = sweep(d.path(), &["render", s(&st), "-o", s(&out), "--frames", "16", "--width", "320", "--height", "240", "--quiet"], &out, Out::Frames(16), RUNS);
    check_both("render", r);
}
