//! `octolod-bench`: a speed-against-error report of octolod against in-core
//! peers, every method run on the same inputs in one run on one machine.
//!
//! Build and run (the `peers` feature pulls in meshoptimizer's C++, so plain
//! builds and CI never compile it):
//!
//! ```sh
//! cargo build --release --bin octolod   # provides `octolod metro`
//! cargo run --release --features peers --bin octolod-bench -- IN.ply [IN2.ply ...] \
//!     --out out/bench-report [--samples 200000] [--repeat 3] [--attr-sweep 2000000]
//! ```
//!
//! Takes: indexed PLYs; octolod settings (`--settings LEAFxRATIO,...`, default
//! `16384x2,65536x2`) and budget (`--mem`); a metro sample count
//! (`--samples`, default metro's own: 10 × the larger face count).
//!
//! Gives, under `--out`: `report.md` (tables), `report.json` (every raw
//! number, including each child's and each metro run's own JSON),
//! `error_vs_speed.svg` and `error_vs_size.svg` (log–log, hand-made SVG, one
//! panel per input), and per input a folder holding every output mesh
//! (`--clean` deletes them). `--suffix -10m` names the four files
//! `report-10m.md` and so on; `--label TEXT` adds a line saying what was
//! measured (the commit, say); `--from-json report.json` measures nothing
//! and writes the report and plots again from an earlier run's JSON (for
//! changes to the layout).
//!
//! The machine may be shared. Every child measures how many cores other
//! processes kept busy during its timed section (the machine's busy time
//! from `/proc/stat` minus its own CPU time, over the wall time; see
//! [`CpuProbe`]), and the report gives it per row and in summary;
//! `--wait-idle S` makes each run first wait, up to S seconds, until other
//! processes use under a quarter of a core.
//!
//! Methods, each run in a child process (this binary re-invoked with the
//! hidden `run-one` subcommand) that prints one JSON line with its timings
//! and its own peak RSS (`VmHWM` from `/proc/self/status`):
//! - `octolod`: `pipeline::build_store` per setting (PLY → soup → octree →
//!   all levels, out of core under `--mem`), then every level L ≥ 1 extracted
//!   whole (welded) as one output. Time = the whole build (one build makes
//!   every level), so each output row of a setting shows the setting's build
//!   time and throughput. Peak RSS is read right after the build, before
//!   extraction.
//! - `meshopt-simplify`: meshoptimizer's edge-collapse `simplify` (no border
//!   lock, target error 1.0 so only the count stops it), in core.
//! - `meshopt-sloppy`: meshoptimizer's grid `simplify_sloppy`, in core.
//! - `oocs`: Lindstrom's out-of-core simplification (2000): uniform-grid
//!   quadric clustering in one pass (implemented here, see [`oocs`]). It runs
//!   on the loaded mesh, so its peak RSS is an in-core one (Lindstrom streams
//!   a triangle soup and holds only the grid).
//!
//! The peers see positions only (meshopt's `simplify` and the OOCS quadric
//! are position-only here); octolod models every attribute the input has,
//! so on inputs with attributes it does more work than its peers.
//! `--repeat N` runs every child N times and keeps the fastest (peak RSS:
//! the largest of the N).
//!
//! The three peers load the whole input with `ply::read::read_all` (reported
//! as `load`), then time only the simplification call; their throughput is
//! input triangles / that time. Their target is the triangle count of each
//! octolod output (levels below `--min-tris` skipped; equal counts run
//! once), so sizes match: meshopt's targets are exact or close, `oocs`
//! searches its grid resolution (untimed, in JSON as `search_seconds`) for the
//! output count nearest the target.
//!
//! Error: `octolod metro INPUT OUTPUT --json` (the binary next to this one,
//! or `--octolod PATH`), run for every output; its JSON is read loosely (the
//! `combined` object's `rms`/`max`/`mean` — both directions together — when
//! present, else any `rms` and `max`/`hausdorff` numbers found) and divided
//! by the input's bounding-box diagonal. Without a working `metro`, errors
//! are "n/a" and everything else is still measured.
//!
//! Ratios are paired output by output within the run: each octolod output
//! (setting, level, T triangles) against each peer's run whose target was T,
//! on the same input: time = octolod build time ÷ peer simplify time (and ÷
//! peer load + simplify), RSS, RMS and Hausdorff octolod ÷ peer. Below 1
//! favours octolod. The summary compares one octolod build (all its levels)
//! with the sum of the peer's runs for the same targets, and the geometric
//! means of the error ratios.
//!
//! `--attr-sweep N` also builds one generated N-triangle sphere four times
//! with different vertex attributes (position only, +uv, +normals,
//! +normals+colors+uvs: quadric dimension 3, 5, 6, 11) and reports build time
//! and peak RSS per input triangle, to show what modelling only the
//! attributes a scene has buys.

use anyhow::{anyhow, bail, Context, Result};
use clap::{Parser, Subcommand, ValueEnum};
use octolod::gen::{GenOptions, Shape};
use octolod::mesh::{Aabb, AttrSet, Vertex};
use octolod::pipeline::{build_store, extract, BuildOptions, CutSpec};
use octolod::ply::read::{read_all, read_body, BodySink, CollectSink};
use octolod::ply::write::{write_ply, PlyWriteOptions};
use octolod::progress::Progress;
use octolod::quadric::{AttrWeights, Quadric, QuadricSpace};
use octolod::store::Store;
use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

// ---------------------------------------------------------------------------
// Command line.

#[derive(Parser)]
#[command(
    name = "octolod-bench",
    about = "Speed-against-error report: octolod against meshoptimizer and an OOCS baseline",
    args_conflicts_with_subcommands = true
)]
struct Cli {
    #[command(subcommand)]
    child: Option<Child>,
    #[command(flatten)]
    bench: BenchArgs,
}

#[derive(clap::Args)]
struct BenchArgs {
    /// Input PLYs (indexed triangle meshes).
    inputs: Vec<PathBuf>,
    /// Report folder.
    #[arg(long, default_value = "out/bench-report")]
    out: PathBuf,
    /// Metro samples per direction (default: metro's, 10 × the larger face count).
    #[arg(long, value_parser = parse_count)]
    samples: Option<u64>,
    /// octolod settings, LEAF_TRISxLEVEL_RATIO, comma separated.
    #[arg(long, default_value = "16384x2,65536x2", value_delimiter = ',')]
    settings: Vec<String>,
    /// octolod memory budget.
    #[arg(long, default_value = "512M")]
    mem: String,
    /// octolod binary providing `metro` (default: `octolod` next to this executable).
    #[arg(long)]
    octolod: Option<PathBuf>,
    /// Skip metro (errors are n/a).
    #[arg(long)]
    no_metro: bool,
    /// octolod outputs smaller than this are not matched by peers nor measured.
    #[arg(long, default_value_t = 500)]
    min_tris: u64,
    /// Also run the attribute sweep on a generated sphere of this many triangles.
    #[arg(long, value_parser = parse_count)]
    attr_sweep: Option<u64>,
    /// Run every method this many times and keep the fastest run (peak RSS: the largest).
    #[arg(long, default_value_t = 1)]
    repeat: u32,
    /// Delete output meshes once measured.
    #[arg(long)]
    clean: bool,
    /// Before each timed child run, wait (at most this many seconds) until
    /// other processes use less than a quarter of a core; 0: do not wait.
    #[arg(long, default_value_t = 0.0)]
    wait_idle: f64,
    /// Suffix for the report's file names (`report-10m.md`,
    /// `error_vs_speed-10m.svg`, ...), so reports can sit side by side.
    #[arg(long, default_value = "", allow_hyphen_values = true)]
    suffix: String,
    /// A line for the report saying what was measured (e.g. the commit the
    /// binaries were built from).
    #[arg(long)]
    label: Option<String>,
    /// Measure nothing: re-render report.md and the plots (into --out, with
    /// --suffix) from a report.json this tool wrote earlier.
    #[arg(long, value_name = "REPORT_JSON")]
    from_json: Option<PathBuf>,
    /// No progress lines on stderr.
    #[arg(long, short)]
    quiet: bool,
}

#[derive(Subcommand)]
enum Child {
    /// Internal: run one method in this process, print one JSON line.
    #[command(hide = true)]
    RunOne(RunOne),
}

#[derive(clap::Args, Clone)]
struct RunOne {
    #[arg(long, value_enum)]
    method: Method,
    /// Output triangle count (peers).
    #[arg(long, default_value_t = 0)]
    target: u64,
    #[arg(long, default_value_t = 16384)]
    leaf_tris: u64,
    #[arg(long, default_value_t = 2)]
    level_ratio: u32,
    #[arg(long, default_value = "512M")]
    mem: String,
    /// octolod: build only, extract nothing.
    #[arg(long)]
    no_extract: bool,
    input: PathBuf,
    /// Output PLY; for octolod a prefix (level L goes to PREFIX-L<L>.ply).
    output: PathBuf,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum Method {
    Octolod,
    MeshoptSimplify,
    MeshoptSloppy,
    Oocs,
}

impl Method {
    fn name(self) -> &'static str {
        match self {
            Method::Octolod => "octolod",
            Method::MeshoptSimplify => "meshopt-simplify",
            Method::MeshoptSloppy => "meshopt-sloppy",
            Method::Oocs => "oocs",
        }
    }
    const PEERS: [Method; 3] = [Method::MeshoptSimplify, Method::MeshoptSloppy, Method::Oocs];
}

fn parse_count(s: &str) -> std::result::Result<u64, String> {
    let t = s.trim().replace('_', "");
    let (num, mul) = match t.chars().last() {
        Some('k' | 'K') => (&t[..t.len() - 1], 1e3),
        Some('M') => (&t[..t.len() - 1], 1e6),
        Some('G') => (&t[..t.len() - 1], 1e9),
        _ => (&t[..], 1.0),
    };
    let v: f64 = num.parse().map_err(|_| format!("not a count: {s:?}"))?;
    if !(v.is_finite() && v >= 0.0) {
        return Err(format!("not a count: {s:?}"));
    }
    Ok((v * mul).round() as u64)
}

/// `LEAFxRATIO` → (leaf_tris, level_ratio).
fn parse_setting(s: &str) -> Result<(u64, u32)> {
    let (a, b) = s.trim().split_once(['x', 'X']).ok_or_else(|| anyhow!("setting {s:?} is not LEAF_TRISxLEVEL_RATIO"))?;
    Ok((parse_count(a).map_err(|e| anyhow!(e))?, b.trim().parse().with_context(|| format!("level ratio in {s:?}"))?))
}

fn main() {
    let cli = Cli::parse();
    let r = match cli.child {
        Some(Child::RunOne(a)) => run_one(&a).map(|j| println!("{j}")),
        None => bench(&cli.bench),
    };
    if let Err(e) = r {
        eprintln!("octolod-bench: error: {e:#}");
        std::process::exit(1);
    }
}

// ---------------------------------------------------------------------------
// Minimal JSON: values, a writer and a lenient parser (no serde in the crate).

#[derive(Clone, Debug, PartialEq)]
enum J {
    Null,
    Bool(bool),
    Num(f64),
    Str(String),
    Arr(Vec<J>),
    Obj(Vec<(String, J)>),
}

impl From<f64> for J {
    fn from(x: f64) -> J {
        if x.is_finite() { J::Num(x) } else { J::Null }
    }
}
impl From<u64> for J {
    fn from(x: u64) -> J {
        J::Num(x as f64)
    }
}
impl From<u32> for J {
    fn from(x: u32) -> J {
        J::Num(x as f64)
    }
}
impl From<bool> for J {
    fn from(x: bool) -> J {
        J::Bool(x)
    }
}
impl From<&str> for J {
    fn from(x: &str) -> J {
        J::Str(x.to_string())
    }
}
impl From<String> for J {
    fn from(x: String) -> J {
        J::Str(x)
    }
}
impl From<&Path> for J {
    fn from(x: &Path) -> J {
        J::Str(x.display().to_string())
    }
}
impl<T: Into<J>> From<Option<T>> for J {
    fn from(x: Option<T>) -> J {
        x.map_or(J::Null, Into::into)
    }
}
impl From<Vec<J>> for J {
    fn from(x: Vec<J>) -> J {
        J::Arr(x)
    }
}

fn obj<const N: usize>(pairs: [(&str, J); N]) -> J {
    J::Obj(pairs.into_iter().map(|(k, v)| (k.to_string(), v)).collect())
}

impl J {
    fn get(&self, key: &str) -> Option<&J> {
        match self {
            J::Obj(kv) => kv.iter().find(|(k, _)| k == key).map(|(_, v)| v),
            _ => None,
        }
    }
    fn num(&self) -> Option<f64> {
        match self {
            J::Num(x) => Some(*x),
            _ => None,
        }
    }
    fn f(&self, key: &str) -> Option<f64> {
        self.get(key).and_then(J::num)
    }
    fn str(&self, key: &str) -> Option<&str> {
        match self.get(key) {
            Some(J::Str(s)) => Some(s),
            _ => None,
        }
    }
    fn arr(&self, key: &str) -> &[J] {
        match self.get(key) {
            Some(J::Arr(a)) => a,
            _ => &[],
        }
    }
    fn push(&mut self, key: &str, v: J) {
        if let J::Obj(kv) = self {
            kv.push((key.to_string(), v));
        }
    }
    /// The first number under any of `keys`, searching depth first.
    fn find_num(&self, keys: &[&str]) -> Option<f64> {
        match self {
            J::Obj(kv) => kv
                .iter()
                .find(|(k, v)| keys.contains(&k.as_str()) && v.num().is_some())
                .and_then(|(_, v)| v.num())
                .or_else(|| kv.iter().find_map(|(_, v)| v.find_num(keys))),
            J::Arr(a) => a.iter().find_map(|v| v.find_num(keys)),
            _ => None,
        }
    }

