//! Parent side: drive the children (`run-one`) and metro, collect a
//! [`Report`], write it (`report.md`, `report.json`, two SVG plots); or
//! read one back (`--from-json`) and write it again.

use crate::runners::wait_idle;
use crate::types::{finite, BaselineJson, BuildOut, ChildOut, InputReport, LevelOut, MachineJson, Method, MetroJson, Report, Row, RowChild, RunOut, SweepRow};
use crate::{baseline_setting, parse_setting, setting_name, Baseline, BenchArgs, Setting};
use anyhow::{anyhow, bail, Context, Result};
use octolod::gen::{GenOptions, Shape};
use octolod::mesh::{Aabb, AttrSet, Vertex};
use octolod::ply::read::{read_body, BodySink};
use octolod::ply::write::PlyWriteOptions;
use octolod::progress::Progress;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

use crate::report::{command_line, now_utc, setting_text, thousands};

/// What the parent knows while it runs.
struct Bench<'a> {
    args: &'a BenchArgs,
    exe: PathBuf,
    /// The `octolod` binary (metro, simplify), if it answers.
    octolod_bin: Option<PathBuf>,
    octolod_note: String,
    metro_bin: Option<PathBuf>,
    metro_note: String,
}

impl Bench<'_> {
    fn say(&self, s: &str) {
        if !self.args.quiet {
            eprintln!("{s}");
        }
    }

    /// Runs a child `--repeat` times; keeps the fastest run's report, with
    /// the largest peak RSS and every run's time (and other processes' CPU
    /// use, and any wait for an idle machine) added.
    fn child<T: ChildOut>(&self, args: &[String]) -> Result<T> {
        let mut best: Option<T> = None;
        let (mut times, mut rss, mut other, mut waits) = (Vec::new(), f64::NAN, Vec::new(), Vec::new());
        for _ in 0..self.args.repeat.max(1) {
            if self.args.wait_idle > 0.0 {
                waits.push(wait_idle(self.args.wait_idle));
            }
            let mut j: T = self.child_once(args)?;
            let t = j.timed().seconds;
            rss = rss.max(j.timed().peak_rss_mib);
            times.push(finite(t));
            other.push(j.timed().other_cpu_cores);
            if best.as_mut().is_none_or(|b| t < b.timed().seconds || b.timed().seconds.is_nan()) {
                best = Some(j);
            }
        }
        let mut j = best.expect("at least one run");
        let tm = j.timed();
        tm.peak_rss_mib = rss;
        tm.seconds_all_runs = times;
        tm.other_cpu_cores_all_runs = other;
        tm.idle_wait_seconds_all_runs = waits;
        Ok(j)
    }

    fn child_once<T: ChildOut>(&self, args: &[String]) -> Result<T> {
        let out = Command::new(&self.exe).arg("run-one").args(args).stdin(Stdio::null()).output().with_context(|| format!("start {}", self.exe.display()))?;
        if !out.status.success() {
            let err = String::from_utf8_lossy(&out.stderr);
            let tail: Vec<&str> = err.lines().rev().take(5).collect();
            let tail: Vec<&str> = tail.into_iter().rev().collect();
            bail!("`run-one {}` failed ({}): {}", args.join(" "), out.status, tail.join(" | "));
        }
        let s = String::from_utf8_lossy(&out.stdout);
        let line = s.lines().rev().find(|l| l.trim_start().starts_with('{')).ok_or_else(|| anyhow!("child printed no JSON"))?;
        serde_json::from_str(line.trim()).context("the child's JSON")
    }

    /// metro's report on `output` against `input`, and its wall seconds.
    fn metro(&self, input: &Path, output: &Path) -> std::result::Result<(MetroJson, f64), String> {
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
        let m = serde_json::from_str(s[start..].trim()).map_err(|e| format!("metro JSON: {e}"))?;
        Ok((m, seconds))
    }
}

