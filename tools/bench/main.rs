//! `octolod-bench`: a speed-against-error report of octolod against in-core
//! peers, every method run on the same inputs in one run on one machine.
//!
//! Build and run (the `peers` feature pulls in meshoptimizer's C++, so plain
//! builds and CI never compile it):
//!
//! ```sh
//! cargo build --release --bin octolod   # provides `octolod metro` and `simplify`
//! cargo run --release --features peers --bin octolod-bench -- IN.ply [IN2.ply ...] \
//!     --out out/bench-report [--samples 200000] [--repeat 3] [--attr-sweep 2000000]
//! ```
//!
//! Takes: indexed PLYs; octolod settings (`--settings LEAFxRATIO[:collapse],...`,
//! default `16384x2,65536x2`; `:collapse` builds with `--simplifier collapse`)
//! and budget (`--mem`); optionally a Python with pymeshlab (`--meshlab`); a metro sample count
//! (`--samples`, default metro's own: 10 × the larger face count).
//!
//! Gives, under `--out`: `report.md` (tables), `report.json` (every raw
//! number, including each child's and each metro run's own JSON; the
//! typed layout is [`types::Report`]),
//! `error_vs_speed.svg` and `error_vs_size.svg` (log–log, hand-made SVG, one
//! panel per input), and per input a folder holding every output mesh
//! (`--clean` deletes them). `--levels 4,7,10` measures only those octolod
//! levels (and runs the peers and simplifiers at their sizes only).
//! `--suffix -10m` names the four files `report-10m.md` and so on; `--label TEXT` adds a line saying what was
//! measured (the commit, say), and the header lists every `--baseline` (label, binary, `--version`); `--from-json report.json` measures nothing
//! and writes the report and plots again from an earlier run's JSON (for
//! changes to the layout).
//!
//! The machine may be shared. Every child measures how many cores other
//! processes kept busy during its timed section (the machine's busy time
//! from `/proc/stat` minus its own CPU time, over the wall time; see
//! [`runners::CpuProbe`]), and the report gives it per row and in summary;
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
//!   quadric clustering in one pass (implemented here, see [`oocs::oocs`]). It runs
//!   on the loaded mesh, so its peak RSS is an in-core one (Lindstrom streams
//!   a triangle soup and holds only the grid).
//! - `meshlab-qec` (with `--meshlab PYTHON`): MeshLab's quadric edge
//!   collapse (`meshing_decimation_quadric_edge_collapse`, MeshLab's
//!   defaults: optimal placement, quality threshold 0.3), the reference
//!   edge collapse, run by `meshlab_qec.py` in that interpreter. Its load
//!   and filter are timed apart, as for the peers above; peak RSS is the
//!   interpreter's whole `ru_maxrss`. Such a Python:
//!   `python3 -m venv out/venv-meshlab && out/venv-meshlab/bin/pip install
//!   pymeshlab` (the venv `tools/metro-crosscheck.sh` makes and reuses).
//! - `octolod-collapse`, `octolod-cluster`: the `octolod` binary's
//!   `simplify IN -o OUT --target-tris N --simplifier collapse|cluster
//!   --json` (build setting: the first of `--settings`, budget `--mem`),
//!   spawned by the child and timed whole (PLY in, store in a scratch
//!   folder, reduce, PLY out); peak RSS is its `ru_maxrss` from `wait4`.
//!   Run at the same targets as the peers (`--no-simplify` skips them).
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
//! or `--octolod PATH`), run for every output; its JSON is read into
//! [`types::MetroJson`] and the `combined` figures (both directions
//! together) are divided by the input's bounding-box diagonal. Without a
//! working `metro`, errors are "n/a" and everything else is still measured.
//!
//! - `octolod @LABEL` (with `--baseline LABEL=BIN`, repeatable): every
//!   setting built again by an older octolod executable BIN (a release
//!   binary built from another commit), through its command line: `BIN
//!   build` timed whole by the wall clock (process start and its output
//!   included), peak RSS its `ru_maxrss`, the phase times, nodes and store
//!   size read from the summary line it prints; then `BIN extract STORE
//!   --level L` per level. Its levels are rows like the current build's
//!   (setting `16384x2 @LABEL`), measured by the same metro; the report
//!   adds a "Current ÷ baseline" table per input. The peers and `octolod
//!   simplify` run at the current build's sizes only.
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
//!
//! Layout: `main.rs` (command line), `driver.rs` (the parent: children,
//! metro, collecting), `runners.rs` (the child side and the `/proc`
//! probes), `oocs.rs` (the OOCS baseline), `types.rs` (every JSON read or
//! written), `report.rs` (Markdown), `plot.rs` (SVG).