    fn parse(s: &str) -> Result<J> {
        let b = s.as_bytes();
        let mut i = 0;
        let v = parse_value(b, &mut i)?;
        skip_ws(b, &mut i);
        if i != b.len() {
            bail!("JSON: trailing characters at byte {i}");
        }
        Ok(v)
    }

    fn write(&self, out: &mut String, indent: Option<usize>) {
        let nl = |out: &mut String, d: usize| {
            if let Some(base) = indent {
                out.push('\n');
                out.push_str(&" ".repeat(base + 2 * d));
            }
        };
        match self {
            J::Null => out.push_str("null"),
            J::Bool(b) => out.push_str(if *b { "true" } else { "false" }),
            J::Num(x) => {
                if x.fract() == 0.0 && x.abs() < 1e15 {
                    let _ = write!(out, "{}", *x as i64);
                } else {
                    let _ = write!(out, "{x}");
                }
            }
            J::Str(s) => write_json_str(out, s),
            J::Arr(a) => {
                out.push('[');
                for (k, v) in a.iter().enumerate() {
                    if k > 0 {
                        out.push(',');
                    }
                    nl(out, 1);
                    v.write(out, indent.map(|d| d + 2));
                }
                if !a.is_empty() {
                    nl(out, 0);
                }
                out.push(']');
            }
            J::Obj(kv) => {
                out.push('{');
                for (k, (key, v)) in kv.iter().enumerate() {
                    if k > 0 {
                        out.push(',');
                    }
                    nl(out, 1);
                    write_json_str(out, key);
                    out.push(':');
                    if indent.is_some() {
                        out.push(' ');
                    }
                    v.write(out, indent.map(|d| d + 2));
                }
                if !kv.is_empty() {
                    nl(out, 0);
                }
                out.push('}');
            }
        }
    }

    fn pretty(&self) -> String {
        let mut s = String::new();
        self.write(&mut s, Some(0));
        s.push('\n');
        s
    }
}

impl std::fmt::Display for J {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut s = String::new();
        self.write(&mut s, None);
        f.write_str(&s)
    }
}

fn write_json_str(out: &mut String, s: &str) {
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\r' => out.push_str("\\r"),
            '\t' => out.push_str("\\t"),
            c if (c as u32) < 0x20 => {
                let _ = write!(out, "\\u{:04x}", c as u32);
            }
            c => out.push(c),
        }
    }
    out.push('"');
}

fn skip_ws(b: &[u8], i: &mut usize) {
    while *i < b.len() && b[*i].is_ascii_whitespace() {
        *i += 1;
    }
}

fn parse_value(b: &[u8], i: &mut usize) -> Result<J> {
    skip_ws(b, i);
    let Some(&c) = b.get(*i) else { bail!("JSON: unexpected end") };
    match c {
        b'{' => {
            *i += 1;
            let mut kv = Vec::new();
            skip_ws(b, i);
            if b.get(*i) == Some(&b'}') {
                *i += 1;
                return Ok(J::Obj(kv));
            }
            loop {
                skip_ws(b, i);
                let J::Str(k) = parse_value(b, i)? else { bail!("JSON: object key is not a string at byte {i}") };
                skip_ws(b, i);
                if b.get(*i) != Some(&b':') {
                    bail!("JSON: expected ':' at byte {i}");
                }
                *i += 1;
                kv.push((k, parse_value(b, i)?));
                skip_ws(b, i);
                match b.get(*i) {
                    Some(b',') => *i += 1,
                    Some(b'}') => {
                        *i += 1;
                        return Ok(J::Obj(kv));
                    }
                    _ => bail!("JSON: expected ',' or '}}' at byte {i}"),
                }
            }
        }
        b'[' => {
            *i += 1;
            let mut a = Vec::new();
            skip_ws(b, i);
            if b.get(*i) == Some(&b']') {
                *i += 1;
                return Ok(J::Arr(a));
            }
            loop {
                a.push(parse_value(b, i)?);
                skip_ws(b, i);
                match b.get(*i) {
                    Some(b',') => *i += 1,
                    Some(b']') => {
                        *i += 1;
                        return Ok(J::Arr(a));
                    }
                    _ => bail!("JSON: expected ',' or ']' at byte {i}"),
                }
            }
        }
        b'"' => {
            *i += 1;
            let mut s = Vec::new();
            while let Some(&c) = b.get(*i) {
                *i += 1;
                match c {
                    b'"' => return Ok(J::Str(String::from_utf8_lossy(&s).into_owned())),
                    b'\\' => {
                        let e = *b.get(*i).ok_or_else(|| anyhow!("JSON: bad escape"))?;
                        *i += 1;
                        match e {
                            b'n' => s.push(b'\n'),
                            b't' => s.push(b'\t'),
                            b'r' => s.push(b'\r'),
                            b'b' => s.push(8),
                            b'f' => s.push(12),
                            b'u' => {
                                let h = b.get(*i..*i + 4).ok_or_else(|| anyhow!("JSON: bad \\u escape"))?;
                                let code = u32::from_str_radix(std::str::from_utf8(h)?, 16)?;
                                *i += 4;
                                let ch = char::from_u32(code).unwrap_or('\u{fffd}');
                                s.extend_from_slice(ch.to_string().as_bytes());
                            }
                            other => s.push(other),
                        }
                    }
                    c => s.push(c),
                }
            }
            bail!("JSON: unterminated string")
        }
        b't' if b[*i..].starts_with(b"true") => {
            *i += 4;
            Ok(J::Bool(true))
        }
        b'f' if b[*i..].starts_with(b"false") => {
            *i += 5;
            Ok(J::Bool(false))
        }
        b'n' if b[*i..].starts_with(b"null") => {
            *i += 4;
            Ok(J::Null)
        }
        // Rust's `{:?}` of non-finite floats, accepted loosely.
        b'N' if b[*i..].starts_with(b"NaN") => {
            *i += 3;
            Ok(J::Null)
        }
        b'i' if b[*i..].starts_with(b"inf") => {
            *i += 3;
            Ok(J::Null)
        }
        _ => {
            let start = *i;
            while *i < b.len() && matches!(b[*i], b'-' | b'+' | b'.' | b'e' | b'E' | b'0'..=b'9') {
                *i += 1;
            }
            let t = std::str::from_utf8(&b[start..*i])?;
            t.parse::<f64>().map(J::Num).map_err(|_| anyhow!("JSON: bad value {:?} at byte {start}", t))
        }
    }
}

// ---------------------------------------------------------------------------
// Child side: one method, one process.

/// Peak resident set of this process (`VmHWM`), MiB.
fn peak_rss_mib() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|kb| kb.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
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
struct CpuProbe {
    t: Instant,
    busy: Option<f64>,
    own: Option<f64>,
}

impl CpuProbe {
    fn start() -> CpuProbe {
        CpuProbe { t: Instant::now(), busy: machine_busy_seconds(), own: own_cpu_seconds() }
    }
    /// Mean cores used by other processes since `start` (clock ticks are
    /// 10 ms, so sections under ~0.2 s read coarsely).
    fn other_cores(&self) -> Option<f64> {
        let wall = self.t.elapsed().as_secs_f64();
        let busy = machine_busy_seconds()? - self.busy?;
        let own = own_cpu_seconds()? - self.own?;
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get()) as f64;
        (wall > 0.0).then(|| ((busy - own) / wall).clamp(0.0, threads))
    }
}

/// Waits up to `max_s` seconds for other processes to use under a quarter
/// of a core (sampled over 1 s windows); returns the seconds waited.
fn wait_idle(max_s: f64) -> f64 {
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

fn run_one(a: &RunOne) -> Result<J> {
    let t_all = Instant::now();
    let mut j = match a.method {
        Method::Octolod => run_octolod(a)?,
        m => run_peer(a, m)?,
    };
    j.push("child_seconds", t_all.elapsed().as_secs_f64().into());
    Ok(j)
}

fn run_octolod(a: &RunOne) -> Result<J> {
    let opts = BuildOptions {
        mem: octolod::mem::parse_size(&a.mem)?,
        leaf_tris: a.leaf_tris,
        max_depth: 16,
        level_ratio: a.level_ratio as f64,
        root_tris: 4096,
        levels: None,
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
            levels.push(obj([
                ("level", u32::from(l).into()),
                ("triangles", nf.into()),
                ("vertices", nv.into()),
                ("nodes", lr.map(|x| x.nodes).into()),
                ("error_bound_max", lr.map(|x| x.error_max).into()),
                ("path", path.as_path().into()),
            ]));
        }
    }
    std::fs::remove_dir_all(&store_dir).with_context(|| format!("remove {}", store_dir.display()))?;
    Ok(obj([
        ("method", "octolod".into()),
        ("leaf_tris", a.leaf_tris.into()),
        ("level_ratio", a.level_ratio.into()),
        ("mem", opts.mem.into()),
        ("input_triangles", r.soup.header.triangles.into()),
        ("attributes", r.soup.header.attrs.describe().into()),
        ("quadric_dim", (r.soup.header.attrs.quadric_dim() as u64).into()),
        ("seconds", seconds.into()),
        ("soup_seconds", r.seconds[0].into()),
        ("octree_seconds", r.seconds[1].into()),
        ("simplify_seconds", r.seconds[2].into()),
        ("soup_external", r.soup.external.into()),
        ("nodes", r.nodes.into()),
        ("leaves", r.octree.leaves.into()),
        ("deepest", u32::from(r.octree.deepest).into()),
        ("disk_bytes", r.disk_bytes.into()),
        ("peak_rss_mib", rss.into()),
        ("peak_rss_with_extract_mib", peak_rss_mib().into()),
        ("other_cpu_cores", other_cpu.into()),
        ("levels", J::Arr(levels)),
    ]))
}

