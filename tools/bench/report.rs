//! `report<suffix>.md`: the tables, from a [`Report`] (a run's, or one read
//! back from its JSON), and the pairing of outputs at the same target.

use crate::types::{finite, BuildOut, InputReport, Method, PairJson, Report, Row, RowChild};
use std::fmt::Write as _;

/// One octolod output (a level, or an `octolod simplify` run) against one
/// peer run at the same target on the same input.
pub struct Pair<'a> {
    pub o: &'a Row,
    pub p: &'a Row,
}

impl Pair<'_> {
    pub fn time(&self) -> f64 {
        self.o.seconds / self.p.seconds
    }
    pub fn time_with_load(&self) -> f64 {
        self.o.seconds / (self.p.seconds + self.p.load_seconds.unwrap_or(0.0))
    }
    pub fn rss(&self) -> f64 {
        self.o.rss_mib / self.p.rss_mib
    }
    pub fn rms(&self) -> Option<f64> {
        Some(self.o.err()?.0 / self.p.err()?.0)
    }
    pub fn hausdorff(&self) -> Option<f64> {
        Some(self.o.err()?.1 / self.p.err()?.1)
    }
    pub fn json(&self) -> PairJson {
        PairJson {
            method: self.o.method,
            setting: self.o.setting.clone(),
            level: self.o.level,
            triangles: self.o.triangles,
            peer: self.p.method,
            peer_triangles: self.p.triangles,
            time_ratio: finite(self.time()),
            time_ratio_with_load: finite(self.time_with_load()),
            rss_ratio: finite(self.rss()),
            rms_ratio: self.rms().and_then(finite),
            hausdorff_ratio: self.hausdorff().and_then(finite),
        }
    }
}

/// Each octolod level against each peer run whose target was its size.
pub fn pairs(rows: &[Row]) -> Vec<Pair<'_>> {
    let mut out = Vec::new();
    for o in rows.iter().filter(|r| r.method == Method::Octolod) {
        for m in Method::PEERS {
            if let Some(p) = rows.iter().find(|p| p.method == m && p.target == Some(o.triangles)) {
                out.push(Pair { o, p });
            }
        }
    }
    out
}

