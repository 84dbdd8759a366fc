//! The typed JSON the tool reads and writes: what a `run-one` child prints,
//! what `octolod metro --json` and `octolod simplify --json` print, and
//! `report.json`, which `--from-json` reads back. Field names are those of
//! the reports written before these types existed, so old reports still
//! read back; fields added since default when absent.
//!
//! Numbers that may be non-finite are written as `null` (JSON has no NaN)
//! and read back as NaN (see [`nullable`]).

use clap::ValueEnum;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// How an output mesh was made.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// `pipeline::build_store` per setting, every level extracted.
    Octolod,
    /// meshoptimizer's edge-collapse `simplify`, in core.
    MeshoptSimplify,
    /// meshoptimizer's grid `simplify_sloppy`, in core.
    MeshoptSloppy,
    /// Lindstrom's OOCS (uniform-grid quadric clustering), see `oocs.rs`.
    Oocs,
    /// MeshLab's quadric edge collapse (pymeshlab), in core, when
    /// `--meshlab PYTHON` is given.
    MeshlabQec,
    /// `octolod simplify --simplifier collapse`, the whole command.
    OctolodCollapse,
    /// `octolod simplify --simplifier cluster`, the whole command.
    OctolodCluster,
}

impl Method {
    pub fn name(self) -> &'static str {
        match self {
            Method::Octolod => "octolod",
            Method::MeshoptSimplify => "meshopt-simplify",
            Method::MeshoptSloppy => "meshopt-sloppy",
            Method::Oocs => "oocs",
            Method::MeshlabQec => "meshlab-qec",
            Method::OctolodCollapse => "octolod-collapse",
            Method::OctolodCluster => "octolod-cluster",
        }
    }
    /// In-core peers, run at every octolod output size.
    pub const PEERS: [Method; 4] = [Method::MeshoptSimplify, Method::MeshoptSloppy, Method::Oocs, Method::MeshlabQec];
    /// `octolod simplify`, run at the same sizes as the peers.
    pub const SIMPLIFIERS: [Method; 2] = [Method::OctolodCollapse, Method::OctolodCluster];
    /// The `--simplifier` value of an `octolod simplify` method.
    pub fn simplifier(self) -> Option<&'static str> {
        match self {
            Method::OctolodCollapse => Some("collapse"),
            Method::OctolodCluster => Some("cluster"),
            _ => None,
        }
    }
    /// The meshoptimizer peer a simplifier is judged against (issue 10:
    /// `collapse` against `simplify`, `cluster` against `simplify_sloppy`).
    pub fn counterpart(self) -> Option<Method> {
        match self {
            Method::OctolodCollapse => Some(Method::MeshoptSimplify),
            Method::OctolodCluster => Some(Method::MeshoptSloppy),
            _ => None,
        }
    }
}

/// `f64` fields written as `null` when not finite and read back as NaN.
pub mod nullable {
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(x: &f64, s: S) -> Result<S::Ok, S::Error> {
        if x.is_finite() {
            s.serialize_f64(*x)
        } else {
            s.serialize_none()
        }
    }
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
    }
}

fn cluster() -> octolod::manifest::Simplifier {
    octolod::manifest::Simplifier::Cluster
}

fn nan() -> f64 {
    f64::NAN
}

/// An `Option<f64>` that is `None` for a non-finite value.
pub fn finite(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

// ---------------------------------------------------------------------------
// What the children print.

/// Timing and memory fields of every child's JSON line; the parent adds
/// the `*_all_runs` lists after `--repeat` and sets `peak_rss_mib` to the
/// largest of the runs.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Timed {
    /// The timed section, wall seconds (of the fastest run).
    #[serde(with = "nullable", default = "nan")]
    pub seconds: f64,
    /// Peak RSS (`VmHWM`, or the child's `ru_maxrss`), MiB.
    #[serde(with = "nullable", default = "nan")]
    pub peak_rss_mib: f64,
    /// Mean cores other processes kept busy during the timed section.
    #[serde(default)]
    pub other_cpu_cores: Option<f64>,
    /// The whole child process, wall seconds.
    #[serde(with = "nullable", default = "nan")]
    pub child_seconds: f64,
    /// `seconds` of every run (`--repeat`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub seconds_all_runs: Vec<Option<f64>>,
    /// `other_cpu_cores` of every run.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub other_cpu_cores_all_runs: Vec<Option<f64>>,
    /// Seconds each run waited for an idle machine (`--wait-idle`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub idle_wait_seconds_all_runs: Vec<f64>,
}