/// Sets a row's error fields from metro's report.
pub fn set_metro(row: &mut Row, m: MetroJson, seconds: f64, diagonal: f64) {
    let c = &m.combined;
    row.rms = finite(c.rms);
    row.hausdorff = finite(c.max);
    row.mean = finite(c.mean);
    row.rms_rel_diag = finite(c.rms / diagonal);
    row.hausdorff_rel_diag = finite(c.max / diagonal);
    row.error_figures = Some("`combined` (both directions)".into());
    row.metro_seconds = Some(seconds);
    row.metro = Some(m);
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
fn scan(path: &Path) -> Result<InputReport> {
    let t = Instant::now();
    let header = octolod::ply::read_header(path)?;
    let mut sink = ScanSink { bbox: Aabb::EMPTY };
    let stats = read_body(path, &header, &mut sink, &Progress::hidden())?;
    let name = path.file_stem().map_or("input".into(), |s| s.to_string_lossy().into_owned());
    Ok(InputReport {
        path: path.to_path_buf(),
        name,
        bytes: std::fs::metadata(path).map(|m| m.len()).unwrap_or(0),
        vertices: stats.vertices,
        triangles: stats.triangles,
        diagonal: sink.bbox.diagonal(),
        attributes: header.attrs.describe(),
        scan_seconds: t.elapsed().as_secs_f64(),
        builds: Vec::new(),
        rows: Vec::new(),
        pairs: Vec::new(),
    })
}

/// The whole run (or `--from-json`).
pub fn bench(args: &BenchArgs) -> Result<()> {
    if let Some(json) = &args.from_json {
        return rerender(args, json);
    }
    if args.inputs.is_empty() && args.attr_sweep.is_none() {
        bail!("give at least one input PLY (or --attr-sweep N)");
    }
    let settings: Vec<Setting> = args.settings.iter().map(|s| parse_setting(s)).collect::<Result<_>>()?;
    if settings.is_empty() {
        bail!("--settings is empty");
    }
    octolod::mem::parse_size(&args.mem)?;
    let baselines = check_baselines(&args.baseline)?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("create {}", args.out.display()))?;
    let exe = std::env::current_exe().context("locate this executable")?;
    let (octolod_bin, octolod_note) = find_octolod(args, &exe);
    let (metro_bin, metro_note) = if args.no_metro { (None, "metro skipped (--no-metro)".to_string()) } else { (octolod_bin.clone(), octolod_note.clone()) };
    let b = Bench { args, exe, octolod_bin, octolod_note, metro_bin, metro_note };
    b.say(&format!(
        "octolod-bench: {} input(s), settings {}, metro: {}",
        args.inputs.len(),
        args.settings.join(","),
        b.metro_bin.as_ref().map_or(b.metro_note.clone(), |p| p.display().to_string())
    ));

    let (cpu, threads, mem_gib) = crate::report::machine();
    let simplify = !args.no_simplify && !args.inputs.is_empty();
    let mut r = Report {
        generated: now_utc(),
        command: command_line(),
        label: args.label.clone(),
        baselines,
        rerendered: None,
        machine: MachineJson { cpu, threads, mem_gib },
        metro: b.metro_bin.as_ref().map_or(b.metro_note.clone(), |p| p.display().to_string()),
        metro_note: b.metro_bin.is_none().then(|| b.metro_note.clone()),
        samples: args.samples,
        repeat: args.repeat,
        mem: args.mem.clone(),
        settings: args.settings.clone(),
        min_tris: args.min_tris,
        wait_idle: args.wait_idle,
        levels: args.levels.clone(),
        simplify_setting: simplify.then(|| format!("{}x{}", settings[0].leaf, settings[0].ratio)),
        inputs: Vec::new(),
        attr_sweep: Vec::new(),
        failures: Vec::new(),
        suffix: args.suffix.clone(),
    };
    for path in &args.inputs {
        let mut info = scan(path)?;
        b.say(&format!(
            "[{}] {} triangles, {} vertices, {}, diagonal {:.4}",
            info.name,
            thousands(info.triangles),
            thousands(info.vertices),
            info.attributes,
            info.diagonal
        ));
        let dir = args.out.join(&info.name);
        std::fs::create_dir_all(&dir).with_context(|| format!("create {}", dir.display()))?;
        bench_input(&b, &mut info, &dir, &settings, simplify, &mut r.failures);
        r.inputs.push(info);
    }
    if let Some(n) = args.attr_sweep {
        r.attr_sweep = attr_sweep(&b, n, settings[0], &mut r.failures)?;
    }

    let path = write_report(args, &mut r)?;
    if args.clean {
        // Every output, and the levels that were extracted but not measured.
        let levels = r.inputs.iter().flat_map(|i| &i.builds).flat_map(|b| &b.levels).map(|l| &l.path);
        for path in r.inputs.iter().flat_map(|i| &i.rows).map(|x| &x.path).chain(levels) {
            let _ = std::fs::remove_file(path);
        }
    }
    b.say(&format!("report: {}", path.display()));
    Ok(())
}

