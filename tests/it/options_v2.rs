//! Issue "Reliability v2", items 6 and 13: counts and option values that
//! panicked, ran away with memory, failed late or quietly gave something
//! else than asked are checked before any work, and the edge cases they
//! reached (the coarsest level, an empty top level, a mesh against itself)
//! give what the commands promise.

use crate::common::cli::{gen, names, octolod, run_limited, s};
use std::path::Path;

fn build(ply: &Path, st: &Path, extra: &[&str]) {
    let mut args = vec!["build", s(ply), "-o", s(st), "--quiet"];
    args.extend_from_slice(extra);
    let o = octolod(&args);
    assert!(o.status.success(), "{args:?}: {}", String::from_utf8_lossy(&o.stderr));
}

/// `info`'s "root: N triangles" and the top level's triangles.
fn root_and_top(st: &Path) -> (u64, u64) {
    let o = octolod(&["info", s(st)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    let root = out.split("root: ").nth(1).and_then(|r| r.split(' ').next()).and_then(|n| n.parse().ok()).unwrap_or_else(|| panic!("{out}"));
    let levels: Vec<Vec<&str>> = out.lines().map(|l| l.split_whitespace().collect::<Vec<_>>()).filter(|w| w.len() > 3 && w[0].parse::<u8>().is_ok()).collect();
    let top = levels.last().unwrap_or_else(|| panic!("{out}"))[2].parse().unwrap();
    (root, top)
}

// ---------------------------------------------------------------------------
// Item 6: render counts.

/// `--settle 2^64-1` panicked after committing an empty render directory
/// (the pose count plus --settle wrapped); `"hold": 1e18` panicked with a
/// capacity overflow; `--frames 1e9` and `"frames_between": 1e15` grew
/// memory until abort. Now each is a usage error naming the option or the
/// field and the limit, before the output directory exists.
#[test]
#[cfg(feature = "view")]
fn render_counts_are_bounded_before_any_work() {
    let d = tempfile::tempdir().unwrap();
    let ply = d.path().join("a.ply");
    gen("sphere", 2000, &ply);
    let st = d.path().join("a.octolod");
    build(&ply, &st, &[]);
    let key = r#"{"eye":[0,0,0],"target":[1,1,1]},{"eye":[0,1,0],"target":[1,1,1]}"#;
    let hold = d.path().join("hold.json");
    std::fs::write(&hold, r#"{"frames":[{"eye":[0,0,0],"target":[1,1,1]}],"hold":1e18}"#).unwrap();
    let between = d.path().join("between.json");
    std::fs::write(&between, format!(r#"{{"keyframes":[{key}],"frames_between":1e15}}"#)).unwrap();
    let before = names(d.path());
    let out = d.path().join("frames");
    let small = ["--width", "64", "--height", "48", "--quiet"];
    for (extra, want) in [
        (vec!["--frames", "1", "--settle", "18446744073709551615"], "--settle 18446744073709551615"),
        (vec!["--frames", "1000000000"], "--frames 1000000000"),
        (vec!["--frames", "60", "--settle", "99941"], "--settle 99941"),
        (vec!["--camera-path", s(&hold)], "\"hold\""),
        (vec!["--camera-path", s(&between)], "\"frames_between\""),
    ] {
        let mut args = vec!["render", s(&st), "--out", s(&out)];
        args.extend_from_slice(&small);
        args.extend_from_slice(&extra);
        let (code, err) = run_limited(&args, 120);
        assert_eq!(code, Some(1), "{extra:?}: {err}");
        assert!(err.contains(want) && err.contains("100000"), "{extra:?}: {err}");
        assert!(!err.contains("panicked"), "{extra:?}: {err}");
        assert!(!out.exists(), "{extra:?} left a render directory");
        assert_eq!(names(d.path()), before, "{extra:?} left something behind");
    }
}

// ---------------------------------------------------------------------------
// Item 13: simplify, build and metro option values and edge cases.

/// 13a: `--target-error 100%` failed ("no triangles to measure": the
/// collapse limit let the whole mesh go) and an error just above the
/// coarsest level's measured one gave a finer level. Any error at least
/// the coarsest level's measured error returns that level, exit 0.
#[test]
fn an_error_target_the_coarsest_level_meets_returns_it() {
    let d = tempfile::tempdir().unwrap();
    let ply = d.path().join("a.ply");
    gen("sphere", 20_000, &ply);
    // The store `simplify` builds: the same build options.
    let st = d.path().join("a.octolod");
    build(&ply, &st, &[]);
    let (root, top) = root_and_top(&st);
    assert!(root > 0 && root == top, "root {root}, top level {top}");
    for simplifier in ["collapse", "cluster"] {
        let run = |e: &str, name: &str| -> serde_json::Value {
            let out = d.path().join(format!("{simplifier}-{name}.ply"));
            let o = octolod(&["simplify", s(&ply), "-o", s(&out), "--target-error", e, "--simplifier", simplifier, "--json", "--quiet"]);
            let err = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(0), "{simplifier} --target-error {e}: {err}");
            serde_json::from_slice(&o.stdout).unwrap_or_else(|x| panic!("{x}: {}", String::from_utf8_lossy(&o.stdout)))
        };
        let all = run("100%", "all");
        assert_eq!(all["triangles"].as_u64(), Some(root), "{simplifier} 100%: {all}");
        assert_eq!(all["reached"].as_bool(), Some(true), "{all}");
        // Exactly the coarsest level's measured error.
        let h = all["hausdorff"].as_f64().unwrap();
        assert!(h > 0.0);
        let at = run(&format!("{h:e}"), "at");
        assert_eq!(at["triangles"].as_u64(), Some(root), "{simplifier} E = {h:e}: {at}");
        assert!(at["hausdorff"].as_f64().unwrap() <= h, "{at}");
    }
}

/// 13b: `--target-tris 0` wrote an empty PLY with exit 0; 13g: a bad
/// `--target-ratio` failed only after the whole build (or, above 1, was
/// taken), `--verify-samples` 0 after it and 10^13 not at all. Each is a
/// usage error before the scratch store is built.
#[test]
fn simplify_options_are_checked_before_the_build() {
    let d = tempfile::tempdir().unwrap();
    let ply = d.path().join("a.ply");
    gen("sphere", 5000, &ply);
    let before = names(d.path());
    let out = d.path().join("out.ply");
    for (extra, want) in [
        (vec!["--target-tris", "0"], "--target-tris must be at least 1"),
        (vec!["--target-ratio", "0"], "--target-ratio must be in (0, 1]"),
        (vec!["--target-ratio", "1.5"], "--target-ratio must be in (0, 1]"),
        (vec!["--target-ratio", "NaN"], "--target-ratio must be in (0, 1]"),
        (vec!["--target-ratio=-0.5"], "--target-ratio must be in (0, 1]"),
        (vec!["--target-tris", "100", "--verify-samples", "0"], "--verify-samples must be at least 1"),
        (vec!["--target-tris", "100", "--verify-samples", "10000000000000"], "--verify-samples 10000000000000 is more than 10000000000 per direction"),
        (vec!["--target-error", "1%", "--verify-samples", "10000000000000"], "--verify-samples 10000000000000 is more than"),
        (vec!["--target-tris", "100", "--level-ratio", "1"], "--level-ratio must be a number above 1"),
    ] {
        let mut args = vec!["simplify", s(&ply), "-o", s(&out)];
        args.extend_from_slice(&extra);
        let o = octolod(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{extra:?}: {err}");
        assert!(err.contains(want), "{extra:?}: {err}");
        assert!(o.stdout.is_empty(), "{extra:?} built first: {}", String::from_utf8_lossy(&o.stdout));
        assert_eq!(names(d.path()), before, "{extra:?} wrote something");
    }
    // The bounds themselves are accepted.
    let o = octolod(&["simplify", s(&ply), "-o", s(&out), "--target-ratio", "1", "--quiet"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// 13c: `build --root-tris 1` halved down to a top level of 0 triangles
/// (its last 8 all collapsed) and `info` said "root: 0 triangles". The
/// builder stops at the last level that keeps triangles.
#[test]
fn the_root_always_holds_triangles() {
    let d = tempfile::tempdir().unwrap();
    let ply = d.path().join("a.ply");
    gen("sphere", 20_000, &ply);
    for simplifier in ["cluster", "collapse"] {
        for root_tris in ["1", "2", "3"] {
            let st = d.path().join(format!("{simplifier}-{root_tris}.octolod"));
            build(&ply, &st, &["--root-tris", root_tris, "--simplifier", simplifier]);
            let (root, top) = root_and_top(&st);
            assert!(root >= 1 && root == top, "{simplifier} --root-tris {root_tris}: root {root}, top level {top}");
            // Every cut of it extracts a mesh.
            let o = octolod(&["extract", s(&st), "--max-error", "100%", "-o", s(&d.path().join("top.ply")), "--force"]);
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
            assert!(String::from_utf8_lossy(&o.stdout).contains(&format!(" {root} triangles")), "{}", String::from_utf8_lossy(&o.stdout));
        }
    }
}

/// 13d: `--level-ratio 1.0001` built 65 levels and stopped silently at a
/// hidden cap with no single root. Now an error naming `--level-ratio`
/// and the cap, before any level is built; NaN, inf and ratios ≤ 1 before
/// any work.
#[test]
fn level_ratios_that_cannot_reach_a_root_are_errors() {
    let d = tempfile::tempdir().unwrap();
    let ply = d.path().join("a.ply");
    gen("sphere", 20_000, &ply);
    let before = names(d.path());
    let st = d.path().join("a.octolod");
    for (ratio, want) in [
        ("1.0001", "more than the 64 levels"),
        ("1.01", "more than the 64 levels"),
        ("1", "must be a number above 1"),
        ("0.5", "must be a number above 1"),
        ("NaN", "must be a number above 1"),
        ("inf", "must be a number above 1"),
    ] {
        let (code, err) = run_limited(&["build", s(&ply), "-o", s(&st), "--quiet", "--level-ratio", ratio], 120);
        assert_eq!(code, Some(1), "--level-ratio {ratio}: {err}");
        assert!(err.contains("--level-ratio") && err.contains(want), "--level-ratio {ratio}: {err}");
        assert_eq!(names(d.path()), before, "--level-ratio {ratio} left something");
    }
    // Low but reachable ratios build to a single root.
    build(&ply, &st, &["--level-ratio", "1.2"]);
    let (root, _) = root_and_top(&st);
    assert!((1..=4096).contains(&root), "{root}");
    // --levels stops the build before the cap: accepted.
    let st2 = d.path().join("b.octolod");
    build(&ply, &st2, &["--level-ratio", "1.0001", "--levels", "2"]);
}

/// 13e: `--max-depth 0` was accepted though its help says 1..=21.
#[test]
fn max_depth_is_range_checked_by_the_parser() {
    let d = tempfile::tempdir().unwrap();
    let ply = d.path().join("a.ply");
    gen("sphere", 2000, &ply);
    let before = names(d.path());
    for depth in ["0", "22"] {
        for cmd in ["build", "simplify"] {
            let out = d.path().join(if cmd == "build" { "x.octolod" } else { "x.ply" });
            let mut args = vec![cmd, s(&ply), "-o", s(&out), "--max-depth", depth];
            if cmd == "simplify" {
                args.extend_from_slice(&["--target-tris", "100"]);
            }
            let o = octolod(&args);
            let err = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
            assert!(err.contains("--max-depth") && err.contains("1..=21"), "{args:?}: {err}");
            assert_eq!(names(d.path()), before);
        }
    }
    build(&ply, &d.path().join("ok.octolod"), &["--max-depth", "1"]);
}

/// A bumpy sphere of radius ~`r` about `c`, as a double-precision ascii
/// PLY (so offsets far below f32's resolution survive).
fn sphere_ply(path: &Path, c: [f64; 3], r: f64, shift: f64) {
    let (nu, nv) = (48usize, 24usize);
    let mut pos = vec![[c[0], c[1], c[2] + r + shift], [c[0], c[1], c[2] - r + shift]];
    for j in 1..nv {
        let th = std::f64::consts::PI * j as f64 / nv as f64;
        for i in 0..nu {
            let ph = 2.0 * std::f64::consts::PI * i as f64 / nu as f64;
            let rr = r * (1.0 + 0.05 * (3.0 * th).sin() * (2.0 * ph).cos());
            pos.push([c[0] + rr * th.sin() * ph.cos(), c[1] + rr * th.sin() * ph.sin(), c[2] + rr * th.cos() + shift]);
        }
    }
    let at = |j: usize, i: usize| 2 + (j - 1) * nu + i % nu;
    let mut tris = Vec::new();
    for i in 0..nu {
        tris.push([0, at(1, i), at(1, i + 1)]);
        tris.push([1, at(nv - 1, i + 1), at(nv - 1, i)]);
        for j in 1..nv - 1 {
            tris.push([at(j, i), at(j + 1, i), at(j + 1, i + 1)]);
            tris.push([at(j, i), at(j + 1, i + 1), at(j, i + 1)]);
        }
    }
    let mut t = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty double x\nproperty double y\nproperty double z\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        pos.len(),
        tris.len()
    );
    for p in &pos {
        t += &format!("{:?} {:?} {:?}\n", p[0], p[1], p[2]);
    }
    for f in &tris {
        t += &format!("3 {} {} {}\n", f[0], f[1], f[2]);
    }
    std::fs::write(path, t).unwrap();
}

fn metro_json(a: &Path, b: &Path, extra: &[&str]) -> (Option<i32>, serde_json::Value) {
    let mut args = vec!["metro", s(a), s(b), "--json", "--quiet"];
    args.extend_from_slice(extra);
    let o = octolod(&args);
    let v = serde_json::from_slice(&o.stdout).unwrap_or_else(|x| panic!("{x}: {}", String::from_utf8_lossy(&o.stderr)));
    (o.status.code(), v)
}

/// 13f: identical meshes measured a Hausdorff distance of 1.4e-16 (the
/// rounding of the distance computation), so `metro A A --max-hausdorff 0`
/// exited 3; far from the origin the rounding grows with the coordinates.
/// Distances within the coordinates' rounding now count as 0, while a
/// real offset of 1e-9 still measures.
#[test]
fn a_mesh_against_itself_measures_zero_and_real_offsets_still_show() {
    let d = tempfile::tempdir().unwrap();
    let gen_sphere = d.path().join("gen.ply");
    gen("sphere", 5000, &gen_sphere);
    let near = d.path().join("near.ply");
    sphere_ply(&near, [0.3, -0.2, 0.1], 1.0, 0.0);
    let far = d.path().join("far.ply");
    sphere_ply(&far, [1e6, 2e6, -1e6], 10.0, 0.0);
    for m in [&gen_sphere, &near, &far] {
        let (code, v) = metro_json(m, m, &["--max-hausdorff", "0", "--max-rms", "0", "--max-mean", "0"]);
        let c = &v["combined"];
        assert_eq!(code, Some(0), "{}: {c}", m.display());
        for k in ["max", "mean", "rms"] {
            assert_eq!(c[k].as_f64(), Some(0.0), "{}: {k} {c}", m.display());
        }
    }
    // Moved by 1e-9 (1e-9 of its size): measured, and over a 0 threshold.
    let moved = d.path().join("moved.ply");
    sphere_ply(&moved, [0.3, -0.2, 0.1], 1.0, 1e-9);
    let (code, v) = metro_json(&near, &moved, &["--max-hausdorff", "0"]);
    let h = v["combined"]["max"].as_f64().unwrap();
    assert!(h > 0.5e-9 && h < 2e-9, "{h}");
    assert!(v["combined"]["mean"].as_f64().unwrap() > 0.0);
    assert_eq!(code, Some(3));
}