/// A child's JSON line, whatever the method.
pub trait ChildOut: serde::de::DeserializeOwned {
    fn timed(&mut self) -> &mut Timed;
}

/// One level an octolod build extracted.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct LevelOut {
    pub level: u8,
    pub triangles: u64,
    pub vertices: u64,
    /// Nodes on the level.
    pub nodes: Option<u64>,
    /// The largest error bound of the level's nodes (object space).
    pub error_bound_max: Option<f64>,
    /// The extracted (welded) PLY.
    pub path: PathBuf,
}

/// What an octolod build child prints (`run-one --method octolod`).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct BuildOut {
    /// Always `octolod`.
    pub method: Method,
    pub leaf_tris: u64,
    /// Reports of the single-hierarchy builds (before levels that halve)
    /// called the setting's second number `cluster_grid`.
    #[serde(alias = "cluster_grid")]
    pub level_ratio: u32,
    /// The node simplifier (reports before it was a setting: cluster).
    #[serde(default = "cluster")]
    pub simplifier: octolod::manifest::Simplifier,
    /// `--mem`, bytes.
    pub mem: u64,
    pub input_triangles: u64,
    /// The input's attributes, e.g. `position(f32)`.
    pub attributes: String,
    pub quadric_dim: u64,
    #[serde(with = "nullable", default = "nan")]
    pub soup_seconds: f64,
    #[serde(with = "nullable", default = "nan")]
    pub octree_seconds: f64,
    #[serde(with = "nullable", default = "nan")]
    pub simplify_seconds: f64,
    /// The soup took the external (out-of-core) path (`None`: a baseline
    /// build, which does not say).
    pub soup_external: Option<bool>,
    /// Nodes, level-0 nodes (leaves) and the octree's depth; `None` where a
    /// baseline's summary line did not give them.
    pub nodes: Option<u64>,
    pub leaves: Option<u64>,
    pub deepest: Option<u32>,
    /// The store's size on disk.
    pub disk_bytes: Option<u64>,
    /// Peak RSS after extracting every level, MiB (`peak_rss_mib` is read
    /// before extraction; baseline: the largest of the build's and the
    /// extract commands' `ru_maxrss`).
    #[serde(with = "nullable", default = "nan")]
    pub peak_rss_with_extract_mib: f64,
    /// Empty with `--no-extract`.
    pub levels: Vec<LevelOut>,
    /// `--baseline LABEL=BIN`: the label, when an older octolod executable
    /// built this through its command line (absent: this bench's library).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub baseline: Option<String>,
    /// Baseline: the build command run, and the total seconds its summary
    /// line reported (its own timing, without process start and exit).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub command: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reported_total_seconds: Option<f64>,
    #[serde(flatten)]
    pub timed: Timed,
}

impl BuildOut {
    /// `LEAFxRATIO`, with `:collapse` for collapse builds and ` @LABEL`
    /// for a baseline's.
    pub fn setting(&self) -> String {
        let s = self.plain_setting();
        match &self.baseline {
            Some(l) => crate::baseline_setting(&s, l),
            None => s,
        }
    }
    /// The setting without a baseline's label.
    pub fn plain_setting(&self) -> String {
        crate::setting_name(self.leaf_tris, self.level_ratio, self.simplifier)
    }
}

impl ChildOut for BuildOut {
    fn timed(&mut self) -> &mut Timed {
        &mut self.timed
    }
}

/// What `octolod simplify --json` prints.
pub type SimplifyJson = octolod::simplify::SimplifyReport;

/// What a one-output child prints: a peer (`meshopt-*`, `oocs`) or an
/// `octolod simplify` run. Fields of other methods are absent.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RunOut {
    pub method: Method,
    /// Triangles asked.
    pub target: u64,
    pub input_triangles: u64,
    /// Loading the input (peers; `octolod simplify` loads inside its time).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub load_seconds: Option<f64>,
    pub triangles: u64,
    pub vertices: u64,
    pub path: PathBuf,
    /// Peers: peak RSS after loading, and of the simplification alone
    /// (`VmHWM` restarted after the load; `None` where Linux refused).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub peak_rss_load_mib: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub peak_rss_simplify_mib: Option<f64>,
    /// meshopt: the error meshopt reports (relative to the mesh extent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub meshopt_result_error: Option<f64>,
    /// meshopt `simplify`: the attributes it weighed
    /// (`simplifyWithAttributes`), when the input has uvs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub meshopt_attributes: Option<String>,
    /// meshlab-qec: the filter and its parameters, as the script ran it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub meshlab_filter: Option<String>,
    /// oocs: cells along the longest side, cells per axis, occupied cells,
    /// representatives clamped to their cell, and the untimed grid search.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grid: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grid_dims: Option<[u64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cells: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub clamped: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub search_seconds: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub search_tries: Option<u64>,
    /// `octolod simplify`: the command run, its exit status (3: target not
    /// met, the closest mesh written) and its `--json` report.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub command: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exit_code: Option<i32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub simplify: Option<SimplifyJson>,
    #[serde(flatten)]
    pub timed: Timed,
}

