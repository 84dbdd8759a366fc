//! The viewer's CPU side, without a GPU (meshes "upload" to themselves):
//! the RAM budget holds on every frame, frames never wait on disk, the
//! selection is always a valid cut of the DAG whose surface is closed,
//! refinement converges, and the hysteresis keeps the cut still when the
//! camera jitters at a threshold.

use crate::common;
use glam::DVec3;
use octolod::gen::Shape;
use octolod::view::camera::{Camera, CameraPath};
use octolod::view::select::Unit;
use octolod::view::{DrawMesh, ViewOptions, Viewer};
use std::path::{Path, PathBuf};
use std::time::Duration;

fn store(dir: &Path, shape: Shape, tris: u64, leaf: u64) -> PathBuf {
    store_and_input(dir, shape, tris, leaf).0
}

fn store_and_input(dir: &Path, shape: Shape, tris: u64, leaf: u64) -> (PathBuf, octolod::mesh::IndexedMesh) {
    common::default_store(dir, shape, tris, 0, 5, leaf)
}

fn opts(ram: u64) -> ViewOptions {
    let mut o = ViewOptions { ram, ..ViewOptions::default() };
    o.select.max_error_px = 1.0;
    o
}

fn up(m: &DrawMesh) -> DrawMesh {
    m.clone()
}

/// The viewer's selection as a store cut: closed under parents, and its
/// surface welded by position has no open edge (the cut's nodes are all
/// drawn here, culled or not).
fn check_closed_cut(v: &Viewer<DrawMesh>, input: &octolod::mesh::IndexedMesh, what: &str) {
    check_cut(v, input, what, true)
}

/// Like [`check_closed_cut`]; an open input may show its own border.
fn check_cut(v: &Viewer<DrawMesh>, input: &octolod::mesh::IndexedMesh, what: &str, closed: bool) {
    let sel = v.selection();
    let st = &v.store;
    for i in 0..st.nodes.len() {
        if sel.selected[i] {
            assert!(st.parents_of(i).iter().all(|&p| sel.selected[p as usize]), "{what}: selection not closed under parents");
        }
    }
    let cut = octolod::store::Cut::from_selected(st, sel.selected.clone());
    let ((pos, tris), shared) = common::cut_mesh_parts(st, &cut);
    let r = common::crack_report(input, &pos, &tris, &shared);
    assert_eq!(r.cracks, 0, "{what}: {r:?}");
    if closed {
        assert_eq!(r.open, 0, "{what}: {r:?}");
    }
    assert_eq!(tris.len() as u64, sel.triangles, "{what}: triangle count");
}

fn run_until_settled(v: &mut Viewer<DrawMesh>, cam: &Camera, vp: (u32, u32)) -> octolod::view::FrameStats {
    for _ in 0..2000 {
        let s = v.frame(cam, vp, &mut up);
        assert!(s.resident_bytes <= s.budget_bytes, "frame {}: {} > {}", s.frame, s.resident_bytes, s.budget_bytes);
        if s.settled && s.pending_loads == 0 {
            return s;
        }
        v.wait_for_loads();
    }
    panic!("never settled");
}

#[test]
fn budget_holds_on_every_frame_and_lru_evicts() {
    let dir = tempfile::tempdir().unwrap();
    let (s, input) = store_and_input(dir.path(), Shape::Terrain, 200_000, 2048);
    // The whole level 0 is ~200k × (12 + ~14) bytes ≈ 5 MB + levels; a 3 MB
    // budget forces eviction along a fly-through.
    let ram = 3 << 20;
    let mut v: Viewer<DrawMesh> = Viewer::open(&s, opts(ram)).unwrap();
    let b = v.bounds();
    let path = CameraPath::parse(
        r#"{"space":"bbox","keyframes":[
            {"eye":[0.0,0.0,0.6],"target":[0.3,0.3,0.2]},
            {"eye":[0.5,0.1,0.4],"target":[0.8,0.5,0.1]},
            {"eye":[0.9,0.9,0.3],"target":[0.5,0.5,0.1]},
            {"eye":[0.2,0.8,0.35],"target":[0.0,0.4,0.1]}],
            "frames_between":25,"hold":5}"#,
        &b,
        DVec3::Z,
    )
    .unwrap();
    let mut peak = 0;
    let mut max_levels = 0;
    for i in 0..path.poses.len() {
        let mut cam = path.camera(i);
        cam.fit_clip(&b);
        let st = v.frame(&cam, (800, 600), &mut up);
        assert!(st.resident_bytes <= ram, "frame {i}: resident {} > budget {ram}", st.resident_bytes);
        assert!(st.peak_resident_bytes <= ram);
        assert!(st.triangles > 0 && !v.draw_list().is_empty(), "frame {i} draws nothing");
        peak = peak.max(st.resident_bytes);
        max_levels = max_levels.max(st.nodes_per_level.iter().filter(|&&n| n > 0).count());
        // The viewer's own cuts along the path are valid and crack-free.
        if i % 20 == 0 {
            check_cut(&v, &input, &format!("fly-through frame {i}"), false);
        }
        // Let some loads land between frames, as a real frame time would.
        std::thread::sleep(Duration::from_millis(2));
    }
    assert!(v.cache.counters.evictions > 0, "a 3 MB budget must evict: {:?}", v.cache.counters);
    assert!(peak > ram / 2, "the budget should be used: peak {peak}");
    assert!(max_levels >= 2, "close-ups over terrain mix levels");
}

