//! The web export in a real browser (issue 31 item 5): a store exported by
//! `octolod tiles`, validated (Khronos glTF validator on every GLB, the 3D
//! Tiles 1.1 schema on tileset.json), served by `octolod serve` (started
//! here), shown by the bundled page in headless Chromium (Debian's
//! `chromium`, driven through the DevTools protocol by puppeteer-core from
//! `web/node_modules`), and each settled screenshot along a camera path
//! compared with `octolod render --brute-force` (full resolution) at the
//! same camera: silhouette IoU ≥ 0.99, no hole pixel (background where the
//! full-resolution surface covers the pixel and its neighbours within the
//! error target), every frame mixing refinement levels, no console error.
//!
//! Needs `tools/ci-deps.sh` (chromium, node, `npm ci --prefix web`) and a
//! Vulkan adapter for `render`; skipped only with OCTOLOD_SKIP_WEB_TESTS=1.

use crate::common::cli::{bin, err, gen_with, octolod, s};
use crate::common::{eroded, mask};
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

fn web_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("web")
}

fn skip() -> bool {
    if std::env::var("OCTOLOD_SKIP_WEB_TESTS").as_deref() == Ok("1") {
        eprintln!("OCTOLOD_SKIP_WEB_TESTS=1: skipping a browser test");
        return true;
    }
    assert!(
        web_dir().join("node_modules/puppeteer-core").is_dir(),
        "web/node_modules is missing: run tools/ci-deps.sh (or `npm ci --prefix web`), or set OCTOLOD_SKIP_WEB_TESTS=1"
    );
    false
}

fn node(args: &[&str]) -> std::process::Output {
    Command::new("node").args(args).current_dir(env!("CARGO_MANIFEST_DIR")).output().expect("node is installed (tools/ci-deps.sh)")
}

/// `octolod serve DIR --port 0`, stopped (SIGTERM) when dropped.
struct Server {
    child: Child,
    url: String,
}

impl Server {
    fn start(dir: &Path) -> Server {
        let mut child = Command::new(bin()).args(["serve", s(dir), "--port", "0", "--quiet"]).stdout(Stdio::piped()).stderr(Stdio::inherit()).spawn().unwrap();
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap()).read_line(&mut line).unwrap();
        let url = line.split_whitespace().nth(1).unwrap_or_else(|| panic!("no URL in {line:?}")).to_string();
        Server { child, url }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        // SAFETY: signalling our own child.
        unsafe { libc::kill(self.child.id() as i32, libc::SIGTERM) };
        let st = self.child.wait().unwrap();
        if !std::thread::panicking() {
            assert_eq!(st.code(), Some(143), "serve did not stop cleanly on SIGTERM");
        }
    }
}

fn psnr(a: &[u8], b: &[u8]) -> f64 {
    let mse = a.iter().zip(b).map(|(&x, &y)| (x as f64 - y as f64).powi(2)).sum::<f64>() / a.len() as f64;
    if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (255.0f64 * 255.0 / mse).log10()
    }
}

/// Builds, exports, validates, serves, shoots and compares one input;
/// gives the browser's report.
fn browser_matches_render(shape: &str, tris: u64, extra_gen: &[&str], cameras: &serde_json::Value, error_px: f64) -> serde_json::Value {
    browser_matches_render_at(shape, tris, extra_gen, cameras, error_px, 0.0)
}