impl RunOut {
    /// A run's common fields; every method's own are absent (set them with
    /// struct update syntax).
    pub fn new(method: Method, target: u64, input_triangles: u64, triangles: u64, vertices: u64, path: PathBuf, timed: Timed) -> RunOut {
        RunOut {
            method,
            target,
            input_triangles,
            load_seconds: None,
            triangles,
            vertices,
            path,
            peak_rss_load_mib: None,
            peak_rss_simplify_mib: None,
            meshopt_result_error: None,
            meshopt_attributes: None,
            meshlab_filter: None,
            grid: None,
            grid_dims: None,
            cells: None,
            clamped: None,
            search_seconds: None,
            search_tries: None,
            command: None,
            exit_code: None,
            simplify: None,
            timed,
        }
    }
}

impl ChildOut for RunOut {
    fn timed(&mut self) -> &mut Timed {
        &mut self.timed
    }
}

// ---------------------------------------------------------------------------
// `octolod metro --json`: the library's own typed report, read back.

/// `octolod metro A B --json` (A: the input, B: an output).
pub type MetroJson = octolod::metro::JsonReport;

// ---------------------------------------------------------------------------
// report.json.

/// Where and by what a report was measured.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct MachineJson {
    pub cpu: String,
    pub threads: usize,
    #[serde(with = "nullable", default = "nan")]
    pub mem_gib: f64,
}

/// One measured output mesh.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Row {
    pub method: Method,
    /// `16384x2` for octolod levels (`16384x2 @LABEL` for a baseline's),
    /// empty otherwise.
    #[serde(default)]
    pub setting: String,
    /// An octolod level built by `--baseline LABEL=BIN`: the label.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub baseline: Option<String>,
    /// octolod: the level.
    pub level: Option<u8>,
    /// Peers and `octolod simplify`: the triangles asked (an octolod
    /// output's count).
    pub target: Option<u64>,
    pub triangles: u64,
    pub vertices: u64,
    pub path: PathBuf,
    /// octolod: the whole build; peers: the simplification alone;
    /// `octolod simplify`: the whole command.
    #[serde(with = "nullable")]
    pub seconds: f64,
    /// Peers: loading the input.
    pub load_seconds: Option<f64>,
    /// M input triangles per second of `seconds`.
    #[serde(rename = "throughput_mtris_per_s", with = "nullable")]
    pub throughput: f64,
    #[serde(rename = "peak_rss_mib", with = "nullable")]
    pub rss_mib: f64,
    /// metro's combined (two-sided) figures, object space.
    pub rms: Option<f64>,
    pub hausdorff: Option<f64>,
    pub mean: Option<f64>,
    /// The same over the input's bounding-box diagonal.
    pub rms_rel_diag: Option<f64>,
    pub hausdorff_rel_diag: Option<f64>,
    /// Which metro figures these are.
    pub error_figures: Option<String>,
    /// Why there are none.
    pub error_note: Option<String>,
    pub metro_seconds: Option<f64>,
    /// metro's whole report.
    pub metro: Option<MetroJson>,
    /// The child's report: its level for octolod, its run otherwise.
    pub child: RowChild,
}

/// What a row's child reported.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(untagged)]
pub enum RowChild {
    /// An octolod level (the build is in `builds`).
    Level(LevelOut),
    /// A peer's or `octolod simplify`'s run.
    Run(Box<RunOut>),
}

impl Row {
    /// A row not yet measured by metro: its output, the run's time and
    /// memory against the input's `n_in` triangles, its child's report
    /// (set the method's own fields with struct update syntax).
    pub fn unmeasured(method: Method, triangles: u64, vertices: u64, path: PathBuf, timed: &Timed, n_in: f64, child: RowChild) -> Row {
        Row {
            method,
            setting: String::new(),
            baseline: None,
            level: None,
            target: None,
            triangles,
            vertices,
            path,
            seconds: timed.seconds,
            load_seconds: None,
            throughput: n_in / timed.seconds / 1e6,
            rss_mib: timed.peak_rss_mib,
            rms: None,
            hausdorff: None,
            mean: None,
            rms_rel_diag: None,
            hausdorff_rel_diag: None,
            error_figures: None,
            error_note: None,
            metro_seconds: None,
            metro: None,
            child,
        }
    }

