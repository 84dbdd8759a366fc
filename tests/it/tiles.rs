//! `octolod tiles` (issue 31 item 2): the tileset is a tree whose errors
//! never grow from a tile to its children, whose boxes hold their content
//! and their children's, whose every level holds every triangle of the
//! store's level, and whose REPLACE cuts — the cuts a 3D Tiles client draws,
//! mixing levels — open no hole: rendered on the GPU (lavapipe in CI) from
//! outside, close up and from inside a closed surface, no background shows
//! where the full-resolution mesh covers the pixel.

use crate::common;
use crate::common::cli::{err, names, octolod, s};
use octolod::gen::Shape;
use octolod::store::Store;
use octolod::tiles::{plan, tile_content, TilesOptions};
use serde_json::Value;
use std::collections::HashSet;
use std::path::Path;

fn opts(tile_tris: u64) -> TilesOptions {
    TilesOptions { tile_tris, ..TilesOptions::default() }
}

/// Checks a tile of tileset.json and its subtree; gives the content URIs.
fn check_tile(t: &Value, parent_error: f64, parent_box: Option<&[f64]>, dir: &Path, uris: &mut Vec<String>) {
    let e = t["geometricError"].as_f64().expect("geometricError");
    assert!(e.is_finite() && e >= 0.0 && e <= parent_error * (1.0 + 1e-12), "error {e} above its parent's {parent_error}");
    let b: Vec<f64> = t["boundingVolume"]["box"].as_array().expect("a box").iter().map(|x| x.as_f64().unwrap()).collect();
    assert_eq!(b.len(), 12);
    if let Some(p) = parent_box {
        for k in 0..3 {
            let (lo, hi) = (b[k] - b[3 + 4 * k], b[k] + b[3 + 4 * k]);
            let (plo, phi) = (p[k] - p[3 + 4 * k], p[k] + p[3 + 4 * k]);
            let tol = 1e-9 * (phi - plo).abs().max(1.0);
            assert!(lo >= plo - tol && hi <= phi + tol, "a child's box leaves its parent's on axis {k}");
        }
    }
    if let Some(u) = t["content"]["uri"].as_str() {
        assert!(dir.join(u).is_file(), "{u} is missing");
        uris.push(u.to_string());
    }
    match t["children"].as_array() {
        Some(c) => {
            assert!(!c.is_empty());
            for k in c {
                check_tile(k, e, Some(&b), dir, uris);
            }
        }
        None => assert!(t["content"].is_object(), "a leaf without content"),
    }
}