fn run_peer(a: &RunOne, m: Method) -> Result<J> {
    if a.target == 0 {
        bail!("--target is required for {}", m.name());
    }
    let t = Instant::now();
    let (_h, CollectSink { vertices, triangles }, _stats) = read_all(&a.input)?;
    let n_in = triangles.len() as u64;
    let mut bbox = Aabb::EMPTY;
    for v in &vertices {
        bbox.add(v.pos);
    }
    let tris: Vec<[u32; 3]> = triangles.iter().map(|t| t.map(|i| i as u32)).collect();
    drop(triangles);
    // meshopt gets packed f32 positions; OOCS keeps the decoded vertices.
    let (verts, pos): (Vec<Vertex>, Vec<[f32; 3]>) = match m {
        Method::Oocs => (vertices, Vec::new()),
        _ => (Vec::new(), vertices.iter().map(|v| v.pos.map(|x| x as f32)).collect()),
    };
    let load_seconds = t.elapsed().as_secs_f64();
    let rss_load = peak_rss_mib();
    let reset = reset_peak_rss();

    let mut extra = Vec::new();
    let (seconds, out_verts, out_tris) = match m {
        Method::MeshoptSimplify | Method::MeshoptSloppy => {
            let idx: &[u32] = bytemuck::cast_slice(&tris);
            let adapter = meshopt::VertexDataAdapter::new(bytemuck::cast_slice(&pos), 12, 0)
                .map_err(|e| anyhow!("meshopt vertex adapter: {e}"))?;
            let target_idx = (a.target as usize).saturating_mul(3);
            let mut err = 0f32;
            let probe = CpuProbe::start();
            let t = Instant::now();
            let out = if m == Method::MeshoptSimplify {
                meshopt::simplify(idx, &adapter, target_idx, 1.0, meshopt::SimplifyOptions::None, Some(&mut err))
            } else {
                meshopt::simplify_sloppy(idx, &adapter, target_idx, 1.0, Some(&mut err))
            };
            let seconds = t.elapsed().as_secs_f64();
            extra.push(("other_cpu_cores", probe.other_cores().into()));
            extra.push(("meshopt_result_error", f64::from(err).into()));
            let faces: Vec<[u32; 3]> = out.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
            let (v, f) = compact(|i| pos[i as usize].map(f64::from), &faces, pos.len());
            (seconds, v, f)
        }
        Method::Oocs => {
            let r = oocs(&verts, &tris, &bbox, a.target);
            extra.push(("grid", r.grid.into()));
            extra.push(("grid_dims", J::Arr(r.dims.iter().map(|&d| J::from(d)).collect())));
            extra.push(("cells", r.cells.into()));
            extra.push(("clamped", r.clamped.into()));
            extra.push(("search_seconds", r.search_seconds.into()));
            extra.push(("search_tries", r.tries.into()));
            extra.push(("other_cpu_cores", r.other_cpu.into()));
            (r.seconds, r.vertices, r.triangles)
        }
        Method::Octolod => unreachable!(),
    };
    let rss_simplify = peak_rss_mib();
    write_ply(&a.output, &PlyWriteOptions::default(), &out_verts, &out_tris)?;
    let mut j = obj([
        ("method", m.name().into()),
        ("target", a.target.into()),
        ("input_triangles", n_in.into()),
        ("load_seconds", load_seconds.into()),
        ("seconds", seconds.into()),
        ("triangles", (out_tris.len() as u64).into()),
        ("vertices", (out_verts.len() as u64).into()),
        ("path", a.output.as_path().into()),
        ("peak_rss_load_mib", rss_load.into()),
        ("peak_rss_simplify_mib", if reset { rss_simplify.into() } else { J::Null }),
        ("peak_rss_mib", rss_load.max(rss_simplify).into()),
    ]);
    for (k, v) in extra {
        j.push(k, v);
    }
    Ok(j)
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

// ---------------------------------------------------------------------------
// OOCS baseline.

/// A uniform grid of cubic cells over a box: `g` cells along the longest axis.
struct Grid {
    lo: [f64; 3],
    h: f64,
    n: [u64; 3],
}

impl Grid {
    fn new(b: &Aabb, g: u32) -> Grid {
        let ext = [0, 1, 2].map(|k| (b.max[k] - b.min[k]).max(0.0));
        let longest = ext[0].max(ext[1]).max(ext[2]);
        let h = if longest > 0.0 { longest / g as f64 } else { 1.0 };
        let n = ext.map(|e| ((e / h).ceil() as u64).clamp(1, g as u64));
        Grid { lo: b.min, h, n }
    }
    #[inline]
    fn coords(&self, p: [f64; 3]) -> [u64; 3] {
        [0, 1, 2].map(|k| {
            let c = ((p[k] - self.lo[k]) / self.h).floor();
            if c > 0.0 { (c as u64).min(self.n[k] - 1) } else { 0 }
        })
    }
    #[inline]
    fn key(&self, p: [f64; 3]) -> u64 {
        let c = self.coords(p);
        c[0] + self.n[0] * (c[1] + self.n[1] * c[2])
    }
    fn cell_box(&self, key: u64) -> Aabb {
        let c = [key % self.n[0], (key / self.n[0]) % self.n[1], key / (self.n[0] * self.n[1])];
        Aabb {
            min: [0, 1, 2].map(|k| self.lo[k] + c[k] as f64 * self.h),
            max: [0, 1, 2].map(|k| self.lo[k] + (c[k] + 1) as f64 * self.h),
        }
    }
}

/// Rotates a triangle so its smallest entry comes first (orientation kept),
/// so identical cell triples compare equal.
#[inline]
fn canonical<T: Ord + Copy>(t: [T; 3]) -> [T; 3] {
    if t[0] <= t[1] && t[0] <= t[2] {
        t
    } else if t[1] <= t[2] {
        [t[1], t[2], t[0]]
    } else {
        [t[2], t[0], t[1]]
    }
}

/// Distinct, non-degenerate cell triples of the mesh on this grid.
fn cell_triangles(keys: &[u32], tris: &[[u32; 3]]) -> Vec<[u32; 3]> {
    let mut out: Vec<[u32; 3]> = tris
        .iter()
        .map(|t| t.map(|i| keys[i as usize]))
        .filter(|c| c[0] != c[1] && c[1] != c[2] && c[0] != c[2])
        .map(canonical)
        .collect();
    out.sort_unstable();
    out.dedup();
    out
}

/// Dense cell numbers (first-seen order) of every vertex, and the grid keys.
fn cell_ids(grid: &Grid, verts: &[Vertex]) -> (Vec<u32>, Vec<u64>) {
    let mut map: HashMap<u64, u32> = HashMap::with_capacity(verts.len() / 2);
    let mut keys = Vec::new();
    let ids = verts
        .iter()
        .map(|v| {
            let k = grid.key(v.pos);
            *map.entry(k).or_insert_with(|| {
                keys.push(k);
                keys.len() as u32 - 1
            })
        })
        .collect();
    (ids, keys)
}

struct OocsResult {
    grid: u32,
    dims: [u64; 3],
    cells: u64,
    clamped: u64,
    tries: u64,
    search_seconds: f64,
    seconds: f64,
    /// Cores other processes used during the timed pass.
    other_cpu: Option<f64>,
    vertices: Vec<Vertex>,
    triangles: Vec<[u32; 3]>,
}

/// Lindstrom's OOCS (2000): one pass of uniform-grid quadric clustering.
/// Every triangle's area-weighted plane quadric (position only, in
/// coordinates local to the box centre) is added to the cell of each of its
/// three corners; each occupied cell's representative minimises its quadric
/// inside the cell (`solve(1e-3, cell box)`, rank-deficient directions kept
/// at the mean of the cell's vertices); triangles whose corners fall in three
/// different cells survive, one per distinct cell triple (rotation-
/// canonical, orientation kept). The grid resolution (cells along the
/// longest side) is searched, untimed, for the output count nearest `target`.
fn oocs(verts: &[Vertex], tris: &[[u32; 3]], bbox: &Aabb, target: u64) -> OocsResult {
    // Search: output ≈ c·g² on a surface; a few secant steps on that model.
    let t0 = Instant::now();
    let count = |g: u32| cell_triangles(&cell_ids(&Grid::new(bbox, g), verts).0, tris).len() as u64;
    let mut g = ((target as f64 / 6.0).sqrt().round() as u32).clamp(1, 1 << 20);
    let mut best = (u64::MAX, g);
    let mut tried = HashMap::new();
    for _ in 0..10 {
        let c = *tried.entry(g).or_insert_with(|| count(g));
        let miss = c.abs_diff(target);
        if miss < best.0 || (miss == best.0 && g < best.1) {
            best = (miss, g);
        }
        if miss * 100 <= target {
            break;
        }
        let next = if c == 0 { g.saturating_mul(2) } else { (g as f64 * (target as f64 / c as f64).sqrt()).round() as u32 };
        let mut next = next.clamp(1, 1 << 20);
        if next == g {
            next = if c < target { g + 1 } else { g.saturating_sub(1).max(1) };
        }
        if tried.contains_key(&next) {
            break;
        }
        g = next;
    }
    let g = best.1;
    let search_seconds = t0.elapsed().as_secs_f64();

    // The timed pass.
    let probe = CpuProbe::start();
    let t = Instant::now();
    let grid = Grid::new(bbox, g);
    let (ids, keys) = cell_ids(&grid, verts);
    let space = QuadricSpace::new(AttrSet::POSITION_ONLY, AttrWeights::default(), bbox.center());
    let cl = Quadric::coeff_len(3);
    let mut acc = vec![0.0f64; keys.len() * cl];
    let local: Vec<[f64; 3]> = verts.iter().map(|v| space.to_local(v.pos)).collect();
    for (v, &id) in local.iter().zip(&ids) {
        let mut q = Quadric::zero(3);
        q.add_point(v);
        q.add_into(&mut acc[id as usize * cl..]);
    }
    for t in tris {
        let q = Quadric::from_triangle(&space, &local[t[0] as usize], &local[t[1] as usize], &local[t[2] as usize]);
        for &i in t {
            q.add_into(&mut acc[ids[i as usize] as usize * cl..]);
        }
    }
    let cell_tris = cell_triangles(&ids, tris);
    let mut remap = vec![u32::MAX; keys.len()];
    let mut vertices = Vec::new();
    let mut clamped = 0u64;
    let triangles = cell_tris
        .iter()
        .map(|c| {
            c.map(|cell| {
                let slot = &mut remap[cell as usize];
                if *slot == u32::MAX {
                    let q = Quadric::from_coeffs(3, &acc[cell as usize * cl..]);
                    let s = q.solve(1e-3, Some(space.local_bounds(&grid.cell_box(keys[cell as usize]))));
                    clamped += s.clamped as u64;
                    *slot = vertices.len() as u32;
                    vertices.push(Vertex { pos: space.to_world([s.x[0], s.x[1], s.x[2]]), ..Default::default() });
                }
                *slot
            })
        })
        .collect();
    let seconds = t.elapsed().as_secs_f64();
    let other_cpu = probe.other_cores();
    OocsResult {
        grid: g,
        dims: grid.n,
        cells: keys.len() as u64,
        clamped,
        tries: tried.len() as u64,
        search_seconds,
        seconds,
        other_cpu,
        vertices,
        triangles,
    }
}

// ---------------------------------------------------------------------------
// Parent side: drive the children and metro, collect, report.

struct InputInfo {
    path: PathBuf,
    name: String,
    bytes: u64,
    vertices: u64,
    triangles: u64,
    diagonal: f64,
    attrs: String,
    scan_seconds: f64,
}

/// One measured output mesh.
#[derive(Clone)]
struct Row {
    input: usize,
    method: Method,
    /// `16384x8` for octolod, empty for peers.
    setting: String,
    level: Option<u8>,
    target: Option<u64>,
    triangles: u64,
    vertices: u64,
    path: PathBuf,
    seconds: f64,
    load_seconds: Option<f64>,
    /// M input triangles per second of `seconds`.
    throughput: f64,
    rss_mib: f64,
    err: Option<Metro>,
    err_note: Option<String>,
    child: J,
}

impl Row {
    fn setting_text(&self) -> String {
        match (self.method, self.level, self.target) {
            (Method::Octolod, Some(l), _) => format!("{} L{l}", self.setting),
            (Method::Oocs, _, Some(t)) => {
                format!("target {} (grid {})", thousands(t), self.child.f("grid").map_or("?".into(), |g| format!("{g}")))
            }
            (_, _, Some(t)) => format!("target {}", thousands(t)),
            _ => self.setting.clone(),
        }
    }
}

#[derive(Clone, Debug)]
struct Metro {
    /// Absolute figures.
    rms: f64,
    max: f64,
    mean: Option<f64>,
    /// Which figures: "combined (both directions)", ...
    which: String,
    samples: Option<f64>,
    /// Samples metro actually took, per direction (it takes every vertex
    /// even when fewer samples are asked).
    taken: Vec<f64>,
    seconds: f64,
    raw: J,
}

struct Bench<'a> {
    args: &'a BenchArgs,
    exe: PathBuf,
    metro_bin: Option<PathBuf>,
    metro_note: String,
}

impl Bench<'_> {
    fn say(&self, s: &str) {
        if !self.args.quiet {
            eprintln!("{s}");
        }
    }

    /// Runs a child `--repeat` times; keeps the fastest run's JSON, with the
    /// largest peak RSS and every run's time (and other processes' CPU use,
    /// and any wait for an idle machine) added.
    fn child(&self, args: &[String]) -> Result<J> {
        let mut best: Option<J> = None;
        let (mut times, mut rss, mut other, mut waits) = (Vec::new(), f64::NAN, Vec::new(), Vec::new());
        for _ in 0..self.args.repeat.max(1) {
            if self.args.wait_idle > 0.0 {
                waits.push(J::from(wait_idle(self.args.wait_idle)));
            }
            let j = self.child_once(args)?;
            let t = j.f("seconds").unwrap_or(f64::NAN);
            rss = rss.max(j.f("peak_rss_mib").unwrap_or(f64::NAN));
            times.push(J::from(t));
            other.push(j.get("other_cpu_cores").cloned().unwrap_or(J::Null));
            if best.as_ref().is_none_or(|b| t < b.f("seconds").unwrap_or(f64::INFINITY)) {
                best = Some(j);
            }
        }
        let mut j = best.expect("at least one run");
        if let J::Obj(kv) = &mut j {
            kv.retain(|(k, _)| k != "peak_rss_mib");
        }
        j.push("peak_rss_mib", rss.into());
        j.push("seconds_all_runs", J::Arr(times));
        j.push("other_cpu_cores_all_runs", J::Arr(other));
        if !waits.is_empty() {
            j.push("idle_wait_seconds_all_runs", J::Arr(waits));
        }
        Ok(j)
    }

    fn child_once(&self, args: &[String]) -> Result<J> {
        let out = Command::new(&self.exe)
            .arg("run-one")
            .args(args)
            .stdin(Stdio::null())
            .output()
            .with_context(|| format!("start {}", self.exe.display()))?;
        if !out.status.success() {
            let err = String::from_utf8_lossy(&out.stderr);
            let tail: Vec<&str> = err.lines().rev().take(5).collect();
            let tail: Vec<&str> = tail.into_iter().rev().collect();
            bail!("`run-one {}` failed ({}): {}", args.join(" "), out.status, tail.join(" | "));
        }
        let s = String::from_utf8_lossy(&out.stdout);
        let line = s.lines().rev().find(|l| l.trim_start().starts_with('{')).ok_or_else(|| anyhow!("child printed no JSON"))?;
        J::parse(line.trim())
    }

    fn metro(&self, input: &Path, output: &Path) -> std::result::Result<Metro, String> {
        let Some(bin) = &self.metro_bin else { return Err(self.metro_note.clone()) };
        let mut cmd = Command::new(bin);
        cmd.arg("--quiet").arg("metro").arg(input).arg(output).arg("--json");
        if let Some(n) = self.args.samples {
            cmd.arg("--samples").arg(n.to_string());
        }
        let t = Instant::now();
        let out = cmd.stdin(Stdio::null()).output().map_err(|e| format!("start {}: {e}", bin.display()))?;
        let seconds = t.elapsed().as_secs_f64();
        // 0: fine; 3: a threshold exceeded (none is given, but accept it).
        if !(out.status.success() || out.status.code() == Some(3)) {
            let err = String::from_utf8_lossy(&out.stderr);
            return Err(format!("metro failed ({}): {}", out.status, err.lines().last().unwrap_or("")));
        }
        let s = String::from_utf8_lossy(&out.stdout);
        let start = s.find('{').ok_or("metro printed no JSON")?;
        let raw = J::parse(s[start..].trim()).map_err(|e| format!("metro JSON: {e}"))?;
        parse_metro(raw, seconds).ok_or_else(|| "metro JSON: no rms/max figures found".to_string())
    }
}

