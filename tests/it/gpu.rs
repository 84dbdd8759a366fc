//! Renderer tests on a real adapter (Mesa lavapipe in CI).
//!
//! They fail when no adapter exists, so a missing driver cannot pass for
//! working rendering; set OCTOLOD_SKIP_GPU_TESTS=1 to skip them explicitly.

use crate::common::gpu::{renderer as renderer_with, without_desktop_session};
use crate::common::{srgb_to_linear, this_test_again};
use glam::{Mat4, Vec3};
use octolod::view::gpu::{clear_rgba8, DrawParams, GpuMesh, Renderer, RendererOptions, WireframeMode, AMBIENT};
use octolod::view::image::{background_fraction, compare};
use octolod::view::overlay::{overlay_text, OverlayImage};
use octolod::view::{DrawMesh, GpuBytes, GpuVertex};

fn renderer(w: u32, h: u32) -> Option<Renderer> {
    renderer_with(w, h, RendererOptions::default())
}

/// Linear clear color; reads back as sRGB (20, 30, 40).
fn clear() -> [f64; 4] {
    [srgb_to_linear(20.0 / 255.0), srgb_to_linear(30.0 / 255.0), srgb_to_linear(40.0 / 255.0), 1.0]
}
const COLOR: [u8; 4] = [200, 100, 50, 255];

/// A `n` x `n` grid of quads covering [-s, s]^2 in the plane z = `z`, facing +z.
fn grid(n: u32, s: f32, z: f32, normal: [f32; 3], color: [u8; 4]) -> DrawMesh {
    let mut vertices = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let x = -s + 2.0 * s * i as f32 / n as f32;
            let y = -s + 2.0 * s * j as f32 / n as f32;
            vertices.push(GpuVertex { pos: [x, y, z], normal, color });
        }
    }
    let mut indices = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let a = j * (n + 1) + i;
            let (b, c, d) = (a + 1, a + n + 1, a + n + 2);
            indices.extend_from_slice(&[a, b, d, a, d, c]);
        }
    }
    DrawMesh { vertices, indices, ..DrawMesh::default() }
}

/// Camera on the z axis at `eye_z` looking at the origin, 60° vertical field of view.
fn params(w: u32, h: u32, eye_z: f32) -> DrawParams {
    let eye = Vec3::new(0.0, 0.0, eye_z);
    let view = glam::camera::rh::view::look_at_mat4(eye, Vec3::ZERO, Vec3::Y);
    let proj = glam::camera::rh::proj::directx::perspective(60f32.to_radians(), w as f32 / h as f32, 0.1, 100.0);
    DrawParams { view_proj: proj * view, eye, light_dir: Vec3::ZERO, wireframe: false, textured: false, clear: clear() }
}

fn px(img: &[u8], w: u32, x: u32, y: u32) -> [u8; 4] {
    let i = ((y * w + x) * 4) as usize;
    [img[i], img[i + 1], img[i + 2], img[i + 3]]
}

fn near(a: [u8; 4], b: [u8; 4], tol: u8) -> bool {
    a.iter().zip(&b).all(|(x, y)| x.abs_diff(*y) <= tol)
}

fn linear_to_srgb(c: f64) -> f64 {
    if c <= 0.0031308 {
        c * 12.92
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    }
}

