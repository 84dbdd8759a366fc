//! `octolod render`: offscreen frames along a camera path.
//!
//! Takes: a store, a camera path (JSON, see [`CameraPath`]) or a default
//! orbit, an image size and the viewer settings. Gives: an output
//! directory with one PNG per frame, `stats.csv` and `stats.json` (the
//! per-frame statistics of the window's overlay plus a summary), and with
//! `--full-res` a reference render of the same path from every leaf at
//! full resolution (`reference/`) with per-frame PSNR and the fraction of
//! differing pixels. The reference streams level 0 through the GPU in
//! batches of 64 MiB (out of core, slow on big stores: it reads every leaf
//! in view per frame). `--brute-force` draws everything at level 0 instead of
//! the budgeted cut (the baseline). The directory appears only when
//! complete (written under a temporary name, then renamed).
//!
//! Frames are rendered exactly as the window renders them: one call of
//! [`Viewer::frame`] per frame, which never waits for a load, so the first
//! frames show the pinned coarse levels and later ones refine as loads
//! land. `--settle` keeps rendering the last pose until nothing is pending.
//!
//! Counts are checked before any work (before the output directory is
//! made): the path's poses and `--settle` add up to at most
//! [`MAX_FRAMES`]; a run that rendered no frame fails and keeps nothing.

use super::camera::{Camera, CameraPath, Up, MAX_FRAMES};
use super::gpu::{DrawParams, GpuMesh, Renderer};
use super::viewer::{load_all_originals, FrameStats, ViewOptions, Viewer};
use super::DrawItem;
use crate::error::{IoContext, Result};
use crate::io::AtomicDir;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Settings of one render run.
#[derive(Clone, Debug)]
pub struct RenderOptions {
    pub store: PathBuf,
    pub camera_path: Option<PathBuf>,
    /// Frames of the default orbit when no path is given.
    pub orbit_frames: usize,
    /// Up axis of the default orbit, and of path files that name none.
    pub up: Up,
    pub out: PathBuf,
    pub width: u32,
    pub height: u32,
    pub view: ViewOptions,
    pub full_res: bool,
    pub brute_force: bool,
    /// Extra frames at the last pose, at most, until loading settles.
    pub settle: usize,
    pub wireframe: bool,
    /// Draw the store's texture, when it has one (off: `--no-texture`,
    /// the shaded view; the texture is then not loaded).
    pub texture: bool,
    /// Pixels whose channels differ by more than this count as different.
    pub diff_tolerance: u8,
    pub quiet: bool,
    /// Replace an existing render directory at `out` (`--force`).
    pub force: bool,
}

/// One rendered frame: its statistics and, with `--full-res`, the comparison.
#[derive(Clone, Debug, serde::Serialize)]
pub struct FrameRecord {
    #[serde(flatten)]
    pub stats: FrameStats,
    /// Share of pixels showing the background.
    pub background_fraction: f64,
    /// PSNR against the full-resolution reference (`--full-res`; `"inf"`
    /// when identical).
    #[serde(serialize_with = "inf_as_text")]
    pub psnr_db: Option<f64>,
    /// Share of pixels differing from the reference (`--full-res`).
    pub diff_fraction: Option<f64>,
}

fn inf_as_text<S: serde::Serializer>(x: &Option<f64>, s: S) -> std::result::Result<S::Ok, S::Error> {
    match x {
        Some(v) if v.is_infinite() && *v > 0.0 => s.serialize_str("inf"),
        Some(v) if v.is_finite() => s.serialize_f64(*v),
        _ => s.serialize_none(),
    }
}

/// `stats.json`: the run's summary, then every frame.
#[derive(serde::Serialize)]
struct StatsFile<'a> {
    store: String,
    width: u32,
    height: u32,
    /// `budgeted` or `brute-force`.
    mode: &'static str,
    budget_bytes: u64,
    frames_rendered: usize,
    max_resident_bytes: u64,
    max_select_ms: f64,
    final_settled: bool,
    #[serde(serialize_with = "inf_as_text")]
    final_psnr_db: Option<f64>,
    final_diff_fraction: Option<f64>,
    load_failures: u64,
    /// The textures drawn, by material slot (null: the store lacks that
    /// image); empty when the store has none, or `--no-texture`.
    textures: Vec<Option<TextureSummary>>,
    frames: &'a [FrameRecord],
}

