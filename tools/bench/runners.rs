//! Child side: one method, one process (`run-one`), printing one JSON line
//! ([`BuildOut`] or [`RunOut`]) with its timings and its peak RSS; and the
//! `/proc` probes they use (peak RSS from the library's
//! [`octolod::progress::peak_rss`], other processes' CPU use).

use crate::oocs::oocs;
use crate::types::{BuildOut, LevelOut, Method, RunOut, SimplifyJson, Timed};
use crate::{Baseline, RunOne};
use anyhow::{anyhow, bail, Context, Result};
use octolod::mesh::{Aabb, Vertex};
use octolod::pipeline::{build_store, extract, BuildOptions, CutSpec};
use octolod::ply::read::{read_all, CollectSink};
use octolod::ply::write::{write_ply, PlyWriteOptions};
use octolod::store::Store;
use std::io::Read as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

/// Peak resident set of this process (`VmHWM`), MiB; NaN where the OS
/// does not tell.
pub fn peak_rss_mib() -> f64 {
    octolod::progress::peak_rss().map_or(f64::NAN, |b| b as f64 / (1024.0 * 1024.0))
}

/// Restarts `VmHWM` from the current RSS (Linux ≥ 4.0); false if refused.
fn reset_peak_rss() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}

/// Busy CPU seconds of the whole machine since boot (`/proc/stat`: user,
/// nice, system, irq, softirq, steal; USER_HZ = 100).
fn machine_busy_seconds() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/stat").ok()?;
    let f: Vec<f64> = s.lines().next()?.split_whitespace().skip(1).take(8).map(|x| x.parse().unwrap_or(0.0)).collect();
    (f.len() == 8).then(|| (f[0] + f[1] + f[2] + f[5] + f[6] + f[7]) / 100.0)
}

/// CPU seconds (user + system, every thread) of this process so far.
fn own_cpu_seconds() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    let f: Vec<&str> = s.rsplit_once(')')?.1.split_whitespace().collect();
    Some((f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?) / 100.0)
}

/// How many cores other processes kept busy during a timed section: the
/// machine's busy CPU time minus this process's, over the wall time. The
/// machine may be shared (other people's compiles), and a timing taken while
/// it is busy is slow for reasons that are not the method's.
pub struct CpuProbe {
    t: Instant,
    busy: Option<f64>,
    own: Option<f64>,
}

impl CpuProbe {
    pub fn start() -> CpuProbe {
        CpuProbe { t: Instant::now(), busy: machine_busy_seconds(), own: own_cpu_seconds() }
    }
    /// Mean cores used by other processes since `start` (clock ticks are
    /// 10 ms, so sections under ~0.2 s read coarsely).
    pub fn other_cores(&self) -> Option<f64> {
        self.other_cores_besides(0.0)
    }
    /// The same, also discounting `extra` CPU seconds that were ours (a
    /// waited-for child process's).
    fn other_cores_besides(&self, extra: f64) -> Option<f64> {
        let wall = self.t.elapsed().as_secs_f64();
        let busy = machine_busy_seconds()? - self.busy?;
        let own = own_cpu_seconds()? - self.own? + extra;
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get()) as f64;
        (wall > 0.0).then(|| ((busy - own) / wall).clamp(0.0, threads))
    }
}

/// Waits up to `max_s` seconds for other processes to use under a quarter
/// of a core (sampled over 1 s windows); returns the seconds waited.
pub fn wait_idle(max_s: f64) -> f64 {
    let t = Instant::now();
    while t.elapsed().as_secs_f64() < max_s {
        let p = CpuProbe::start();
        std::thread::sleep(std::time::Duration::from_secs(1));
        match p.other_cores() {
            Some(c) if c >= 0.25 => continue,
            _ => break,
        }
    }
    t.elapsed().as_secs_f64()
}

/// Runs `a`, returns its JSON line.
pub fn run_one(a: &RunOne) -> Result<String> {
    let t_all = Instant::now();
    let line = match a.method {
        Method::Octolod => {
            let mut j = match &a.baseline {
                Some(bl) => run_octolod_cli(a, bl)?,
                None => run_octolod(a)?,
            };
            j.timed.child_seconds = t_all.elapsed().as_secs_f64();
            serde_json::to_string(&j)?
        }
        m => {
            let mut j = match m {
                _ if m.simplifier().is_some() => run_simplify(a, m)?,
                Method::MeshlabQec => run_meshlab(a)?,
                _ => run_peer(a, m)?,
            };
            j.timed.child_seconds = t_all.elapsed().as_secs_f64();
            serde_json::to_string(&j)?
        }
    };
    Ok(line)
}