#[test]
fn quad_is_lit_in_its_color_and_outside_is_clear() {
    let (w, h) = (64, 48);
    let Some(mut r) = renderer(w, h) else { return };
    eprintln!("adapter: {:?}", r.adapter_info());
    let front = r.upload(&grid(1, 1.0, 0.0, [0.0, 0.0, 1.0], COLOR));
    let away = r.upload(&grid(1, 1.0, 0.0, [0.0, 0.0, -1.0], COLOR));
    let clear = clear_rgba8(clear());
    // Front, back (no culling) and with the normal pointing away (two-sided).
    for (eye_z, m, normal) in [(3.0, &front, "+z"), (-3.0, &front, "+z"), (3.0, &away, "-z")] {
        let img = r.render_offscreen(&params(w, h, eye_z), &whole(&[m])).unwrap();
        assert_eq!(img.len(), (w * h * 4) as usize);
        // Headlight on a quad facing the eye: the vertex color, unchanged.
        let c = px(&img, w, w / 2, h / 2);
        assert!(near(c, COLOR, 2), "eye z {eye_z}, normal {normal}: center {c:?}, want {COLOR:?}");
        for (x, y) in [(0, 0), (w - 1, 0), (0, h - 1), (w - 1, h - 1), (2, h / 2), (w - 3, h / 2)] {
            assert_eq!(px(&img, w, x, y), clear, "pixel ({x},{y}) should be background");
        }
        // The quad spans 2/(2*3*tan 30°) = 57.7% of the height.
        let covered = 1.0 - background_fraction(&img, w, h, clear);
        let expect = (2.0 / (6.0 * 30f64.to_radians().tan())).powi(2) * h as f64 / w as f64;
        assert!((covered - expect).abs() < 0.03, "covered {covered}, expected about {expect}");
    }
}

#[test]
fn fixed_light_at_grazing_angle_leaves_ambient_only() {
    let (w, h) = (32, 32);
    let Some(mut r) = renderer(w, h) else { return };
    let quad = r.upload(&grid(1, 1.0, 0.0, [0.0, 0.0, 1.0], COLOR));
    let mut p = params(w, h, 3.0);
    p.light_dir = Vec3::X; // perpendicular to the normal
    let img = r.render_offscreen(&p, &whole(&[&quad])).unwrap();
    let want = [0, 1, 2].map(|k| {
        let lin = srgb_to_linear(COLOR[k] as f64 / 255.0) * AMBIENT as f64;
        (linear_to_srgb(lin) * 255.0).round() as u8
    });
    let c = px(&img, w, w / 2, h / 2);
    assert!(near(c, [want[0], want[1], want[2], 255], 2), "center {c:?}, want {want:?}");
    // Light along the normal: full color again.
    p.light_dir = Vec3::Z;
    let img = r.render_offscreen(&p, &whole(&[&quad])).unwrap();
    assert!(near(px(&img, w, w / 2, h / 2), COLOR, 2));
}

#[test]
fn depth_test_keeps_the_nearer_surface_in_any_order() {
    let (w, h) = (32, 32);
    let Some(mut r) = renderer(w, h) else { return };
    let red = [220, 10, 10, 255];
    let green = [10, 220, 10, 255];
    let near_q = r.upload(&grid(1, 0.5, 0.5, [0.0, 0.0, 1.0], red));
    let far_q = r.upload(&grid(1, 1.0, -0.5, [0.0, 0.0, 1.0], green));
    let p = params(w, h, 3.0);
    for order in [[&near_q, &far_q], [&far_q, &near_q]] {
        let img = r.render_offscreen(&p, &whole(&order)).unwrap();
        assert!(near(px(&img, w, w / 2, h / 2), red, 3));
        // Outside the small near quad but inside the far one.
        assert!(near(px(&img, w, w / 2 - 7, h / 2), green, 3));
    }
}