/// A texture a render drew: the store's file, the finest level kept and
/// how many finer ones `--ram` dropped, and the bytes it held.
#[derive(serde::Serialize)]
struct TextureSummary {
    file: String,
    width: u32,
    height: u32,
    levels_dropped: u32,
    bytes: u64,
}

impl TextureSummary {
    fn of(t: &super::texture::MipChain) -> TextureSummary {
        TextureSummary { file: t.name.clone(), width: t.size().0, height: t.size().1, levels_dropped: t.dropped, bytes: t.bytes() }
    }
}

/// What a run produced.
#[derive(Clone, Debug)]
pub struct RenderReport {
    pub frames: Vec<FrameRecord>,
    pub out: PathBuf,
}

pub const CLEAR: [f64; 4] = [0.05, 0.06, 0.08, 1.0];

/// The clear colour as the RGBA8 value it renders to.
pub fn clear_rgba8(srgb_target: bool) -> [u8; 4] {
    let enc = |c: f64| {
        let v = if srgb_target { crate::color::linear_to_srgb(c) } else { c };
        (v.clamp(0.0, 1.0) * 255.0).round() as u8
    };
    [enc(CLEAR[0]), enc(CLEAR[1]), enc(CLEAR[2]), 255]
}

pub fn draw_params(cam: &Camera, origin: glam::DVec3, w: u32, h: u32, wireframe: bool) -> DrawParams {
    DrawParams {
        view_proj: cam.view_proj(origin, w as f64 / h.max(1) as f64),
        eye: cam.eye_rel(origin),
        // Towards the light: over the viewer's right shoulder.
        light_dir: (-cam.forward() * 0.8 + cam.cam_up() * 0.5 + cam.right() * 0.35).normalize().as_vec3(),
        wireframe,
        textured: false,
        clear: CLEAR,
    }
}

/// Checks the run's counts before any work: the path's poses (the orbit's
/// `--frames`, or the path file's after expansion, counted without making
/// them) and `--settle`, at most [`MAX_FRAMES`] together.
fn check_counts(o: &RenderOptions, path_text: Option<&str>) -> Result<()> {
    use crate::error::Error;
    if o.orbit_frames > MAX_FRAMES {
        return Err(Error::Usage(format!("render: --frames {} is more than {MAX_FRAMES} frames", o.orbit_frames)));
    }
    let poses = match (&o.camera_path, path_text) {
        (Some(p), Some(t)) => CameraPath::count_text(t, p)?,
        _ => o.orbit_frames.max(1),
    };
    if o.settle > MAX_FRAMES - poses {
        return Err(Error::Usage(format!(
            "render: --settle {} is too many: the path's {poses} frames and --settle may add up to at most {MAX_FRAMES} frames",
            o.settle
        )));
    }
    Ok(())
}