mod driver;
mod oocs;
mod plot;
mod report;
mod runners;
mod types;

use anyhow::{anyhow, Context, Result};
use clap::{Parser, Subcommand};
use std::path::PathBuf;
use types::Method;

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
pub struct BenchArgs {
    /// Input PLYs (indexed triangle meshes).
    pub inputs: Vec<PathBuf>,
    /// Report folder.
    #[arg(long, default_value = "out/bench-report")]
    pub out: PathBuf,
    /// Metro samples per direction (default: metro's, 10 × the larger face count).
    #[arg(long, value_parser = parse_count)]
    pub samples: Option<u64>,
    /// octolod settings, LEAF_TRISxLEVEL_RATIO[:collapse], comma separated
    /// (`:collapse`: `build --simplifier collapse`; default cluster).
    #[arg(long, default_value = "16384x2,65536x2", value_delimiter = ',')]
    pub settings: Vec<String>,
    /// octolod memory budget.
    #[arg(long, default_value = "512M")]
    pub mem: String,
    /// octolod binary providing `metro` and `simplify` (default: `octolod` next to this executable).
    #[arg(long)]
    pub octolod: Option<PathBuf>,
    /// A Python interpreter with pymeshlab: adds MeshLab's quadric edge
    /// collapse (`meshlab-qec`) as a peer. Absent: that peer is not run.
    #[arg(long, value_name = "PYTHON")]
    pub meshlab: Option<PathBuf>,
    /// Skip metro (errors are n/a).
    #[arg(long)]
    pub no_metro: bool,
    /// octolod outputs smaller than this are not matched by peers nor measured.
    #[arg(long, default_value_t = 500)]
    pub min_tris: u64,
    /// Measure only these octolod levels (comma separated; default: every
    /// level of at least --min-tris); peers and simplifiers run at their sizes.
    #[arg(long, value_delimiter = ',')]
    pub levels: Vec<u8>,
    /// Skip the `octolod simplify` runs (collapse, cluster).
    #[arg(long)]
    pub no_simplify: bool,
    /// Also run the attribute sweep on a generated sphere of this many triangles.
    #[arg(long, value_parser = parse_count)]
    pub attr_sweep: Option<u64>,
    /// Run every method this many times and keep the fastest run (peak RSS: the largest).
    #[arg(long, default_value_t = 1)]
    pub repeat: u32,
    /// Delete output meshes once measured.
    #[arg(long)]
    pub clean: bool,
    /// Before each timed child run, wait (at most this many seconds) until
    /// other processes use less than a quarter of a core; 0: do not wait.
    #[arg(long, default_value_t = 0.0)]
    pub wait_idle: f64,
    /// Suffix for the report's file names (`report-10m.md`,
    /// `error_vs_speed-10m.svg`, ...), so reports can sit side by side.
    #[arg(long, default_value = "", allow_hyphen_values = true)]
    pub suffix: String,
    /// A line for the report saying what was measured (e.g. the commit the
    /// binaries were built from).
    #[arg(long)]
    pub label: Option<String>,
    /// An older octolod executable to compare with: for every setting it
    /// also builds through its command line (`BIN build`, `BIN extract`),
    /// and its levels are measured and reported as setting `LEAFxRATIO
    /// @LABEL`. May be given more than once.
    #[arg(long, value_name = "LABEL=BIN", value_parser = parse_baseline)]
    pub baseline: Vec<Baseline>,
    /// Measure nothing: re-render report.md and the plots (into --out, with
    /// --suffix) from a report.json this tool wrote earlier.
    #[arg(long, value_name = "REPORT_JSON")]
    pub from_json: Option<PathBuf>,
    /// No progress lines on stderr.
    #[arg(long, short)]
    pub quiet: bool,
}