fn run_octolod(a: &RunOne) -> Result<BuildOut> {
    let params = octolod::manifest::BuildParams {
        mem: octolod::mem::parse_size(&a.mem)?,
        leaf_tris: a.leaf_tris,
        level_ratio: a.level_ratio as f64,
        simplifier: a.simplifier,
        ..Default::default()
    };
    let opts = BuildOptions {
        params,
        quiet: true,
        // The bench's own store from an earlier run (refused if it is anything else).
        force: true,
    };
    let store_dir = PathBuf::from(format!("{}.octolod", a.output.display()));
    let probe = CpuProbe::start();
    let t = Instant::now();
    let r = build_store(&a.input, &store_dir, &opts)?;
    let seconds = t.elapsed().as_secs_f64();
    let other_cpu = probe.other_cores();
    let rss = peak_rss_mib();
    let mut levels = Vec::new();
    if !a.no_extract {
        let store = Store::open(&store_dir)?;
        for l in 1..=store.top_level() {
            let path = PathBuf::from(format!("{}-L{l}.ply", a.output.display()));
            let (nv, nf) = extract(&store, CutSpec::Level(l), &path, true, true)?;
            let lr = r.levels.iter().find(|x| x.level == l);
            levels.push(LevelOut { level: l, triangles: nf, vertices: nv, nodes: lr.map(|x| x.nodes), error_bound_max: lr.map(|x| x.error_max), path });
        }
    }
    let quadric_dim = octolod::manifest::Manifest::read(&store_dir).ok().map(|m| m.quadric_dim);
    std::fs::remove_dir_all(&store_dir).with_context(|| format!("remove {}", store_dir.display()))?;
    Ok(BuildOut {
        method: Method::Octolod,
        leaf_tris: a.leaf_tris,
        level_ratio: a.level_ratio,
        simplifier: a.simplifier,
        mem: opts.params.mem,
        input_triangles: r.soup.header.triangles,
        attributes: r.soup.header.attrs.describe(),
        // The dimension used (normals the levels derive are not in it).
        quadric_dim: quadric_dim.unwrap_or_else(|| r.soup.header.attrs.quadric_dim()) as u64,
        soup_seconds: r.seconds[0],
        octree_seconds: r.seconds[1],
        simplify_seconds: r.seconds[2],
        soup_external: Some(r.soup.external),
        nodes: Some(r.nodes),
        leaves: Some(r.octree.leaves),
        deepest: Some(u32::from(r.octree.deepest)),
        disk_bytes: Some(r.disk_bytes),
        peak_rss_with_extract_mib: peak_rss_mib(),
        levels,
        baseline: None,
        command: None,
        reported_total_seconds: None,
        timed: Timed { seconds, peak_rss_mib: rss, other_cpu_cores: other_cpu, ..Timed::default() },
    })
}