    /// metro's combined (RMS, Hausdorff), object space, when measured.
    pub fn err(&self) -> Option<(f64, f64)> {
        Some((self.rms?, self.hausdorff?))
    }
    pub fn run(&self) -> Option<&RunOut> {
        match &self.child {
            RowChild::Run(r) => Some(r),
            RowChild::Level(_) => None,
        }
    }
    /// Other processes' CPU use during this row's own run (peers and
    /// `octolod simplify`; an octolod level's is its build's).
    pub fn other_cpu(&self) -> Option<f64> {
        self.run().and_then(|r| r.timed.other_cpu_cores)
    }
}

/// An octolod output or `octolod simplify` run against a peer at the same
/// target (written to the JSON; recomputed, not read, on `--from-json`).
#[derive(Clone, Debug, Serialize)]
pub struct PairJson {
    /// The octolod side's method (`octolod`, `octolod-collapse`, ...).
    pub method: Method,
    pub setting: String,
    pub level: Option<u8>,
    pub triangles: u64,
    pub peer: Method,
    pub peer_triangles: u64,
    pub time_ratio: Option<f64>,
    pub time_ratio_with_load: Option<f64>,
    pub rss_ratio: Option<f64>,
    pub rms_ratio: Option<f64>,
    pub hausdorff_ratio: Option<f64>,
}

/// One input and everything measured on it.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct InputReport {
    pub path: PathBuf,
    /// The file stem.
    pub name: String,
    pub bytes: u64,
    pub vertices: u64,
    pub triangles: u64,
    pub attributes: String,
    #[serde(rename = "bbox_diagonal", with = "nullable")]
    pub diagonal: f64,
    #[serde(with = "nullable", default = "nan")]
    pub scan_seconds: f64,
    /// One octolod build per setting.
    #[serde(default)]
    pub builds: Vec<BuildOut>,
    #[serde(default)]
    pub rows: Vec<Row>,
    #[serde(default, skip_deserializing)]
    pub pairs: Vec<PairJson>,
}

/// One build of `--attr-sweep`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SweepRow {
    /// `position only`, `+uv`, ...
    pub label: String,
    pub attributes: String,
    pub quadric_dim: u64,
    pub triangles: u64,
    pub ply_bytes: u64,
    pub build: BuildOut,
}

/// One `--baseline LABEL=BIN`, as the report records it.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct BaselineJson {
    pub label: String,
    pub bin: PathBuf,
    /// What `BIN --version` printed (first line), if it answers.
    pub version: Option<String>,
}

/// `report<suffix>.json`: every number of a run.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Report {
    /// When it was measured (UTC).
    pub generated: String,
    /// The command line.
    pub command: String,
    /// `--label`.
    pub label: Option<String>,
    /// `--baseline`: older octolod executables built beside this one.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub baselines: Vec<BaselineJson>,
    /// `--from-json`: when and from what the Markdown was re-rendered.
    pub rerendered: Option<String>,
    pub machine: MachineJson,
    /// The `octolod` binary metro ran from, or why metro did not run.
    pub metro: String,
    /// Why metro did not run; `None` when it did.
    pub metro_note: Option<String>,
    /// `--samples`.
    pub samples: Option<u64>,
    pub repeat: u32,
    pub mem: String,
    pub settings: Vec<String>,
    pub min_tris: u64,
    #[serde(default)]
    pub wait_idle: f64,
    /// `--levels`: the only octolod levels measured (empty: all).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub levels: Vec<u8>,
    /// `octolod simplify` runs: the build setting they used (`LEAFxRATIO`),
    /// absent when none ran.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub simplify_setting: Option<String>,
    pub inputs: Vec<InputReport>,
    #[serde(default)]
    pub attr_sweep: Vec<SweepRow>,
    #[serde(default)]
    pub failures: Vec<String>,
    /// `--suffix` of the files (not stored).
    #[serde(skip)]
    pub suffix: String,
}

impl Report {
    /// The `octolod` binary metro ran from, if it did.
    pub fn metro_bin(&self) -> Option<PathBuf> {
        self.metro_note.is_none().then(|| PathBuf::from(&self.metro))
    }
    /// Fills the derived `pairs` of every input.
    pub fn fill_pairs(&mut self) {
        for inp in &mut self.inputs {
            inp.pairs = crate::report::pairs(&inp.rows).iter().chain(&crate::report::simplify_pairs(&inp.rows)).map(|p| p.json()).collect();
        }
    }
}