#[test]
fn wireframe_covers_fewer_pixels_than_fill() {
    let (w, h) = (96, 64);
    for line_list in [false, true] {
        let Some(mut r) = renderer_with(w, h, RendererOptions { line_list_wireframe: line_list, ..Default::default() }) else {
            return;
        };
        let mode = r.wireframe_mode();
        assert_eq!(mode == WireframeMode::LineList, line_list || !r.device().features().contains(wgpu::Features::POLYGON_MODE_LINE));
        let mesh = grid(6, 1.0, 0.0, [0.0, 0.0, 1.0], COLOR);
        let g = r.upload(&mesh);
        let line_bytes = if mode == WireframeMode::LineList { mesh.indices.len() as u64 * 2 * 4 } else { 0 };
        assert_eq!(g.gpu_bytes(), mesh.bytes() + line_bytes);
        let clear = clear_rgba8(clear());
        let mut p = params(w, h, 3.0);
        let fill = r.render_offscreen(&p, &whole(&[&g])).unwrap();
        p.wireframe = true;
        let wire = r.render_offscreen(&p, &whole(&[&g])).unwrap();
        let cov_fill = 1.0 - background_fraction(&fill, w, h, clear);
        let cov_wire = 1.0 - background_fraction(&wire, w, h, clear);
        eprintln!("{mode:?}: fill covers {cov_fill:.3}, wireframe {cov_wire:.3}");
        assert!(cov_wire > 0.02, "{mode:?}: wireframe draws almost nothing ({cov_wire})");
        assert!(cov_wire < 0.6 * cov_fill, "{mode:?}: wireframe {cov_wire} vs fill {cov_fill}");
        // Wireframe pixels lie on the filled area (or its 1-pixel rim:
        // lines on the outer edges may rasterise just outside the fill).
        for y in 0..h {
            for x in 0..w {
                if px(&wire, w, x, y) == clear {
                    continue;
                }
                let filled_nearby =
                    (y.saturating_sub(1)..(y + 2).min(h)).any(|yy| (x.saturating_sub(1)..(x + 2).min(w)).any(|xx| px(&fill, w, xx, yy) != clear));
                assert!(filled_nearby, "{mode:?}: wireframe pixel ({x},{y}) away from the filled area");
            }
        }
    }
}

#[test]
fn widths_that_are_not_multiples_of_64_read_back_without_row_padding() {
    for (w, h) in [(250u32, 130u32), (67, 33)] {
        let Some(mut r) = renderer(w, h) else { return };
        // Identity transform: a quad over the left half of clip space.
        let mut m = grid(1, 1.0, 0.5, [0.0, 0.0, 1.0], COLOR);
        for v in &mut m.vertices {
            v.pos[0] = if v.pos[0] < 0.0 { -1.0 } else { 0.0 };
        }
        let g = r.upload(&m);
        let p = DrawParams { view_proj: Mat4::IDENTITY, eye: Vec3::new(0.0, 0.0, -10.0), clear: clear(), ..Default::default() };
        let img = r.render_offscreen(&p, &whole(&[&g])).unwrap();
        assert_eq!(img.len(), (w * h * 4) as usize);
        let clear = clear_rgba8(clear());
        let edge = w / 2;
        for y in 0..h {
            for x in [0, edge.saturating_sub(2)] {
                assert!(near(px(&img, w, x, y), COLOR, 2), "{w}x{h}: ({x},{y}) = {:?}", px(&img, w, x, y));
            }
            for x in [edge + 2, w - 1] {
                assert_eq!(px(&img, w, x, y), clear, "{w}x{h}: ({x},{y})");
            }
        }
    }
}

#[test]
fn clear_color_reads_back_exactly_and_empty_meshes_draw_nothing() {
    let (w, h) = (16, 8);
    let Some(mut r) = renderer(w, h) else { return };
    let empty = r.upload(&DrawMesh::default());
    assert_eq!(empty.gpu_bytes(), 0);
    assert_eq!(clear_rgba8(clear()), [20, 30, 40, 255]);
    for k in [0u8, 1, 7, 20, 64, 128, 200, 254, 255] {
        let c = srgb_to_linear(k as f64 / 255.0);
        let p = DrawParams { clear: [c, 1.0 - c, c, 1.0], ..Default::default() };
        let img = r.render_offscreen(&p, &whole(&[&empty])).unwrap();
        assert_eq!(background_fraction(&img, w, h, clear_rgba8(p.clear)), 1.0, "clear {k}: got {:?}", px(&img, w, 0, 0));
    }
    // The headless driver's background and its expected bytes agree with the renderer.
    let p = DrawParams { clear: octolod::view::headless::CLEAR, ..Default::default() };
    let img = r.render_offscreen(&p, &whole(&[&empty])).unwrap();
    assert_eq!(px(&img, w, 3, 3), octolod::view::headless::clear_rgba8(true));
    assert_eq!(px(&img, w, 3, 3), clear_rgba8(p.clear));
}