/// Writes `report<suffix>.md`, `report<suffix>.json` and the two plots
/// under `--out`; returns the Markdown's path.
fn write_report(args: &BenchArgs, r: &mut Report) -> Result<PathBuf> {
    std::fs::create_dir_all(&args.out).with_context(|| format!("create {}", args.out.display()))?;
    let write = |name: &str, text: String| -> Result<PathBuf> {
        let path = args.out.join(name);
        std::fs::write(&path, text).with_context(|| format!("write {}", path.display()))?;
        Ok(path)
    };
    r.fill_pairs();
    let sfx = r.suffix.clone();
    let md = write(&format!("report{sfx}.md"), crate::report::report_md(r))?;
    write(&format!("report{sfx}.json"), serde_json::to_string_pretty(r)? + "\n")?;
    let (speed, size) = crate::plot::plots(&r.inputs);
    write(&format!("error_vs_speed{sfx}.svg"), speed)?;
    write(&format!("error_vs_size{sfx}.svg"), size)?;
    Ok(md)
}

/// Reads a `report.json` this tool wrote.
pub fn read_report(text: &str, suffix: &str) -> Result<Report> {
    let mut r: Report = serde_json::from_str(text)?;
    r.suffix = suffix.to_string();
    Ok(r)
}

/// `--from-json`: reads a report.json and writes the report and plots
/// again (for changes to the report's layout without measuring again; the
/// numbers are the JSON's).
fn rerender(args: &BenchArgs, json: &Path) -> Result<()> {
    let text = std::fs::read_to_string(json).with_context(|| format!("read {}", json.display()))?;
    let mut r = read_report(&text, &args.suffix).with_context(|| format!("read {}", json.display()))?;
    r.rerendered = Some(format!("{} from `{}` by `{}`", now_utc(), json.display(), command_line()));
    let path = write_report(args, &mut r)?;
    if !args.quiet {
        eprintln!("report: {} (re-rendered from {})", path.display(), json.display());
    }
    Ok(())
}

/// The `octolod` binary (`--octolod`, or the one next to this executable),
/// if its `metro` subcommand answers `--help`; else why not.
fn find_octolod(args: &BenchArgs, exe: &Path) -> (Option<PathBuf>, String) {
    let candidate = args.octolod.clone().unwrap_or_else(|| exe.with_file_name("octolod"));
    match Command::new(&candidate).args(["metro", "--help"]).stdin(Stdio::null()).output() {
        Ok(o) if o.status.success() => (Some(candidate), String::new()),
        Ok(o) => (
            None,
            format!("`{} metro` unavailable ({}); errors n/a", candidate.display(), String::from_utf8_lossy(&o.stderr).lines().next().unwrap_or("").trim()),
        ),
        Err(e) => (None, format!("`{}` not runnable ({e}); errors n/a", candidate.display())),
    }
}

/// `--baseline`: refuses a label given twice and a binary whose `build
/// --help` does not answer (before anything is measured); records each with
/// what its `--version` prints, if it does.
fn check_baselines(baselines: &[Baseline]) -> Result<Vec<BaselineJson>> {
    let mut out: Vec<BaselineJson> = Vec::new();
    for bl in baselines {
        if out.iter().any(|o| o.label == bl.label) {
            bail!("--baseline {bl}: the label {:?} is given twice", bl.label);
        }
        let help = Command::new(&bl.bin).args(["build", "--help"]).stdin(Stdio::null()).output();
        match help {
            Ok(o) if o.status.success() => {}
            Ok(o) => bail!("--baseline {bl}: `build --help` failed ({}): {}", o.status, String::from_utf8_lossy(&o.stderr).lines().next().unwrap_or("").trim()),
            Err(e) => bail!("--baseline {bl}: not runnable: {e}"),
        }
        let version = Command::new(&bl.bin)
            .arg("--version")
            .stdin(Stdio::null())
            .output()
            .ok()
            .filter(|o| o.status.success())
            .and_then(|o| String::from_utf8_lossy(&o.stdout).lines().next().map(|l| l.trim().to_string()))
            .filter(|l| !l.is_empty());
        out.push(BaselineJson { label: bl.label.clone(), bin: bl.bin.clone(), version });
    }
    Ok(out)
}

/// A row for an octolod level.
fn level_row(b: &BuildOut, l: &LevelOut, n_in: f64) -> Row {
    Row {
        setting: b.setting(),
        baseline: b.baseline.clone(),
        level: Some(l.level),
        ..Row::unmeasured(Method::Octolod, l.triangles, l.vertices, l.path.clone(), &b.timed, n_in, RowChild::Level(l.clone()))
    }
}