#[test]
fn the_tileset_is_a_monotone_tree_of_the_store_levels() {
    let d = tempfile::tempdir().unwrap();
    let (st, _) = common::default_store(d.path(), Shape::Sphere, 60_000, 0, 3, 2000);
    let out = d.path().join("web");
    let o = octolod(&["tiles", s(&st), "-o", s(&out), "--tile-tris", "2000", "--quiet"]);
    assert!(o.status.success(), "{}", err(&o));
    let ts: Value = serde_json::from_slice(&std::fs::read(out.join("tileset.json")).unwrap()).unwrap();
    assert_eq!(ts["asset"]["version"], "1.1");
    assert_eq!(ts["root"]["refine"], "REPLACE");
    let t: Vec<f64> = ts["root"]["transform"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
    assert_eq!(t.len(), 16);
    let up: Vec<f64> = ts["asset"]["extras"]["octolod"]["up"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
    // The transform (column-major) takes the model's up axis to +Z.
    let img: Vec<f64> = (0..3).map(|r| (0..3).map(|c| t[4 * c + r] * up[c]).sum()).collect();
    assert!((img[0]).abs() < 1e-12 && (img[1]).abs() < 1e-12 && (img[2] - 1.0).abs() < 1e-12, "{img:?}");
    let mut uris = Vec::new();
    check_tile(&ts["root"], ts["geometricError"].as_f64().unwrap(), None, &out, &mut uris);
    // Every GLB is referenced once; nothing else is in the directory.
    let files: HashSet<String> = names(&out.join("t")).into_iter().map(|n| format!("t/{n}")).collect();
    assert_eq!(files.len(), uris.len());
    assert_eq!(files, uris.iter().cloned().collect::<HashSet<_>>());
    assert_eq!(names(&out), [".octolod-tiles", "t", "tileset.json"]);
    // Several levels, several tiles per level at the bottom.
    let levels: HashSet<&str> = uris.iter().map(|u| u[2..].split('-').next().unwrap()).collect();
    assert!(levels.len() >= 4, "{levels:?}");
    assert!(uris.iter().filter(|u| u.starts_with("t/0-")).count() >= 8);
    // A second export needs --force, and then replaces it.
    assert!(!octolod(&["tiles", s(&st), "-o", s(&out), "--quiet"]).status.success());
    assert!(octolod(&["tiles", s(&st), "-o", s(&out), "--quiet", "--force"]).status.success());
}

/// Every triangle of every level is in a tile of that level (a tile holds
/// the triangles reaching into its cell, then its skirt).
#[test]
fn every_level_triangle_is_in_a_tile_of_its_level() {
    let d = tempfile::tempdir().unwrap();
    let (st, _) = common::default_store(d.path(), Shape::Terrain, 40_000, 0, 3, 2000);
    let store = Store::open(&st).unwrap();
    let p = plan(&store, &opts(1500)).unwrap();
    let key = |v: &octolod::mesh::Vertex| v.pos.map(f64::to_bits);
    for level in 0..=store.top_level() {
        let mut have = HashSet::new();
        for t in (0..p.tiles.len()).filter(|&t| p.tiles[t].level == level) {
            let Some(c) = tile_content(&store, &p, t).unwrap() else { continue };
            let own = c.mesh.triangles.len() - c.skirt as usize;
            for tri in &c.mesh.triangles[..own] {
                let mut k = tri.map(|i| key(&c.mesh.vertices[i as usize]));
                k.sort();
                have.insert(k);
            }
        }
        let cut = store.level_cut(level);
        for m in store.cut_meshes(&cut) {
            let m = m.unwrap();
            for tri in &m.triangles {
                let mut k = tri.map(|i| key(&m.vertices[i as usize]));
                k.sort();
                assert!(have.contains(&k), "level {level}: a triangle is in no tile");
            }
        }
    }
}

/// The tiles a 3D Tiles client draws for a camera: refine (REPLACE) while
/// a tile's screen-space error exceeds `sse_px`; a tile without content is
/// always refined (the export splices it out).
#[cfg(feature = "view")]
fn client_cut(p: &octolod::tiles::Plan, eye: glam::DVec3, fov_y: f64, height: f64, sse_px: f64) -> Vec<usize> {
    fn dist(b: &octolod::mesh::Aabb, e: glam::DVec3) -> f64 {
        let q = glam::DVec3::from(b.min).max(e.min(glam::DVec3::from(b.max)));
        (q - e).length()
    }
    let mut drawn = Vec::new();
    let mut stack: Vec<usize> = (0..p.tiles.len()).filter(|&t| p.tiles[t].parent.is_none()).collect();
    while let Some(t) = stack.pop() {
        let tile = &p.tiles[t];
        let sse = tile.error * height / (dist(&tile.cell_bounds, eye).max(1e-12) * 2.0 * (fov_y / 2.0).tan());
        if !tile.children.is_empty() && sse > sse_px {
            stack.extend(&tile.children);
        } else {
            drawn.push(t);
        }
    }
    drawn
}

#[test]
#[cfg(feature = "view")]
fn client_cuts_mixing_levels_show_no_background_where_the_surface_is() {
    use crate::common::{eroded, mask};
    use octolod::view::gpu::{DrawParams, RendererOptions};
    use octolod::view::{draw_mesh, DrawItem};
    let d = tempfile::tempdir().unwrap();
    let (st, _) = common::default_store(d.path(), Shape::Sphere, 120_000, 0, 7, 2000);
    let store = Store::open(&st).unwrap();
    let p = plan(&store, &opts(1500)).unwrap();
    let (w, h) = (320u32, 240u32);
    // Back faces culled, as glTF's single-sided materials are in a browser:
    // a slit between neighbours at different levels shows the background.
    let Some(mut r) = crate::common::gpu::renderer(w, h, RendererOptions { cull_back_faces: true, ..Default::default() }) else { return };
    let b = store.header.bbox;
    let c = glam::DVec3::from(b.center());
    let radius = 0.5 * b.diagonal() / 3f64.sqrt();
    let origin = b.center();
    let attrs = store.payload_layout.attrs;
    let full = draw_mesh(&octolod::pipeline::weld_union(&store.payload_layout, store.cut_meshes(&store.level_cut(0)).map(|m| m.unwrap())), attrs, origin);
    let full = r.upload(&full);
    let clear = [0.0, 0.0, 0.0, 1.0];
    let bg = [0u8, 0, 0, 255];
    let fov = 50f64.to_radians();
    let mut levels_seen = HashSet::new();
    // Far; near (close to the wall: neighbours at several levels); grazing
    // (just above the surface, looking along it to the horizon).
    let views = [
        (c + glam::DVec3::new(2.5, 1.0, 1.5) * radius, c),
        (c + glam::DVec3::new(0.0, 0.3, 1.25) * radius, c),
        (c + glam::DVec3::new(0.0, 0.0, 1.04) * radius, c + glam::DVec3::new(1.0, 0.0, 0.9) * radius),
        (c + glam::DVec3::new(0.3, -0.2, 1.1) * radius, c + glam::DVec3::new(-1.0, 0.2, 0.4) * radius),
    ];
    for (k, (eye, target)) in views.into_iter().enumerate() {
        let cam = octolod::view::camera::Camera::look_at(eye, target, glam::DVec3::Y, 50.0);
        let params = DrawParams {
            view_proj: cam.view_proj(glam::DVec3::from(origin), w as f64 / h as f64),
            eye: cam.eye_rel(glam::DVec3::from(origin)),
            light_dir: glam::Vec3::ZERO,
            wireframe: false,
            textured: false,
            clear,
        };
        let reference = r.render_offscreen(&params, &[DrawItem::whole(&full, full.triangles())]).unwrap();
        for sse in [1.0, 4.0, 16.0] {
            let cut = client_cut(&p, eye, fov, h as f64, sse);
            let meshes: Vec<_> =
                cut.iter().filter_map(|&t| tile_content(&store, &p, t).unwrap()).map(|c| r.upload(&draw_mesh(&c.mesh, attrs, origin))).collect();
            let levels: HashSet<u8> = cut.iter().map(|&t| p.tiles[t].level).collect();
            levels_seen.insert(levels.len());
            let items: Vec<_> = meshes.iter().map(|m| DrawItem::whole(m, m.triangles())).collect();
            let img = r.render_offscreen(&params, &items).unwrap();
            // A hole: background where the full-resolution surface covers
            // the pixel and every pixel within the cut's error of it (the
            // silhouette itself may move by that much).
            let inside = eroded(&mask(&reference, bg), w, h, sse.ceil() as i64 + 1);
            let drawn = mask(&img, bg);
            let holes = (0..(w * h) as usize).filter(|&i| inside[i] && !drawn[i]).count();
            assert_eq!(holes, 0, "view {k}, SSE {sse} px: {holes} hole pixels (levels {levels:?})");
        }
    }
    assert!(levels_seen.iter().any(|&n| n >= 3), "no cut mixed three levels: {levels_seen:?}");
}

/// The checks above catch a broken export: a tile whose error is above its
/// parent's, a missing content file, a child's box outside its parent's.
#[test]
fn the_tileset_checks_catch_a_broken_export() {
    let d = tempfile::tempdir().unwrap();
    let (st, _) = common::default_store(d.path(), Shape::Sphere, 20_000, 0, 3, 2000);
    let out = d.path().join("web");
    assert!(octolod(&["tiles", s(&st), "-o", s(&out), "--tile-tris", "1000", "--quiet"]).status.success());
    let ts: Value = serde_json::from_slice(&std::fs::read(out.join("tileset.json")).unwrap()).unwrap();
    let top = ts["geometricError"].as_f64().unwrap();
    let check = |t: &Value| std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| check_tile(t, top, None, &out, &mut Vec::new()))).is_ok();
    assert!(check(&ts["root"]));
    let mut raised = ts["root"].clone();
    raised["children"][0]["geometricError"] = serde_json::json!(1e9);
    assert!(!check(&raised), "an error above its parent's passed");
    let mut moved = ts["root"].clone();
    moved["children"][0]["boundingVolume"]["box"][0] = serde_json::json!(1e9);
    assert!(!check(&moved), "a box outside its parent's passed");
    fn first_uri(t: &Value) -> Option<String> {
        t["content"]["uri"].as_str().map(String::from).or_else(|| t["children"].as_array()?.iter().find_map(first_uri))
    }
    let uri = first_uri(&ts["root"]).unwrap();
    std::fs::remove_file(out.join(&uri)).unwrap();
    assert!(!check(&ts["root"]), "a missing content file passed");
}