/// [`browser_matches_render`], each frame also within `min_psnr` dB of
/// the full-resolution render.
fn browser_matches_render_at(shape: &str, tris: u64, extra_gen: &[&str], cameras: &serde_json::Value, error_px: f64, min_psnr: f64) -> serde_json::Value {
    let d = tempfile::tempdir().unwrap();
    let ply = d.path().join("in.ply");
    gen_with(shape, tris, &ply, extra_gen);
    let st = d.path().join("s.octolod");
    let o = octolod(&["build", s(&ply), "-o", s(&st), "--quiet", "--leaf-tris", "4096"]);
    assert!(o.status.success(), "{}", err(&o));
    let tiles = d.path().join("tiles");
    let o = octolod(&["tiles", s(&st), "-o", s(&tiles), "--quiet", "--tile-tris", "4096"]);
    assert!(o.status.success(), "{}", err(&o));
    let v = node(&["web/test/validate.mjs", s(&tiles)]);
    assert!(v.status.success(), "validation failed: {}{}", String::from_utf8_lossy(&v.stdout), err(&v));

    let cams = d.path().join("cameras.json");
    std::fs::write(&cams, cameras.to_string()).unwrap();
    let (w, h) = (480u32, 360u32);
    let shots = d.path().join("shots");
    let server = Server::start(&tiles);
    let b = node(&[
        "web/test/shoot.mjs",
        "--url",
        &server.url,
        "--cameras",
        s(&cams),
        "--out",
        s(&shots),
        "--width",
        &w.to_string(),
        "--height",
        &h.to_string(),
        "--error-target",
        &error_px.to_string(),
    ]);
    assert!(b.status.success(), "the browser run failed: {}{}", String::from_utf8_lossy(&b.stdout), err(&b));
    drop(server);
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(shots.join("browser.json")).unwrap()).unwrap();

    let reference = d.path().join("reference");
    let o = octolod(&[
        "render",
        s(&st),
        "-o",
        s(&reference),
        "--camera-path",
        s(&cams),
        "--brute-force",
        "--width",
        &w.to_string(),
        "--height",
        &h.to_string(),
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", err(&o));
    let bg = octolod::view::headless::clear_rgba8(true);
    let frames = report["frames"].as_array().unwrap();
    assert_eq!(frames.len(), cameras["frames"].as_array().unwrap().len());
    let mut lines = Vec::new();
    for (i, f) in frames.iter().enumerate() {
        let name = format!("frame-{i:05}.png");
        let (bw, bh, web) = octolod::view::image::read_png(shots.join(&name)).unwrap();
        let (rw, rh, full) = octolod::view::image::read_png(reference.join(&name)).unwrap();
        assert_eq!((bw, bh, rw, rh), (w, h, w, h));
        let (mw, mf) = (mask(&web, bg), mask(&full, bg));
        let inter = mw.iter().zip(&mf).filter(|(a, b)| **a && **b).count();
        let union = mw.iter().zip(&mf).filter(|(a, b)| **a || **b).count();
        let iou = inter as f64 / union.max(1) as f64;
        let inside = eroded(&mf, w, h, error_px.ceil() as i64 + 1);
        let holes = inside.iter().zip(&mw).filter(|(i, m)| **i && !**m).count();
        let depths = f["depths"].as_array().map_or(0, |d| d.len());
        let p = psnr(&web, &full);
        lines.push(format!(
            "{shape} frame {i}: IoU {iou:.4}, holes {holes}, PSNR {p:.1} dB, tile depths {}, {} tiles, {} triangles",
            f["depths"], f["tilesVisible"], f["triangles"]
        ));
        assert!(f["settled"].as_bool() == Some(true), "frame {i} did not settle");
        assert!(iou >= 0.99, "{}", lines.last().unwrap());
        assert_eq!(holes, 0, "{}", lines.last().unwrap());
        assert!(depths >= 2, "frame {i} draws one refinement level only: {}", lines.last().unwrap());
        assert!(p >= min_psnr, "{}", lines.last().unwrap());
    }
    // The console: shoot.mjs fails on errors; nothing but warnings logged.
    for m in report["console"].as_array().into_iter().flatten() {
        assert_ne!(m["type"].as_str(), Some("error"), "{m}");
    }
    println!("{}", lines.join("\n"));
    report
}

#[test]
fn a_sphere_in_the_browser_matches_the_full_resolution_render() {
    if skip() {
        return;
    }
    // An orbit from afar to close over the surface, in bbox space. The
    // first view is near enough that its cut mixes depths: from 2.7 box
    // sizes away the whole sphere fits one depth since its node errors
    // fell (colours weigh a hundredth of the cell in clustering).
    let cameras = serde_json::json!({
        "fov_y_deg": 50, "space": "bbox", "up": [0, 1, 0],
        "frames": [
            {"eye": [1.6, 1.1, 1.8], "target": [0.5, 0.5, 0.5]},
            {"eye": [-0.6, 0.9, 1.6], "target": [0.5, 0.5, 0.5]},
            {"eye": [0.5, 1.35, 0.9], "target": [0.5, 0.6, 0.5]},
            {"eye": [1.15, 0.55, 0.8], "target": [0.3, 0.45, 0.4]}
        ]
    });
    browser_matches_render("sphere", 300_000, &["--colors"], &cameras, 1.0);
}

/// The textured scans' camera path (bbox space, Z up): two oblique views
/// over the dome, so even collapse levels, whose errors are small and
/// even, refine at two depths or more in every frame.
fn scan_cameras() -> serde_json::Value {
    serde_json::json!({
        "fov_y_deg": 50, "space": "bbox", "up": [0, 0, 1],
        "frames": [
            {"eye": [0.5, -0.3, 0.8], "target": [0.5, 0.7, 0.3]},
            {"eye": [0.2, 0.05, 0.9], "target": [0.6, 0.6, 0.3]}
        ]
    })
}

/// Issue 32, item 2: a textured scan (a many-island atlas, the texture
/// baked from the surface) in the browser: the tiles' per-level copies of
/// the texture are drawn upright (glTF's v runs down) and match `render`'s
/// full-resolution textured frame; tiles of a level share one texture.
#[test]
fn a_textured_scan_in_the_browser_matches_the_full_resolution_render() {
    if skip() {
        return;
    }
    let cameras = scan_cameras();
    let report = browser_matches_render_at("scan", 200_000, &["--atlas", "8", "--texture", "1024"], &cameras, 1.0, 24.0);
    for f in report["frames"].as_array().unwrap() {
        let shared = f["sharedTextures"].as_array().unwrap();
        assert!(!shared.is_empty() && shared.len() <= 6, "one texture per drawn level at most: {shared:?}");
        assert!(shared.iter().all(|n| n.as_str().unwrap().starts_with("texture-0-")), "{shared:?}");
    }
}

/// Issue 32, several textures: a scan whose atlas islands are spread over
/// three tinted textures (MeshLab's face `texnumber`). Each tile draws a
/// primitive per material from its level's copy of that material's image:
/// the page loads copies of all three, and every frame matches `render`'s
/// full-resolution frame, which draws each face with its own texture (a
/// face drawn from another slot's image shows another tint).
#[test]
fn a_scan_with_three_textures_in_the_browser_draws_each_face_from_its_own() {
    if skip() {
        return;
    }
    let cameras = scan_cameras();
    let report = browser_matches_render_at("scan", 200_000, &["--atlas", "8", "--texture", "512", "--textures", "3"], &cameras, 1.0, 24.0);
    let last = report["frames"].as_array().unwrap().last().unwrap();
    let shared: Vec<&str> = last["sharedTextures"].as_array().unwrap().iter().map(|n| n.as_str().unwrap()).collect();
    for k in 0..3 {
        let n = shared.iter().filter(|s| s.starts_with(&format!("texture-{k}-"))).count();
        assert!((1..=6).contains(&n), "slot {k}: {n} copies loaded, one per drawn level at most: {shared:?}");
    }
    assert!(shared.iter().all(|s| ["texture-0-", "texture-1-", "texture-2-"].iter().any(|p| s.starts_with(p))), "{shared:?}");
}

#[test]
fn a_terrain_in_the_browser_matches_the_full_resolution_render() {
    if skip() {
        return;
    }
    // A height field stands on its thin axis (`--up auto`): grazing views.
    let cameras = serde_json::json!({
        "fov_y_deg": 50, "space": "bbox",
        "frames": [
            {"eye": [0.5, -0.6, 1.4], "target": [0.5, 0.5, 0.0]},
            {"eye": [0.05, 0.05, 0.9], "target": [0.7, 0.7, 0.2]},
            {"eye": [1.1, 0.4, 0.6], "target": [0.3, 0.5, 0.2]}
        ]
    });
    browser_matches_render("terrain", 300_000, &[], &cameras, 2.0);
}