/// Each `octolod simplify` run against each peer run at the same target.
pub fn simplify_pairs(rows: &[Row]) -> Vec<Pair<'_>> {
    let mut out = Vec::new();
    for o in rows.iter().filter(|r| Method::SIMPLIFIERS.contains(&r.method)) {
        for m in Method::PEERS {
            if let Some(p) = rows.iter().find(|p| p.method == m && p.target.is_some() && p.target == o.target) {
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

pub fn thousands(n: u64) -> String {
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
pub fn now_utc() -> String {
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

/// (CPU model, hardware threads, GiB of RAM).
pub fn machine() -> (String, usize, f64) {
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

pub fn command_line() -> String {
    std::env::args().collect::<Vec<_>>().join(" ")
}

/// What a row's "setting" column says.
pub fn setting_text(r: &Row) -> String {
    match (r.method, r.level, r.target, &r.child) {
        (Method::Octolod, Some(l), _, _) => format!("{} L{l}", r.setting),
        (_, _, Some(t), RowChild::Run(run)) if run.grid.is_some() => format!("target {} (grid {})", thousands(t), run.grid.unwrap_or(0)),
        (_, _, Some(t), RowChild::Run(run)) if run.simplify.is_some() => {
            let s = run.simplify.as_ref().expect("checked");
            format!("target {} (from {}, {}{})", thousands(t), s.start, s.route, if s.reached { "" } else { ", not reached" })
        }
        (_, _, Some(t), _) => format!("target {}", thousands(t)),
        _ => r.setting.clone(),
    }
}

/// The Markdown report.
pub fn report_md(r: &Report) -> String {
    let mut s = String::new();
    let w = &mut s;
    let _ = writeln!(w, "# octolod speed-against-error report\n");
    let _ = writeln!(
        w,
        "Generated {} by `{}`.{}{}\n",
        r.generated,
        r.command,
        if r.repeat > 1 { format!(" Every method ran {} times; times are the fastest run, peak RSS the largest.", r.repeat) } else { String::new() },
        r.rerendered.as_ref().map_or(String::new(), |x| format!(" Tables and plots re-rendered {x}; the numbers are those of the run."))
    );
    if let Some(l) = &r.label {
        let _ = writeln!(w, "Measured: {l}.\n");
    }
    if !r.baselines.is_empty() {
        let list: Vec<String> = r
            .baselines
            .iter()
            .map(|b| format!("`@{}` = `{}`{}", b.label, b.bin.display(), b.version.as_ref().map_or(String::new(), |v| format!(" (`{v}`)"))))
            .collect();
        let _ = writeln!(w, "Baselines (older octolod executables, each built every setting through its command line): {}.\n", list.join(", "));
    }
    let _ = writeln!(
        w,
        "Machine: {}, {} hardware threads, {:.1} GiB RAM. octolod uses all threads (rayon); meshoptimizer, the OOCS baseline and MeshLab's edge collapse (pymeshlab, when run) are single-threaded.\n",
        r.machine.cpu, r.machine.threads, r.machine.mem_gib
    );
    // Other processes' CPU use during the timed sections (the machine may be
    // shared): kept runs and every run.
    let timed = || {
        r.inputs
            .iter()
            .flat_map(|i| i.builds.iter().map(|b| &b.timed).chain(i.rows.iter().filter_map(|r| r.run()).map(|x| &x.timed)))
            .chain(r.attr_sweep.iter().map(|s| &s.build.timed))
    };
    let kept: Vec<f64> = timed().filter_map(|t| t.other_cpu_cores).collect();
    let all: Vec<f64> = timed().flat_map(|t| t.other_cpu_cores_all_runs.iter().flatten().copied()).collect();
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
            if r.wait_idle > 0.0 { format!(" Each run first waited (up to {} s) for other processes to use under 0.25 cores.", r.wait_idle) } else { String::new() }
        );
    }
    let rows = || r.inputs.iter().flat_map(|i| &i.rows);
    let metros = || rows().filter_map(|x| x.metro.as_ref());
    let which = rows().find(|x| x.err().is_some()).and_then(|x| x.error_figures.clone());
    let samples = metros().next().map(|m| m.samples_target);
    let (tlo, thi) = metros().flat_map(|m| [m.a_to_b.samples, m.b_to_a.samples]).fold((u64::MAX, 0), |(lo, hi), t| (lo.min(t), hi.max(t)));
    match (r.metro_bin(), which) {
        (Some(bin), Some(which)) => {
            let _ = writeln!(
                w,
                "Error: `{} metro INPUT OUTPUT --json{}` ({} samples per direction asked, {} taken: metro takes every vertex even when fewer are asked), figures from {which}, divided by the input's bounding-box diagonal.\n",
                bin.display(),
                r.samples.map_or(String::new(), |n| format!(" --samples {n}")),
                samples.map_or("metro's default".into(), thousands),
                if tlo <= thi { format!("{}–{}", thousands(tlo), thousands(thi)) } else { "?".into() },
            );
        }
        (Some(bin), None) => {
            let _ = writeln!(w, "Error: `{} metro` ran but gave no figures; errors n/a.\n", bin.display());
        }
        (None, _) => {
            let _ = writeln!(w, "Error: {}.\n", r.metro_note.as_deref().unwrap_or("metro did not run"));
        }
    }
    let _ = writeln!(
        w,
        "How to read: octolod rows show the whole build (PLY → all levels, out of core under `--mem {}`), its time and throughput repeated on each level it produced; peer rows show one in-core simplification of the whole input to the matching octolod output size, timed without loading (load separate). Throughput is always input triangles per second. Peers see positions only, but for meshoptimizer `simplify` on inputs with uvs: it then weighs them (`simplifyWithAttributes`, weight 1, its seam handling) as the textured-mesh issue asks; octolod models every attribute the input has. Peak RSS is each child process's `VmHWM` (octolod: read after the build, before extraction; peers: including the load). Ratios pair each octolod output with each peer's run at the same target on the same input; below 1 favours octolod.{}\n",
        r.mem,
        match &r.simplify_setting {
            Some(set) => format!(
                " `octolod-collapse` and `octolod-cluster` rows are whole `octolod simplify IN -o OUT --target-tris N --simplifier collapse|cluster --mem {} --leaf-tris {} --level-ratio {}` commands (PLY → store in a scratch folder → the nearest level reduced to N → PLY, out of core), at the peers' targets; their time includes loading and building, and their peak RSS is the command's `ru_maxrss`.",
                r.mem,
                set.split_once('x').map_or("?", |x| x.0),
                set.split_once('x').map_or("?", |x| x.1)
            ),
            None => String::new(),
        }
    );
    if !r.baselines.is_empty() {
        let _ = writeln!(
            w,
            "Baselines: rows whose setting ends in `@LABEL` are the same setting built by that `--baseline` executable through its command line (`BIN build IN -o STORE --leaf-tris L --level-ratio R --simplifier S --mem M`, then `BIN extract STORE --level L -o OUT` per level), measured like the current build's levels. Their time is the wall clock around the whole `build` command, so it includes process start and the binary's own output; peak RSS is the command's `ru_maxrss`; soup / octree / simplify seconds, nodes and the store's size are read from the summary line it prints (n/a where it does not). The peers and `octolod simplify` ran only at the current build's output sizes, so a baseline level pairs with a peer only where its size equals one of those. \"Current ÷ baseline\" divides each current figure by the baseline's for the same setting: below 1 means the current build takes less time, memory or error, except for throughput, where above 1 means it is faster.\n"
        );
    }

    for info in &r.inputs {
        let dim = info.builds.first().map(|b| b.quadric_dim);
        let _ = writeln!(
            w,
            "## {}\n\n`{}`: {} triangles, {} vertices, {}{}, {:.1} MB, bbox diagonal {:.6}.\n",
            info.name,
            info.path.display(),
            thousands(info.triangles),
            thousands(info.vertices),
            info.attributes,
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
        for b in &info.builds {
            let t = b.timed.seconds;
            let _ = writeln!(
                w,
                "| {} | {} | {} | {t:.2} | {} | {:.3} | {:.0} | {} | {} |",
                b.setting(),
                b.levels.len(),
                b.nodes.map_or("n/a".into(), thousands),
                [b.soup_seconds, b.octree_seconds, b.simplify_seconds].map(|x| opt(Some(x), |x| format!("{x:.2}"))).join(" / "),
                info.triangles as f64 / t / 1e6,
                b.timed.peak_rss_mib,
                opt(b.disk_bytes.map(|d| d as f64 / 1e6), |d| format!("{d:.1}")),
                opt(b.timed.other_cpu_cores, |c| format!("{c:.2}")),
            );
        }
        vs_baseline_section(w, info);
        let _ = writeln!(w, "\n### All outputs\n");
        let _ = writeln!(
            w,
            "| method | setting | output tris | time (s) | load (s) | M input tris/s | peak RSS (MiB) | RMS / diag | Hausdorff / diag | others' CPU (cores) |"
        );
        let _ = writeln!(w, "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|");
        let mut mine: Vec<&Row> = info.rows.iter().collect();
        mine.sort_by(|a, b| a.method.cmp(&b.method).then(b.triangles.cmp(&a.triangles)));
        for x in &mine {
            let others = match x.method {
                Method::Octolod => info.builds.iter().find(|b| b.setting() == x.setting).and_then(|b| b.timed.other_cpu_cores),
                _ => x.other_cpu(),
            };
            let _ = writeln!(
                w,
                "| {} | {} | {} | {:.3} | {} | {:.3} | {:.0} | {} | {} | {} |",
                x.method.name(),
                setting_text(x),
                thousands(x.triangles),
                x.seconds,
                match x.method {
                    Method::Octolod => "in build".to_string(),
                    Method::OctolodCollapse | Method::OctolodCluster => "in time".to_string(),
                    _ => opt(x.load_seconds, |l| format!("{l:.3}")),
                },
                x.throughput,
                x.rss_mib,
                opt(x.err().map(|e| e.0 / info.diagonal), sci),
                opt(x.err().map(|e| e.1 / info.diagonal), sci),
                opt(others, |c| format!("{c:.2}")),
            );
        }
        let _ = writeln!(w, "\n### Ratios, octolod ÷ peer at the same target\n");
        let _ =
            writeln!(w, "| octolod output | tris | peer | peer tris | time (build ÷ simplify) | time (build ÷ load+simplify) | peak RSS | RMS | Hausdorff |");
        let _ = writeln!(w, "|---|---:|---|---:|---:|---:|---:|---:|---:|");
        let ps = pairs(&info.rows);
        for p in &ps {
            let _ = writeln!(
                w,
                "| {} | {} | {} | {} | {} | {} | {} | {} | {} |",
                setting_text(p.o),
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
        simplify_section(w, &info.rows);
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
        for b in &info.builds {
            let setting = b.setting();
            for m in Method::PEERS {
                let sel: Vec<&Pair> = ps.iter().filter(|p| p.o.setting == setting && p.p.method == m).collect();
                if sel.is_empty() {
                    continue;
                }
                let build = b.timed.seconds;
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

    sweep_section(w, r);
    if !r.failures.is_empty() {
        let _ = writeln!(w, "## What failed\n");
        for f in &r.failures {
            let _ = writeln!(w, "- {f}");
        }
        let _ = writeln!(w);
    }
    let sfx = &r.suffix;
    let _ = writeln!(w, "## Plots\n");
    let _ = writeln!(w, "![RMS error vs throughput](error_vs_speed{sfx}.svg)\n");
    let _ = writeln!(w, "![RMS error vs output size](error_vs_size{sfx}.svg)\n");
    let _ = writeln!(w, "Raw numbers: `report{sfx}.json`.");
    s
}

/// A `--baseline` build and the current build of the same setting, on one
/// input.
pub struct VsBaseline<'a> {
    pub cur: &'a BuildOut,
    pub base: &'a BuildOut,
    /// Per level measured in both: (current row, baseline row).
    pub levels: Vec<(&'a Row, &'a Row)>,
}

/// Every baseline build of an input with the current build of its setting.
pub fn vs_baselines(info: &InputReport) -> Vec<VsBaseline<'_>> {
    let mut out = Vec::new();
    for base in info.builds.iter().filter(|b| b.baseline.is_some()) {
        let Some(cur) = info.builds.iter().find(|c| c.baseline.is_none() && c.plain_setting() == base.plain_setting()) else { continue };
        let (cs, bs) = (cur.setting(), base.setting());
        let levels = info
            .rows
            .iter()
            .filter(|r| r.method == Method::Octolod && r.setting == cs)
            .filter_map(|c| Some((c, info.rows.iter().find(|r| r.method == Method::Octolod && r.setting == bs && r.level == c.level)?)))
            .collect();
        out.push(VsBaseline { cur, base, levels });
    }
    out
}

/// Current ÷ baseline, figure by figure (`n/a` where either is missing).
fn cur_by_base(c: Option<f64>, b: Option<f64>) -> String {
    opt(c.zip(b).map(|(c, b)| c / b), ratio)
}

/// The progress lines comparing each baseline with the current build.
pub fn vs_baseline_lines(info: &InputReport) -> Vec<String> {
    let n_in = info.triangles as f64;
    let mut out = Vec::new();
    for v in vs_baselines(info) {
        let (c, b) = (&v.cur.timed, &v.base.timed);
        out.push(format!(
            "{} current ÷ @{}: build time {:.2} / {:.2} s = {}, M input tris/s {:.3} / {:.3} = {}, peak RSS {:.0} / {:.0} MiB = {}",
            v.cur.setting(),
            v.base.baseline.as_deref().unwrap_or("?"),
            c.seconds,
            b.seconds,
            ratio(c.seconds / b.seconds),
            n_in / c.seconds / 1e6,
            n_in / b.seconds / 1e6,
            ratio(b.seconds / c.seconds),
            c.peak_rss_mib,
            b.peak_rss_mib,
            ratio(c.peak_rss_mib / b.peak_rss_mib),
        ));
        for (cr, br) in &v.levels {
            out.push(format!(
                "  L{}: triangles {} / {} = {}, RMS {}, Hausdorff {}",
                cr.level.unwrap_or(0),
                thousands(cr.triangles),
                thousands(br.triangles),
                ratio(cr.triangles as f64 / br.triangles as f64),
                cur_by_base(cr.rms, br.rms),
                cur_by_base(cr.hausdorff, br.hausdorff),
            ));
        }
    }
    out
}

/// The "Current ÷ baseline" tables of an input (nothing without baselines).
fn vs_baseline_section(w: &mut String, info: &InputReport) {
    let vs = vs_baselines(info);
    if vs.is_empty() {
        return;
    }
    let n_in = info.triangles as f64;
    let _ = writeln!(w, "\n### Current ÷ baseline\n");
    let _ =
        writeln!(w, "Each figure is current / baseline, then their ratio (current ÷ baseline; for throughput, below 1 means the current build is slower).\n");
    let _ = writeln!(w, "| setting | baseline | build time (s) | ÷ | M input tris/s | ÷ | peak RSS (MiB) | ÷ |");
    let _ = writeln!(w, "|---|---|---:|---:|---:|---:|---:|---:|");
    for v in &vs {
        let (c, b) = (&v.cur.timed, &v.base.timed);
        let (ct, bt) = (n_in / c.seconds / 1e6, n_in / b.seconds / 1e6);
        let _ = writeln!(
            w,
            "| {} | @{} | {:.2} / {:.2} | {} | {ct:.3} / {bt:.3} | {} | {:.0} / {:.0} | {} |",
            v.cur.setting(),
            v.base.baseline.as_deref().unwrap_or("?"),
            c.seconds,
            b.seconds,
            ratio(c.seconds / b.seconds),
            ratio(ct / bt),
            c.peak_rss_mib,
            b.peak_rss_mib,
            ratio(c.peak_rss_mib / b.peak_rss_mib),
        );
    }
    if vs.iter().all(|v| v.levels.is_empty()) {
        return;
    }
    let d = info.diagonal;
    let _ = writeln!(w, "\n| setting | baseline | level | triangles | ÷ | RMS / diag | ÷ | Hausdorff / diag | ÷ |");
    let _ = writeln!(w, "|---|---|---:|---:|---:|---:|---:|---:|---:|");
    for v in &vs {
        for (cr, br) in &v.levels {
            let _ = writeln!(
                w,
                "| {} | @{} | L{} | {} / {} | {} | {} / {} | {} | {} / {} | {} |",
                v.cur.setting(),
                v.base.baseline.as_deref().unwrap_or("?"),
                cr.level.unwrap_or(0),
                thousands(cr.triangles),
                thousands(br.triangles),
                ratio(cr.triangles as f64 / br.triangles as f64),
                opt(cr.rms.map(|x| x / d), sci),
                opt(br.rms.map(|x| x / d), sci),
                cur_by_base(cr.rms, br.rms),
                opt(cr.hausdorff.map(|x| x / d), sci),
                opt(br.hausdorff.map(|x| x / d), sci),
                cur_by_base(cr.hausdorff, br.hausdorff),
            );
        }
    }
}

/// `octolod simplify` against the peers at the same targets, and the
/// bounds issue 10 sets: `collapse` RMS ≤ 1.0× and Hausdorff ≤ 1.2×
/// meshopt `simplify`'s; `cluster` RMS ≤ meshopt `simplify_sloppy`'s.
fn simplify_section(w: &mut String, rows: &[Row]) {
    let ps = simplify_pairs(rows);
    if ps.is_empty() {
        return;
    }
    let _ = writeln!(w, "\n### octolod simplify ÷ peer at the same target\n");
    let _ = writeln!(
        w,
        "One row per `octolod simplify` run; each peer's columns divide its figure by that peer's run at the same target. Time is the whole command ÷ the peer's load + simplification. Below 1 favours octolod.\n"
    );
    let mut head = String::from("| simplifier | target | tris |");
    let mut rule = String::from("|---|---:|---:|");
    // Peers that ran (meshlab-qec only with --meshlab).
    let peers: Vec<Method> = Method::PEERS.into_iter().filter(|&m| rows.iter().any(|r| r.method == m)).collect();
    for &m in &peers {
        let n = m.name();
        let _ = write!(head, " time ÷ {n} | peak RSS ÷ {n} | RMS ÷ {n} | Hausdorff ÷ {n} |");
        rule.push_str("---:|---:|---:|---:|");
    }
    let _ = writeln!(w, "{head}\n{rule}");
    for o in rows.iter().filter(|r| Method::SIMPLIFIERS.contains(&r.method)) {
        let _ = write!(w, "| {} | {} | {} |", o.method.simplifier().unwrap_or("?"), o.target.map_or("?".into(), thousands), thousands(o.triangles));
        for &m in &peers {
            match ps.iter().find(|p| std::ptr::eq(p.o, o) && p.p.method == m) {
                Some(p) => {
                    let _ = write!(w, " {} | {} | {} | {} |", ratio(p.time_with_load()), ratio(p.rss()), opt(p.rms(), ratio), opt(p.hausdorff(), ratio));
                }
                None => w.push_str(" n/a | n/a | n/a | n/a |"),
            }
        }
        w.push('\n');
    }
    let _ = writeln!(w);
    for m in Method::SIMPLIFIERS {
        let Some(peer) = m.counterpart() else { continue };
        let sel: Vec<&Pair> = ps.iter().filter(|p| p.o.method == m && p.p.method == peer).collect();
        if sel.is_empty() {
            continue;
        }
        let range = |xs: &[f64]| -> String {
            let (lo, hi) = xs.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), &x| (lo.min(x), hi.max(x)));
            match xs.len() {
                0 => "n/a".into(),
                1 => ratio(lo),
                _ => format!("{}–{}", ratio(lo), ratio(hi)),
            }
        };
        let within = |xs: &[f64], bound: f64| format!("{} (≤ {bound} at {} of {})", range(xs), xs.iter().filter(|&&x| x <= bound).count(), xs.len());
        let rms: Vec<f64> = sel.iter().filter_map(|p| p.rms()).collect();
        let hd: Vec<f64> = sel.iter().filter_map(|p| p.hausdorff()).collect();
        let hd_text = if m == Method::OctolodCollapse { format!(", Hausdorff {}", within(&hd, 1.2)) } else { format!(", Hausdorff {}", range(&hd)) };
        let _ = writeln!(w, "- `{}` ÷ {} over {} targets: RMS {}{hd_text}.", m.simplifier().unwrap_or("?"), peer.name(), sel.len(), within(&rms, 1.0),);
    }
}

/// The attribute sweep's table.
fn sweep_section(w: &mut String, r: &Report) {
    let sweep = &r.attr_sweep;
    if sweep.is_empty() {
        return;
    }
    let base = &sweep[0];
    let bt = base.build.timed.seconds / base.triangles as f64;
    let br = base.build.timed.peak_rss_mib / base.triangles as f64;
    let bs = base.build.simplify_seconds;
    let _ = writeln!(w, "## Model only what a scene needs: attribute sweep\n");
    let _ = writeln!(
        w,
        "The same generated sphere ({} triangles, seed 1) with four vertex attribute sets, built by octolod with setting {} under `--mem {}` (build only). The quadric dimension follows the attributes present, so a position-only input pays nothing for attributes it does not have.\n",
        thousands(base.triangles),
        r.settings.first().map_or("", |s| s.as_str()),
        r.mem
    );
    let _ = writeln!(
        w,
        "| attributes | quadric dim | PLY (MB) | build (s) | soup / octree / simplify (s) | ns per input tri | peak RSS (MiB) | RSS bytes per input tri | store on disk (MB) | time ÷ position-only | simplify ÷ position-only | RSS ÷ position-only | others' CPU (cores) |"
    );
    let _ = writeln!(w, "|---|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|");
    for x in sweep {
        let b = &x.build;
        let (t, rss, simp) = (b.timed.seconds, b.timed.peak_rss_mib, b.simplify_seconds);
        let _ = writeln!(
            w,
            "| {} (`{}`) | {} | {:.1} | {t:.2} | {:.2} / {:.2} / {simp:.2} | {:.0} | {rss:.0} | {:.0} | {:.1} | {} | {} | {} | {} |",
            x.label,
            x.attributes,
            x.quadric_dim,
            x.ply_bytes as f64 / 1e6,
            b.soup_seconds,
            b.octree_seconds,
            t * 1e9 / x.triangles as f64,
            rss * 1048576.0 / x.triangles as f64,
            b.disk_bytes.map_or(f64::NAN, |d| d as f64 / 1e6),
            ratio(t / x.triangles as f64 / bt),
            ratio(simp / bs),
            ratio(rss / x.triangles as f64 / br),
            opt(b.timed.other_cpu_cores, |c| format!("{c:.2}")),
        );
    }
    let budget = octolod::mem::parse_size(&r.mem).map_or(f64::NAN, |b| b as f64 / 1048576.0);
    if sweep.iter().all(|x| x.build.timed.peak_rss_mib >= 0.95 * budget) {
        let _ = writeln!(
            w,
            "\nEvery build here filled its `--mem {}` budget, so peak RSS is the budget whatever the attributes: at this size they cost time and disk, not memory.",
            r.mem
        );
    }
    let _ = writeln!(w);
}