/// Bad input: a store of another version, a damaged store, an output in the
/// way; a clear error and nothing written.
#[test]
fn bad_stores_and_outputs_in_the_way_are_refused_and_leave_nothing() {
    let d = tempfile::tempdir().unwrap();
    let (st, _) = common::default_store(d.path(), Shape::Sphere, 20_000, 0, 3, 2000);
    let before = names(d.path());
    let user = d.path().join("mine");
    std::fs::create_dir(&user).unwrap();
    std::fs::write(user.join("notes.txt"), b"keep").unwrap();
    let o = octolod(&["tiles", s(&st), "-o", s(&user), "--force"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(err(&o).contains("not an octolod tileset directory"), "{}", err(&o));
    assert_eq!(names(&user), ["notes.txt"]);
    std::fs::remove_dir_all(&user).unwrap();
    // Another version: byte 8 of nodes.bin.
    let index = st.join("nodes.bin");
    let good = std::fs::read(&index).unwrap();
    let mut b = good.clone();
    b[8] = 1;
    std::fs::write(&index, &b).unwrap();
    let out = d.path().join("web");
    let o = octolod(&["tiles", s(&st), "-o", s(&out)]);
    assert_eq!(o.status.code(), Some(1));
    assert!(err(&o).contains("version 1"), "{}", err(&o));
    std::fs::write(&index, &good).unwrap();
    // A damaged payload: found when its tile is written.
    let pack = st.join("level-0.pack");
    let mut p = std::fs::read(&pack).unwrap();
    let n = p.len();
    p[n / 2] ^= 0xff;
    std::fs::write(&pack, &p).unwrap();
    let o = octolod(&["tiles", s(&st), "-o", s(&out)]);
    assert_eq!(o.status.code(), Some(1));
    assert!(err(&o).contains("level-0.pack"), "{}", err(&o));
    assert_eq!(names(d.path()), before, "a failed export left something");
}