/// Reads metro's JSON loosely: the combined (two-sided) figures if present,
/// else the worse of two directions, else any `rms` and `max`/`hausdorff`.
fn parse_metro(raw: J, seconds: f64) -> Option<Metro> {
    const MAX: [&str; 4] = ["max", "hausdorff", "max_distance", "hausdorff_distance"];
    const RMS: [&str; 2] = ["rms", "rms_distance"];
    const MEAN: [&str; 3] = ["mean", "mean_distance", "avg"];
    let samples = raw.find_num(&["samples_target"]);
    let taken: Vec<f64> = ["a_to_b", "b_to_a"].iter().filter_map(|k| raw.get(k)?.f("samples")).collect();
    for key in ["combined", "both", "two_sided", "symmetric"] {
        if let Some(c) = raw.get(key) {
            if let (Some(rms), Some(max)) = (c.find_num(&RMS), c.find_num(&MAX)) {
                let max = raw.f("hausdorff").map_or(max, |h| h.max(max));
                return Some(Metro {
                    rms,
                    max,
                    mean: c.find_num(&MEAN),
                    which: format!("`{key}` (both directions)"),
                    samples,
                    taken,
                    seconds,
                    raw,
                });
            }
        }
    }
    let dirs: Vec<&J> = ["a_to_b", "b_to_a", "forward", "backward"].iter().filter_map(|k| raw.get(k)).collect();
    if !dirs.is_empty() {
        let rms = dirs.iter().filter_map(|d| d.find_num(&RMS)).fold(f64::NAN, f64::max);
        let max = dirs.iter().filter_map(|d| d.find_num(&MAX)).fold(f64::NAN, f64::max);
        if rms.is_finite() && max.is_finite() {
            return Some(Metro { rms, max, mean: None, which: "worse of the two directions".into(), samples, taken, seconds, raw });
        }
    }
    let rms = raw.find_num(&RMS)?;
    let max = raw.find_num(&MAX)?;
    let mean = raw.find_num(&MEAN);
    Some(Metro { rms, max, mean, which: "first `rms`/`max` found".into(), samples, taken, seconds, raw })
}

struct ScanSink {
    bbox: Aabb,
}

impl BodySink for ScanSink {
    fn vertices(&mut self, _first: u64, batch: &[Vertex]) -> octolod::Result<()> {
        for v in batch {
            self.bbox.add(v.pos);
        }
        Ok(())
    }
    fn triangles(&mut self, _batch: &[[u64; 3]]) -> octolod::Result<()> {
        Ok(())
    }
}

/// Counts, bbox diagonal and attributes of a PLY in one streaming pass (which
/// also warms the page cache, so every method reads it warm).
fn scan(path: &Path) -> Result<InputInfo> {
    let t = Instant::now();
    let header = octolod::ply::read_header(path)?;
    let mut sink = ScanSink { bbox: Aabb::EMPTY };
    let stats = read_body(path, &header, &mut sink, &Progress::hidden())?;
    let name = path.file_stem().map_or("input".into(), |s| s.to_string_lossy().into_owned());
    Ok(InputInfo {
        path: path.to_path_buf(),
        name,
        bytes: std::fs::metadata(path).map(|m| m.len()).unwrap_or(0),
        vertices: stats.vertices,
        triangles: stats.triangles,
        diagonal: sink.bbox.diagonal(),
        attrs: header.attrs.describe(),
        scan_seconds: t.elapsed().as_secs_f64(),
    })
}

fn bench(args: &BenchArgs) -> Result<()> {
    if let Some(json) = &args.from_json {
        return rerender(args, json);
    }
    if args.inputs.is_empty() && args.attr_sweep.is_none() {
        bail!("give at least one input PLY (or --attr-sweep N)");
    }
    let settings: Vec<(u64, u32)> = args.settings.iter().map(|s| parse_setting(s)).collect::<Result<_>>()?;
    if settings.is_empty() {
        bail!("--settings is empty");
    }
    octolod::mem::parse_size(&args.mem)?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("create {}", args.out.display()))?;
    let exe = std::env::current_exe().context("locate this executable")?;
    let (metro_bin, metro_note) = if args.no_metro {
        (None, "metro skipped (--no-metro)".to_string())
    } else {
        find_metro(args, &exe)
    };
    let b = Bench { args, exe, metro_bin, metro_note };
    b.say(&format!(
        "octolod-bench: {} input(s), settings {}, metro: {}",
        args.inputs.len(),
        args.settings.join(","),
        b.metro_bin.as_ref().map_or(b.metro_note.clone(), |p| p.display().to_string())
    ));

    let mut inputs = Vec::new();
    let mut rows: Vec<Row> = Vec::new();
    let mut builds: Vec<(usize, String, J)> = Vec::new();
    let mut failures: Vec<String> = Vec::new();
    for (ii, path) in args.inputs.iter().enumerate() {
        let info = scan(path)?;
        b.say(&format!(
            "[{}] {} triangles, {} vertices, {}, diagonal {:.4}",
            info.name,
            thousands(info.triangles),
            thousands(info.vertices),
            info.attrs,
            info.diagonal
        ));
        let dir = args.out.join(&info.name);
        std::fs::create_dir_all(&dir).with_context(|| format!("create {}", dir.display()))?;
        bench_input(&b, ii, &info, &dir, &settings, &mut rows, &mut builds, &mut failures);
        inputs.push(info);
    }

    let sweep = match args.attr_sweep {
        Some(n) => attr_sweep(&b, n, settings[0], &mut failures)?,
        None => Vec::new(),
    };

    let meta = Meta::of_run(&b);
    let path = write_report(args, &meta, &inputs, &rows, &builds, &sweep, &failures)?;
    if args.clean {
        for r in &rows {
            let _ = std::fs::remove_file(&r.path);
        }
    }
    b.say(&format!("report: {}", path.display()));
    Ok(())
}

/// Writes `report<suffix>.md`, `report<suffix>.json` and the two plots
/// under `--out`; returns the Markdown's path.
fn write_report(
    args: &BenchArgs,
    meta: &Meta,
    inputs: &[InputInfo],
    rows: &[Row],
    builds: &[(usize, String, J)],
    sweep: &[SweepRow],
    failures: &[String],
) -> Result<PathBuf> {
    std::fs::create_dir_all(&args.out).with_context(|| format!("create {}", args.out.display()))?;
    let write = |name: &str, text: String| -> Result<PathBuf> {
        let path = args.out.join(name);
        std::fs::write(&path, text).with_context(|| format!("write {}", path.display()))?;
        Ok(path)
    };
    let sfx = &meta.suffix;
    let md = write(&format!("report{sfx}.md"), report_md(meta, inputs, rows, builds, sweep, failures))?;
    write(&format!("report{sfx}.json"), report_json(meta, inputs, rows, builds, sweep, failures).pretty())?;
    let (speed, size) = plots(inputs, rows);
    write(&format!("error_vs_speed{sfx}.svg"), speed)?;
    write(&format!("error_vs_size{sfx}.svg"), size)?;
    Ok(md)
}

/// How a report was made: from this run, or read back from its JSON.
struct Meta {
    generated: String,
    command: String,
    cpu: String,
    threads: usize,
    mem_gib: f64,
    metro_bin: Option<PathBuf>,
    metro_note: String,
    samples: Option<u64>,
    repeat: u32,
    mem: String,
    settings: Vec<String>,
    min_tris: u64,
    wait_idle: f64,
    suffix: String,
    label: Option<String>,
    /// `--from-json`: when and from what the Markdown was re-rendered.
    rerendered: Option<String>,
}

impl Meta {
    fn of_run(b: &Bench) -> Meta {
        let (cpu, threads, mem_gib) = machine();
        Meta {
            generated: now_utc(),
            command: command_line(),
            cpu,
            threads,
            mem_gib,
            metro_bin: b.metro_bin.clone(),
            metro_note: b.metro_note.clone(),
            samples: b.args.samples,
            repeat: b.args.repeat,
            mem: b.args.mem.clone(),
            settings: b.args.settings.clone(),
            min_tris: b.args.min_tris,
            wait_idle: b.args.wait_idle,
            suffix: b.args.suffix.clone(),
            label: b.args.label.clone(),
            rerendered: None,
        }
    }
}

/// `--from-json`: rebuilds the rows from a report.json and writes the
/// report and plots again (for changes to the report's layout without
/// measuring again; the numbers are the JSON's).
fn rerender(args: &BenchArgs, json: &Path) -> Result<()> {
    let text = std::fs::read_to_string(json).with_context(|| format!("read {}", json.display()))?;
    let j = J::parse(&text).with_context(|| format!("parse {}", json.display()))?;
    let rerendered = format!("{} from `{}` by `{}`", now_utc(), json.display(), command_line());
    let r = read_report(&j, &args.suffix, Some(rerendered)).with_context(|| format!("read {}", json.display()))?;
    let path = write_report(args, &r.meta, &r.inputs, &r.rows, &r.builds, &r.sweep, &r.failures)?;
    if !args.quiet {
        eprintln!("report: {} (re-rendered from {})", path.display(), json.display());
    }
    Ok(())
}

/// Everything a report is made of.
struct Report {
    meta: Meta,
    inputs: Vec<InputInfo>,
    rows: Vec<Row>,
    builds: Vec<(usize, String, J)>,
    sweep: Vec<SweepRow>,
    failures: Vec<String>,
}

/// Reads back what [`report_json`] wrote.
fn read_report(j: &J, suffix: &str, rerendered: Option<String>) -> Result<Report> {
    let m = j.get("machine");
    let (metro_bin, metro_note) = match (j.str("metro"), j.get("metro_note")) {
        (Some(bin), Some(J::Null) | None) if !bin.contains(' ') => (Some(PathBuf::from(bin)), String::new()),
        (bin, note) => (None, note.and_then(|n| if let J::Str(s) = n { Some(s.clone()) } else { None }).or(bin.map(String::from)).unwrap_or_default()),
    };
    let meta = Meta {
        generated: j.str("generated").unwrap_or("?").to_string(),
        command: j.str("command").unwrap_or("?").to_string(),
        cpu: m.and_then(|m| m.str("cpu")).unwrap_or("?").to_string(),
        threads: m.and_then(|m| m.f("threads")).unwrap_or(0.0) as usize,
        mem_gib: m.and_then(|m| m.f("mem_gib")).unwrap_or(f64::NAN),
        metro_bin,
        metro_note,
        samples: j.f("samples").map(|x| x as u64),
        repeat: j.f("repeat").unwrap_or(1.0) as u32,
        mem: j.str("mem").unwrap_or("?").to_string(),
        settings: j.arr("settings").iter().filter_map(|s| if let J::Str(s) = s { Some(s.clone()) } else { None }).collect(),
        min_tris: j.f("min_tris").unwrap_or(0.0) as u64,
        wait_idle: j.f("wait_idle").unwrap_or(0.0),
        suffix: suffix.to_string(),
        label: j.str("label").map(String::from),
        rerendered,
    };
    let (mut inputs, mut rows, mut builds) = (Vec::new(), Vec::new(), Vec::new());
    for (ii, inp) in j.arr("inputs").iter().enumerate() {
        let info = InputInfo {
            path: PathBuf::from(inp.str("path").unwrap_or("?")),
            name: inp.str("name").unwrap_or("?").to_string(),
            bytes: inp.f("bytes").unwrap_or(0.0) as u64,
            vertices: inp.f("vertices").unwrap_or(0.0) as u64,
            triangles: inp.f("triangles").unwrap_or(0.0) as u64,
            diagonal: inp.f("bbox_diagonal").unwrap_or(f64::NAN),
            attrs: inp.str("attributes").unwrap_or("?").to_string(),
            scan_seconds: inp.f("scan_seconds").unwrap_or(f64::NAN),
        };
        for b in inp.arr("builds") {
            let setting = format!("{}x{}", b.f("leaf_tris").unwrap_or(0.0), b.f("level_ratio").unwrap_or(0.0));
            builds.push((ii, setting, b.clone()));
        }
        for r in inp.arr("rows") {
            let method = match r.str("method") {
                Some("octolod") => Method::Octolod,
                Some("meshopt-simplify") => Method::MeshoptSimplify,
                Some("meshopt-sloppy") => Method::MeshoptSloppy,
                Some("oocs") => Method::Oocs,
                other => bail!("unknown method {other:?}"),
            };
            let err = match r.get("metro") {
                Some(raw @ J::Obj(_)) => parse_metro(raw.clone(), r.f("metro_seconds").unwrap_or(f64::NAN)),
                _ => None,
            };
            rows.push(Row {
                input: ii,
                method,
                setting: r.str("setting").unwrap_or("").to_string(),
                level: r.f("level").map(|l| l as u8),
                target: r.f("target").map(|t| t as u64),
                triangles: r.f("triangles").unwrap_or(0.0) as u64,
                vertices: r.f("vertices").unwrap_or(0.0) as u64,
                path: PathBuf::from(r.str("path").unwrap_or("")),
                seconds: r.f("seconds").unwrap_or(f64::NAN),
                load_seconds: r.f("load_seconds"),
                throughput: r.f("throughput_mtris_per_s").unwrap_or(f64::NAN),
                rss_mib: r.f("peak_rss_mib").unwrap_or(f64::NAN),
                err,
                err_note: r.str("error_note").map(String::from),
                child: r.get("child").cloned().unwrap_or(J::Null),
            });
        }
        inputs.push(info);
    }
    let sweep = j
        .arr("attr_sweep")
        .iter()
        .map(|r| {
            let label = r.str("label").unwrap_or("?").to_string();
            let bits = SWEEP_SETS.iter().find(|(l, _)| *l == label).map_or(0, |s| s.1);
            SweepRow {
                label,
                attrs: AttrSet(bits),
                triangles: r.f("triangles").unwrap_or(0.0) as u64,
                ply_bytes: r.f("ply_bytes").unwrap_or(0.0) as u64,
                child: r.get("build").cloned().unwrap_or(J::Null),
            }
        })
        .collect::<Vec<_>>();
    let failures: Vec<String> = j.arr("failures").iter().filter_map(|f| if let J::Str(s) = f { Some(s.clone()) } else { None }).collect();
    Ok(Report { meta, inputs, rows, builds, sweep, failures })
}