#[test]
fn overlay_is_blended_at_the_top_left_and_identical_renders_compare_equal() {
    let (w, h) = (120, 64);
    let Some(mut r) = renderer(w, h) else { return };
    let p = DrawParams { clear: [1.0, 1.0, 1.0, 1.0], ..Default::default() };
    let plain = r.render_offscreen(&p, &whole(&[])).unwrap();
    let ov: OverlayImage = overlay_text(&["fps 60".to_string()]);
    let with = r.render_offscreen_overlay(&p, &[], Some(&ov)).unwrap();
    let again = r.render_offscreen_overlay(&p, &[], Some(&ov)).unwrap();
    assert_eq!(compare(&with, &again, w, h, 0).psnr_db, f64::INFINITY);
    let d = compare(&plain, &with, w, h, 0);
    assert!(d.differing_fraction > 0.05, "{d:?}");
    let m = octolod::view::gpu::OVERLAY_MARGIN;
    // Panel (dark, translucent over white) inside, untouched outside.
    let inside = px(&with, w, m + 1, m + 1);
    assert!(inside[0] < 180 && inside[0] > 20, "panel pixel {inside:?}");
    assert_eq!(px(&with, w, m - 1, m - 1), [255; 4]);
    assert_eq!(px(&with, w, m + ov.width + 1, m + 1), [255; 4]);
    assert_eq!(px(&with, w, w - 1, h - 1), [255; 4]);
    // Some text pixels are white again.
    let text = (0..ov.height).flat_map(|y| (0..ov.width).map(move |x| (x, y))).any(|(x, y)| {
        let i = ((y * ov.width + x) * 4) as usize;
        ov.rgba[i + 3] == 255 && px(&with, w, m + x, m + y) == [255; 4]
    });
    assert!(text);
}

/// Draw items for whole meshes.
fn whole<'a>(ms: &[&'a GpuMesh]) -> Vec<octolod::view::DrawItem<'a, GpuMesh>> {
    ms.iter().map(|m| octolod::view::DrawItem::whole(*m, m.triangles())).collect()
}

/// Set in the child process of
/// [`renderer_prints_no_wayland_error_line_without_a_desktop_session`].
const WAYLAND_CHILD: &str = "OCTOLOD_TEST_WAYLAND_CHILD";