#[test]
fn frames_never_wait_for_slow_reads() {
    let dir = tempfile::tempdir().unwrap();
    let s = store(dir.path(), Shape::Sphere, 100_000, 1024);
    let mut o = opts(64 << 20);
    o.io_delay = Duration::from_millis(3000);
    o.pin_share = 0.0; // only the roots are resident: everything else must load
    let mut v: Viewer<DrawMesh> = Viewer::open(&s, o).unwrap();
    let mut cam = Camera::frame_all(&v.bounds(), DVec3::Z, 50.0);
    cam.dolly(0.3);
    cam.fit_clip(&v.bounds());
    // Counts, not times: every read sleeps 3 s, so a frame that waited on
    // one would come back with that load done. Five frames (a few ms each)
    // must all come back with loads pending and none done, drawing the
    // pinned roots meanwhile.
    let pinned = v.cache.counters.loads_done; // the roots, read at open
    for _ in 0..5 {
        let st = v.frame(&cam, (1024, 768), &mut up);
        assert_eq!(st.loads_done, pinned, "frame {} waited for a read", st.frame);
        assert!(st.triangles > 0, "the pinned root is always drawn");
        assert!(st.pending_loads > 0 && !st.settled);
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn cuts_are_valid_and_closed_and_converge() {
    let dir = tempfile::tempdir().unwrap();
    let (s, input) = store_and_input(dir.path(), Shape::Sphere, 60_000, 1024);
    let mut v: Viewer<DrawMesh> = Viewer::open(&s, opts(256 << 20)).unwrap();
    let b = v.bounds();
    // Far away: the whole model in view, coarse.
    let mut cam = Camera::frame_all(&b, DVec3::Z, 50.0);
    cam.fit_clip(&b);
    let far = run_until_settled(&mut v, &cam, (96, 72));
    assert!(far.nodes_per_level.iter().skip(1).sum::<u32>() > 0, "a 96×72 view is coarse: {:?}", far.nodes_per_level);
    check_closed_cut(&v, &input, "far");
    assert!(far.max_error_px <= 1.0 + 1e-9);
    // Large viewport + tight threshold: refines to level 0 everywhere visible.
    v.selector.opts.max_error_px = 1e-9;
    let fine = run_until_settled(&mut v, &cam, (4000, 3000));
    check_closed_cut(&v, &input, "fine");
    // Everything is refined to level 0, except nodes whose error is
    // exactly 0 (nothing moved), which are as exact.
    for &u in v.cut() {
        let i = v.hierarchy.info(u);
        assert!(i.level == 0 || i.error == 0.0, "node {u} at level {} with error {}", i.level, i.error);
    }
    assert!(fine.nodes_per_level[0] > 0);
    assert!(fine.triangles > far.triangles);
    // A close-up from the side: mixed levels, parts behind the camera culled.
    v.selector.opts.max_error_px = 1.0;
    let mut near = Camera::look_at(DVec3::from(b.center()) + DVec3::new(0.0, -0.62, 0.0) * b.diagonal(), DVec3::from(b.center()), DVec3::Z, 50.0);
    near.fit_clip(&b);
    let st = run_until_settled(&mut v, &near, (1280, 720));
    assert!(st.triangles > far.triangles && st.triangles < fine.triangles, "{} vs {} / {}", st.triangles, far.triangles, fine.triangles);
    check_closed_cut(&v, &input, "near");
    // Nearer still, looking along the surface: near parts fine, far parts coarse.
    let mut graze = Camera::look_at(
        DVec3::from(b.center()) + DVec3::new(0.0, -0.36, 0.0) * b.diagonal(),
        DVec3::from(b.center()) + DVec3::new(0.0, 0.0, 0.4) * b.diagonal(),
        DVec3::Z,
        50.0,
    );
    graze.fit_clip(&b);
    let st = run_until_settled(&mut v, &graze, (1280, 720));
    assert!(st.nodes_per_level.iter().filter(|&&n| n > 0).count() >= 2, "{:?}", st.nodes_per_level);
}

/// The drawn nodes as a set (their order follows the traversal).
fn sorted_cut(v: &Viewer<DrawMesh>) -> Vec<Unit> {
    let mut c = v.cut().to_vec();
    c.sort_unstable();
    c
}

#[test]
fn hysteresis_keeps_the_cut_when_the_camera_jitters() {
    let dir = tempfile::tempdir().unwrap();
    let s = store(dir.path(), Shape::Sphere, 60_000, 1024);
    let mut v: Viewer<DrawMesh> = Viewer::open(&s, opts(256 << 20)).unwrap();
    let b = v.bounds();
    // Far enough that the whole model stays in view: cut changes are LOD only.
    let mut base = Camera::frame_all(&b, DVec3::Z, 50.0);
    base.dolly(2.5);
    // Find a distance where some unit sits right at the threshold: walk in
    // until the settled cut changes, then jitter ±1% around that point.
    let mut prev: Vec<Unit> = vec![];
    let mut at = None;
    for k in 0..200 {
        let mut c = base;
        c.dolly(1.0 - k as f64 * 0.004);
        c.fit_clip(&b);
        run_until_settled(&mut v, &c, (800, 600));
        let cut = sorted_cut(&v);
        if k > 0 && cut != prev {
            at = Some(c);
            break;
        }
        prev = cut;
    }
    let c = at.expect("no threshold crossing found");
    let settled_cut = sorted_cut(&v);
    // Step back past the crossing and forth again: the lowered threshold
    // for refined units keeps the finer cut.
    let jitter = |v: &mut Viewer<DrawMesh>| -> bool {
        let mut popped = false;
        for j in 0..10 {
            let mut cj = c;
            cj.dolly(if j % 2 == 0 { 1.008 } else { 1.0 });
            cj.fit_clip(&b);
            v.frame(&cj, (800, 600), &mut up);
            v.wait_for_loads();
            popped |= sorted_cut(v) != settled_cut;
        }
        popped
    };
    assert!(!jitter(&mut v), "the cut popped while the camera jittered");
    // Without hysteresis the same jitter pops (so the check above can fail).
    v.selector.opts.hysteresis = 1.0;
    assert!(jitter(&mut v), "without hysteresis the cut should follow the jitter");
    let _ = prev;
}

#[test]
fn a_budget_below_the_coarsest_level_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let s = store(dir.path(), Shape::Sphere, 20_000, 1024);
    let e = Viewer::<DrawMesh>::open(&s, opts(4 << 10)).err().expect("4 KiB cannot hold anything");
    assert!(e.to_string().contains("--ram"), "{e}");
}

/// Issue 11 (item 2): node loads that fail are counted in every frame's
/// statistics and shown in the overlay (the window also logs each message),
/// instead of being recorded and never read.
#[test]
fn failed_loads_show_in_the_frame_statistics_and_the_overlay() {
    let dir = tempfile::tempdir().unwrap();
    let s = store(dir.path(), Shape::Sphere, 60_000, 2048);
    common::corrupt_packs_below_top(&s);
    let mut o = opts(64 << 20);
    o.select.max_error_px = 0.25;
    o.pin_share = 0.0; // only the roots are loaded at open
    let mut v: Viewer<DrawMesh> = Viewer::open(&s, o).unwrap();
    let b = v.bounds();
    let mut cam = Camera::frame_all(&b, DVec3::Z, 50.0);
    cam.fit_clip(&b);
    let healthy = v.frame(&cam, (800, 600), &mut up);
    assert_eq!(healthy.load_failures, 0, "nothing has been read yet");
    let mut last = healthy.clone();
    for _ in 0..200 {
        last = v.frame(&cam, (800, 600), &mut up);
        if last.load_failures > 0 && last.pending_loads == 0 {
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(last.load_failures > 0, "{last:?}");
    assert_eq!(last.load_failures, v.load_failures().0);
    let (_, msgs) = v.load_failures();
    assert!(msgs.iter().all(|m| m.contains("level-")), "{msgs:?}");
    let lines = last.overlay_lines(60.0);
    assert!(lines.iter().any(|l| l.contains(&format!("{} node load(s) FAILED", last.load_failures))), "{lines:?}");
    assert!(!healthy.overlay_lines(60.0).iter().any(|l| l.contains("FAILED")));
    // The roots still draw: a failure leaves a coarser, valid picture.
    assert!(last.triangles > 0 && !v.draw_list().is_empty());
}

/// Reliability v2, item 15: close to the surface, looking at one part,
/// the overlay reported thousands of pixels of error for a refined view:
/// nodes whose bounds hold the eye draw their coarse patches for the
/// children behind the camera, and their whole-node error counted. The
/// figure is now the error on screen (drawn patches inside the frustum).
#[test]
fn max_error_counts_only_what_is_on_screen() {
    let dir = tempfile::tempdir().unwrap();
    let (s, input) = store_and_input(dir.path(), Shape::Sphere, 60_000, 1024);
    let mut v: Viewer<DrawMesh> = Viewer::open(&s, opts(256 << 20)).unwrap();
    let b = v.bounds();
    let c = DVec3::from(b.center());
    // Just outside the bumpy unit sphere, inside every node's bounds that
    // reach this corner, looking at the nearest part of the surface.
    let eye = c + DVec3::new(0.62, -0.62, 0.62);
    let mut cam = Camera::look_at(eye, c, DVec3::Z, 50.0);
    cam.fit_clip(&b);
    let vp = (1280, 720);
    let st = run_until_settled(&mut v, &cam, vp);
    check_cut(&v, &input, "close-up", true);
    // The scenario: drawn nodes whose own bounds project far above the
    // threshold (they reach the eye), refined where they are in view.
    let whole = v
        .cut()
        .iter()
        .filter(|&&u| !v.hierarchy.children(u).is_empty())
        .map(|&u| v.selector.priority(&v.hierarchy, u, &cam, cam.eye, vp.1 as f64))
        .fold(0.0, f64::max);
    assert!(whole > 10.0, "the close-up should draw nodes reaching the eye: {whole} px");
    assert_eq!(v.selection().budget_limited, 0);
    assert!(st.max_error_px <= 1.0 + 1e-9, "settled close-up reports {} px (whole nodes: {whole} px)", st.max_error_px);
    assert!(st.max_error_px > 0.0, "coarse patches are on screen: some error is left");
    assert!(st.overlay_lines(60.0)[3].contains(&format!("max error {:.2} px", st.max_error_px)));
    // A genuinely budget-limited cut still reports its error on screen
    // (what `render` warns about).
    v.selector.opts.tri_budget = 1;
    let st = run_until_settled(&mut v, &cam, vp);
    assert!(v.selection().budget_limited > 0);
    assert!(st.max_error_px > 1.0, "a budget-limited close-up reports {} px", st.max_error_px);
}

/// At every RAM budget from the smallest that opens the store up, a still
/// camera settles within a few frames: a refinement that needs several
/// nodes at once keeps the ones it has while it loads the rest, so a budget
/// that fits only part of such a group never evicts and reloads it without
/// end (at `--ram 100K` on this sphere every frame did, 602 of them).
#[test]
fn every_budget_settles_without_reloading_without_end() {
    let dir = tempfile::tempdir().unwrap();
    let (ply, _) = common::gen_ply_seeded(dir.path(), Shape::Sphere, 20_000, 0, 5);
    let params = octolod::manifest::BuildParams { leaf_tris: 1000, root_tris: 500, ..Default::default() };
    let st = common::build_store_at(dir.path(), &ply, &common::build_options(params));
    let mut settled = 0;
    for ram in (40u64..=400).step_by(6).map(|k| k << 10) {
        let Ok(mut v) = Viewer::<DrawMesh>::open(&st, opts(ram)) else { continue };
        let b = v.bounds();
        let mut cam = Camera::frame_all(&b, DVec3::Z, 45.0);
        cam.fit_clip(&b);
        let mut frames = 0;
        let s = loop {
            frames += 1;
            let s = v.frame(&cam, (200, 150), &mut up);
            if s.settled || frames == 200 {
                break s;
            }
            v.wait_for_loads();
        };
        assert!(frames < 50, "--ram {} KiB: not settled after {frames} frames ({} loads, {} evictions)", ram >> 10, s.loads_done, s.evictions);
        settled += 1;
    }
    assert!(settled > 40, "{settled} budgets opened the store");
}