/// The `octolod` binary, if its `metro` subcommand answers `--help`.
fn find_metro(args: &BenchArgs, exe: &Path) -> (Option<PathBuf>, String) {
    let candidate = args.octolod.clone().unwrap_or_else(|| exe.with_file_name("octolod"));
    match Command::new(&candidate).args(["metro", "--help"]).stdin(Stdio::null()).output() {
        Ok(o) if o.status.success() => (Some(candidate), String::new()),
        Ok(o) => (
            None,
            format!(
                "`{} metro` unavailable ({}); errors n/a",
                candidate.display(),
                String::from_utf8_lossy(&o.stderr).lines().next().unwrap_or("").trim()
            ),
        ),
        Err(e) => (None, format!("`{}` not runnable ({e}); errors n/a", candidate.display())),
    }
}

#[allow(clippy::too_many_arguments)]
fn bench_input(
    b: &Bench,
    ii: usize,
    info: &InputInfo,
    dir: &Path,
    settings: &[(u64, u32)],
    rows: &mut Vec<Row>,
    builds: &mut Vec<(usize, String, J)>,
    failures: &mut Vec<String>,
) {
    let n_in = info.triangles as f64;
    let input = info.path.display().to_string();
    for &(leaf, grid) in settings {
        let setting = format!("{leaf}x{grid}");
        let prefix = dir.join(format!("octolod-{setting}"));
        let args = vec![
            "--method".into(),
            "octolod".into(),
            "--leaf-tris".into(),
            leaf.to_string(),
            "--level-ratio".into(),
            grid.to_string(),
            "--mem".into(),
            b.args.mem.clone(),
            input.clone(),
            prefix.display().to_string(),
        ];
        let j = match b.child(&args) {
            Ok(j) => j,
            Err(e) => {
                b.say(&format!("[{}] octolod {setting}: FAILED: {e:#}", info.name));
                failures.push(format!("{}: octolod {setting}: {e:#}", info.name));
                continue;
            }
        };
        let seconds = j.f("seconds").unwrap_or(f64::NAN);
        let rss = j.f("peak_rss_mib").unwrap_or(f64::NAN);
        b.say(&format!(
            "[{}] octolod {setting}: build {:.2} s ({:.3} M tri/s), peak {:.0} MiB, {} levels",
            info.name,
            seconds,
            n_in / seconds / 1e6,
            rss,
            j.arr("levels").len()
        ));
        for l in j.arr("levels") {
            let tris = l.f("triangles").unwrap_or(0.0) as u64;
            let path = PathBuf::from(l.str("path").unwrap_or_default());
            let level = l.f("level").unwrap_or(0.0) as u8;
            if tris < b.args.min_tris {
                b.say(&format!("[{}]   L{level}: {} triangles < --min-tris, skipped", info.name, thousands(tris)));
                continue;
            }
            let mut row = Row {
                input: ii,
                method: Method::Octolod,
                setting: setting.clone(),
                level: Some(level),
                target: None,
                triangles: tris,
                vertices: l.f("vertices").unwrap_or(0.0) as u64,
                path,
                seconds,
                load_seconds: None,
                throughput: n_in / seconds / 1e6,
                rss_mib: rss,
                err: None,
                err_note: None,
                child: l.clone(),
            };
            measure(b, info, &mut row);
            rows.push(row);
        }
        builds.push((ii, setting, j));
    }

    // Peers at every distinct octolod output size.
    let mut targets: Vec<u64> = rows.iter().filter(|r| r.input == ii && r.method == Method::Octolod).map(|r| r.triangles).collect();
    targets.sort_unstable_by(|a, b| b.cmp(a));
    targets.dedup();
    for m in Method::PEERS {
        for &target in &targets {
            let out = dir.join(format!("{}-{target}.ply", m.name()));
            let args = vec![
                "--method".into(),
                m.name().into(),
                "--target".into(),
                target.to_string(),
                input.clone(),
                out.display().to_string(),
            ];
            let j = match b.child(&args) {
                Ok(j) => j,
                Err(e) => {
                    b.say(&format!("[{}] {} target {target}: FAILED: {e:#}", info.name, m.name()));
                    failures.push(format!("{}: {} target {target}: {e:#}", info.name, m.name()));
                    continue;
                }
            };
            let seconds = j.f("seconds").unwrap_or(f64::NAN);
            let mut row = Row {
                input: ii,
                method: m,
                setting: String::new(),
                level: None,
                target: Some(target),
                triangles: j.f("triangles").unwrap_or(0.0) as u64,
                vertices: j.f("vertices").unwrap_or(0.0) as u64,
                path: out,
                seconds,
                load_seconds: j.f("load_seconds"),
                throughput: n_in / seconds / 1e6,
                rss_mib: j.f("peak_rss_mib").unwrap_or(f64::NAN),
                err: None,
                err_note: None,
                child: j,
            };
            measure(b, info, &mut row);
            rows.push(row);
        }
    }
}

/// Runs metro on a row's output and prints the row's progress line.
fn measure(b: &Bench, info: &InputInfo, row: &mut Row) {
    match b.metro(&info.path, &row.path) {
        Ok(m) => row.err = Some(m),
        Err(e) => row.err_note = Some(e),
    }
    let err = match &row.err {
        Some(m) => format!("RMS {:.3e}, Hausdorff {:.3e} of diag (metro {:.1} s)", m.rms / info.diagonal, m.max / info.diagonal, m.seconds),
        None => "error n/a".into(),
    };
    let load = row.load_seconds.map_or(String::new(), |l| format!(" + load {l:.2} s"));
    let time = match row.method {
        Method::Octolod => "(build above)".to_string(),
        _ => format!("{:.3} s{load} ({:.3} M tri/s), peak {:.0} MiB", row.seconds, row.throughput, row.rss_mib),
    };
    b.say(&format!("[{}] {} {}: {} tris, {time}, {err}", info.name, row.method.name(), row.setting_text(), thousands(row.triangles)));
}

// ---------------------------------------------------------------------------
// Attribute sweep.

/// The attribute sets of `--attr-sweep`: label, attribute bits.
const SWEEP_SETS: [(&str, u32); 4] = [
    ("position only", 0),
    ("+uv", AttrSet::UV),
    ("+normals", AttrSet::NORMAL),
    ("+normals+colors+uvs", AttrSet::NORMAL | AttrSet::COLOR | AttrSet::UV),
];

struct SweepRow {
    label: String,
    attrs: AttrSet,
    triangles: u64,
    ply_bytes: u64,
    child: J,
}

fn attr_sweep(b: &Bench, n: u64, (leaf, grid): (u64, u32), failures: &mut Vec<String>) -> Result<Vec<SweepRow>> {
    let dir = b.args.out.join("attr-sweep");
    std::fs::create_dir_all(&dir).with_context(|| format!("create {}", dir.display()))?;
    let mut out = Vec::new();
    for (label, bits) in SWEEP_SETS {
        let attrs = AttrSet(bits);
        let tag = label.trim_start_matches('+').replace(['+', ' '], "-");
        let path = dir.join(format!("sphere-{n}-{tag}.ply"));
        if !path.exists() {
            let t = Instant::now();
            octolod::gen::write(
                &GenOptions { shape: Shape::Sphere, tris: n, seed: 1, attrs },
                &PlyWriteOptions::default(),
                &path,
                true,
                false,
            )?;
            b.say(&format!("[attr-sweep] generated {} in {:.1} s", path.display(), t.elapsed().as_secs_f64()));
        }
        let info = scan(&path)?;
        let args = vec![
            "--method".into(),
            "octolod".into(),
            "--leaf-tris".into(),
            leaf.to_string(),
            "--level-ratio".into(),
            grid.to_string(),
            "--mem".into(),
            b.args.mem.clone(),
            "--no-extract".into(),
            path.display().to_string(),
            dir.join(format!("build-{tag}")).display().to_string(),
        ];
        match b.child(&args) {
            Ok(j) => {
                let s = j.f("seconds").unwrap_or(f64::NAN);
                b.say(&format!(
                    "[attr-sweep] {label} (dim {}): build {:.2} s ({:.0} ns/tri), peak {:.0} MiB",
                    attrs.quadric_dim(),
                    s,
                    s * 1e9 / info.triangles as f64,
                    j.f("peak_rss_mib").unwrap_or(f64::NAN)
                ));
                out.push(SweepRow { label: label.to_string(), attrs, triangles: info.triangles, ply_bytes: info.bytes, child: j });
            }
            Err(e) => {
                b.say(&format!("[attr-sweep] {label}: FAILED: {e:#}"));
                failures.push(format!("attr-sweep {label}: {e:#}"));
            }
        }
    }
    Ok(out)
}

// ---------------------------------------------------------------------------
// Pairing.

/// One octolod output against one peer run at the same target.
struct Pair<'a> {
    o: &'a Row,
    p: &'a Row,
}

impl Pair<'_> {
    fn time(&self) -> f64 {
        self.o.seconds / self.p.seconds
    }
    fn time_with_load(&self) -> f64 {
        self.o.seconds / (self.p.seconds + self.p.load_seconds.unwrap_or(0.0))
    }
    fn rss(&self) -> f64 {
        self.o.rss_mib / self.p.rss_mib
    }
    fn rms(&self) -> Option<f64> {
        Some(self.o.err.as_ref()?.rms / self.p.err.as_ref()?.rms)
    }
    fn hausdorff(&self) -> Option<f64> {
        Some(self.o.err.as_ref()?.max / self.p.err.as_ref()?.max)
    }
}

fn pairs(rows: &[Row]) -> Vec<Pair<'_>> {
    let mut out = Vec::new();
    for o in rows.iter().filter(|r| r.method == Method::Octolod) {
        for m in Method::PEERS {
            if let Some(p) = rows.iter().find(|p| p.input == o.input && p.method == m && p.target == Some(o.triangles)) {
                out.push(Pair { o, p });
            }
        }
    }
    out
}

fn geomean(xs: impl Iterator<Item = f64>) -> Option<f64> {
    let (s, n) = xs.filter(|x| x.is_finite() && *x > 0.0).fold((0.0, 0u32), |(s, n), x| (s + x.ln(), n + 1));
    (n > 0).then(|| (s / n as f64).exp())
}

// ---------------------------------------------------------------------------
// Report.

fn thousands(n: u64) -> String {
    let s = n.to_string();
    let mut out = String::new();
    for (k, c) in s.chars().enumerate() {
        if k > 0 && (s.len() - k) % 3 == 0 {
            out.push(',');
        }
        out.push(c);
    }
    out
}

fn opt(x: Option<f64>, f: impl Fn(f64) -> String) -> String {
    match x {
        Some(v) if v.is_finite() => f(v),
        _ => "n/a".into(),
    }
}

fn sci(x: f64) -> String {
    format!("{x:.3e}")
}

fn ratio(x: f64) -> String {
    if !x.is_finite() {
        "n/a".into()
    } else if x >= 100.0 {
        format!("{x:.0}")
    } else if x >= 10.0 {
        format!("{x:.1}")
    } else {
        format!("{x:.2}")
    }
}

/// UTC date and time from the system clock.
fn now_utc() -> String {
    let secs = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs()) as i64;
    let (days, rem) = (secs.div_euclid(86400), secs.rem_euclid(86400));
    // Howard Hinnant's civil_from_days.
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + (m <= 2) as i64;
    format!("{y:04}-{m:02}-{d:02} {:02}:{:02} UTC", rem / 3600, rem % 3600 / 60)
}

fn machine() -> (String, usize, f64) {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| s.lines().find(|l| l.starts_with("model name")).and_then(|l| l.split_once(':')).map(|(_, v)| v.trim().to_string()))
        .unwrap_or_else(|| "unknown CPU".into());
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mem = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|s| s.lines().find(|l| l.starts_with("MemTotal:")).and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok()))
        .map_or(f64::NAN, |kb| kb / (1024.0 * 1024.0));
    (cpu, cores, mem)
}

fn command_line() -> String {
    std::env::args().collect::<Vec<_>>().join(" ")
}