/// `--baseline LABEL=BIN`: the same build by an older octolod executable,
/// through its command line: `BIN build INPUT -o STORE --leaf-tris L
/// --level-ratio R --simplifier S --mem M --force`, timed by the wall clock
/// around the command (process start and its own output included), peak
/// RSS its `ru_maxrss`; then `BIN extract STORE --level L -o OUT` for every
/// level above 0, counted from the written PLY's header. The rest of what
/// [`run_octolod`] reports comes from the summary line and level table the
/// build prints, where this binary prints them ([`parse_build_summary`],
/// [`parse_level_table`]); what it does not print stays `None` or NaN.
fn run_octolod_cli(a: &RunOne, bl: &Baseline) -> Result<BuildOut> {
    let bin = &bl.bin;
    let mem = octolod::mem::parse_size(&a.mem)?;
    let header = octolod::ply::read_header(&a.input)?;
    // Flags an older binary may lack: asked for only where its help has them.
    let help = subcommand_help(bin, "build")?;
    let store_dir = PathBuf::from(format!("{}.octolod", a.output.display()));
    let mut cmd = Command::new(bin);
    cmd.arg("build")
        .arg(&a.input)
        .arg("-o")
        .arg(&store_dir)
        .args(["--leaf-tris", &a.leaf_tris.to_string()])
        .args(["--level-ratio", &a.level_ratio.to_string()])
        .args(["--mem", &a.mem]);
    if help.contains("--simplifier") {
        cmd.args(["--simplifier", a.simplifier.name()]);
    } else if a.simplifier != octolod::manifest::Simplifier::Cluster {
        bail!("`{} build` has no --simplifier: it cannot build with {}", bin.display(), a.simplifier.name());
    }
    for flag in ["--quiet", "--force"] {
        if help.contains(flag) {
            cmd.arg(flag);
        }
    }
    let build = spawn_timed(&mut cmd, bin)?;
    if build.code != 0 {
        bail!("`{}` failed (status {})", build.command, build.code);
    }
    // The summary may go to either stream.
    let text = format!("{}\n{}", build.stdout, build.stderr);
    let sum = parse_build_summary(&text).unwrap_or_default();
    let table = parse_level_table(&text);
    // The top level: the table's, or the summary's level count; unknown,
    // levels are extracted until one fails.
    let top = table.iter().map(|l| l.level).max().or_else(|| sum.levels.and_then(|n| u8::try_from(n.checked_sub(1)?).ok()));
    let mut levels = Vec::new();
    let mut rss_extract = build.peak_rss_mib;
    if !a.no_extract {
        for l in 1..=top.unwrap_or(u8::MAX) {
            let path = PathBuf::from(format!("{}-L{l}.ply", a.output.display()));
            // The bench's own output of an earlier run (so no --force, which older binaries may lack).
            match std::fs::remove_file(&path) {
                Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(e).with_context(|| format!("remove {}", path.display())),
                _ => {}
            }
            let mut cmd = Command::new(bin);
            cmd.arg("extract").arg(&store_dir).args(["--level", &l.to_string()]).arg("-o").arg(&path);
            let ex = match spawn_timed(&mut cmd, bin) {
                Ok(ex) if ex.code == 0 => ex,
                Ok(_) | Err(_) if top.is_none() && !levels.is_empty() => break,
                Ok(ex) => bail!("`{}` failed (status {})", ex.command, ex.code),
                Err(e) => return Err(e),
            };
            rss_extract = rss_extract.max(ex.peak_rss_mib);
            let h = octolod::ply::read_header(&path).with_context(|| format!("read what `{}` wrote", ex.command))?;
            let row = table.iter().find(|x| x.level == l);
            levels.push(LevelOut {
                level: l,
                triangles: h.face_count(),
                vertices: h.vertex_count(),
                nodes: row.and_then(|x| x.nodes),
                error_bound_max: row.and_then(|x| x.error_max),
                path,
            });
        }
    }
    let quadric_dim = octolod::manifest::Manifest::read(&store_dir).ok().map(|m| m.quadric_dim);
    std::fs::remove_dir_all(&store_dir).with_context(|| format!("remove {}", store_dir.display()))?;
    Ok(BuildOut {
        method: Method::Octolod,
        leaf_tris: a.leaf_tris,
        level_ratio: a.level_ratio,
        simplifier: a.simplifier,
        mem,
        input_triangles: sum.triangles.unwrap_or_else(|| header.face_count()),
        attributes: header.attrs.describe(),
        quadric_dim: quadric_dim.unwrap_or_else(|| header.attrs.quadric_dim()) as u64,
        soup_seconds: sum.soup.unwrap_or(f64::NAN),
        octree_seconds: sum.octree.unwrap_or(f64::NAN),
        simplify_seconds: sum.simplify.unwrap_or(f64::NAN),
        soup_external: None,
        nodes: sum.nodes,
        leaves: sum.leaves,
        deepest: sum.depth,
        disk_bytes: sum.disk_bytes,
        peak_rss_with_extract_mib: rss_extract,
        levels,
        baseline: Some(bl.label.clone()),
        command: Some(build.command),
        reported_total_seconds: sum.total,
        timed: Timed { seconds: build.seconds, peak_rss_mib: build.peak_rss_mib, other_cpu_cores: build.other_cpu_cores, ..Timed::default() },
    })
}