/// A row for a peer's or `octolod simplify`'s run.
fn run_row(j: RunOut, n_in: f64) -> Row {
    let (method, target, load_seconds) = (j.method, j.target, j.load_seconds);
    let (triangles, vertices, path, timed) = (j.triangles, j.vertices, j.path.clone(), j.timed.clone());
    Row { target: Some(target), load_seconds, ..Row::unmeasured(method, triangles, vertices, path, &timed, n_in, RowChild::Run(Box::new(j))) }
}

/// Every method on one input: the octolod builds (one per setting, each
/// followed by every `--baseline`'s build of it), then the peers and the
/// simplifiers at every output size of the current builds kept.
fn bench_input(b: &Bench, info: &mut InputReport, dir: &Path, settings: &[Setting], simplify: bool, failures: &mut Vec<String>) {
    let n_in = info.triangles as f64;
    let input = info.path.display().to_string();
    let builds = settings.iter().flat_map(|st| std::iter::once(None).chain(b.args.baseline.iter().map(Some)).map(move |bl| (st, bl)));
    for (st, bl) in builds {
        let plain = setting_name(st.leaf, st.ratio, st.simplifier);
        let (setting, prefix) = match bl {
            Some(bl) => (baseline_setting(&plain, &bl.label), dir.join(format!("octolod-{}-at-{}", plain.replace(':', "-"), bl.label))),
            None => (plain.clone(), dir.join(format!("octolod-{}", plain.replace(':', "-")))),
        };
        let mut args = vec![
            "--method".into(),
            "octolod".into(),
            "--leaf-tris".into(),
            st.leaf.to_string(),
            "--level-ratio".into(),
            st.ratio.to_string(),
            "--simplifier".into(),
            st.simplifier.name().into(),
            "--mem".into(),
            b.args.mem.clone(),
            input.clone(),
            prefix.display().to_string(),
        ];
        if let Some(bl) = bl {
            args.extend(["--baseline".into(), bl.to_string()]);
        }
        let j: BuildOut = match b.child(&args) {
            Ok(j) => j,
            Err(e) => {
                b.say(&format!("[{}] octolod {setting}: FAILED: {e:#}", info.name));
                failures.push(format!("{}: octolod {setting}: {e:#}", info.name));
                continue;
            }
        };
        let seconds = j.timed.seconds;
        b.say(&format!(
            "[{}] octolod {setting}: build {:.2} s ({:.3} M tri/s), peak {:.0} MiB, {} levels",
            info.name,
            seconds,
            n_in / seconds / 1e6,
            j.timed.peak_rss_mib,
            j.levels.len()
        ));
        for l in &j.levels {
            if !b.args.levels.is_empty() && !b.args.levels.contains(&l.level) {
                continue;
            }
            if l.triangles < b.args.min_tris {
                b.say(&format!("[{}]   L{}: {} triangles < --min-tris, skipped", info.name, l.level, thousands(l.triangles)));
                continue;
            }
            let mut row = level_row(&j, l, n_in);
            measure(b, info, &mut row);
            info.rows.push(row);
        }
        info.builds.push(j);
    }
    for line in crate::report::vs_baseline_lines(info) {
        b.say(&format!("[{}] {line}", info.name));
    }

    // Peers, then `octolod simplify`, at every distinct output size of the
    // current octolod builds (not the baselines', which would run every
    // peer again for sizes a level or so apart).
    let mut targets: Vec<u64> = info.rows.iter().filter(|r| r.method == Method::Octolod && r.baseline.is_none()).map(|r| r.triangles).collect();
    targets.sort_unstable_by(|a, b| b.cmp(a));
    targets.dedup();
    let methods: Vec<Method> = Method::PEERS
        .into_iter()
        .filter(|&m| m != Method::MeshlabQec || b.args.meshlab.is_some())
        .chain(Method::SIMPLIFIERS.into_iter().filter(|_| simplify))
        .collect();
    let (leaf, ratio) = (settings[0].leaf, settings[0].ratio);
    for m in methods {
        for &target in &targets {
            let out = dir.join(format!("{}-{target}.ply", m.name()));
            let mut args: Vec<String> =
                vec!["--method".into(), m.name().into(), "--target".into(), target.to_string(), input.clone(), out.display().to_string()];
            if m.simplifier().is_some() {
                let Some(bin) = &b.octolod_bin else {
                    b.say(&format!("[{}] {}: skipped: {}", info.name, m.name(), b.octolod_note));
                    failures.push(format!("{}: {} target {target}: skipped: {}", info.name, m.name(), b.octolod_note));
                    continue;
                };
                args.extend([
                    "--octolod".into(),
                    bin.display().to_string(),
                    "--mem".into(),
                    b.args.mem.clone(),
                    "--leaf-tris".into(),
                    leaf.to_string(),
                    "--level-ratio".into(),
                    ratio.to_string(),
                ]);
            }
            if let (Method::MeshlabQec, Some(py)) = (m, &b.args.meshlab) {
                args.extend(["--python".into(), py.display().to_string()]);
            }
            let j: RunOut = match b.child(&args) {
                Ok(j) => j,
                Err(e) => {
                    b.say(&format!("[{}] {} target {target}: FAILED: {e:#}", info.name, m.name()));
                    failures.push(format!("{}: {} target {target}: {e:#}", info.name, m.name()));
                    continue;
                }
            };
            let mut row = run_row(j, n_in);
            measure(b, info, &mut row);
            info.rows.push(row);
        }
    }
}