/// Other processes' mean CPU use (cores) during a child's kept run.
fn other_cpu(j: &J) -> Option<f64> {
    j.f("other_cpu_cores")
}

fn report_md(meta: &Meta, inputs: &[InputInfo], rows: &[Row], builds: &[(usize, String, J)], sweep: &[SweepRow], failures: &[String]) -> String {
    let mut s = String::new();
    let (cpu, cores, mem) = (&meta.cpu, meta.threads, meta.mem_gib);
    let w = &mut s;
    let _ = writeln!(w, "# octolod speed-against-error report\n");
    let _ = writeln!(
        w,
        "Generated {} by `{}`.{}{}\n",
        meta.generated,
        meta.command,
        if meta.repeat > 1 { format!(" Every method ran {} times; times are the fastest run, peak RSS the largest.", meta.repeat) } else { String::new() },
        meta.rerendered.as_ref().map_or(String::new(), |r| format!(" Tables and plots re-rendered {r}; the numbers are those of the run."))
    );
    if let Some(l) = &meta.label {
        let _ = writeln!(w, "Measured: {l}.\n");
    }
    let _ = writeln!(w, "Machine: {cpu}, {cores} hardware threads, {mem:.1} GiB RAM. octolod uses all threads (rayon); meshoptimizer and the OOCS baseline are single-threaded.\n");
    // Other processes' CPU use during the timed sections (the machine may be
    // shared): kept runs and every run.
    let kept: Vec<f64> = builds
        .iter()
        .map(|(_, _, j)| j)
        .chain(rows.iter().filter(|r| r.method != Method::Octolod).map(|r| &r.child))
        .chain(sweep.iter().map(|r| &r.child))
        .filter_map(other_cpu)
        .collect();
    let all: Vec<f64> = builds
        .iter()
        .map(|(_, _, j)| j)
        .chain(rows.iter().filter(|r| r.method != Method::Octolod).map(|r| &r.child))
        .chain(sweep.iter().map(|r| &r.child))
        .flat_map(|j| j.arr("other_cpu_cores_all_runs").iter().filter_map(J::num))
        .collect();
    if !kept.is_empty() {
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        let max = |v: &[f64]| v.iter().copied().fold(0.0f64, f64::max);
        let busy = kept.iter().filter(|&&c| c >= 0.25).count();
        let _ = writeln!(
            w,
            "Other processes' CPU use during the timed sections (machine busy time minus the child's own, from `/proc/stat`; the machine is shared): kept runs {:.2} cores on average, at most {:.2}, {busy} of {} kept runs at or above 0.25 cores; all {} runs at most {:.2}.{} The \"others' CPU\" columns give it per kept run: a time taken beside a busy neighbour is slower than the method.\n",
            mean(&kept),
            max(&kept),
            kept.len(),
            all.len(),
            max(&all),
            if meta.wait_idle > 0.0 { format!(" Each run first waited (up to {} s) for other processes to use under 0.25 cores.", meta.wait_idle) } else { String::new() }
        );
    }
    let which = rows.iter().find_map(|r| r.err.as_ref()).map(|m| m.which.clone());
    let samples = rows.iter().find_map(|r| r.err.as_ref().and_then(|m| m.samples));
    let taken = rows.iter().filter_map(|r| r.err.as_ref()).flat_map(|m| m.taken.iter().copied());
    let (tlo, thi) = taken.fold((f64::INFINITY, 0.0f64), |(lo, hi), t| (lo.min(t), hi.max(t)));
    match (&meta.metro_bin, which) {
        (Some(bin), Some(which)) => {
            let _ = writeln!(
                w,
                "Error: `{} metro INPUT OUTPUT --json{}` ({} samples per direction asked, {} taken: metro takes every vertex even when fewer are asked), figures from {which}, divided by the input's bounding-box diagonal.\n",
                bin.display(),
                meta.samples.map_or(String::new(), |n| format!(" --samples {n}")),
                samples.map_or("metro's default".into(), |n| thousands(n as u64)),
                if tlo.is_finite() { format!("{}–{}", thousands(tlo as u64), thousands(thi as u64)) } else { "?".into() },
            );
        }
        (Some(bin), None) => {
            let _ = writeln!(w, "Error: `{} metro` ran but gave no figures; errors n/a.\n", bin.display());
        }
        (None, _) => {
            let _ = writeln!(w, "Error: {}.\n", meta.metro_note);
        }
    }
    let _ = writeln!(
        w,
        "How to read: octolod rows show the whole build (PLY → all levels, out of core under `--mem {}`), its time and throughput repeated on each level it produced; peer rows show one in-core simplification of the whole input to the matching octolod output size, timed without loading (load separate). Throughput is always input triangles per second. Peers see positions only; octolod models every attribute the input has. Peak RSS is each child process's `VmHWM` (octolod: read after the build, before extraction; peers: including the load). Ratios pair each octolod output with each peer's run at the same target on the same input; below 1 favours octolod.\n",
        meta.mem
    );

    for (ii, info) in inputs.iter().enumerate() {
        let dim = builds.iter().find(|(i, _, _)| *i == ii).and_then(|(_, _, j)| j.f("quadric_dim"));
        let _ = writeln!(
            w,
            "## {}\n\n`{}`: {} triangles, {} vertices, {}{}, {:.1} MB, bbox diagonal {:.6}.\n",
            info.name,
            info.path.display(),
            thousands(info.triangles),
            thousands(info.vertices),
            info.attrs,
            dim.map_or(String::new(), |d| format!(" (octolod quadric dimension {d})")),
            info.bytes as f64 / 1e6,
            info.diagonal
        );
        let _ = writeln!(w, "### octolod builds\n");
        let _ = writeln!(
            w,
            "| setting | levels | nodes | time (s) | soup / octree / simplify (s) | M input tris/s | peak RSS (MiB) | store on disk (MB) | others' CPU (cores) |"
        );
        let _ = writeln!(w, "|---|---:|---:|---:|---|---:|---:|---:|---:|");
        for (_, setting, j) in builds.iter().filter(|(i, _, _)| *i == ii) {
            let t = j.f("seconds").unwrap_or(f64::NAN);
            let _ = writeln!(
                w,
                "| {setting} | {} | {} | {t:.2} | {:.2} / {:.2} / {:.2} | {:.3} | {:.0} | {:.1} | {} |",
                j.arr("levels").len(),
                thousands(j.f("nodes").unwrap_or(0.0) as u64),
                j.f("soup_seconds").unwrap_or(f64::NAN),
                j.f("octree_seconds").unwrap_or(f64::NAN),
                j.f("simplify_seconds").unwrap_or(f64::NAN),
                info.triangles as f64 / t / 1e6,
                j.f("peak_rss_mib").unwrap_or(f64::NAN),
                j.f("disk_bytes").unwrap_or(f64::NAN) / 1e6,
                opt(other_cpu(j), |c| format!("{c:.2}")),
            );
        }
        let _ = writeln!(w, "\n### All outputs\n");
        let _ = writeln!(
            w,
            "| method | setting | output tris | time (s) | load (s) | M input tris/s | peak RSS (MiB) | RMS / diag | Hausdorff / diag | others' CPU (cores) |"
        );
        let _ = writeln!(w, "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|");
        let mut mine: Vec<&Row> = rows.iter().filter(|r| r.input == ii).collect();
        mine.sort_by(|a, b| (a.method as u8).cmp(&(b.method as u8)).then(b.triangles.cmp(&a.triangles)));
        for r in &mine {
            let others = match r.method {
                Method::Octolod => builds.iter().find(|(i, s, _)| *i == ii && *s == r.setting).and_then(|(_, _, j)| other_cpu(j)),
                _ => other_cpu(&r.child),
            };
            let _ = writeln!(
                w,
                "| {} | {} | {} | {:.3} | {} | {:.3} | {:.0} | {} | {} | {} |",
                r.method.name(),
                r.setting_text(),
                thousands(r.triangles),
                r.seconds,
                match r.method {
                    Method::Octolod => "in build".to_string(),
                    _ => opt(r.load_seconds, |x| format!("{x:.3}")),
                },
                r.throughput,
                r.rss_mib,
                opt(r.err.as_ref().map(|m| m.rms / info.diagonal), sci),
                opt(r.err.as_ref().map(|m| m.max / info.diagonal), sci),
                opt(others, |c| format!("{c:.2}")),
            );
        }
        let _ = writeln!(w, "\n### Ratios, octolod ÷ peer at the same target\n");
        let _ = writeln!(
            w,
            "| octolod output | tris | peer | peer tris | time (build ÷ simplify) | time (build ÷ load+simplify) | peak RSS | RMS | Hausdorff |"
        );
        let _ = writeln!(w, "|---|---:|---|---:|---:|---:|---:|---:|---:|");
        let ps: Vec<Pair> = pairs(rows).into_iter().filter(|p| p.o.input == ii).collect();
        for p in &ps {
            let _ = writeln!(
                w,
                "| {} | {} | {} | {} | {} | {} | {} | {} | {} |",
                p.o.setting_text(),
                thousands(p.o.triangles),
                p.p.method.name(),
                thousands(p.p.triangles),
                ratio(p.time()),
                ratio(p.time_with_load()),
                ratio(p.rss()),
                opt(p.rms(), ratio),
                opt(p.hausdorff(), ratio),
            );
        }
        let _ = writeln!(w, "\n### Summary per setting and peer\n");
        let _ = writeln!(
            w,
            "One octolod build gives all its levels; a peer needs one run per target. \"peer total\" sums the peer's simplification times (and loads) over the targets matched here.\n"
        );
        let _ = writeln!(
            w,
            "| octolod setting | peer | targets | octolod build (s) | peer total simplify (s) | peer total load+simplify (s) | build ÷ total | geo-mean RMS ratio | geo-mean Hausdorff ratio |"
        );
        let _ = writeln!(w, "|---|---|---:|---:|---:|---:|---:|---:|---:|");
        for (_, setting, j) in builds.iter().filter(|(i, _, _)| *i == ii) {
            for m in Method::PEERS {
                let sel: Vec<&Pair> = ps.iter().filter(|p| &p.o.setting == setting && p.p.method == m).collect();
                if sel.is_empty() {
                    continue;
                }
                let build = j.f("seconds").unwrap_or(f64::NAN);
                let tot: f64 = sel.iter().map(|p| p.p.seconds).sum();
                let tot_l: f64 = sel.iter().map(|p| p.p.seconds + p.p.load_seconds.unwrap_or(0.0)).sum();
                let _ = writeln!(
                    w,
                    "| {setting} | {} | {} | {build:.2} | {tot:.2} | {tot_l:.2} | {} | {} | {} |",
                    m.name(),
                    sel.len(),
                    ratio(build / tot),
                    opt(geomean(sel.iter().filter_map(|p| p.rms())), ratio),
                    opt(geomean(sel.iter().filter_map(|p| p.hausdorff())), ratio),
                );
            }
        }
        let _ = writeln!(w);
    }

    if !sweep.is_empty() {
        let base = &sweep[0];
        let bt = base.child.f("seconds").unwrap_or(f64::NAN) / base.triangles as f64;
        let br = base.child.f("peak_rss_mib").unwrap_or(f64::NAN) / base.triangles as f64;
        let bs = base.child.f("simplify_seconds").unwrap_or(f64::NAN);
        let _ = writeln!(w, "## Model only what a scene needs: attribute sweep\n");
        let _ = writeln!(
            w,
            "The same generated sphere ({} triangles, seed 1) with four vertex attribute sets, built by octolod with setting {} under `--mem {}` (build only). The quadric dimension follows the attributes present, so a position-only input pays nothing for attributes it does not have.\n",
            thousands(base.triangles),
            meta.settings.first().map_or("", |s| s.as_str()),
            meta.mem
        );
        let _ = writeln!(
            w,
            "| attributes | quadric dim | PLY (MB) | build (s) | soup / octree / simplify (s) | ns per input tri | peak RSS (MiB) | RSS bytes per input tri | store on disk (MB) | time ÷ position-only | simplify ÷ position-only | RSS ÷ position-only | others' CPU (cores) |"
        );
        let _ = writeln!(w, "|---|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|");
        for r in sweep {
            let t = r.child.f("seconds").unwrap_or(f64::NAN);
            let rss = r.child.f("peak_rss_mib").unwrap_or(f64::NAN);
            let simp = r.child.f("simplify_seconds").unwrap_or(f64::NAN);
            let _ = writeln!(
                w,
                "| {} (`{}`) | {} | {:.1} | {t:.2} | {:.2} / {:.2} / {simp:.2} | {:.0} | {rss:.0} | {:.0} | {:.1} | {} | {} | {} | {} |",
                r.label,
                r.attrs.describe(),
                r.attrs.quadric_dim(),
                r.ply_bytes as f64 / 1e6,
                r.child.f("soup_seconds").unwrap_or(f64::NAN),
                r.child.f("octree_seconds").unwrap_or(f64::NAN),
                t * 1e9 / r.triangles as f64,
                rss * 1048576.0 / r.triangles as f64,
                r.child.f("disk_bytes").unwrap_or(f64::NAN) / 1e6,
                ratio(t / r.triangles as f64 / bt),
                ratio(simp / bs),
                ratio(rss / r.triangles as f64 / br),
                opt(other_cpu(&r.child), |c| format!("{c:.2}")),
            );
        }
        let budget = octolod::mem::parse_size(&meta.mem).map_or(f64::NAN, |b| b as f64 / 1048576.0);
        if sweep.iter().all(|r| r.child.f("peak_rss_mib").is_some_and(|m| m >= 0.95 * budget)) {
            let _ = writeln!(
                w,
                "\nEvery build here filled its `--mem {}` budget, so peak RSS is the budget whatever the attributes: at this size they cost time and disk, not memory.",
                meta.mem
            );
        }
        let _ = writeln!(w);
    }

    if !failures.is_empty() {
        let _ = writeln!(w, "## What failed\n");
        for f in failures {
            let _ = writeln!(w, "- {f}");
        }
        let _ = writeln!(w);
    }
    let sfx = &meta.suffix;
    let _ = writeln!(w, "## Plots\n");
    let _ = writeln!(w, "![RMS error vs throughput](error_vs_speed{sfx}.svg)\n");
    let _ = writeln!(w, "![RMS error vs output size](error_vs_size{sfx}.svg)\n");
    let _ = writeln!(w, "Raw numbers: `report{sfx}.json`.");
    s
}