#[derive(Subcommand)]
enum Child {
    /// Internal: run one method in this process, print one JSON line.
    #[command(hide = true)]
    RunOne(RunOne),
}

#[derive(clap::Args, Clone)]
pub struct RunOne {
    #[arg(long, value_enum)]
    pub method: Method,
    /// Output triangle count (peers).
    #[arg(long, default_value_t = 0)]
    pub target: u64,
    #[arg(long, default_value_t = 16384)]
    pub leaf_tris: u64,
    #[arg(long, default_value_t = 2)]
    pub level_ratio: u32,
    /// octolod: the node simplifier (`cluster` or `collapse`).
    #[arg(long, default_value = "cluster")]
    pub simplifier: octolod::manifest::Simplifier,
    #[arg(long, default_value = "512M")]
    pub mem: String,
    /// `meshlab-qec`: the Python interpreter with pymeshlab.
    #[arg(long)]
    pub python: Option<PathBuf>,
    /// `octolod` binary for the `octolod-collapse`/`octolod-cluster` methods.
    #[arg(long)]
    pub octolod: Option<PathBuf>,
    /// octolod: build only, extract nothing.
    #[arg(long)]
    pub no_extract: bool,
    /// octolod: build with this executable through its command line
    /// instead of the library (`--baseline` of the bench).
    #[arg(long, value_name = "LABEL=BIN", value_parser = parse_baseline)]
    pub baseline: Option<Baseline>,
    pub input: PathBuf,
    /// Output PLY; for octolod a prefix (level L goes to PREFIX-L<L>.ply).
    pub output: PathBuf,
}

pub fn parse_count(s: &str) -> std::result::Result<u64, String> {
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

/// One octolod build setting: leaf triangles, level ratio, node simplifier.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Setting {
    pub leaf: u64,
    pub ratio: u32,
    pub simplifier: octolod::manifest::Simplifier,
}

/// `LEAFxRATIO[:SIMPLIFIER]` → a [`Setting`] (default simplifier: cluster).
pub fn parse_setting(s: &str) -> Result<Setting> {
    let (size, simplifier) = match s.trim().split_once(':') {
        Some((a, b)) => (a, b.trim().parse().map_err(|e: String| anyhow!("setting {s:?}: {e}"))?),
        None => (s.trim(), octolod::manifest::Simplifier::Cluster),
    };
    let (a, b) = size.split_once(['x', 'X']).ok_or_else(|| anyhow!("setting {s:?} is not LEAF_TRISxLEVEL_RATIO[:SIMPLIFIER]"))?;
    Ok(Setting { leaf: parse_count(a).map_err(|e| anyhow!(e))?, ratio: b.trim().parse().with_context(|| format!("level ratio in {s:?}"))?, simplifier })
}

/// A setting's text: `LEAFxRATIO`, with `:collapse` for collapse builds.
pub fn setting_name(leaf: u64, ratio: u32, simplifier: octolod::manifest::Simplifier) -> String {
    match simplifier {
        octolod::manifest::Simplifier::Cluster => format!("{leaf}x{ratio}"),
        s => format!("{leaf}x{ratio}:{}", s.name()),
    }
}

/// A baseline build's setting text: the setting, then ` @LABEL`
/// (`16384x2:collapse @before`).
pub fn baseline_setting(setting: &str, label: &str) -> String {
    format!("{setting} @{label}")
}

/// `--baseline LABEL=BIN`: an older octolod executable and the label its
/// rows carry.
#[derive(Clone, Debug, PartialEq)]
pub struct Baseline {
    pub label: String,
    pub bin: PathBuf,
}

impl std::fmt::Display for Baseline {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        write!(f, "{}={}", self.label, self.bin.display())
    }
}