/// `BIN SUBCOMMAND --help`, stdout and stderr together.
fn subcommand_help(bin: &Path, sub: &str) -> Result<String> {
    let out = Command::new(bin).args([sub, "--help"]).stdin(Stdio::null()).output().with_context(|| format!("start {}", bin.display()))?;
    if !out.status.success() {
        bail!("`{} {sub} --help` failed ({})", bin.display(), out.status);
    }
    Ok(format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr)))
}

/// What the summary line of `octolod build` says (`build: 20000000
/// triangles, 3673 level-0 nodes, 7822 nodes, 14 levels; soup 2.58 s,
/// partition 1.15 s (0 counting passes), levels 15.27 s, total 19.01 s;
/// 711.0 MiB on disk; peak RSS 130.9 MiB`); older versions said `leaves`,
/// `depth N`, `octree` and `simplify`. A field the line lacks is `None`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BuildSummary {
    pub triangles: Option<u64>,
    pub leaves: Option<u64>,
    pub nodes: Option<u64>,
    pub depth: Option<u32>,
    /// Levels built, level 0 included.
    pub levels: Option<u32>,
    pub soup: Option<f64>,
    /// Partition (octree) seconds.
    pub octree: Option<f64>,
    /// Levels (simplification) seconds.
    pub simplify: Option<f64>,
    pub total: Option<f64>,
    /// The store on disk (printed in MiB to 0.1, so to about 50 KiB).
    pub disk_bytes: Option<u64>,
    pub peak_rss_mib: Option<f64>,
}

/// A size as `octolod` prints it (`711.0 MiB`), bytes.
fn parse_bytes(num: &str, unit: &str) -> Option<f64> {
    let x: f64 = num.parse().ok()?;
    let mul = match unit {
        "B" => 1.0,
        "KiB" => 1024.0,
        "MiB" => 1024.0 * 1024.0,
        "GiB" => 1024.0 * 1024.0 * 1024.0,
        "TiB" => 1024.0f64.powi(4),
        _ => return None,
    };
    (x.is_finite() && x >= 0.0).then_some(x * mul)
}

/// The last `build: ...` line in `text`, read clause by clause (clauses are
/// split at `,` and `;`; unknown ones are skipped); `None` without such a line.
pub fn parse_build_summary(text: &str) -> Option<BuildSummary> {
    let line = text.lines().rev().find_map(|l| l.trim().strip_prefix("build:"))?;
    let mut s = BuildSummary::default();
    for clause in line.split([',', ';']) {
        let t: Vec<&str> = clause.split_whitespace().collect();
        let (Some(&first), Some(&second)) = (t.first(), t.get(1)) else { continue };
        let rest = t[1..].join(" ");
        let int = || first.parse::<u64>().ok();
        // `NAME X s` (seconds); `peak RSS X MiB`.
        let secs = || (t.get(2) == Some(&"s")).then(|| second.parse::<f64>().ok()).flatten();
        match (first, rest.as_str()) {
            (_, "triangles") => s.triangles = int(),
            (_, "level-0 nodes" | "leaves") => s.leaves = int(),
            (_, "nodes") => s.nodes = int(),
            (_, "levels") => s.levels = int().and_then(|n| u32::try_from(n).ok()),
            ("depth", _) => s.depth = second.parse().ok(),
            ("soup", _) => s.soup = secs(),
            ("partition" | "octree", _) => s.octree = secs(),
            ("levels" | "simplify", _) => s.simplify = secs(),
            ("total", _) => s.total = secs(),
            ("peak", _) if second == "RSS" => s.peak_rss_mib = t.get(2).zip(t.get(3)).and_then(|(n, u)| parse_bytes(n, u)).map(|b| b / 1048576.0),
            (_, r) if r.ends_with(" on disk") => s.disk_bytes = parse_bytes(first, second).map(|b| b.round() as u64),
            _ => {}
        }
    }
    Some(s)
}

/// One row of the level table `octolod build` prints after its summary.
#[derive(Clone, Debug, PartialEq)]
pub struct LevelLine {
    pub level: u8,
    pub nodes: Option<u64>,
    pub triangles: Option<u64>,
    pub error_max: Option<f64>,
}