fn report_json(meta: &Meta, inputs: &[InputInfo], rows: &[Row], builds: &[(usize, String, J)], sweep: &[SweepRow], failures: &[String]) -> J {
    let (cpu, cores, mem) = (meta.cpu.as_str(), meta.threads, meta.mem_gib);
    let ps = pairs(rows);
    let inputs_j: Vec<J> = inputs
        .iter()
        .enumerate()
        .map(|(ii, info)| {
            let rows_j: Vec<J> = rows
                .iter()
                .filter(|r| r.input == ii)
                .map(|r| {
                    let e = r.err.as_ref();
                    obj([
                        ("method", r.method.name().into()),
                        ("setting", J::from(r.setting.as_str())),
                        ("level", r.level.map(u32::from).into()),
                        ("target", r.target.into()),
                        ("triangles", r.triangles.into()),
                        ("vertices", r.vertices.into()),
                        ("path", r.path.as_path().into()),
                        ("seconds", r.seconds.into()),
                        ("load_seconds", r.load_seconds.into()),
                        ("throughput_mtris_per_s", r.throughput.into()),
                        ("peak_rss_mib", r.rss_mib.into()),
                        ("rms", e.map(|m| m.rms).into()),
                        ("hausdorff", e.map(|m| m.max).into()),
                        ("mean", e.and_then(|m| m.mean).into()),
                        ("rms_rel_diag", e.map(|m| m.rms / info.diagonal).into()),
                        ("hausdorff_rel_diag", e.map(|m| m.max / info.diagonal).into()),
                        ("error_figures", e.map(|m| m.which.clone()).into()),
                        ("error_note", r.err_note.clone().into()),
                        ("metro_seconds", e.map(|m| m.seconds).into()),
                        ("metro", e.map_or(J::Null, |m| m.raw.clone())),
                        ("child", r.child.clone()),
                    ])
                })
                .collect();
            let pairs_j: Vec<J> = ps
                .iter()
                .filter(|p| p.o.input == ii)
                .map(|p| {
                    obj([
                        ("setting", p.o.setting.as_str().into()),
                        ("level", p.o.level.map(u32::from).into()),
                        ("triangles", p.o.triangles.into()),
                        ("peer", p.p.method.name().into()),
                        ("peer_triangles", p.p.triangles.into()),
                        ("time_ratio", p.time().into()),
                        ("time_ratio_with_load", p.time_with_load().into()),
                        ("rss_ratio", p.rss().into()),
                        ("rms_ratio", p.rms().into()),
                        ("hausdorff_ratio", p.hausdorff().into()),
                    ])
                })
                .collect();
            let builds_j: Vec<J> = builds.iter().filter(|(i, _, _)| *i == ii).map(|(_, _, j)| j.clone()).collect();
            obj([
                ("path", info.path.as_path().into()),
                ("name", info.name.as_str().into()),
                ("bytes", info.bytes.into()),
                ("vertices", info.vertices.into()),
                ("triangles", info.triangles.into()),
                ("attributes", info.attrs.as_str().into()),
                ("bbox_diagonal", info.diagonal.into()),
                ("scan_seconds", info.scan_seconds.into()),
                ("builds", J::Arr(builds_j)),
                ("rows", J::Arr(rows_j)),
                ("pairs", J::Arr(pairs_j)),
            ])
        })
        .collect();
    let sweep_j: Vec<J> = sweep
        .iter()
        .map(|r| {
            obj([
                ("label", r.label.as_str().into()),
                ("attributes", r.attrs.describe().into()),
                ("quadric_dim", (r.attrs.quadric_dim() as u64).into()),
                ("triangles", r.triangles.into()),
                ("ply_bytes", r.ply_bytes.into()),
                ("build", r.child.clone()),
            ])
        })
        .collect();
    obj([
        ("generated", meta.generated.as_str().into()),
        ("command", meta.command.as_str().into()),
        ("label", meta.label.clone().into()),
        ("rerendered", meta.rerendered.clone().into()),
        ("machine", obj([("cpu", cpu.into()), ("threads", (cores as u64).into()), ("mem_gib", mem.into())])),
        ("metro", meta.metro_bin.as_deref().map(J::from).unwrap_or_else(|| J::from(meta.metro_note.as_str()))),
        ("metro_note", if meta.metro_bin.is_some() { J::Null } else { meta.metro_note.as_str().into() }),
        ("samples", meta.samples.into()),
        ("repeat", meta.repeat.into()),
        ("mem", meta.mem.as_str().into()),
        ("settings", J::Arr(meta.settings.iter().map(|s| J::from(s.as_str())).collect())),
        ("min_tris", meta.min_tris.into()),
        ("wait_idle", meta.wait_idle.into()),
        ("inputs", J::Arr(inputs_j)),
        ("attr_sweep", J::Arr(sweep_j)),
        ("failures", J::Arr(failures.iter().map(|f| J::from(f.as_str())).collect())),
    ])
}

// ---------------------------------------------------------------------------
// SVG plots.

#[derive(Clone, Copy)]
enum Marker {
    Circle,
    Square,
    Triangle,
    Diamond,
    Cross,
}

struct Series {
    label: String,
    color: &'static str,
    marker: Marker,
    /// (x, y, hover text), joined by a line in this order when `join`.
    points: Vec<(f64, f64, String)>,
    join: bool,
}

/// One plot area (one input).
struct Panel {
    title: String,
    series: Vec<Series>,
}

const OCTOLOD_COLORS: [&str; 4] = ["#1f4e99", "#4a90d9", "#7b3fa0", "#0b8a8a"];

fn method_color(m: Method) -> &'static str {
    match m {
        Method::Octolod => OCTOLOD_COLORS[0],
        Method::MeshoptSimplify => "#e07b00",
        Method::MeshoptSloppy => "#2e9d3a",
        Method::Oocs => "#c62828",
    }
}