/// Reliability v2, item 14: `view` (which keeps Mesa's device-select layer
/// on) and any run on the GL backend printed "error: XDG_RUNTIME_DIR is
/// invalid or not set in the environment." from libwayland's display
/// probes on a headless session. `view` needs a display, so this drives
/// the same renderer set-up as `view` and `render` do — the quieting call
/// `main` makes, then a renderer and a frame — in a child process (the
/// line goes straight to its stderr) without XDG_RUNTIME_DIR,
/// WAYLAND_DISPLAY or NODEVICE_SELECT, on the default backends and on GL.
#[test]
fn renderer_prints_no_wayland_error_line_without_a_desktop_session() {
    if let Some(backend) = std::env::var_os(WAYLAND_CHILD) {
        octolod::view::quiet::quiet_wayland_probes();
        let mut r = match Renderer::headless(16, 16) {
            Ok(r) => r,
            Err(e) if backend == "gl" => {
                println!("NO-GL-ADAPTER: {e}");
                return;
            }
            Err(e) if crate::common::gpu_tests_skipped() => {
                println!("SKIPPED: {e}");
                return;
            }
            Err(e) => panic!("{e} (set OCTOLOD_SKIP_GPU_TESTS=1 to skip GPU tests)"),
        };
        let m = r.upload(&grid(2, 1.0, 0.0, [0.0, 0.0, 1.0], COLOR));
        let img = r.render_offscreen(&params(16, 16, 3.0), &whole(&[&m])).unwrap();
        assert!(background_fraction(&img, 16, 16, clear_rgba8(clear())) < 1.0);
        println!("CHILD-RENDERED on {:?}", r.adapter_info().backend);
        return;
    }
    for backend in ["default", "gl"] {
        let mut cmd = this_test_again(module_path!(), "renderer_prints_no_wayland_error_line_without_a_desktop_session");
        cmd.env(WAYLAND_CHILD, backend);
        without_desktop_session(&mut cmd, backend);
        let o = cmd.output().unwrap();
        let (out, err) = (String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
        assert!(o.status.success(), "{backend}: {out}\n{err}");
        if out.contains("SKIPPED") {
            eprintln!("skipping GPU test (OCTOLOD_SKIP_GPU_TESTS=1): {out}");
            return;
        }
        if out.contains("NO-GL-ADAPTER") {
            eprintln!("no GL adapter here: GL case skipped ({out})");
            continue;
        }
        assert!(out.contains("CHILD-RENDERED"), "{backend}: the child did not render: {out}\n{err}");
        let bad: Vec<&str> = err.lines().chain(out.lines()).filter(|l| l.trim_start().starts_with("error")).collect();
        assert!(bad.is_empty(), "{backend}: error lines on a successful run: {bad:?}\n{err}");
    }
}

/// `grid` with uvs spanning [0, 1]² over it (u along x, v along y).
fn textured_grid(n: u32, color: [u8; 4]) -> DrawMesh {
    let mut m = grid(n, 1.0, 0.0, [0.0, 0.0, 1.0], color);
    m.uvs = m.vertices.iter().map(|v| [(v.pos[0] + 1.0) / 2.0, (v.pos[1] + 1.0) / 2.0]).collect();
    m
}

/// Issue 32, item 3: the texture is sampled upright (v = 0 is the image's
/// bottom row, MeshLab's convention), lit like vertex colours, tinted by
/// them only when asked, drawn only when `textured`; minified, it is the
/// linear-light mean of its texels (mipmaps), not an aliased texel; its
/// uv buffer counts in the mesh's bytes.
#[test]
fn textures_are_sampled_upright_lit_and_mipmapped() {
    use octolod::view::texture::MipChain;
    let (w, h) = (64, 64);
    let Some(mut r) = renderer(w, h) else { return };
    // Image quadrants (top row first): red, green / blue, white.
    let (red, green, blue, white) = ([230, 20, 20, 255], [20, 230, 20, 255], [20, 20, 230, 255], [255, 255, 255, 255]);
    let mut rgba = Vec::new();
    for y in 0..8 {
        for x in 0..8 {
            rgba.extend_from_slice(&match (y < 4, x < 4) {
                (true, true) => red,
                (true, false) => green,
                (false, true) => blue,
                (false, false) => white,
            });
        }
    }
    let chain = MipChain::new("quadrants", 8, 8, rgba);
    assert_eq!(r.set_texture(&chain, false).unwrap(), chain.bytes());
    let d = textured_grid(4, COLOR);
    assert_eq!(d.bytes(), grid(4, 1.0, 0.0, [0.0, 0.0, 1.0], COLOR).bytes() + 25 * 8);
    let quad = r.upload(&d);
    assert_eq!(quad.gpu_bytes(), d.bytes());
    let mut p = params(w, h, 3.0);
    p.light_dir = Vec3::Z;
    p.textured = true;
    let img = r.render_offscreen(&p, &whole(&[&quad])).unwrap();
    // The quad spans about 37 of 64 pixels; sample inside each quadrant.
    let (lo, hi) = (w / 2 - 9, w / 2 + 8);
    for (x, y, want, what) in [(lo, lo, red, "top left"), (hi, lo, green, "top right"), (lo, hi, blue, "bottom left"), (hi, hi, white, "bottom right")] {
        let c = px(&img, w, x, y);
        assert!(near(c, want, 3), "{what}: {c:?}, want {want:?}");
    }
    // Not textured: the vertex colour.
    p.textured = false;
    let img = r.render_offscreen(&p, &whole(&[&quad])).unwrap();
    assert!(near(px(&img, w, lo, lo), COLOR, 2));
    // Tinted: white texels take the vertex colour.
    r.set_texture(&chain, true).unwrap();
    p.textured = true;
    let img = r.render_offscreen(&p, &whole(&[&quad])).unwrap();
    assert!(near(px(&img, w, hi, hi), COLOR, 3), "{:?}", px(&img, w, hi, hi));
    // A fine black-and-white checker seen small: the mean of its texels in
    // linear light (sRGB 188), whichever texels the pixels fall on.
    let n = 256u32;
    let checker: Vec<u8> = (0..n * n).flat_map(|i| if (i % n + i / n) % 2 == 0 { [0, 0, 0, 255] } else { [255, 255, 255, 255] }).collect();
    r.set_texture(&MipChain::new("checker", n, n, checker), false).unwrap();
    let img = r.render_offscreen(&params(w, h, 3.0), &whole(&[&quad])).unwrap();
    let mut p = params(w, h, 3.0);
    p.light_dir = Vec3::Z;
    p.textured = true;
    let img2 = r.render_offscreen(&p, &whole(&[&quad])).unwrap();
    assert_ne!(img, img2);
    for (x, y) in [(w / 2, h / 2), (lo, lo), (hi, hi)] {
        let c = px(&img2, w, x, y);
        assert!(near(c, [188, 188, 188, 255], 12), "pixel {x},{y}: {c:?}");
    }
}

/// Issue 32: each face is drawn with its own material's texture. A plane
/// of four vertical strips, quads emitted row by row so the materials
/// interleave: red texture (slot 0), blue texture (slot 1), a slot whose
/// image the store lacks (2) and `NO_TEXTURE`; the last two draw shaded
/// in the vertex colour. Two patches (top and bottom rows) keep their
/// triangles when the node is ordered by material, so drawing one patch
/// draws exactly its half; T (not textured) draws every strip shaded.
#[test]
fn each_material_is_drawn_with_its_own_texture() {
    use octolod::mesh::{AttrSet, IndexedMesh, Vertex};
    use octolod::store::{NodeMesh, Patch};
    use octolod::view::texture::MipChain;
    use octolod::view::MaterialRun;
    let (w, h) = (96, 96);
    let Some(mut r) = renderer(w, h) else { return };
    let (red, blue) = ([230, 20, 20, 255], [20, 20, 230, 255]);
    let solid = |name: &str, c: [u8; 4]| MipChain::new(name, 4, 4, c.repeat(16));
    let (t0, t1) = (solid("red", red), solid("blue", blue));
    assert_eq!(r.set_textures([Some(&t0), Some(&t1), None], false).unwrap(), t0.bytes() + t1.bytes());
    assert!(r.has_texture());
    // 8 x 8 quads over [-1, 1]²; column i is in strip i / 2.
    let strip_material = [0u16, 1, 2, Vertex::NO_TEXTURE];
    let n = 8u32;
    let mut mesh = IndexedMesh::default();
    for j in 0..n {
        for i in 0..n {
            let material = strip_material[(i / 2) as usize];
            let base = mesh.vertices.len() as u32;
            for (di, dj) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let (u, v) = ((i + di) as f32 / n as f32, (j + dj) as f32 / n as f32);
                mesh.vertices.push(Vertex { pos: [2.0 * u as f64 - 1.0, 2.0 * v as f64 - 1.0, 0.0], color: COLOR, uv: [u, v], material, ..Vertex::default() });
            }
            mesh.triangles.extend([[base, base + 1, base + 3], [base, base + 3, base + 2]]);
        }
    }
    // Rows 0..4 (bottom, y < 0) are patch 0, rows 4..8 patch 1.
    let half = n * n; // triangles per half: 4 rows of 8 quads of 2
    let patches = vec![Patch { child: 1, first: 0, count: half }, Patch { child: 2, first: half, count: half }];
    let attrs = AttrSet::POSITION_ONLY.with(AttrSet::COLOR, true).with(AttrSet::UV, true).with(AttrSet::MATERIAL, true);
    let d = octolod::view::draw_node(&NodeMesh { mesh, patches: patches.clone() }, attrs, [0.0; 3]);
    // Per patch one run per material (16 triangles each), none merged across.
    let runs: Vec<(u32, u32, u16)> = d.materials.iter().map(|m: &MaterialRun| (m.first, m.count, m.material)).collect();
    let want: Vec<(u32, u32, u16)> = (0..8).map(|k| (16 * k, 16, strip_material[k as usize % 4])).collect();
    assert_eq!(runs, want);
    assert_eq!(d.patches, patches);
    // GPU bytes per vertex are unchanged: 28 + 8 for the uvs.
    assert_eq!(d.bytes(), d.vertices.len() as u64 * 36 + d.indices.len() as u64 * 4);
    let m = r.upload(&d);
    assert_eq!(m.gpu_bytes(), d.bytes());
    let mut p = params(w, h, 3.0);
    p.light_dir = Vec3::Z;
    p.textured = true;
    // The pixel showing world point (x, y, 0).
    let at = |x: f32, y: f32| {
        let c = p.view_proj * glam::Vec4::new(x, y, 0.0, 1.0);
        let (nx, ny) = (c.x / c.w, c.y / c.w);
        (((nx + 1.0) / 2.0 * w as f32) as u32, ((1.0 - ny) / 2.0 * h as f32) as u32)
    };
    let strips = [(-0.75, red, "slot 0 (red)"), (-0.25, blue, "slot 1 (blue)"), (0.25, COLOR, "slot 2 (no image)"), (0.75, COLOR, "NO_TEXTURE")];
    let check = |img: &[u8], y: f32, textured: bool, what: &str| {
        for (x, want, strip) in strips {
            let want = if textured { want } else { COLOR };
            let (px_x, px_y) = at(x, y);
            let c = px(img, w, px_x, px_y);
            assert!(near(c, want, 3), "{what}, {strip} at {x},{y} (pixel {px_x},{px_y}): {c:?}, want {want:?}");
        }
    };
    let img = r.render_offscreen(&p, &whole(&[&m])).unwrap();
    for y in [-0.6, 0.6] {
        check(&img, y, true, "textured");
    }
    // One patch: its half only, still per material.
    let top = vec![octolod::view::DrawItem { mesh: &m, ranges: std::iter::once(half..2 * half).collect() }];
    let img = r.render_offscreen(&p, &top).unwrap();
    check(&img, 0.6, true, "top patch alone");
    for (x, ..) in strips {
        let (px_x, px_y) = at(x, -0.6);
        assert_eq!(px(&img, w, px_x, px_y), clear_rgba8(clear()), "bottom half drawn at {x}");
    }
    // A range across both patches' runs: the bottom patch's last two runs
    // (its strips 2 and 3, ordered last) and the top patch's first two.
    let mid = vec![octolod::view::DrawItem { mesh: &m, ranges: std::iter::once(half / 2..half + half / 2).collect() }];
    let img = r.render_offscreen(&p, &mid).unwrap();
    let bg = clear_rgba8(clear());
    for ((x, want, strip), (bottom, top)) in strips.into_iter().zip([(false, true), (false, true), (true, false), (true, false)]) {
        for (y, drawn) in [(-0.6, bottom), (0.6, top)] {
            let c = px(&img, w, at(x, y).0, at(x, y).1);
            assert!(if drawn { near(c, want, 3) } else { c == bg }, "range across runs, {strip} at y {y}: {c:?}");
        }
    }
    // The T toggle: shaded, every strip in the vertex colour.
    p.textured = false;
    let img = r.render_offscreen(&p, &whole(&[&m])).unwrap();
    for y in [-0.6, 0.6] {
        check(&img, y, false, "shaded");
    }
    // Only slot 0 set: slot 1's faces draw shaded, as a missing image does.
    r.set_textures([Some(&t0)], false).unwrap();
    p.textured = true;
    let img = r.render_offscreen(&p, &whole(&[&m])).unwrap();
    let (bx, by) = at(-0.25, 0.6);
    assert!(near(px(&img, w, bx, by), COLOR, 3), "{:?}", px(&img, w, bx, by));
    let (rx, ry) = at(-0.75, 0.6);
    assert!(near(px(&img, w, rx, ry), red, 3), "{:?}", px(&img, w, rx, ry));
}