/// The level table (`level nodes triangles err max ...`, one row per
/// level), its columns found by the header's names; empty without one.
pub fn parse_level_table(text: &str) -> Vec<LevelLine> {
    let mut lines = text.lines().skip_while(|l| !(l.trim_start().starts_with("level") && l.contains("triangles")));
    let Some(head) = lines.next() else { return Vec::new() };
    let cols: Vec<String> = head.replace("err max", "err_max").replace("err min", "err_min").split_whitespace().map(str::to_string).collect();
    let col = |name: &str| cols.iter().position(|c| c == name);
    let (nodes, tris, err) = (col("nodes"), col("triangles"), col("err_max"));
    let mut out = Vec::new();
    for l in lines {
        let t: Vec<&str> = l.split_whitespace().collect();
        let Some(level) = t.first().and_then(|x| x.parse::<u8>().ok()) else { break };
        let get = |i: Option<usize>| i.and_then(|i| t.get(i).copied());
        out.push(LevelLine {
            level,
            nodes: get(nodes).and_then(|x| x.parse().ok()),
            triangles: get(tris).and_then(|x| x.parse().ok()),
            error_max: get(err).and_then(|x| x.parse().ok()),
        });
    }
    out
}

/// A [`RunOut`] with only the fields every method has.
fn run_out(a: &RunOne, m: Method, input_triangles: u64, triangles: u64, vertices: u64, timed: Timed) -> RunOut {
    RunOut::new(m, a.target, input_triangles, triangles, vertices, a.output.clone(), timed)
}

fn run_peer(a: &RunOne, m: Method) -> Result<RunOut> {
    if a.target == 0 {
        bail!("--target is required for {}", m.name());
    }
    let t = Instant::now();
    let (_h, CollectSink { vertices, triangles, .. }, _stats) = read_all(&a.input)?;
    let n_in = triangles.len() as u64;
    let mut bbox = Aabb::EMPTY;
    for v in &vertices {
        bbox.add(v.pos);
    }
    let tris: Vec<[u32; 3]> = triangles.iter().map(|t| t.map(|i| i as u32)).collect();
    drop(triangles);
    // meshopt gets packed f32 positions; OOCS keeps the decoded vertices.
    // meshopt `simplify` weighs uvs where the input has them (its
    // `simplifyWithAttributes`, the peer for textured meshes), at
    // weight 1: uvs span [0, 1] as meshopt's unit-box positions do.
    let uvs: Vec<f32> = if m == Method::MeshoptSimplify && _h.attrs.uv() { vertices.iter().flat_map(|v| v.uv).collect() } else { Vec::new() };
    let (verts, pos): (Vec<Vertex>, Vec<[f32; 3]>) = match m {
        Method::Oocs => (vertices, Vec::new()),
        _ => (Vec::new(), vertices.iter().map(|v| v.pos.map(|x| x as f32)).collect()),
    };
    let load_seconds = t.elapsed().as_secs_f64();
    let rss_load = peak_rss_mib();
    let reset = reset_peak_rss();

    let mut j = run_out(a, m, n_in, 0, 0, Timed::default());
    let (seconds, out_verts, out_tris) = match m {
        Method::MeshoptSimplify | Method::MeshoptSloppy => {
            let idx: &[u32] = bytemuck::cast_slice(&tris);
            let adapter = meshopt::VertexDataAdapter::new(bytemuck::cast_slice(&pos), 12, 0).map_err(|e| anyhow!("meshopt vertex adapter: {e}"))?;
            let target_idx = (a.target as usize).saturating_mul(3);
            let mut err = 0f32;
            let probe = CpuProbe::start();
            let t = Instant::now();
            let out = if m == Method::MeshoptSimplify && !uvs.is_empty() {
                // No vertex locked (the crate takes the lock array whole).
                let locks = vec![false; pos.len()];
                meshopt::simplify_with_attributes_and_locks(
                    idx,
                    &adapter,
                    &uvs,
                    &[1.0, 1.0],
                    8,
                    &locks,
                    target_idx,
                    1.0,
                    meshopt::SimplifyOptions::None,
                    Some(&mut err),
                )
            } else if m == Method::MeshoptSimplify {
                meshopt::simplify(idx, &adapter, target_idx, 1.0, meshopt::SimplifyOptions::None, Some(&mut err))
            } else {
                meshopt::simplify_sloppy(idx, &adapter, target_idx, 1.0, Some(&mut err))
            };
            let seconds = t.elapsed().as_secs_f64();
            j.timed.other_cpu_cores = probe.other_cores();
            j.meshopt_result_error = Some(f64::from(err));
            j.meshopt_attributes = (!uvs.is_empty()).then(|| "uv (weight 1)".to_string());
            let faces: Vec<[u32; 3]> = out.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
            let (v, f) = compact(|i| pos[i as usize].map(f64::from), &faces, pos.len());
            (seconds, v, f)
        }
        Method::Oocs => {
            let r = oocs(&verts, &tris, &bbox, a.target);
            j.grid = Some(r.grid);
            j.grid_dims = Some(r.dims);
            j.cells = Some(r.cells);
            j.clamped = Some(r.clamped);
            j.search_seconds = Some(r.search_seconds);
            j.search_tries = Some(r.tries);
            j.timed.other_cpu_cores = r.other_cpu;
            (r.seconds, r.vertices, r.triangles)
        }
        _ => unreachable!("not a peer: {m:?}"),
    };
    let rss_simplify = peak_rss_mib();
    write_ply(&a.output, &PlyWriteOptions::default(), &out_verts, &out_tris)?;
    j.load_seconds = Some(load_seconds);
    j.triangles = out_tris.len() as u64;
    j.vertices = out_verts.len() as u64;
    j.peak_rss_load_mib = Some(rss_load).filter(|x| x.is_finite());
    j.peak_rss_simplify_mib = Some(rss_simplify).filter(|x| reset && x.is_finite());
    j.timed.seconds = seconds;
    j.timed.peak_rss_mib = rss_load.max(rss_simplify);
    Ok(j)
}

