//! `octolod` command line: a thin layer over the library's stages.

use clap::{Parser, Subcommand};
use octolod::mesh::Aabb;
use octolod::ply::read::BodySink;
use octolod::progress::{peak_rss, Progress};
use octolod::view::camera::Up;
#[cfg(feature = "view")]
use octolod::view::select::SelectOptions;
#[cfg(feature = "view")]
use octolod::view::viewer::ViewOptions;
#[cfg(feature = "view")]
use octolod::view::window::WindowOptions;
use octolod::{mem, ply, soup, Result};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
#[cfg(feature = "view")]
use std::time::Duration;

/// `println!` for the commands' reports: a closed stdout is
/// [`octolod::Error::ClosedOutput`] (returned with `?`), never a panic.
macro_rules! out {
    ($($t:tt)*) => {
        say(format_args!($($t)*))?
    };
}

fn say(args: std::fmt::Arguments) -> Result<()> {
    use std::io::Write;
    let mut o = std::io::stdout().lock();
    o.write_fmt(args).and_then(|()| o.write_all(b"\n")).map_err(|e| match e.kind() {
        std::io::ErrorKind::BrokenPipe => octolod::Error::ClosedOutput,
        _ => octolod::Error::io("standard output", "write", e),
    })
}

#[derive(Parser)]
#[command(name = "octolod", version, about = "Simplify and view triangle meshes far larger than RAM")]
struct Cli {
    /// No progress bars (they are also hidden when stderr is not a terminal).
    #[arg(long, short, global = true)]
    quiet: bool,
    /// Replace an existing output of the same kind (a store, a PLY, glTF or
    /// soup octolod wrote, a render or tileset directory, a plan or a
    /// shard). Anything else is never replaced.
    #[arg(long, global = true)]
    force: bool,
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Turn an indexed PLY into a triangle soup (out-of-core dereference of every corner).
    Soup {
        input: PathBuf,
        #[arg(short, long)]
        output: PathBuf,
        /// Working-memory budget (e.g. 128M, 2G).
        #[arg(long, default_value = mem::DEFAULT_BUDGET_ARG)]
        mem: String,
        /// Use the external (out-of-core) path even when the vertices fit in memory.
        #[arg(long)]
        external: bool,
        /// Print the report as JSON on stdout instead of a summary line.
        #[arg(long)]
        json: bool,
    },
    /// Build a store: PLY → soup → octree → bottom-up LODs, under --mem.
    Build {
        input: PathBuf,
        #[arg(short, long)]
        output: PathBuf,
        #[command(flatten)]
        params: BuildArgs,
        /// Node simplifier: cluster (generalized-quadric vertex clustering,
        /// fast), collapse (quadric edge collapse with attributes, accurate)
        /// or auto (collapse for textured inputs, whose atlas seams
        /// clustering simplifies less well; cluster otherwise).
        #[arg(long, default_value = "auto")]
        simplifier: octolod::manifest::Simplifier,
        /// Build one shard of a sharded build (with --shard): the plan
        /// gives the parameters, -o names the shard's directory.
        #[arg(long, requires = "shard")]
        plan: Option<PathBuf>,
        /// The shard to build (0-based, from the plan's list).
        #[arg(long, requires = "plan")]
        shard: Option<u32>,
        /// With --plan: print the shard's report as JSON.
        #[arg(long, requires = "plan")]
        json: bool,
    },
    /// Plan a sharded build: one pass over the input splits it into shards
    /// of about equal triangle counts (then `build --plan P --shard I` for
    /// each shard, anywhere, and `merge`).
    Plan {
        input: PathBuf,
        #[arg(short, long)]
        output: PathBuf,
        /// Number of shards.
        #[arg(long, default_value_t = 4, conflicts_with = "shard_tris")]
        shards: u32,
        /// Instead of --shards: as many shards as hold about this many triangles each.
        #[arg(long)]
        shard_tris: Option<u64>,
        /// Levels each shard builds before the merge (default: as many as
        /// leave the smallest shard four leaves of triangles).
        #[arg(long)]
        shard_levels: Option<u8>,
        #[command(flatten)]
        params: BuildArgs,
        /// Node simplifier of the whole build (see `build`).
        #[arg(long, default_value = "auto")]
        simplifier: octolod::manifest::Simplifier,
        /// Print the plan's summary as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Merge a plan's built shards into one store (builds the levels above
    /// the shards up to the root).
    Merge {
        plan: PathBuf,
        /// The shards' directories, every shard of the plan once.
        #[arg(required = true)]
        shards: Vec<PathBuf>,
        #[arg(short, long)]
        output: PathBuf,
        /// Working-memory budget (e.g. 512M, 2G).
        #[arg(long, default_value = mem::DEFAULT_BUDGET_ARG)]
        mem: String,
        /// Copy the shards' packs into the store's own (one pack file per
        /// level) instead of hard-linking them in as parts (the default; a
        /// shard on another filesystem is copied either way).
        #[arg(long)]
        copy: bool,
        /// Print the report as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Per level: nodes, triangles, bytes, error range, build time.
    Info { store: PathBuf },
    /// Export a store as a 3D Tiles 1.1 tileset (tileset.json + one GLB per tile) for web viewers and Cesium.
    Tiles(TilesArgs),
    /// Write a cut of a store as one indexed PLY, or glTF by the output's
    /// extension (OUT.glb, or OUT.gltf + OUT.bin): a whole level, or the cut at an error.
    Extract(ExtractArgs),
    /// One mesh of the size (or error) asked: builds a store in a scratch
    /// directory, then reduces its nearest level to exactly that size.
    #[command(group(clap::ArgGroup::new("target").required(true).args(["target_tris", "target_ratio", "target_error"])))]
    Simplify(SimplifyArgs),
    /// Two-sided Metro surface distance between meshes A and B (PLY paths or STORE@L).
    ///
    /// Exit status: 0 within every given threshold, 3 when one is exceeded, 1 on errors.
    Metro(MetroArgs),
    /// Render frames offscreen along a camera path (PNG + per-frame statistics).
    ///
    /// Works without a display (e.g. Mesa lavapipe). With --full-res, also
    /// renders the path from every leaf at full resolution and reports PSNR
    /// and the fraction of differing pixels per frame.
    #[cfg_attr(not(feature = "view"), command(about = "Render frames offscreen (not in this build: it has no `view` feature)", long_about = None))]
    Render(RenderArgs),
    /// Open an interactive window on a store (needs a display; `render` works without).
    ///
    /// Examine (1): drag orbits, right/shift-drag pans, wheel dollies. Fly (2), walk (3):
    /// WASD, Q/E down/up, drag looks, shift faster. Tab cycles modes; R reset, F frame all,
    /// Z wireframe, T texture, +/- field of view, F1/H overlay, V vsync, U up axis, Esc quit.
    #[cfg_attr(not(feature = "view"), command(about = "Open an interactive window on a store (not in this build: it has no `view` feature)", long_about = None))]
    View {
        store: PathBuf,
        #[command(flatten)]
        view: ViewArgs,
        #[command(flatten)]
        window: WindowArgs,
    },
    /// Print an input's header (PLY, STL or OBJ), counts, attribute set,
    /// bounding box and decode speed.
    #[command(alias = "info-input")]
    PlyInfo {
        input: PathBuf,
        /// Only parse the header (no bbox, no body validation).
        #[arg(long)]
        header_only: bool,
    },
    /// Serve a 3D Tiles directory (or a store, exported first) and the browser viewer page over HTTP.
    ///
    /// `/` is the viewer page, `/tiles/` the tileset. Prints one line,
    /// `serving URL (tileset: URL)`, once listening; runs until SIGINT/SIGTERM.
    Serve {
        /// A 3D Tiles directory (holding tileset.json) or a store.
        input: PathBuf,
        /// Port to listen on (0: any free port).
        #[arg(long, default_value_t = 8080)]
        port: u16,
        /// Address to listen on.
        #[arg(long, default_value = "127.0.0.1")]
        bind: std::net::IpAddr,
        /// Open the page in the default browser (xdg-open; best effort).
        #[arg(long)]
        open: bool,
    },
}

// The arguments of the commands with many: each command's function takes
// its own. No `///` comments on these structs: clap would take one for the
// command's about text, which is the variant's.

#[derive(clap::Args)]
struct TilesArgs {
    store: PathBuf,
    /// Output directory (tileset.json, t/*.glb).
    #[arg(short, long)]
    output: PathBuf,
    /// Quantized attributes (KHR_mesh_quantization).
    #[arg(long)]
    quantize: bool,
    /// meshopt-compressed buffers (EXT_meshopt_compression, with an uncompressed fallback).
    #[arg(long)]
    compress: bool,
    /// Working-memory budget (e.g. 512M).
    #[arg(long, default_value = mem::DEFAULT_BUDGET_ARG)]
    mem: String,
    /// Split a level's cell while it holds more triangles than this.
    #[arg(long, default_value_t = 32768)]
    tile_tris: u64,
    /// Up axis of the model: auto (as `view`), x, y, z, -x, -y or -z.
    #[arg(long, default_value = "auto")]
    up: String,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args)]
struct ExtractArgs {
    store: PathBuf,
    /// The whole level L (default 0, the input).
    #[arg(long, conflicts_with = "max_error")]
    level: Option<u8>,
    /// The cut whose every part has error at most E (object space, or `0.1%` of the diagonal).
    #[arg(long, value_name = "E")]
    max_error: Option<String>,
    #[arg(short, long)]
    output: PathBuf,
    /// Do not weld vertices shared between nodes (streams, no level in memory).
    #[arg(long)]
    no_weld: bool,
    /// glTF outputs: KHR_mesh_quantization (16-bit positions, 8-bit normals, 16-bit uvs).
    #[arg(long)]
    quantize: bool,
    /// glTF outputs: EXT_meshopt_compression of the vertex and index buffers.
    #[arg(long)]
    compress: bool,
}

#[derive(clap::Args)]
struct SimplifyArgs {
    input: PathBuf,
    #[arg(short, long)]
    output: PathBuf,
    /// Output triangles (within 1 %).
    #[arg(long, value_name = "N")]
    target_tris: Option<u64>,
    /// Output triangles as a fraction of the input's (e.g. 0.1).
    #[arg(long, value_name = "R")]
    target_ratio: Option<f64>,
    /// The smallest mesh whose measured Hausdorff distance to the input
    /// (both directions) is at most E (object space, or `0.1%` of the diagonal).
    #[arg(long, value_name = "E")]
    target_error: Option<String>,
    /// Node simplifier: collapse (quadric edge collapse, accurate) or
    /// cluster (generalized-quadric vertex clustering, fast).
    #[arg(long, default_value = "collapse")]
    simplifier: octolod::manifest::Simplifier,
    /// Metro samples per direction when checking --target-error
    /// [default: metro's own, 10 × the larger face count].
    #[arg(long)]
    verify_samples: Option<u64>,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    params: BuildArgs,
}

#[derive(clap::Args)]
struct MetroArgs {
    /// Reference mesh: a PLY, or STORE@L for level L of an octolod store.
    a: String,
    /// Compared mesh: a PLY, or STORE@L.
    b: String,
    /// Samples per direction (default: 10 × the larger face count).
    #[arg(long)]
    samples: Option<u64>,
    /// Seed of the face samples' randomness.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    json: bool,
    /// Fail (exit 3) when the two-sided Hausdorff distance exceeds this (0.01, or 0.1% of A's bbox diagonal).
    #[arg(long)]
    max_hausdorff: Option<String>,
    /// Fail (exit 3) when the RMS distance over both directions exceeds this.
    #[arg(long)]
    max_rms: Option<String>,
    /// Fail (exit 3) when the mean distance over both directions exceeds this.
    #[arg(long)]
    max_mean: Option<String>,
    /// Memory budget (default 512M): pages STORE@L operands' nodes in and out; given, PLYs (held whole) must fit it too.
    #[arg(long)]
    mem: Option<String>,
    /// Also measure the uv and colour difference at the closest point
    /// (both operands held whole with their attributes).
    #[arg(long)]
    attributes: bool,
}

#[derive(clap::Args)]
struct RenderArgs {
    store: PathBuf,
    /// Camera path JSON (default: an orbit of --frames frames).
    #[arg(long)]
    camera_path: Option<PathBuf>,
    #[arg(long, default_value_t = 60)]
    frames: usize,
    /// Up axis of the default orbit and of path files that name none:
    /// auto (Y, or a height field's thin axis), x, y, z, -x, -y or -z.
    #[arg(long, default_value = "auto")]
    up: String,
    /// Output directory (PNG frames, stats.csv, stats.json).
    #[arg(short = 'o', long, visible_alias = "output")]
    out: PathBuf,
    #[arg(long, default_value_t = 960)]
    width: u32,
    #[arg(long, default_value_t = 540)]
    height: u32,
    #[command(flatten)]
    view: ViewArgs,
    /// Also render a full-resolution reference and compare.
    #[arg(long)]
    full_res: bool,
    /// Draw everything at level 0 (the baseline) instead of the budgeted cut.
    #[arg(long)]
    brute_force: bool,
    /// After the path, keep rendering its last pose until loading settles (at most N frames).
    #[arg(long, default_value_t = 600)]
    settle: usize,
    #[arg(long)]
    wireframe: bool,
    /// Channel difference above which a pixel counts as different.
    #[arg(long, default_value_t = 16)]
    diff_tolerance: u8,
}

/// Command-line settings shared by `octolod view` and `octolod render`.
#[derive(clap::Args, Clone, Debug)]
struct ViewArgs {
    /// Hard memory limit for node data (index, CPU copies, GPU buffers, in-flight loads).
    #[arg(long, default_value = "512M")]
    ram: String,
    /// Refine nodes whose projected error exceeds this many pixels.
    #[arg(long, default_value_t = 1.0)]
    max_error_px: f64,
    /// Most triangles drawn per frame.
    #[arg(long, default_value_t = 20_000_000)]
    tri_budget: u64,
    /// Distance-only LOD (the original design): refine while the eye is
    /// nearer than F × the node's cell diagonal, instead of projected error.
    #[arg(long, value_name = "F")]
    distance_lod: Option<f64>,
    /// Background I/O threads.
    #[arg(long, default_value_t = 2)]
    io_threads: usize,
    /// Upload at most this much per frame (e.g. 64M).
    #[arg(long, default_value = "64M")]
    upload_per_frame: String,
    /// Simulate a slow disk: sleep this many milliseconds per node read.
    #[arg(long, default_value_t = 0)]
    io_delay_ms: u64,
    /// Do not load or draw the store's texture: the shaded view, and the
    /// texture's share of --ram stays free for nodes (T toggles the
    /// texture in the window when it is loaded).
    #[arg(long)]
    no_texture: bool,
}

#[cfg(feature = "view")]
impl ViewArgs {
    fn options(&self) -> Result<ViewOptions> {
        let ram = mem::parse_budget(&self.ram, "--ram")?;
        let upload = mem::parse_size(&self.upload_per_frame)?;
        if !(self.max_error_px > 0.0 && self.max_error_px.is_finite()) {
            return Err(octolod::Error::Usage("--max-error-px must be a positive number".into()));
        }
        if let Some(f) = self.distance_lod {
            if !(f > 0.0 && f.is_finite()) {
                return Err(octolod::Error::Usage("--distance-lod must be a positive number".into()));
            }
        }
        Ok(ViewOptions {
            ram,
            select: SelectOptions {
                max_error_px: self.max_error_px,
                tri_budget: self.tri_budget.max(1),
                distance_lod: self.distance_lod,
                ..SelectOptions::default()
            },
            io_threads: self.io_threads.max(1),
            io_delay: Duration::from_millis(self.io_delay_ms),
            upload_per_frame: upload.max(1),
            ..ViewOptions::default()
        })
    }
}

/// Command-line settings of the window (the viewer's are [`ViewArgs`]).
#[derive(clap::Args, Clone, Debug)]
struct WindowArgs {
    /// Window width in pixels.
    #[arg(long, default_value_t = 1280)]
    width: u32,
    /// Window height in pixels.
    #[arg(long, default_value_t = 800)]
    height: u32,
    /// Present with vsync (default: lowest latency, Mailbox or Immediate).
    #[arg(long)]
    vsync: bool,
    /// Up axis of the model: auto, x, y, z, -x, -y or -z. `auto` takes Y
    /// (the usual convention of scans, MeshLab, Blender exports) unless the
    /// model is a height field, whose thin axis is then up.
    #[arg(long, default_value = "auto")]
    up: String,
    /// Vertical field of view in degrees.
    #[arg(long, default_value_t = 50.0)]
    fov: f64,
    /// Start in wireframe.
    #[arg(long)]
    wireframe: bool,
    /// Start with the statistics overlay hidden (F1 or H shows it).
    #[arg(long)]
    no_overlay: bool,
    /// Quit after N frames (scripted runs, screenshots).
    #[arg(long, value_name = "N")]
    frames: Option<u64>,
}

#[cfg(feature = "view")]
impl WindowArgs {
    fn options(&self, store: PathBuf, view: ViewOptions, texture: bool, quiet: bool) -> Result<WindowOptions> {
        check_size(self.width, self.height)?;
        if !(self.fov > 1.0 && self.fov < 170.0) {
            return Err(octolod::Error::Usage("--fov must be between 1 and 170 degrees".into()));
        }
        Ok(WindowOptions {
            store,
            view,
            width: self.width,
            height: self.height,
            vsync: self.vsync,
            quiet,
            up: Up::parse(&self.up)?,
            fov_deg: self.fov,
            wireframe: self.wireframe,
            texture,
            overlay: !self.no_overlay,
            max_frames: self.frames,
        })
    }
}

#[cfg(feature = "view")]
fn check_size(width: u32, height: u32) -> Result<()> {
    if width == 0 || height == 0 || width > 16384 || height > 16384 {
        return Err(octolod::Error::Usage("--width/--height must be within 1..16384".into()));
    }
    Ok(())
}

#[derive(clap::Args, Clone)]
struct BuildArgs {
    /// Working-memory budget (e.g. 512M, 2G).
    #[arg(long, default_value = mem::DEFAULT_BUDGET_ARG)]
    mem: String,
    /// Split a level's octree cell while it holds more triangles than this.
    #[arg(long, default_value_t = 16384)]
    leaf_tris: u64,
    /// Never split deeper than this (1..=21).
    #[arg(long, default_value_t = 16, value_parser = clap::value_parser!(u8).range(1..=21))]
    max_depth: u8,
    /// Each level holds about 1/R of the triangles of the level below.
    #[arg(long, default_value_t = 2.0)]
    level_ratio: f64,
    /// The root (the coarsest level, one node) holds at most this many triangles.
    #[arg(long, default_value_t = 4096)]
    root_tris: u64,
    /// Build levels up to this one only (default: up to the root).
    #[arg(long)]
    levels: Option<u8>,
    /// How the levels above level 0 get an input's normals: average
    /// (out of the quadric, each vertex the mean of those it stands for:
    /// faster), carry (in the quadric, 3 more dimensions: keeps creases) or
    /// auto (average unless the input's normals have creases).
    /// Level 0 keeps the input's.
    #[arg(long, default_value = "auto")]
    normals: octolod::manifest::Normals,
}

impl BuildArgs {
    fn options(&self, quiet: bool, force: bool) -> Result<octolod::pipeline::BuildOptions> {
        if self.leaf_tris < MIN_LEAF_TRIS {
            return Err(octolod::Error::Usage(format!(
                "--leaf-tris {} is below the minimum {MIN_LEAF_TRIS}: smaller nodes cost more in records, seams and reads than they save",
                self.leaf_tris
            )));
        }
        let params = octolod::manifest::BuildParams {
            mem: mem::parse_budget(&self.mem, "--mem")?,
            leaf_tris: self.leaf_tris,
            max_depth: self.max_depth,
            level_ratio: self.level_ratio,
            root_tris: self.root_tris,
            levels: self.levels,
            normals: self.normals,
            ..Default::default()
        };
        octolod::lod::check_params(&params)?;
        Ok(octolod::pipeline::BuildOptions { params, quiet, force })
    }
}

/// Smallest `--leaf-tris` the CLI accepts.
const MIN_LEAF_TRIS: u64 = 256;

fn print_build(r: &octolod::pipeline::BuildReport) -> Result<()> {
    out!(
        "build: {} triangles, {} level-0 nodes, {} nodes, {} levels; soup {:.2} s, partition {:.2} s ({} counting pass{}), levels {:.2} s, total {:.2} s; {} on disk; peak RSS {}",
        r.soup.header.triangles,
        r.octree.leaves,
        r.nodes,
        r.levels.len(),
        r.seconds[0],
        r.seconds[1],
        r.octree.counting_passes,
        if r.octree.counting_passes == 1 { "" } else { "es" },
        r.seconds[2],
        r.seconds[3],
        octolod::progress::mib(r.disk_bytes),
        peak_rss().map(octolod::progress::mib).unwrap_or_else(|| "n/a".into())
    );
    out!("{:>5} {:>7} {:>13} {:>11} {:>8} {:>10} {:>8}", "level", "nodes", "triangles", "err max", "locked", "prev.lock", "time");
    for l in &r.levels {
        out!(
            "{:>5} {:>7} {:>13} {:>11.3e} {:>7.1}% {:>9} {:>7.2}s",
            l.level,
            l.nodes,
            l.triangles,
            l.error_max,
            100.0 * l.locked_fraction,
            if l.level == 0 { String::new() } else { format!("{:.1}%", 100.0 * l.prev_locked_still_fraction) },
            l.seconds
        );
    }
    Ok(())
}

fn main() -> ExitCode {
    octolod::mem::limit_arenas();
    octolod::io::raise_open_files();
    // Rust starts with SIGPIPE ignored: a closed stdout (`octolod info S |
    // head -1`) is then an error on write ([`out!`]), which unwinds the
    // command like any error (its temp paths removed, nothing committed
    // after it) and ends quietly with 128 + SIGPIPE, the status a shell
    // reports for a command its reader stopped.
    let cli = Cli::parse();
    #[cfg(feature = "view")]
    if matches!(cli.cmd, Cmd::Render(_)) {
        quiet_device_select();
    }
    #[cfg(feature = "view")]
    if matches!(cli.cmd, Cmd::Render(_) | Cmd::View { .. }) {
        // Before any wgpu or winit call (see octolod::view::quiet).
        octolod::view::quiet::quiet_wayland_probes();
    }
    octolod::io::signal::install();
    match run(cli) {
        Ok(code) => code,
        Err(octolod::Error::ClosedOutput) => ExitCode::from(128 + libc::SIGPIPE as u8),
        Err(e) => {
            // Interrupted: 128 + the signal, as a shell reports it, and no message.
            let status = octolod::io::signal::exit_status(&e);
            if status == 1 {
                eprintln!("octolod: error: {e}");
            }
            ExitCode::from(status)
        }
    }
}

/// Offscreen rendering presents to no display, so Mesa's implicit Vulkan
/// layer that picks the GPU driving the display has nothing to choose by;
/// it only probes the desktop session's displays. Turn it off for
/// `render`, unless the user asked it for a device
/// (`MESA_VK_DEVICE_SELECT`) or set the switch themselves. (The
/// "error: XDG_RUNTIME_DIR is invalid" line its Wayland probe printed
/// without a session, as do the GL backend's and `view`'s, is dropped by
/// `octolod::view::quiet` whether or not the layer runs.)
#[cfg(feature = "view")]
fn quiet_device_select() {
    if std::env::var_os("MESA_VK_DEVICE_SELECT").is_none() && std::env::var_os("NODEVICE_SELECT").is_none() {
        // SAFETY: called from main before any other thread exists.
        unsafe { std::env::set_var("NODEVICE_SELECT", "1") };
    }
}

/// `view` and `render` in a build without the `view` feature (no wgpu, no
/// winit): they stay in the command line, so `--help` lists them and a
/// script gets this error (exit 1) instead of "unrecognized subcommand".
#[cfg(not(feature = "view"))]
fn no_view() -> octolod::Error {
    octolod::Error::Usage("this octolod was built without the `view` feature (cargo install octolod --features view)".into())
}

/// Runs the command line's command; `--quiet` and `--force` go to the commands that take them.
fn run(cli: Cli) -> Result<ExitCode> {
    let Cli { quiet, force, cmd } = cli;
    match cmd {
        Cmd::Soup { input, output, mem, external, json } => cmd_soup(&input, &output, &mem, external, json, quiet, force),
        Cmd::Build { input, output, params, plan: Some(plan), shard: Some(shard), json, .. } => {
            cmd_build_shard(&input, &output, &plan, shard, &params.mem, json, quiet, force)
        }
        Cmd::Build { input, output, params, simplifier, .. } => cmd_build(&input, &output, &params, simplifier, quiet, force),
        Cmd::Plan { input, output, shards, shard_tris, shard_levels, params, simplifier, json } => {
            let mut o = params.options(quiet, force)?;
            o.params.simplifier = simplifier;
            let opts = octolod::shard::PlanOptions { params: o.params, shards, shard_tris, shard_levels, quiet: quiet || json };
            cmd_plan(&input, &output, &opts, force, json)
        }
        Cmd::Merge { plan, shards, output, mem, copy, json } => cmd_merge(&plan, &shards, &output, &mem, copy, json, quiet, force),
        Cmd::Info { store } => info(&store).map(|()| ExitCode::SUCCESS),
        Cmd::Tiles(args) => cmd_tiles(args, quiet, force),
        Cmd::Extract(args) => cmd_extract(args, force),
        Cmd::Simplify(args) => cmd_simplify(args, quiet, force),
        Cmd::Metro(args) => cmd_metro(args, quiet),
        #[cfg(not(feature = "view"))]
        Cmd::Render(_) | Cmd::View { .. } => Err(no_view()),
        #[cfg(feature = "view")]
        Cmd::Render(args) => cmd_render(args, quiet, force),
        #[cfg(feature = "view")]
        Cmd::View { store, view, window } => {
            octolod::view::window::run_window(window.options(store, view.options()?, !view.no_texture, quiet)?).map(|()| ExitCode::SUCCESS)
        }
        Cmd::PlyInfo { input, header_only } => ply_info(&input, header_only, quiet).map(|()| ExitCode::SUCCESS),
        Cmd::Serve { input, port, bind, open } => cmd_serve(&input, port, bind, open, quiet),
    }
}

fn cmd_soup(input: &Path, output: &Path, mem: &str, external: bool, json: bool, quiet: bool, force: bool) -> Result<ExitCode> {
    let opts = soup::SoupOptions { mem: mem::parse_budget(mem, "--mem")?, quiet, force_external: external, replace: force, ..Default::default() };
    let rep = soup::build_soup(input, output, &opts)?;
    let peak = peak_rss();
    if json {
        out!("{}", serde_json::to_string(&rep.json(opts.mem, peak)).expect("the report serializes"));
    } else {
        out!("{}", rep.summary(peak));
    }
    Ok(ExitCode::SUCCESS)
}

fn cmd_build(input: &Path, output: &Path, params: &BuildArgs, simplifier: octolod::manifest::Simplifier, quiet: bool, force: bool) -> Result<ExitCode> {
    let mut o = params.options(quiet, force)?;
    o.params.simplifier = simplifier;
    let r = octolod::pipeline::build_store(input, output, &o)?;
    print_build(&r)?;
    Ok(ExitCode::SUCCESS)
}

fn cmd_plan(input: &Path, output: &Path, opts: &octolod::shard::PlanOptions, force: bool, json: bool) -> Result<ExitCode> {
    let p = octolod::shard::plan(input, output, opts, force)?;
    if json {
        out!("{}", serde_json::to_string_pretty(&p).expect("the plan serializes"));
    } else {
        let est: Vec<u64> = p.shards.iter().map(|s| s.est_triangles).collect();
        out!(
            "plan {}: {} triangles in {} shards (largest {}, smallest {} triangles), {} levels per shard; {:.2} s -> {}",
            p.plan_id,
            p.triangles,
            p.shards.len(),
            est.iter().max().unwrap_or(&0),
            est.iter().min().unwrap_or(&0),
            p.shard_levels,
            p.seconds,
            output.display()
        );
    }
    Ok(ExitCode::SUCCESS)
}

#[allow(clippy::too_many_arguments, reason = "the command line's options, each distinct")]
fn cmd_build_shard(input: &Path, output: &Path, plan_path: &Path, shard: u32, mem_arg: &str, json: bool, quiet: bool, force: bool) -> Result<ExitCode> {
    let plan = octolod::shard::Plan::read(plan_path)?;
    let opts = octolod::shard::ShardOptions { mem: mem::parse_budget(mem_arg, "--mem")?, quiet: quiet || json, force };
    let r = octolod::shard::build_shard(input, &plan, plan_path, shard, output, opts)?;
    let peak = peak_rss();
    if json {
        let mut v = serde_json::to_value(&r).expect("the report serializes");
        v["peak_rss"] = serde_json::json!(peak);
        out!("{v}");
    } else if r.skipped {
        out!("shard {}: already built in {} (plan {}); nothing to do", r.shard, output.display(), plan.plan_id);
    } else {
        out!(
            "shard {}: {} of {} triangles, {} boundary positions locked, {} levels, {} nodes; {:.2} s; peak RSS {} -> {}",
            r.shard,
            r.triangles,
            r.input_triangles,
            r.boundary_positions,
            r.levels,
            r.nodes,
            r.seconds,
            peak.map(octolod::progress::mib).unwrap_or_else(|| "n/a".into()),
            output.display()
        );
    }
    Ok(ExitCode::SUCCESS)
}

#[allow(clippy::too_many_arguments, reason = "the command's flags")]
fn cmd_merge(plan_path: &Path, shards: &[PathBuf], output: &Path, mem_arg: &str, copy: bool, json: bool, quiet: bool, force: bool) -> Result<ExitCode> {
    let plan = octolod::shard::Plan::read(plan_path)?;
    let o = octolod::shard::MergeOptions { mem: mem::parse_budget(mem_arg, "--mem")?, quiet: quiet || json, force, copy };
    let r = octolod::shard::merge(&plan, shards, output, o)?;
    let peak = peak_rss();
    if json {
        let mut v = serde_json::to_value(&r).expect("the report serializes");
        v["peak_rss"] = serde_json::json!(peak);
        out!("{v}");
    } else {
        out!(
            "merge: {} shards, {} nodes, {} levels; simplified {} triangles of the shards' tops; packs linked {}, copied {}; {:.2} s; peak RSS {} -> {}",
            r.shards,
            r.nodes,
            r.levels,
            r.merged_triangles,
            octolod::progress::mib(r.linked_bytes),
            octolod::progress::mib(r.copied_bytes),
            r.seconds,
            peak.map(octolod::progress::mib).unwrap_or_else(|| "n/a".into()),
            output.display()
        );
    }
    Ok(ExitCode::SUCCESS)
}

fn cmd_tiles(args: TilesArgs, quiet: bool, force: bool) -> Result<ExitCode> {
    let TilesArgs { store, output, quantize, compress, mem, tile_tris, up, json } = args;
    let s = octolod::store::Store::open(&store)?;
    let o = octolod::tiles::TilesOptions {
        quantize,
        compress,
        mem: mem::parse_budget(&mem, "--mem")?,
        tile_tris,
        up: Up::parse(&up)?,
        quiet: quiet || json,
        force,
    };
    let r = octolod::tiles::export(&s, &output, &o)?;
    if json {
        out!("{}", serde_json::to_string_pretty(&r).expect("the report serializes"));
    } else {
        out!(
            "tiles: {} tiles ({} with content, depth {}), {} triangles of which {} skirt, from {} store triangles; {} for a {} store ({:.2}x); {:.2} s, {:.2} M store tri/s -> {}",
            r.tiles,
            r.contents,
            r.depth,
            r.triangles,
            r.skirt_triangles,
            r.store_triangles,
            octolod::progress::mib(r.tileset_bytes),
            octolod::progress::mib(r.store_bytes),
            r.tileset_bytes as f64 / r.store_bytes.max(1) as f64,
            r.seconds,
            r.mtris_per_s,
            output.display()
        );
    }
    Ok(ExitCode::SUCCESS)
}

fn cmd_extract(args: ExtractArgs, force: bool) -> Result<ExitCode> {
    let ExtractArgs { store, level, max_error, output, no_weld, quantize, compress } = args;
    let s = octolod::store::Store::open(&store)?;
    let spec = match max_error {
        Some(e) => {
            let t = octolod::metro::Threshold::parse(&e)?;
            octolod::pipeline::CutSpec::MaxError(t.limit(s.header.bbox.diagonal()))
        }
        None => octolod::pipeline::CutSpec::Level(level.unwrap_or(0)),
    };
    let gltf = octolod::gltf::GltfOptions { quantize, compress, textures: Vec::new() };
    let (nv, nf) = octolod::pipeline::extract_as(&s, spec, &output, !no_weld, force, &gltf)?;
    out!("extract: {}: {nv} vertices, {nf} triangles -> {}", spec.describe(), output.display());
    Ok(ExitCode::SUCCESS)
}

/// `simplify`: a store built in a scratch directory (dropped, with the
/// directory, when this returns), then reduced to the target.
fn cmd_simplify(args: SimplifyArgs, quiet: bool, force: bool) -> Result<ExitCode> {
    use octolod::simplify::{SimplifyOptions, Target};
    let SimplifyArgs { input, output, target_tris, target_ratio, target_error, simplifier, verify_samples, json, params } = args;
    let _input = octolod::io::protect(&input);
    octolod::io::check_output(&output, octolod::io::OutputKind::Ply, force)?;
    let threshold = target_error.as_deref().map(octolod::metro::Threshold::parse).transpose()?;
    octolod::simplify::check_options(target_tris, target_ratio, verify_samples)?;
    let bo = params.options(quiet || json, false)?;
    let tmp = octolod::io::scratch_dir(&output)?;
    let dir = tmp.path().join("store.octolod");
    let r = octolod::pipeline::build_store(&input, &dir, &bo)?;
    if !json {
        print_build(&r)?;
    }
    let s = octolod::store::Store::open(&dir)?;
    let target = match (target_tris, target_ratio, threshold) {
        (Some(n), _, _) => Target::Tris(n),
        (_, Some(r), _) => Target::Ratio(r),
        (_, _, Some(t)) => Target::Error(t.limit(s.header.bbox.diagonal())),
        _ => unreachable!("clap requires one target"),
    };
    let o = SimplifyOptions { target, simplifier, mem: bo.params.mem, verify_samples, force };
    let rep = octolod::simplify::simplify_store(&s, &output, &o)?;
    if json {
        out!("{}", serde_json::to_string_pretty(&rep).expect("the report serializes"));
    } else {
        out!(
            "simplify: {} from {} ({} triangles, {:?}, {}): {} vertices, {} triangles -> {}",
            match rep.target_triangles {
                Some(n) => format!("{n} triangles asked"),
                None => format!(
                    "error <= {:e} asked, measured {:e} after {} tries",
                    rep.target_error.unwrap_or(f64::NAN),
                    rep.hausdorff.unwrap_or(f64::NAN),
                    rep.tries
                ),
            },
            rep.start,
            rep.start_triangles,
            simplifier,
            rep.route,
            rep.vertices,
            rep.triangles,
            output.display()
        );
        if let Some(n) = &rep.note {
            eprintln!("simplify: {n}");
        }
    }
    if !rep.reached {
        eprintln!("simplify: target not met (see above); the closest mesh was written");
        // Returning (not `exit`) drops the scratch store first.
        return Ok(ExitCode::from(3));
    }
    Ok(ExitCode::SUCCESS)
}

fn cmd_metro(args: MetroArgs, quiet: bool) -> Result<ExitCode> {
    use octolod::metro::{Limits, MemOptions, Options, RunOptions, Source};
    let MetroArgs { a, b, samples, seed, json, max_hausdorff, max_rms, max_mean, mem, attributes } = args;
    let limits = Limits::parse(max_hausdorff.as_deref(), max_rms.as_deref(), max_mean.as_deref())?;
    let options = Options::checked(samples, seed, quiet)?;
    let mem = MemOptions::parse(mem.as_deref())?;
    let run = RunOptions { a: Source::parse(&a)?, b: Source::parse(&b)?, options, mem, limits, json, attributes };
    if !octolod::metro::run(&run)? {
        return Ok(ExitCode::from(octolod::metro::EXIT_THRESHOLD));
    }
    Ok(ExitCode::SUCCESS)
}

#[cfg(feature = "view")]
fn cmd_render(args: RenderArgs, quiet: bool, force: bool) -> Result<ExitCode> {
    let RenderArgs { store, camera_path, frames, up, out, width, height, view, full_res, brute_force, settle, wireframe, diff_tolerance } = args;
    if frames == 0 {
        return Err(octolod::Error::Usage("render: --frames must be at least 1".into()));
    }
    check_size(width, height)?;
    let o = octolod::view::headless::RenderOptions {
        store,
        camera_path,
        orbit_frames: frames,
        up: Up::parse(&up)?,
        out,
        width,
        height,
        texture: !view.no_texture,
        view: view.options()?,
        full_res,
        brute_force,
        settle,
        wireframe,
        diff_tolerance,
        quiet,
        force,
    };
    let r = octolod::view::headless::render(&o)?;
    let max_res = r.frames.iter().map(|f| f.stats.resident_bytes).max().unwrap_or(0);
    let max_sel = r.frames.iter().map(|f| f.stats.select_ms).fold(0.0, f64::max);
    let Some(last) = r.frames.last() else {
        return Err(octolod::Error::Usage("render: no frame was rendered".into()));
    };
    let cmp = match (last.psnr_db, last.diff_fraction) {
        (Some(p), Some(d)) => format!(", last frame vs full-res: PSNR {p:.1} dB, {:.3}% pixels differ", 100.0 * d),
        _ => String::new(),
    };
    let tex = match last.stats.texture_bytes {
        0 => String::new(),
        b => format!(" (texture {})", octolod::progress::mib(b)),
    };
    out!(
        "render: {} frames -> {}; peak resident {}{tex} of {}; select <= {max_sel:.2} ms; last frame {} triangles{}{cmp}",
        r.frames.len(),
        r.out.display(),
        octolod::progress::mib(max_res),
        octolod::progress::mib(o.view.ram),
        last.stats.triangles,
        if last.stats.settled { " (settled)" } else { " (still loading)" }
    );
    // A settled cut coarser than asked: the budget stopped refinement.
    let asked = o.view.select.max_error_px;
    if o.view.select.distance_lod.is_none() && !o.brute_force && last.stats.max_error_px > asked * 1.001 {
        eprintln!(
            "octolod: warning: the last frame's cut has {:.2} px of projected error where {asked} px was asked: --ram {} (or the triangle budget) held back refinement",
            last.stats.max_error_px,
            octolod::progress::bytes(o.view.ram)
        );
    }
    Ok(ExitCode::SUCCESS)
}

fn cmd_serve(input: &Path, port: u16, bind: std::net::IpAddr, open: bool, quiet: bool) -> Result<ExitCode> {
    let o = octolod::serve::ServeOptions { port, bind, quiet, ..Default::default() };
    let server = octolod::serve::bind(input, &o)?;
    out!("serving {} (tileset: {})", server.url(), server.tileset_url());
    if open {
        octolod::serve::open_browser(&server.url(), quiet);
    }
    server.run().map(|()| ExitCode::SUCCESS)
}

/// `ply-info`'s decode: the bounding box, and with materials the use of
/// each texture slot (triangles from a PLY's `texnumber`; vertices where the
/// reader splits them by material, OBJ and glTF).
struct BboxSink {
    bbox: Aabb,
    /// Per material id, triangles (`face_materials`) or vertices; the last
    /// entry counts [`octolod::mesh::Vertex::NO_TEXTURE`].
    per_slot: Vec<u64>,
    face_materials: bool,
}

impl BboxSink {
    fn count(&mut self, m: u16) {
        let k = if m == octolod::mesh::Vertex::NO_TEXTURE { self.per_slot.len() - 1 } else { (m as usize).min(self.per_slot.len() - 1) };
        self.per_slot[k] += 1;
    }
}

impl BodySink for BboxSink {
    fn vertices(&mut self, _first: u64, batch: &[octolod::mesh::Vertex]) -> Result<()> {
        for v in batch {
            self.bbox.add(v.pos);
            if !self.per_slot.is_empty() && !self.face_materials {
                self.count(v.material);
            }
        }
        Ok(())
    }
    fn triangles(&mut self, _batch: &[[u64; 3]]) -> Result<()> {
        Ok(())
    }
    fn materials(&mut self, batch: &[u16]) -> Result<()> {
        if !self.per_slot.is_empty() {
            for &m in batch {
                self.count(m);
            }
        }
        Ok(())
    }
}

fn info(dir: &std::path::Path) -> Result<()> {
    let s = octolod::store::Store::open(dir)?;
    let h = &s.header;
    out!("store: {}", dir.display());
    let manifest = octolod::manifest::Manifest::read(dir).ok();
    // Averaged normals are not in the quadrics.
    let averaged = manifest.as_ref().is_some_and(|m| h.attrs.normal() && m.params.normals == octolod::manifest::Normals::Average);
    out!(
        "attributes: {} (quadric dimension {}){}",
        h.attrs.describe(),
        manifest.as_ref().map_or(h.attrs.quadric_dim(), |m| m.quadric_dim),
        if h.derived_normals {
            ", normals computed at build time"
        } else if averaged {
            ", normals averaged"
        } else {
            ""
        }
    );
    out!("nodes: {}, levels: {}, root: {} triangles", s.nodes.len(), h.levels, s.nodes[s.root()].tris);
    if let Some(m) = &manifest {
        out!("simplifier: {}", m.params.simplifier.name());
        for t in &m.textures {
            match &t.file {
                Some(f) => out!("texture: {} ({}, {} bytes)", t.name, f, t.bytes),
                None => out!("texture: {} (not found beside the input)", t.name),
            }
        }
    }
    let ml = |level: u8| manifest.as_ref().and_then(|m| m.levels.iter().find(|l| l.level == level).cloned());
    out!(
        "{:>5} {:>8} {:>14} {:>14} {:>12} {:>12} {:>8} {:>9} {:>9}",
        "level",
        "nodes",
        "triangles",
        "bytes",
        "err min",
        "err max",
        "locked",
        "prev.lock",
        "time"
    );
    for level in 0..=s.top_level() {
        let ids = s.level_nodes(level);
        let tris: u64 = ids.iter().map(|&i| s.nodes[i].tris as u64).sum();
        let bytes: u64 = ids.iter().map(|&i| s.nodes[i].bytes as u64).sum();
        let emin = ids.iter().map(|&i| s.nodes[i].error as f64).fold(f64::INFINITY, f64::min);
        let emax = ids.iter().map(|&i| s.nodes[i].error as f64).fold(0.0, f64::max);
        let m = ml(level);
        out!(
            "{level:>5} {:>8} {tris:>14} {bytes:>14} {:>12.3e} {emax:>12.3e} {:>8} {:>9} {:>9}",
            ids.len(),
            if ids.is_empty() { 0.0 } else { emin },
            m.as_ref().map(|m| format!("{:.1}%", 100.0 * m.locked_fraction)).unwrap_or_default(),
            m.as_ref().filter(|_| level > 0).map(|m| format!("{:.1}%", 100.0 * m.prev_locked_still_fraction)).unwrap_or_default(),
            m.as_ref().map(|m| format!("{:.2} s", m.seconds)).unwrap_or_else(|| "n/a".into()),
        );
    }
    out!(
        "locked: share of the level's vertex positions locked when it was simplified; prev.lock: share of the level below's locked positions still locked here"
    );
    Ok(())
}

fn ply_info(input: &std::path::Path, header_only: bool, quiet: bool) -> Result<()> {
    use octolod::input::Details;
    let len = std::fs::metadata(input).map(|m| m.len()).unwrap_or(0);
    let scan = Progress::bytes(len, "scanning", quiet || octolod::input::Format::of(input)? == octolod::input::Format::Ply);
    let h = octolod::input::read_header(input, &scan)?;
    scan.finish();
    out!("file: {}", input.display());
    match &h.details {
        Details::Ply(p) => {
            out!("format: {}", p.encoding.header_name());
            out!("header bytes: {}", p.body_offset);
            for c in &p.comments {
                out!("comment: {c}");
            }
            for e in &p.elements {
                let props: Vec<String> = e
                    .props
                    .iter()
                    .map(|p| match p.ty {
                        ply::PropType::Scalar(s) => format!("{} {}", s.name(), p.name),
                        ply::PropType::List(c, s) => format!("list {} {} {}", c.name(), s.name(), p.name),
                    })
                    .collect();
                out!("element {} {}: {}", e.name, e.count, props.join(", "));
            }
        }
        Details::Stl(i) => {
            out!("format: STL {}", if i.binary { "binary" } else { "ascii" });
            out!("vertices below: the triangles' corners, welded by position bits where a mesh is built");
            out!("name: {}", i.name);
        }
        Details::Obj(i) => {
            out!("format: OBJ");
            out!("v: {}, vt: {}, vn: {}, f: {} ({} corners)", i.positions, i.texcoords, i.normals, i.faces, i.corners);
            for m in &i.mtllibs {
                let mtl = input.parent().unwrap_or(std::path::Path::new(".")).join(m);
                match octolod::input::obj::read_mtl(&mtl) {
                    Ok(mats) => {
                        out!("mtllib: {m} ({} materials)", mats.len());
                        for t in &mats {
                            let tex = t.map_kd.as_ref().map(|f| {
                                let found = mtl.parent().is_some_and(|d| d.join(f).is_file());
                                format!("map_Kd {f} ({})", if found { "found" } else { "missing" })
                            });
                            out!("  material {}: {}", t.name, tex.unwrap_or_else(|| "no texture".into()));
                        }
                    }
                    Err(e) => out!("mtllib: {m} (not read: {e})"),
                }
            }
        }
        Details::Gltf(i) => {
            out!("format: glTF");
            out!("primitives: {}", i.primitives);
            for im in &i.images {
                match im {
                    octolod::input::gltf::GltfImage::File(u) => {
                        let found = input.parent().unwrap_or(std::path::Path::new(".")).join(u).is_file();
                        out!("base colour image: {u} ({})", if found { "found" } else { "missing" });
                    }
                    octolod::input::gltf::GltfImage::Embedded { index, mime, name } => {
                        out!("base colour image: images[{index}] {}({mime}, in a buffer)", name.as_deref().map(|n| format!("{n} ")).unwrap_or_default());
                    }
                }
            }
        }
    }
    out!("vertices: {}", h.vertex_count());
    out!("faces: {}", h.face_count());
    out!("attributes: {}", h.attrs.describe());
    if h.attrs.normal() {
        // `build --normals auto` averages normals without creases out of it.
        let averaged = h.attrs.with(octolod::mesh::AttrSet::NORMAL, false).quadric_dim();
        out!("quadric dimension: {} ({averaged} where build averages the normals)", h.attrs.quadric_dim());
    } else {
        out!("quadric dimension: {}", h.attrs.quadric_dim());
    }
    // The texture slots a store would copy, by material id.
    let slots = h.texture_sources(input, true);
    if !slots.is_empty() {
        let dir = input.parent().unwrap_or(std::path::Path::new("."));
        out!(
            "textures: {} ({})",
            slots.len(),
            if h.attrs.material() {
                "each face names its own"
            } else if slots.len() > 1 {
                "no face says which: every face draws the first"
            } else {
                "every face draws it"
            }
        );
        for (k, t) in slots.iter().enumerate() {
            let what = match t {
                octolod::manifest::TextureSource::File(f) => format!("{f} ({})", if dir.join(f).is_file() { "found" } else { "missing" }),
                octolod::manifest::TextureSource::Embedded { name, bytes, .. } => format!("{name} (embedded, {} bytes)", bytes.len()),
                octolod::manifest::TextureSource::Missing(name) => format!("{name} (missing)"),
            };
            out!("  texture {k}: {what}");
        }
    }
    if header_only {
        return Ok(());
    }
    let progress = Progress::bytes(len, "decoding", quiet);
    let face_materials = matches!(h.details, Details::Ply(_));
    let per_slot = if h.attrs.material() { vec![0; slots.len() + 1] } else { Vec::new() };
    let mut sink = BboxSink { bbox: Aabb::EMPTY, per_slot, face_materials };
    let t0 = std::time::Instant::now();
    let st = octolod::input::read_body(input, &h, octolod::mem::DEFAULT_BUDGET, &std::env::temp_dir(), &mut sink, &progress)?;
    let secs = t0.elapsed().as_secs_f64();
    progress.finish();
    let b = sink.bbox;
    if st.vertices != h.vertex_count() {
        out!("vertices decoded: {} (each distinct (v, vt, vn) corner of a kept triangle)", st.vertices);
    }
    out!("triangles (after fan triangulation): {}", st.triangles);
    out!("degenerate triangles: {}", st.degenerate);
    out!("polygons (>3 corners): {}", st.polygons);
    if let Some((none, slots)) = sink.per_slot.split_last() {
        let what = if face_materials { "triangles" } else { "vertices" };
        let mut parts: Vec<String> = slots.iter().enumerate().map(|(k, n)| format!("{k}: {n}")).collect();
        if *none > 0 {
            parts.push(format!("none: {none}"));
        }
        out!("{what} per texture: {}", parts.join(", "));
    }
    out!(
        "decoded: {} bytes in {:.3} s ({:.1} MB/s, {:.2} M faces/s)",
        st.bytes,
        secs,
        st.bytes as f64 / 1e6 / secs.max(1e-9),
        st.faces as f64 / 1e6 / secs.max(1e-9)
    );
    if b.is_empty() {
        out!("bbox: empty");
    } else {
        out!("bbox: min [{}, {}, {}] max [{}, {}, {}] diagonal {}", b.min[0], b.min[1], b.min[2], b.max[0], b.max[1], b.max[2], b.diagonal());
    }
    Ok(())
}