/// Runs metro on a row's output and prints the row's progress line.
fn measure(b: &Bench, info: &InputReport, row: &mut Row) {
    match b.metro(&info.path, &row.path) {
        Ok((m, seconds)) => set_metro(row, m, seconds, info.diagonal),
        Err(e) => row.error_note = Some(e),
    }
    let err = match (row.err(), row.metro_seconds) {
        (Some((rms, max)), Some(s)) => format!("RMS {:.3e}, Hausdorff {:.3e} of diag (metro {s:.1} s)", rms / info.diagonal, max / info.diagonal),
        _ => "error n/a".into(),
    };
    let load = row.load_seconds.map_or(String::new(), |l| format!(" + load {l:.2} s"));
    let time = match row.method {
        Method::Octolod => "(build above)".to_string(),
        _ => format!("{:.3} s{load} ({:.3} M tri/s), peak {:.0} MiB", row.seconds, row.throughput, row.rss_mib),
    };
    b.say(&format!("[{}] {} {}: {} tris, {time}, {err}", info.name, row.method.name(), setting_text(row), thousands(row.triangles)));
}

/// The attribute sets of `--attr-sweep`: label, attribute bits.
const SWEEP_SETS: [(&str, u32); 4] =
    [("position only", 0), ("+uv", AttrSet::UV), ("+normals", AttrSet::NORMAL), ("+normals+colors+uvs", AttrSet::NORMAL | AttrSet::COLOR | AttrSet::UV)];