/// `octolod simplify IN -o OUT --target-tris N --simplifier S --json` as a
/// child of this one, timed whole (PLY in, store built in a scratch
/// folder, reduced, PLY out); its peak RSS is its `ru_maxrss` (the kernel's
/// record of its `VmHWM`), read when it is reaped.
fn run_simplify(a: &RunOne, m: Method) -> Result<RunOut> {
    if a.target == 0 {
        bail!("--target is required for {}", m.name());
    }
    let bin = a.octolod.as_ref().ok_or_else(|| anyhow!("--octolod is required for {}", m.name()))?;
    let mut cmd = Command::new(bin);
    cmd.arg("--quiet")
        .arg("--force")
        .arg("simplify")
        .arg(&a.input)
        .arg("-o")
        .arg(&a.output)
        .args(["--target-tris", &a.target.to_string()])
        .args(["--simplifier", m.simplifier().expect("a simplifier")])
        .args(["--mem", &a.mem])
        .args(["--leaf-tris", &a.leaf_tris.to_string()])
        .args(["--level-ratio", &a.level_ratio.to_string()])
        .arg("--json");
    let Spawned { command, stdout: out, code, seconds, peak_rss_mib, other_cpu_cores, .. } = spawn_timed(&mut cmd, bin)?;
    let start = out.find('{').ok_or_else(|| anyhow!("`{command}` printed no JSON"))?;
    let rep: SimplifyJson = serde_json::from_str(out[start..].trim()).with_context(|| format!("`{command}`'s JSON"))?;
    let timed = Timed { seconds, peak_rss_mib, other_cpu_cores, ..Timed::default() };
    let mut j = run_out(a, m, rep.input_triangles, rep.triangles, rep.vertices, timed);
    j.command = Some(command);
    j.exit_code = Some(code);
    j.simplify = Some(rep);
    Ok(j)
}

/// What `meshlab_qec.py` prints.
#[derive(serde::Deserialize)]
struct MeshlabJson {
    input_triangles: u64,
    load_seconds: f64,
    seconds: f64,
    triangles: u64,
    vertices: u64,
    filter: String,
}