/// `LABEL=BIN` → a [`Baseline`]. The label names rows and output files, so
/// it is letters, digits, `.`, `_` and `-` only (no spaces, no `@`).
pub fn parse_baseline(s: &str) -> std::result::Result<Baseline, String> {
    let (label, bin) = s.split_once('=').ok_or_else(|| format!("--baseline {s:?} is not LABEL=BIN (e.g. before=/tmp/octolod-1f786c3)"))?;
    let label = label.trim();
    if label.is_empty() {
        return Err(format!("--baseline {s:?}: empty label"));
    }
    if let Some(c) = label.chars().find(|c| !(c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-'))) {
        return Err(format!("--baseline {s:?}: the label may hold letters, digits, '.', '_' and '-' only, not {c:?}"));
    }
    if bin.trim().is_empty() {
        return Err(format!("--baseline {s:?}: empty binary path"));
    }
    Ok(Baseline { label: label.to_string(), bin: PathBuf::from(bin) })
}

fn main() {
    // As `octolod`'s main does, so a library build in a `run-one` child
    // holds the memory the `octolod build` command would (and compares
    // with a `--baseline` binary's): without the cap, glibc's extra arenas
    // kept freed buffers resident, 44-51 MiB against the command's 32-34
    // on a 100 K scan.
    octolod::mem::limit_arenas();
    let cli = Cli::parse();
    let r = match cli.child {
        Some(Child::RunOne(a)) => runners::run_one(&a).map(|j| println!("{j}")),
        None => driver::bench(&cli.bench),
    };
    if let Err(e) = r {
        eprintln!("octolod-bench: error: {e:#}");
        std::process::exit(1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use octolod::manifest::Simplifier;

    /// Settings name their simplifier after a colon (default cluster), and
    /// read back from the name a build reports.
    #[test]
    fn settings_parse_with_their_simplifier() {
        let s = parse_setting("16k x2").unwrap();
        assert_eq!(s, Setting { leaf: 16000, ratio: 2, simplifier: Simplifier::Cluster });
        let c = parse_setting("16384x2:collapse").unwrap();
        assert_eq!(c, Setting { leaf: 16384, ratio: 2, simplifier: Simplifier::Collapse });
        assert_eq!(setting_name(c.leaf, c.ratio, c.simplifier), "16384x2:collapse");
        assert_eq!(setting_name(16384, 2, Simplifier::Cluster), "16384x2");
        assert_eq!(parse_setting(&setting_name(16384, 4, Simplifier::Collapse)).unwrap().ratio, 4);
        assert!(parse_setting("16384x2:grid").is_err());
        assert!(parse_setting("16384").is_err());
    }

    /// `--baseline LABEL=BIN`: the label before the first `=`, a path after;
    /// a missing `=`, an empty label or path, and labels that would not
    /// read back from a row's setting or name a file are refused.
    #[test]
    fn baselines_parse() {
        let b = parse_baseline("before=/tmp/octolod-1f786c3").unwrap();
        assert_eq!(b, Baseline { label: "before".into(), bin: "/tmp/octolod-1f786c3".into() });
        assert_eq!(b.to_string(), "before=/tmp/octolod-1f786c3");
        // Only the first `=` splits: a path may hold one.
        assert_eq!(parse_baseline("v1.2_rc-3=/opt/a=b/octolod").unwrap().bin, PathBuf::from("/opt/a=b/octolod"));
        assert_eq!(parse_baseline(" old =bin").unwrap().label, "old");
        for bad in ["/tmp/octolod", "=/tmp/octolod", " =/tmp/octolod", "my build=/tmp/octolod", "a@b=/x", "a/b=/x", "old=", "old= "] {
            assert!(parse_baseline(bad).is_err(), "{bad:?} accepted");
        }
        assert!(parse_baseline("/tmp/octolod").unwrap_err().contains("LABEL=BIN"));
        assert!(parse_baseline("my build=/x").unwrap_err().contains("' '"));
        assert_eq!(baseline_setting(&setting_name(16384, 2, Simplifier::Collapse), "before"), "16384x2:collapse @before");
        // On the command line, repeated.
        let cli = Cli::try_parse_from(["octolod-bench", "x.ply", "--baseline", "a=/bin/a", "--baseline", "b=/bin/b"]).unwrap();
        assert_eq!(cli.bench.baseline.iter().map(|b| b.label.as_str()).collect::<Vec<_>>(), ["a", "b"]);
        assert!(Cli::try_parse_from(["octolod-bench", "x.ply", "--baseline", "/bin/a"]).is_err());
    }
}