/// `--attr-sweep N`: one generated N-triangle sphere per attribute set,
/// built (not extracted) with the first setting.
fn attr_sweep(b: &Bench, n: u64, st: Setting, failures: &mut Vec<String>) -> Result<Vec<SweepRow>> {
    let dir = b.args.out.join("attr-sweep");
    std::fs::create_dir_all(&dir).with_context(|| format!("create {}", dir.display()))?;
    let mut out = Vec::new();
    for (label, bits) in SWEEP_SETS {
        let attrs = AttrSet(bits);
        let tag = label.trim_start_matches('+').replace(['+', ' '], "-");
        let path = dir.join(format!("sphere-{n}-{tag}.ply"));
        if !path.exists() {
            let t = Instant::now();
            octolod::gen::write(&GenOptions { shape: Shape::Sphere, tris: n, seed: 1, attrs }, &PlyWriteOptions::default(), &path, true, false)?;
            b.say(&format!("[attr-sweep] generated {} in {:.1} s", path.display(), t.elapsed().as_secs_f64()));
        }
        let info = scan(&path)?;
        let args = vec![
            "--method".into(),
            "octolod".into(),
            "--leaf-tris".into(),
            st.leaf.to_string(),
            "--level-ratio".into(),
            st.ratio.to_string(),
            "--simplifier".into(),
            st.simplifier.name().into(),
            "--mem".into(),
            b.args.mem.clone(),
            "--no-extract".into(),
            path.display().to_string(),
            dir.join(format!("build-{tag}")).display().to_string(),
        ];
        match b.child::<BuildOut>(&args) {
            Ok(j) => {
                let s = j.timed.seconds;
                b.say(&format!(
                    "[attr-sweep] {label} (dim {}): build {:.2} s ({:.0} ns/tri), peak {:.0} MiB",
                    attrs.quadric_dim(),
                    s,
                    s * 1e9 / info.triangles as f64,
                    j.timed.peak_rss_mib
                ));
                out.push(SweepRow {
                    label: label.to_string(),
                    attributes: attrs.describe(),
                    quadric_dim: attrs.quadric_dim() as u64,
                    triangles: info.triangles,
                    ply_bytes: info.bytes,
                    build: j,
                });
            }
            Err(e) => {
                b.say(&format!("[attr-sweep] {label}: FAILED: {e:#}"));
                failures.push(format!("attr-sweep {label}: {e:#}"));
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::report::report_md;
    use crate::types::{SimplifyJson, Timed};

    /// A metro report as `octolod metro --json` prints it (one null: a
    /// figure that was not finite).
    const METRO: &str = r#"{"a":{"source":"x.ply","vertices":50,"faces":96,"area":12.5,"bbox":{"min":[-1.0,-1.0,-1.0],"max":[1.0,1.0,1.0]},"diagonal":3.4641016151377544},"b":{"source":"o.ply","vertices":22,"faces":40,"area":12.1,"bbox":{"min":[-1.0,-1.0,-1.0],"max":[1.0,1.0,1.0]},"diagonal":3.4641016151377544},"diagonal":2.0,"diagonal_of":"a","union_diagonal":2.0,"seed":1,"samples_target":1000,"a_to_b":{"samples":1000,"vertex_samples":50,"edge_samples":100,"face_samples":850,"max":0.15,"mean":0.04,"rms":0.08,"max_rel":0.075,"mean_rel":0.02,"rms_rel":0.04,"max_at":[0.1,0.2,0.3]},"b_to_a":{"samples":1000,"vertex_samples":22,"edge_samples":100,"face_samples":878,"max":0.2,"mean":0.06,"rms":0.12,"max_rel":0.1,"mean_rel":0.03,"rms_rel":0.06,"max_at":[0.1,0.2,null]},"combined":{"samples":2000,"vertex_samples":72,"edge_samples":200,"face_samples":1728,"max":0.2,"mean":0.05,"rms":0.1,"max_rel":0.1,"mean_rel":0.025,"rms_rel":0.05,"max_at":[0.1,0.2,0.3]},"hausdorff":0.2,"hausdorff_rel":0.1,"thresholds":[],"pass":true}"#;

    fn run(method: Method, target: u64) -> RunOut {
        let timed = Timed { seconds: 0.5, peak_rss_mib: 30.0, other_cpu_cores: Some(0.1), child_seconds: 0.7, ..Timed::default() };
        RunOut {
            load_seconds: (method.simplifier().is_none()).then_some(0.1),
            grid: (method == Method::Oocs).then_some(7),
            exit_code: method.simplifier().map(|_| 0),
            simplify: method.simplifier().map(|_| SimplifyJson {
                route: "in-memory".into(),
                start: "level 1".into(),
                start_triangles: 48,
                input_triangles: 96,
                target_triangles: Some(target),
                target_error: None,
                vertices: 22,
                triangles: target,
                reached: true,
                note: None,
                hausdorff: None,
                tries: 0,
                verify_samples: None,
                choice: None,
            }),
            ..RunOut::new(method, target, 96, target, 22, format!("{}-{target}.ply", method.name()).into(), timed)
        }
    }

    fn sample_report() -> Report {
        let build = BuildOut {
            method: Method::Octolod,
            leaf_tris: 16384,
            level_ratio: 8,
            simplifier: octolod::manifest::Simplifier::Cluster,
            mem: 1 << 29,
            input_triangles: 96,
            attributes: "position(f32)".into(),
            quadric_dim: 3,
            soup_seconds: 0.1,
            octree_seconds: 0.1,
            simplify_seconds: 0.3,
            soup_external: Some(false),
            nodes: Some(3),
            leaves: Some(2),
            deepest: Some(1),
            disk_bytes: Some(1000),
            peak_rss_with_extract_mib: f64::NAN,
            levels: vec![LevelOut { level: 1, triangles: 40, vertices: 22, nodes: Some(1), error_bound_max: Some(0.01), path: "o.ply".into() }],
            baseline: None,
            command: None,
            reported_total_seconds: None,
            timed: Timed {
                seconds: 0.5,
                peak_rss_mib: 30.0,
                other_cpu_cores: Some(0.1),
                child_seconds: 0.6,
                seconds_all_runs: vec![Some(0.5), None],
                ..Timed::default()
            },
        };
        let metro: MetroJson = serde_json::from_str(METRO).unwrap();
        let mut rows = vec![level_row(&build, &build.levels[0], 96.0)];
        rows.extend(
            [Method::MeshoptSimplify, Method::MeshoptSloppy, Method::Oocs, Method::OctolodCollapse, Method::OctolodCluster].map(|m| run_row(run(m, 40), 96.0)),
        );
        for (k, r) in rows.iter_mut().enumerate() {
            let mut m = metro.clone();
            m.combined.rms *= 1.0 + k as f64 * 0.1;
            set_metro(r, m, 0.3, 2.0);
        }
        Report {
            generated: "2026-01-01 00:00 UTC".into(),
            command: "octolod-bench x.ply".into(),
            label: Some("commit x".into()),
            baselines: vec![],
            rerendered: None,
            machine: MachineJson { cpu: "cpu".into(), threads: 2, mem_gib: 8.0 },
            metro: "octolod".into(),
            metro_note: None,
            samples: Some(1000),
            repeat: 2,
            mem: "512M".into(),
            settings: vec!["16384x8".into()],
            min_tris: 500,
            wait_idle: 0.0,
            levels: vec![],
            simplify_setting: Some("16384x8".into()),
            inputs: vec![InputReport {
                path: "x.ply".into(),
                name: "x".into(),
                bytes: 100,
                vertices: 50,
                triangles: 96,
                attributes: "position(f32)".into(),
                diagonal: 2.0,
                scan_seconds: 0.1,
                builds: vec![build.clone()],
                rows,
                pairs: vec![],
            }],
            attr_sweep: vec![SweepRow { label: "+uv".into(), attributes: "position(f32)+uv".into(), quadric_dim: 5, triangles: 96, ply_bytes: 200, build }],
            failures: vec![],
            suffix: "-t".into(),
        }
    }

    /// `--from-json` gives back the report the run wrote.
    #[test]
    fn report_json_reads_back() {
        let mut r = sample_report();
        r.fill_pairs();
        let md = report_md(&r);
        let text = serde_json::to_string_pretty(&r).unwrap();
        let back = read_report(&text, "-t").unwrap();
        assert_eq!(report_md(&back), md);
        assert!(back.inputs[0].builds[0].peak_rss_with_extract_mib.is_nan());
        assert_eq!(back.inputs[0].builds[0].timed.seconds_all_runs, vec![Some(0.5), None]);
        assert!(md.contains("| oocs | target 40 (grid 7) | 40 |"), "{md}");
        assert!(md.contains("| octolod-collapse | target 40 (from level 1, in-memory) | 40 |"), "{md}");
        assert!(md.contains("### octolod simplify ÷ peer at the same target"), "{md}");
        assert!(md.contains("| collapse | 40 | 40 | 0.83 | 1.00 | 1.27 | 1.00 | 0.83 | 1.00 | 1.17 | 1.00 |"), "{md}");
        assert!(md.contains("- `collapse` ÷ meshopt-simplify over 1 targets: RMS 1.27 (≤ 1 at 0 of 1)"), "{md}");
        assert!(md.contains("![RMS error vs throughput](error_vs_speed-t.svg)"));
        // Pairs: octolod against the three peers, each simplifier against them too.
        assert_eq!(r.inputs[0].pairs.len(), 9);
        let (speed, size) = crate::plot::plots(&back.inputs);
        for svg in [speed, size] {
            assert!(svg.contains(">octolod simplify collapse<") && svg.contains(">octolod simplify cluster<"), "{svg}");
        }
    }

    /// MeshLab's edge collapse pairs like any peer where it ran (and only
    /// then gets columns), and a collapse build's rows name its setting.
    #[test]
    fn meshlab_peer_and_collapse_setting_in_the_report() {
        let mut r = sample_report();
        r.fill_pairs();
        assert!(!report_md(&r).contains("meshlab-qec"));
        let mut r = sample_report();
        let info = &mut r.inputs[0];
        info.builds[0].simplifier = octolod::manifest::Simplifier::Collapse;
        info.rows[0].setting = info.builds[0].setting();
        let mut ml = run_row(RunOut { meshlab_filter: Some("qec".into()), ..run(Method::MeshlabQec, 40) }, 96.0);
        set_metro(&mut ml, serde_json::from_str(METRO).unwrap(), 0.3, 2.0);
        info.rows.push(ml);
        r.fill_pairs();
        // octolod's level and both simplifiers against four peers.
        assert_eq!(r.inputs[0].pairs.len(), 12);
        let md = report_md(&r);
        assert!(md.contains("| 16384x8:collapse L1 | 40 | meshlab-qec | 40 |"), "{md}");
        assert!(md.contains("RMS ÷ meshlab-qec"), "{md}");
        assert!(md.contains("| 16384x8:collapse | meshlab-qec | 1 |"), "{md}");
    }

    /// A `--baseline` build's levels are rows like the current build's
    /// (setting `LEAFxRATIO[:collapse] @LABEL`, paired with the peers at
    /// their size), compared with the current build of the same setting,
    /// and read back from the JSON.
    #[test]
    fn baseline_rows_in_the_report() {
        let mut r = sample_report();
        let info = &mut r.inputs[0];
        let cur = &mut info.builds[0];
        cur.simplifier = octolod::manifest::Simplifier::Collapse;
        info.rows[0].setting = cur.setting();
        let base = BuildOut {
            baseline: Some("before".into()),
            nodes: None,
            disk_bytes: None,
            soup_seconds: f64::NAN,
            command: Some("octolod build x.ply -o s".into()),
            timed: Timed { seconds: 1.0, peak_rss_mib: 60.0, ..Timed::default() },
            ..cur.clone()
        };
        assert_eq!(base.setting(), "16384x8:collapse @before");
        let mut row = level_row(&base, &LevelOut { triangles: 40, ..base.levels[0].clone() }, 96.0);
        let mut m: MetroJson = serde_json::from_str(METRO).unwrap();
        m.combined.rms *= 2.0;
        set_metro(&mut row, m, 0.3, 2.0);
        info.rows.push(row);
        info.builds.push(base);
        r.baselines = vec![BaselineJson { label: "before".into(), bin: "/tmp/octolod-old".into(), version: Some("octolod 0.1.0".into()) }];
        r.fill_pairs();
        // The baseline's level against the three peers too.
        assert_eq!(r.inputs[0].pairs.len(), 12);
        let md = report_md(&r);
        assert!(
            md.contains(
                "Baselines (older octolod executables, each built every setting through its command line): `@before` = `/tmp/octolod-old` (`octolod 0.1.0`)."
            ),
            "{md}"
        );
        assert!(md.contains("| 16384x8:collapse @before | 1 | n/a | 1.00 | n/a / 0.10 / 0.30 | 0.000 | 60 | n/a | n/a |"), "{md}");
        assert!(md.contains("| 16384x8:collapse | @before | 0.50 / 1.00 | 0.50 | 0.000 / 0.000 | 2.00 | 30 / 60 | 0.50 |"), "{md}");
        assert!(md.contains("| 16384x8:collapse | @before | L1 | 40 / 40 | 1.00 | 5.000e-2 / 1.000e-1 | 0.50 | 1.000e-1 / 1.000e-1 | 1.00 |"), "{md}");
        assert!(md.contains("| 16384x8:collapse @before L1 | 40 | meshopt-simplify | 40 |"), "{md}");
        assert!(md.contains("| 16384x8:collapse @before | oocs | 1 |"), "{md}");
        let lines = crate::report::vs_baseline_lines(&r.inputs[0]);
        assert_eq!(lines[1], "  L1: triangles 40 / 40 = 1.00, RMS 0.50, Hausdorff 1.00");
        let back = read_report(&serde_json::to_string_pretty(&r).unwrap(), "-t").unwrap();
        assert_eq!(report_md(&back), md);
        assert_eq!(back.inputs[0].rows.last().unwrap().baseline.as_deref(), Some("before"));
    }

    /// metro's figures are read from its `combined` object.
    #[test]
    fn metro_json_is_typed() {
        let m: MetroJson = serde_json::from_str(METRO).unwrap();
        assert_eq!((m.combined.rms, m.combined.max, m.combined.mean), (0.1, 0.2, 0.05));
        assert!(m.b_to_a.max_at[2].is_nan());
        assert_eq!(m.a_to_b.samples, 1000);
        // Written back, it reads the same.
        let again: MetroJson = serde_json::from_str(&serde_json::to_string(&m).unwrap()).unwrap();
        assert_eq!(again.combined.rms, 0.1);
        assert!(serde_json::from_str::<MetroJson>(r#"{"combined":{"rms":1}}"#).is_err());
    }

    /// Reports written before the typed JSON still read back.
    #[test]
    fn old_reports_read_back() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/bench");
        let Ok(entries) = std::fs::read_dir(&dir) else { return };
        for e in entries.flatten().filter(|e| e.path().extension().is_some_and(|x| x == "json")) {
            let text = std::fs::read_to_string(e.path()).unwrap();
            let r = read_report(&text, "").unwrap_or_else(|err| panic!("{}: {err:#}", e.path().display()));
            assert!(!r.inputs.is_empty());
            assert!(r.inputs.iter().flat_map(|i| &i.rows).all(|x| x.err().is_some()), "{}", e.path().display());
            assert!(report_md(&r).contains("### Ratios, octolod ÷ peer at the same target"));
        }
    }
}