/// MeshLab's quadric edge collapse (`meshlab_qec.py`, run by `--python`):
/// its own load and filter times (the filter alone is the timed section,
/// as for the in-process peers); peak RSS is the interpreter's
/// `ru_maxrss`, load included.
fn run_meshlab(a: &RunOne) -> Result<RunOut> {
    if a.target == 0 {
        bail!("--target is required for meshlab-qec");
    }
    let py = a.python.as_ref().ok_or_else(|| anyhow!("--python is required for meshlab-qec"))?;
    let mut cmd = Command::new(py);
    cmd.arg("-c").arg(include_str!("meshlab_qec.py")).arg(&a.input).arg(&a.output).arg(a.target.to_string());
    let Spawned { command, stdout, code, peak_rss_mib, other_cpu_cores, .. } = spawn_timed(&mut cmd, py)?;
    if code != 0 {
        bail!("`{command}` failed (status {code})");
    }
    let line = stdout.lines().rev().find(|l| l.trim_start().starts_with('{')).ok_or_else(|| anyhow!("meshlab_qec.py printed no JSON"))?;
    let rep: MeshlabJson = serde_json::from_str(line.trim()).context("meshlab_qec.py's JSON")?;
    let timed = Timed { seconds: rep.seconds, peak_rss_mib, other_cpu_cores, ..Timed::default() };
    let mut j = run_out(a, Method::MeshlabQec, rep.input_triangles, rep.triangles, rep.vertices, timed);
    j.load_seconds = Some(rep.load_seconds);
    j.meshlab_filter = Some(rep.filter);
    Ok(j)
}

/// A finished child command: its stdout, exit status (negative: the
/// signal), wall seconds, peak RSS (`ru_maxrss`, MiB) and the cores other
/// processes kept busy meanwhile.
struct Spawned {
    command: String,
    stdout: String,
    stderr: String,
    code: i32,
    seconds: f64,
    peak_rss_mib: f64,
    other_cpu_cores: Option<f64>,
}

/// Runs `cmd` (program `bin`) to its end, timed. Exit status 0 and 3
/// (`octolod simplify`: size not met, the closest mesh written) are
/// returned; any other is an error carrying the last lines of its stderr.
fn spawn_timed(cmd: &mut Command, bin: &Path) -> Result<Spawned> {
    // The command as reported: a long argument (meshlab-qec's script) by its size.
    let arg = |a: &std::ffi::OsStr| match a.to_string_lossy() {
        t if t.len() > 200 => format!("<{} bytes>", t.len()),
        t => t.into_owned(),
    };
    let command = std::iter::once(arg(cmd.get_program())).chain(cmd.get_args().map(arg)).collect::<Vec<_>>().join(" ");
    let probe = CpuProbe::start();
    let t = Instant::now();
    let mut child = cmd.stdin(Stdio::null()).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().with_context(|| format!("start {}", bin.display()))?;
    let mut err_pipe = child.stderr.take().expect("piped");
    let err_reader = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = err_pipe.read_to_string(&mut s);
        s
    });
    let mut stdout = String::new();
    child.stdout.take().expect("piped").read_to_string(&mut stdout).context("read the child's stdout")?;
    let (status, usage) = wait4(child.id())?;
    let seconds = t.elapsed().as_secs_f64();
    let cpu = usage.ru_utime.tv_sec as f64 + usage.ru_utime.tv_usec as f64 * 1e-6 + usage.ru_stime.tv_sec as f64 + usage.ru_stime.tv_usec as f64 * 1e-6;
    let other_cpu_cores = probe.other_cores_besides(cpu);
    let stderr = err_reader.join().unwrap_or_default();
    let code = if libc::WIFEXITED(status) { libc::WEXITSTATUS(status) } else { -libc::WTERMSIG(status) };
    if code != 0 && code != 3 {
        let tail: Vec<&str> = stderr.lines().rev().take(5).collect();
        bail!("`{command}` failed (status {code}): {}", tail.into_iter().rev().collect::<Vec<_>>().join(" | "));
    }
    Ok(Spawned { command, stdout, stderr, code, seconds, peak_rss_mib: usage.ru_maxrss as f64 / 1024.0, other_cpu_cores })
}

/// Reaps child `pid`: its wait status and resource usage.
fn wait4(pid: u32) -> Result<(i32, libc::rusage)> {
    let mut status = 0;
    // SAFETY: an all-zero rusage is valid, and wait4 only writes to the two
    // out-parameters, both live for the call.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    loop {
        let r = unsafe { libc::wait4(pid as libc::pid_t, &mut status, 0, &mut usage) };
        if r == pid as libc::pid_t {
            return Ok((status, usage));
        }
        let e = std::io::Error::last_os_error();
        if e.kind() != std::io::ErrorKind::Interrupted {
            return Err(anyhow!("wait for child {pid}: {e}"));
        }
    }
}

