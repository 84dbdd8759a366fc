//! Child side: one method, one process (`run-one`), printing one JSON line
//! ([`BuildOut`] or [`RunOut`]) with its timings and its peak RSS; and the
//! `/proc` probes they use (peak RSS from the library's
//! [`octolod::progress::peak_rss`], other processes' CPU use).

use crate::oocs::oocs;
use crate::types::{BuildOut, LevelOut, Method, RunOut, SimplifyJson, Timed};
use crate::RunOne;
use anyhow::{anyhow, bail, Context, Result};
use octolod::mesh::{Aabb, Vertex};
use octolod::pipeline::{build_store, extract, BuildOptions, CutSpec};
use octolod::ply::read::{read_all, CollectSink};
use octolod::ply::write::{write_ply, PlyWriteOptions};
use octolod::store::Store;
use std::io::Read as _;
use std::path::PathBuf;
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
            let mut j = run_octolod(a)?;
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
    std::fs::remove_dir_all(&store_dir).with_context(|| format!("remove {}", store_dir.display()))?;
    Ok(BuildOut {
        method: Method::Octolod,
        leaf_tris: a.leaf_tris,
        level_ratio: a.level_ratio,
        simplifier: a.simplifier,
        mem: opts.params.mem,
        input_triangles: r.soup.header.triangles,
        attributes: r.soup.header.attrs.describe(),
        quadric_dim: r.soup.header.attrs.quadric_dim() as u64,
        soup_seconds: r.seconds[0],
        octree_seconds: r.seconds[1],
        simplify_seconds: r.seconds[2],
        soup_external: r.soup.external,
        nodes: r.nodes,
        leaves: r.octree.leaves,
        deepest: u32::from(r.octree.deepest),
        disk_bytes: r.disk_bytes,
        peak_rss_with_extract_mib: peak_rss_mib(),
        levels,
        timed: Timed { seconds, peak_rss_mib: rss, other_cpu_cores: other_cpu, ..Timed::default() },
    })
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
    let Spawned { command, stdout: out, code, seconds, peak_rss_mib, other_cpu_cores } = spawn_timed(&mut cmd, bin)?;
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
    code: i32,
    seconds: f64,
    peak_rss_mib: f64,
    other_cpu_cores: Option<f64>,
}

/// Runs `cmd` (program `bin`) to its end, timed. Exit status 0 and 3
/// (`octolod simplify`: size not met, the closest mesh written) are
/// returned; any other is an error carrying the last lines of its stderr.
fn spawn_timed(cmd: &mut Command, bin: &std::path::Path) -> Result<Spawned> {
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
    Ok(Spawned { command, stdout, code, seconds, peak_rss_mib: usage.ru_maxrss as f64 / 1024.0, other_cpu_cores })
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