/// Renders the path; see the module doc.
pub fn render(o: &RenderOptions) -> Result<RenderReport> {
    // The camera path is read once (a FIFO works), counted, later parsed.
    let path_text = o.camera_path.as_deref().map(CameraPath::read_text).transpose()?;
    check_counts(o, path_text.as_deref())?;
    // The store and the camera path are never replaced by this output.
    let _inputs = [Some(&o.store), o.camera_path.as_ref()].map(|p| p.map(|p| crate::io::protect(p)));
    let out = AtomicDir::create(&o.out, crate::io::OutputKind::Frames, o.force)?;
    let mut renderer = Renderer::headless(o.width, o.height)?;
    let mut view = o.view.clone();
    let store = crate::store::Store::open(&o.store)?;
    let textures = super::texture::prepare(&store, &mut view, o.texture)?;
    let mut viewer: Viewer<GpuMesh> = Viewer::with_store(store, view)?;
    if !textures.is_empty() {
        renderer.set_textures(textures.slots.iter().map(Option::as_ref), viewer.store.payload_layout.attrs.color())?;
    }
    let bounds = viewer.bounds();
    let origin = viewer.origin();
    let path = match &o.camera_path {
        Some(p) => CameraPath::load_text(path_text.as_deref().unwrap_or_default(), p, &bounds, o.up.resolve(&bounds))?,
        None => CameraPath::orbit(&bounds, o.orbit_frames.max(1), 0, o.up.resolve(&bounds)),
    };
    let reference = if o.brute_force {
        let (meshes, tris) = load_all_originals(&viewer.store, &mut |m| renderer.upload(m))?;
        let bytes: u64 = meshes.iter().map(|(m, _)| super::GpuBytes::gpu_bytes(m)).sum();
        Some((meshes, tris, bytes))
    } else {
        None
    };
    if o.full_res {
        std::fs::create_dir_all(out.path().join("reference")).ctx(out.path(), "create directory")?;
    }
    let clear8 = clear_rgba8(true);
    let total = path.poses.len().saturating_add(o.settle);
    let progress = crate::progress::Progress::items(total as u64, "rendering", o.quiet);
    let mut frames = Vec::new();
    let mut i = 0usize;
    loop {
        let last_pose = i + 1 >= path.poses.len();
        if i >= total {
            break;
        }
        let mut cam = path.camera(i);
        cam.fit_clip(&bounds);
        let (mut stats, meshes): (FrameStats, Vec<DrawItem<GpuMesh>>) = if o.brute_force {
            let (r, tris, bytes) = reference.as_ref().unwrap();
            let (tris, bytes) = (*tris, *bytes);
            let s = FrameStats {
                frame: i as u64 + 1,
                triangles: tris,
                nodes: r.len() as u32,
                nodes_per_level: vec![r.len() as u32],
                resident_bytes: bytes,
                peak_resident_bytes: bytes,
                budget_bytes: o.view.ram,
                texture_bytes: viewer.opts.texture_bytes,
                hit_rate: 1.0,
                settled: true,
                ..FrameStats::default()
            };
            (s, r.iter().map(|(m, t)| DrawItem::whole(m, *t)).collect())
        } else {
            let s = viewer.frame(&cam, (o.width, o.height), &mut |m| renderer.upload(m));
            (s, viewer.draw_list())
        };
        let mut p = draw_params(&cam, origin, o.width, o.height, o.wireframe);
        p.textured = !textures.is_empty();
        let t = Instant::now();
        let img = renderer.render_offscreen(&p, &meshes)?;
        stats.draw_ms = t.elapsed().as_secs_f64() * 1e3;
        let name = format!("frame-{:05}.png", i);
        super::image::write_png(out.path().join(&name), o.width, o.height, &img)?;
        let mut rec =
            FrameRecord { background_fraction: super::image::background_fraction(&img, o.width, o.height, clear8), stats, psnr_db: None, diff_fraction: None };
        if o.full_res {
            let ref_img = full_res_frame(&mut renderer, &viewer.store, &cam, &p, (o.width, o.height), REFERENCE_BATCH)?;
            super::image::write_png(out.path().join("reference").join(&name), o.width, o.height, &ref_img)?;
            let d = super::image::compare(&img, &ref_img, o.width, o.height, o.diff_tolerance);
            rec.psnr_db = Some(d.psnr_db);
            rec.diff_fraction = Some(d.differing_fraction);
        }
        let settled = rec.stats.settled;
        frames.push(rec);
        progress.inc(1);
        // Each frame is a safe point for signals.
        crate::io::signal::check()?;
        i += 1;
        if last_pose && i >= path.poses.len() && (settled || o.brute_force) {
            break;
        }
    }
    progress.finish();
    if frames.is_empty() {
        return Err(crate::error::Error::Usage("render: no frame was rendered; nothing is kept".into()));
    }
    write_stats(out.path(), &frames, o, &textures)?;
    // Frames drawn while nodes failed to load are not what was asked:
    // nothing is kept and the run fails, naming the first failures.
    let (failed, msgs) = viewer.load_failures();
    if failed > 0 {
        return Err(crate::error::Error::input(
            crate::error::Location { file: o.store.clone(), ..Default::default() },
            format!("render: {failed} node load(s) failed: {}", msgs.join("; ")),
        ));
    }
    out.commit()?;
    Ok(RenderReport { frames, out: o.out.clone() })
}