/// Keeps only the vertices `faces` use, renumbered in first-use order.
fn compact(pos: impl Fn(u32) -> [f64; 3], faces: &[[u32; 3]], n: usize) -> (Vec<Vertex>, Vec<[u32; 3]>) {
    let mut map = vec![u32::MAX; n];
    let mut verts = Vec::new();
    let tris = faces
        .iter()
        .map(|f| {
            f.map(|i| {
                let slot = &mut map[i as usize];
                if *slot == u32::MAX {
                    *slot = verts.len() as u32;
                    verts.push(Vertex { pos: pos(i), ..Default::default() });
                }
                *slot
            })
        })
        .collect();
    (verts, tris)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The current summary line, every field read.
    #[test]
    fn build_summary_parses() {
        let line = "build: 20000000 triangles, 3673 level-0 nodes, 7822 nodes, 14 levels; soup 2.58 s, partition 1.15 s (0 counting passes), levels 15.27 s, total 19.01 s; 711.0 MiB on disk; peak RSS 130.9 MiB";
        let s = parse_build_summary(&format!("progress\n{line}\nlevel nodes\n")).unwrap();
        assert_eq!(
            s,
            BuildSummary {
                triangles: Some(20_000_000),
                leaves: Some(3673),
                nodes: Some(7822),
                depth: None,
                levels: Some(14),
                soup: Some(2.58),
                octree: Some(1.15),
                simplify: Some(15.27),
                total: Some(19.01),
                disk_bytes: Some((711.0 * 1048576.0) as u64),
                peak_rss_mib: Some(130.9),
            }
        );
    }

    /// Fields a line lacks (an older or cut-short line, `n/a` figures) are
    /// `None`; the v1 wording (`leaves`, `depth`, `octree`, `simplify`) reads
    /// into the same fields; no line at all is `None`.
    #[test]
    fn build_summary_with_missing_fields() {
        let s = parse_build_summary("build: 1000 triangles, 9 nodes; soup 0.10 s, total 0.70 s; peak RSS n/a").unwrap();
        assert_eq!(s, BuildSummary { triangles: Some(1000), nodes: Some(9), soup: Some(0.1), total: Some(0.7), ..BuildSummary::default() });
        let v1 = parse_build_summary(
            "build: 1000 triangles, 5 leaves, 9 nodes, depth 2, 3 levels; soup 0.10 s, octree 0.20 s, simplify 0.30 s, total 0.70 s; 1.5 GiB on disk; peak RSS 12.0 MiB",
        )
        .unwrap();
        assert_eq!((v1.leaves, v1.depth, v1.levels, v1.octree, v1.simplify), (Some(5), Some(2), Some(3), Some(0.2), Some(0.3)));
        assert_eq!(v1.disk_bytes, Some(3 << 29));
        assert_eq!(parse_build_summary("build:"), Some(BuildSummary::default()));
        assert_eq!(parse_build_summary("nothing here\n"), None);
    }

    /// The level table by its header's names (level 0 has no `prev.lock`).
    #[test]
    fn level_table_parses() {
        let text = "build: 100056 triangles\nlevel   nodes     triangles     err max   locked  prev.lock     time\n    0      16        100056     0.000e0     2.7%              0.18s\n    1       7         50024    7.809e-4     2.7%      1.4%    0.08s\n";
        let t = parse_level_table(text);
        assert_eq!(t.len(), 2);
        assert_eq!(t[1], LevelLine { level: 1, nodes: Some(7), triangles: Some(50024), error_max: Some(7.809e-4) });
        // v1's columns: bytes and err min before err max.
        let v1 = parse_level_table(
            "level    nodes   triangles   bytes   err min   err max   time\n    1        3        400     9000    1.0e-3    2.5e-3   0.01s\nbye\n",
        );
        assert_eq!(v1, vec![LevelLine { level: 1, nodes: Some(3), triangles: Some(400), error_max: Some(2.5e-3) }]);
        assert!(parse_level_table("no table").is_empty());
    }
}