/// (error vs speed, error vs size): one panel per input, on shared axes.
fn plots(inputs: &[InputInfo], rows: &[Row]) -> (String, String) {
    // Colour: method (octolod: shades per setting); shape: octolod setting
    // (peers: circles).
    let markers = [Marker::Square, Marker::Diamond, Marker::Triangle, Marker::Cross];
    let mut keys: Vec<(usize, Method, String)> = Vec::new();
    for r in rows {
        let k = (r.input, r.method, r.setting.clone());
        if !keys.contains(&k) {
            keys.push(k);
        }
    }
    let mut settings: Vec<String> = Vec::new();
    for r in rows.iter().filter(|r| r.method == Method::Octolod) {
        if !settings.contains(&r.setting) {
            settings.push(r.setting.clone());
        }
    }
    let make = |x: &dyn Fn(&Row) -> f64, join_peers: bool| -> Vec<Panel> {
        inputs
            .iter()
            .enumerate()
            .map(|(ii, info)| {
                let series = keys
                    .iter()
                    .filter(|k| k.0 == ii)
                    .map(|(_, m, setting)| {
                        let mut rs: Vec<&Row> = rows.iter().filter(|r| r.input == ii && r.method == *m && &r.setting == setting).collect();
                        rs.sort_by_key(|r| std::cmp::Reverse(r.triangles));
                        let points = rs
                            .iter()
                            .filter_map(|r| {
                                let e = r.err.as_ref()?;
                                Some((
                                    x(r),
                                    e.rms / info.diagonal,
                                    format!(
                                        "{} {}: {} tris, {:.3} M tri/s, RMS {:.3e}, Hausdorff {:.3e}",
                                        r.method.name(),
                                        r.setting_text(),
                                        thousands(r.triangles),
                                        r.throughput,
                                        e.rms / info.diagonal,
                                        e.max / info.diagonal
                                    ),
                                ))
                            })
                            .collect();
                        let k = settings.iter().position(|s| s == setting).unwrap_or(0);
                        let (label, color, marker) = match m {
                            Method::Octolod => {
                                (format!("octolod {setting}"), OCTOLOD_COLORS[k % OCTOLOD_COLORS.len()], markers[k % markers.len()])
                            }
                            m => (m.name().to_string(), method_color(*m), Marker::Circle),
                        };
                        Series { label, color, marker, points, join: join_peers || *m == Method::Octolod }
                    })
                    .collect();
                Panel { title: format!("{}: {} triangles, {}", info.name, thousands(info.triangles), info.attrs), series }
            })
            .collect()
    };
    let speed = svg_plot(
        "RMS error vs throughput",
        "throughput (M input triangles / s, log)",
        "RMS error / bbox diagonal (log)",
        &make(&|r| r.throughput, false),
        "octolod: one build makes every level, so a setting's outputs share its throughput (joined by a line); peers: one run per output",
    );
    let size = svg_plot(
        "RMS error vs output size",
        "output triangles (log)",
        "RMS error / bbox diagonal (log)",
        &make(&|r| r.triangles as f64, true),
        "peers are run at each octolod output size",
    );
    (speed, size)
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

/// Log-axis range (log10 units) around the data.
fn log_range(vals: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in vals.filter(|v| v.is_finite() && *v > 0.0) {
        lo = lo.min(v.log10());
        hi = hi.max(v.log10());
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let span = (hi - lo).max(0.3);
    let mid = 0.5 * (lo + hi);
    let (lo, hi) = (mid - span / 2.0, mid + span / 2.0);
    (lo - 0.06 * span, hi + 0.06 * span)
}

/// Ticks in [lo, hi] (log10 units): (value, labelled).
fn log_ticks(lo: f64, hi: f64) -> Vec<(f64, bool)> {
    let span = hi - lo;
    let mut out = Vec::new();
    for e in (lo.floor() as i32)..=(hi.ceil() as i32) {
        for m in 1..=9 {
            let v = m as f64 * 10f64.powi(e);
            let l = v.log10();
            if l < lo - 1e-9 || l > hi + 1e-9 {
                continue;
            }
            let labelled = m == 1 || (span < 2.5 && (m == 2 || m == 5)) || span < 1.0;
            out.push((v, labelled));
        }
    }
    out
}

fn tick_label(v: f64) -> String {
    if (1e-3..1e6).contains(&v) {
        let s = format!("{v:.6}");
        let s = s.trim_end_matches('0').trim_end_matches('.');
        if v >= 1000.0 {
            thousands(v.round() as u64)
        } else {
            s.to_string()
        }
    } else {
        let e = v.log10().floor() as i32;
        let m = (v / 10f64.powi(e)).round();
        if m == 1.0 { format!("1e{e}") } else { format!("{m}e{e}") }
    }
}

fn marker_svg(m: Marker, x: f64, y: f64, color: &str) -> String {
    let r = 4.5;
    match m {
        Marker::Circle => format!("<circle cx=\"{x:.1}\" cy=\"{y:.1}\" r=\"{r}\" fill=\"{color}\" stroke=\"white\" stroke-width=\"1\"/>"),
        Marker::Square => format!(
            "<rect x=\"{:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"{:.1}\" fill=\"{color}\" stroke=\"white\" stroke-width=\"1\"/>",
            x - r,
            y - r,
            2.0 * r,
            2.0 * r
        ),
        Marker::Triangle => format!(
            "<polygon points=\"{:.1},{:.1} {:.1},{:.1} {:.1},{:.1}\" fill=\"{color}\" stroke=\"white\" stroke-width=\"1\"/>",
            x,
            y - 1.3 * r,
            x - 1.2 * r,
            y + r,
            x + 1.2 * r,
            y + r
        ),
        Marker::Diamond => format!(
            "<polygon points=\"{:.1},{:.1} {:.1},{:.1} {:.1},{:.1} {:.1},{:.1}\" fill=\"{color}\" stroke=\"white\" stroke-width=\"1\"/>",
            x,
            y - 1.3 * r,
            x + 1.3 * r,
            y,
            x,
            y + 1.3 * r,
            x - 1.3 * r,
            y
        ),
        Marker::Cross => format!(
            "<path d=\"M{:.1},{:.1}L{:.1},{:.1}M{:.1},{:.1}L{:.1},{:.1}\" stroke=\"{color}\" stroke-width=\"2.5\"/>",
            x - r,
            y - r,
            x + r,
            y + r,
            x - r,
            y + r,
            x + r,
            y - r
        ),
    }
}

/// Log–log plot, one panel per input stacked (each scaled to its data), one
/// legend.
fn svg_plot(title: &str, xlabel: &str, ylabel: &str, panels: &[Panel], note: &str) -> String {
    let (px0, px1) = (90.0, 680.0);
    let (top, ph, gap) = (64.0, 440.0, 84.0);
    let n = panels.len().max(1) as f64;
    let (w, h) = (980.0, top + n * ph + (n - 1.0) * gap + 70.0);
    let mut s = String::new();
    let _ = writeln!(
        s,
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" viewBox=\"0 0 {w} {h}\" font-family=\"Helvetica, Arial, sans-serif\" font-size=\"12\">"
    );
    let _ = writeln!(s, "<rect width=\"{w}\" height=\"{h}\" fill=\"white\"/>");
    let _ = writeln!(s, "<text x=\"{:.1}\" y=\"24\" text-anchor=\"middle\" font-size=\"16\" font-weight=\"bold\">{}</text>", (px0 + px1) / 2.0, esc(title));
    for (k, panel) in panels.iter().enumerate() {
        let py0 = top + k as f64 * (ph + gap);
        let py1 = py0 + ph;
        let all = || panel.series.iter().flat_map(|s| s.points.iter());
        let (xlo, xhi) = log_range(all().map(|p| p.0));
        let (ylo, yhi) = log_range(all().map(|p| p.1));
        let sx = |v: f64| px0 + (v.log10() - xlo) / (xhi - xlo) * (px1 - px0);
        let sy = |v: f64| py1 - (v.log10() - ylo) / (yhi - ylo) * (py1 - py0);
        if panels.len() > 1 || !panel.title.is_empty() {
            let _ = writeln!(s, "<text x=\"{px0}\" y=\"{:.1}\" font-size=\"13\" font-weight=\"bold\">{}</text>", py0 - 8.0, esc(&panel.title));
        }
        // Grid and ticks.
        for (v, lab) in log_ticks(xlo, xhi) {
            let x = sx(v);
            let (stroke, sw) = if lab { ("#d0d0d0", 1.0) } else { ("#eeeeee", 0.8) };
            let _ = writeln!(s, "<line x1=\"{x:.1}\" y1=\"{py0}\" x2=\"{x:.1}\" y2=\"{py1}\" stroke=\"{stroke}\" stroke-width=\"{sw}\"/>");
            let _ = writeln!(s, "<line x1=\"{x:.1}\" y1=\"{py1}\" x2=\"{x:.1}\" y2=\"{:.1}\" stroke=\"#333\"/>", py1 + if lab { 6.0 } else { 3.0 });
            if lab {
                let _ = writeln!(s, "<text x=\"{x:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text>", py1 + 20.0, tick_label(v));
            }
        }
        for (v, lab) in log_ticks(ylo, yhi) {
            let y = sy(v);
            let (stroke, sw) = if lab { ("#d0d0d0", 1.0) } else { ("#eeeeee", 0.8) };
            let _ = writeln!(s, "<line x1=\"{px0}\" y1=\"{y:.1}\" x2=\"{px1}\" y2=\"{y:.1}\" stroke=\"{stroke}\" stroke-width=\"{sw}\"/>");
            let _ = writeln!(s, "<line x1=\"{:.1}\" y1=\"{y:.1}\" x2=\"{px0}\" y2=\"{y:.1}\" stroke=\"#333\"/>", px0 - if lab { 6.0 } else { 3.0 });
            if lab {
                let _ = writeln!(s, "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\">{}</text>", px0 - 9.0, y + 4.0, tick_label(v));
            }
        }
        let _ = writeln!(
            s,
            "<rect x=\"{px0}\" y=\"{py0}\" width=\"{:.1}\" height=\"{:.1}\" fill=\"none\" stroke=\"#333\"/>",
            px1 - px0,
            py1 - py0
        );
        let _ = writeln!(s, "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\" font-size=\"13\">{}</text>", (px0 + px1) / 2.0, py1 + 44.0, esc(xlabel));
        let _ = writeln!(
            s,
            "<text x=\"22\" y=\"{:.1}\" text-anchor=\"middle\" font-size=\"13\" transform=\"rotate(-90 22 {:.1})\">{}</text>",
            (py0 + py1) / 2.0,
            (py0 + py1) / 2.0,
            esc(ylabel)
        );
        if panel.series.iter().all(|s| s.points.is_empty()) {
            let _ = writeln!(
                s,
                "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\" font-size=\"14\" fill=\"#888\">no error figures (metro unavailable)</text>",
                (px0 + px1) / 2.0,
                (py0 + py1) / 2.0
            );
        }
        // Data: lines first, markers on top.
        for se in panel.series.iter().filter(|s| s.join && s.points.len() > 1) {
            let pts: Vec<String> = se.points.iter().map(|p| format!("{:.1},{:.1}", sx(p.0), sy(p.1))).collect();
            let _ = writeln!(
                s,
                "<polyline points=\"{}\" fill=\"none\" stroke=\"{}\" stroke-width=\"1.6\" stroke-opacity=\"0.75\"/>",
                pts.join(" "),
                se.color
            );
        }
        for se in &panel.series {
            for p in &se.points {
                let _ = writeln!(s, "<g><title>{}</title>{}</g>", esc(&p.2), marker_svg(se.marker, sx(p.0), sy(p.1), se.color));
            }
        }
    }
    // One legend: every distinct series label, in first-seen order.
    let mut legend: Vec<&Series> = Vec::new();
    for se in panels.iter().flat_map(|p| p.series.iter()) {
        if !legend.iter().any(|l| l.label == se.label) {
            legend.push(se);
        }
    }
    let lx = px1 + 20.0;
    let mut ly = top + 8.0;
    let _ = writeln!(s, "<text x=\"{lx}\" y=\"{ly}\" font-weight=\"bold\">method</text>");
    ly += 20.0;
    for se in legend {
        let _ = writeln!(s, "<line x1=\"{lx}\" y1=\"{ly:.1}\" x2=\"{:.1}\" y2=\"{ly:.1}\" stroke=\"{}\" stroke-width=\"1.6\"/>", lx + 26.0, se.color);
        let _ = writeln!(s, "{}", marker_svg(se.marker, lx + 13.0, ly, se.color));
        let _ = writeln!(s, "<text x=\"{:.1}\" y=\"{:.1}\">{}</text>", lx + 34.0, ly + 4.0, esc(&se.label));
        ly += 20.0;
    }
    ly += 10.0;
    let mut notes = wrap(note, 44);
    notes.push(String::new());
    let joined = if panels.iter().flat_map(|p| &p.series).all(|s| s.join) { "lines join one method's outputs, largest first; " } else { "" };
    notes.extend(wrap(&format!("{joined}colour: method, shape: octolod setting"), 44));
    if panels.len() > 1 {
        notes.push(String::new());
        notes.extend(wrap("one panel per input, each scaled to its own data", 44));
    }
    for line in notes {
        if !line.is_empty() {
            let _ = writeln!(s, "<text x=\"{lx}\" y=\"{ly:.1}\" font-size=\"11\" fill=\"#555\">{}</text>", esc(&line));
        }
        ly += if line.is_empty() { 6.0 } else { 14.0 };
    }
    s.push_str("</svg>\n");
    s
}

fn wrap(text: &str, width: usize) -> Vec<String> {
    let mut lines = Vec::new();
    let mut cur = String::new();
    for word in text.split_whitespace() {
        if !cur.is_empty() && cur.len() + 1 + word.len() > width {
            lines.push(std::mem::take(&mut cur));
        }
        if !cur.is_empty() {
            cur.push(' ');
        }
        cur.push_str(word);
    }
    if !cur.is_empty() {
        lines.push(cur);
    }
    lines
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_round_trip_and_loose_metro() {
        let j = obj([("a", 1.5.into()), ("b", J::Arr(vec![J::Null, true.into(), "x\"y".into()])), ("n", 3u64.into())]);
        assert_eq!(J::parse(&j.to_string()).unwrap(), j);
        assert_eq!(J::parse(&j.pretty()).unwrap(), j);
        let raw = J::parse(
            r#"{"a_to_b":{"max":0.5,"rms":0.1},"b_to_a":{"max":0.7,"rms":0.2},"combined":{"max":0.7,"mean":0.05,"rms":0.15},"hausdorff":0.7}"#,
        )
        .unwrap();
        let m = parse_metro(raw, 0.0).unwrap();
        assert_eq!((m.rms, m.max, m.mean), (0.15, 0.7, Some(0.05)));
        let m = parse_metro(J::parse(r#"{"forward":{"hausdorff":2,"rms":1},"backward":{"hausdorff":3,"rms":0.5}}"#).unwrap(), 0.0).unwrap();
        assert_eq!((m.rms, m.max), (1.0, 3.0));
    }

    #[test]
    fn oocs_hits_target_and_keeps_no_degenerates() {
        let g = octolod::gen::Generator::new(&GenOptions { shape: Shape::Sphere, tris: 20_000, seed: 1, attrs: AttrSet::POSITION_ONLY });
        let (v, f) = g.mesh();
        let mut bbox = Aabb::EMPTY;
        v.iter().for_each(|x| bbox.add(x.pos));
        let r = oocs(&v, &f, &bbox, 2000);
        let n = r.triangles.len() as f64;
        assert!((1000.0..4000.0).contains(&n), "{n}");
        for t in &r.triangles {
            assert!(t[0] != t[1] && t[1] != t[2] && t[0] != t[2]);
        }
        // Representatives stay near the unit-ish sphere.
        for x in &r.vertices {
            let rad = (x.pos[0].powi(2) + x.pos[1].powi(2) + x.pos[2].powi(2)).sqrt();
            assert!((0.8..1.2).contains(&rad), "{rad}");
        }
    }

    /// `--from-json` gives back the report the run wrote.
    #[test]
    fn report_json_reads_back() {
        let meta = Meta {
            generated: "2026-01-01 00:00 UTC".into(),
            command: "octolod-bench x.ply".into(),
            cpu: "cpu".into(),
            threads: 2,
            mem_gib: 8.0,
            metro_bin: Some(PathBuf::from("octolod")),
            metro_note: String::new(),
            samples: Some(1000),
            repeat: 2,
            mem: "512M".into(),
            settings: vec!["16384x8".into()],
            min_tris: 500,
            wait_idle: 0.0,
            suffix: "-t".into(),
            label: Some("commit x".into()),
            rerendered: None,
        };
        let info = InputInfo {
            path: "x.ply".into(),
            name: "x".into(),
            bytes: 100,
            vertices: 50,
            triangles: 96,
            diagonal: 2.0,
            attrs: "position(f32)".into(),
            scan_seconds: 0.1,
        };
        let metro = J::parse(r#"{"combined":{"max":0.2,"mean":0.05,"rms":0.1},"samples_target":1000}"#).unwrap();
        let row = |method, setting: &str, level, target, child: J| Row {
            input: 0,
            method,
            setting: setting.into(),
            level,
            target,
            triangles: 40,
            vertices: 22,
            path: "o.ply".into(),
            seconds: 0.5,
            load_seconds: target.map(|_| 0.1),
            throughput: 96.0 / 0.5 / 1e6,
            rss_mib: 30.0,
            err: parse_metro(metro.clone(), 0.3),
            err_note: None,
            child,
        };
        let build = obj([("leaf_tris", 16384u64.into()), ("level_ratio", 8u32.into()), ("seconds", 0.5.into()), ("other_cpu_cores", 0.1.into())]);
        let rows = vec![
            row(Method::Octolod, "16384x8", Some(1), None, J::Null),
            row(Method::Oocs, "", None, Some(40), obj([("grid", 7u32.into()), ("other_cpu_cores", 0.0.into())])),
        ];
        let builds = vec![(0, "16384x8".to_string(), build)];
        let sweep = vec![SweepRow {
            label: "+uv".into(),
            attrs: AttrSet(AttrSet::UV),
            triangles: 96,
            ply_bytes: 200,
            child: obj([("seconds", 0.2.into())]),
        }];
        let md = report_md(&meta, &[info], &rows, &builds, &sweep, &[]);
        let info = InputInfo { path: "x.ply".into(), name: "x".into(), bytes: 100, vertices: 50, triangles: 96, diagonal: 2.0, attrs: "position(f32)".into(), scan_seconds: 0.1 };
        let j = J::parse(&report_json(&meta, &[info], &rows, &builds, &sweep, &[]).pretty()).unwrap();
        let r = read_report(&j, "-t", None).unwrap();
        assert_eq!(report_md(&r.meta, &r.inputs, &r.rows, &r.builds, &r.sweep, &r.failures), md);
        assert!(md.contains("| oocs | target 40 (grid 7) | 40 |"), "{md}");
        assert!(md.contains("![RMS error vs throughput](error_vs_speed-t.svg)"));
    }

    #[test]
    fn log_axis_ticks() {
        let t = log_ticks(-3.2, -0.9);
        assert!(t.iter().any(|&(v, l)| (v - 1e-3).abs() < 1e-12 && l));
        assert!(t.iter().any(|&(v, l)| (v - 2e-2).abs() < 1e-12 && l));
        assert_eq!(tick_label(0.002), "0.002");
        assert_eq!(tick_label(2e-5), "2e-5");
        assert_eq!(tick_label(20000.0), "20,000");
        assert_eq!(canonical([5, 1, 3]), [1, 3, 5]);
        assert_eq!(canonical([3, 5, 1]), [1, 3, 5]);
        assert_eq!(canonical([1, 5, 3]), [1, 5, 3]);
    }
}