/// Every level-0 (input) triangle in view, drawn in batches of at most
/// `batch_bytes` (default [`REFERENCE_BATCH`]) read in store order: the full-resolution
/// reference without holding level 0 in memory.
pub fn full_res_frame(
    renderer: &mut Renderer,
    store: &crate::store::Store,
    cam: &Camera,
    p: &DrawParams,
    size: (u32, u32),
    batch_bytes: u64,
) -> Result<Vec<u8>> {
    let frustum = cam.frustum(size.0 as f64 / size.1.max(1) as f64);
    let leaves: Vec<usize> = store.level_nodes(0).into_iter().filter(|&i| !frustum.culls(&store.nodes[i].bounds)).collect();
    let ctx = super::viewer::load_ctx(store);
    let mut next = 0usize;
    renderer.render_offscreen_batched(p, &mut |r: &Renderer| {
        if next >= leaves.len() {
            return Ok(None);
        }
        crate::io::signal::check()?;
        let (mut batch, mut bytes) = (Vec::new(), 0u64);
        while next < leaves.len() && bytes < batch_bytes {
            let m = super::draw_node(&store.read_node(leaves[next])?, ctx.attrs, ctx.origin);
            bytes += m.bytes();
            batch.push(r.upload(&m));
            next += 1;
        }
        Ok(Some(batch))
    })
}

/// Bytes of GPU-ready meshes per reference batch.
pub const REFERENCE_BATCH: u64 = 64 << 20;

/// A CSV cell for one JSON value (lists joined by spaces, `null` empty).
fn csv_cell(v: &serde_json::Value) -> String {
    match v {
        serde_json::Value::Null => String::new(),
        serde_json::Value::String(s) => s.clone(),
        serde_json::Value::Array(a) => a.iter().map(csv_cell).collect::<Vec<_>>().join(" "),
        other => other.to_string(),
    }
}

fn write_stats(dir: &Path, frames: &[FrameRecord], o: &RenderOptions, textures: &super::texture::TextureSet) -> Result<()> {
    let csv = dir.join("stats.csv");
    let mut f = std::io::BufWriter::new(std::fs::File::create(&csv).ctx(&csv, "create")?);
    for (i, r) in frames.iter().enumerate() {
        let serde_json::Value::Object(row) = serde_json::to_value(r).expect("a frame record serializes") else {
            unreachable!("a struct serializes to an object")
        };
        if i == 0 {
            writeln!(f, "{}", row.keys().cloned().collect::<Vec<_>>().join(",")).ctx(&csv, "write")?;
        }
        writeln!(f, "{}", row.values().map(csv_cell).collect::<Vec<_>>().join(",")).ctx(&csv, "write")?;
    }
    f.flush().ctx(&csv, "write")?;
    let js = dir.join("stats.json");
    let last = frames.last();
    let file = StatsFile {
        store: o.store.display().to_string(),
        width: o.width,
        height: o.height,
        mode: if o.brute_force { "brute-force" } else { "budgeted" },
        budget_bytes: o.view.ram,
        frames_rendered: frames.len(),
        max_resident_bytes: frames.iter().map(|r| r.stats.resident_bytes).max().unwrap_or(0),
        max_select_ms: frames.iter().map(|r| r.stats.select_ms).fold(0.0, f64::max),
        final_settled: last.is_some_and(|r| r.stats.settled),
        final_psnr_db: last.and_then(|r| r.psnr_db),
        final_diff_fraction: last.and_then(|r| r.diff_fraction),
        load_failures: last.map_or(0, |r| r.stats.load_failures),
        textures: if textures.is_empty() { Vec::new() } else { textures.slots.iter().map(|t| t.as_ref().map(TextureSummary::of)).collect() },
        frames,
    };
    let text = serde_json::to_string_pretty(&file).expect("the stats serialize");
    std::fs::write(&js, text + "\n").ctx(&js, "write")
}
