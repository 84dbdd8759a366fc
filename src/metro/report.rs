//! The report of a comparison: figures per direction and combined, the
//! operands' summaries, thresholds checked, as a table or as JSON.
//!
//! Takes: a [`Report`] and the [`Limits`] given. Gives: [`Report::table`],
//! and [`Report::to_json`], which serialises the typed [`JsonReport`]
//! (whose documentation is the format) with serde.

use super::measure::Distances;
use crate::error::{Error, Result};
use crate::geom::{Mesh, P3};
use crate::mesh::Aabb;
use serde::{Deserialize, Serialize};
use std::fmt;

/// Figures of one operand.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshSummary {
    /// The spec it was loaded from (`A`/`B` when compared in memory).
    pub source: String,
    /// Vertices referenced by triangles.
    pub vertices: u64,
    pub faces: u64,
    pub area: f64,
    pub bbox: Aabb,
}

impl MeshSummary {
    pub(super) fn of(m: &Mesh, source: &str) -> MeshSummary {
        MeshSummary {
            source: source.to_string(),
            vertices: m.referenced_vertices().len() as u64,
            faces: m.triangles.len() as u64,
            area: m.area(),
            bbox: m.bbox(),
        }
    }
}

/// Seconds spent (not part of the JSON report, which is deterministic).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Timings {
    pub load: f64,
    pub bvh: f64,
    pub a_to_b: f64,
    pub b_to_a: f64,
}

/// The result of [`compare`](super::compare).
#[derive(Clone, Debug, PartialEq)]
pub struct Report {
    pub a: MeshSummary,
    pub b: MeshSummary,
    /// The diagonal relative figures and percentage thresholds refer to:
    /// A's bounding box.
    pub diagonal: f64,
    /// Diagonal of the union of both boxes (what vcglib's Metro uses).
    pub union_diagonal: f64,
    pub seed: u64,
    /// Samples per direction asked for.
    pub samples_target: u64,
    pub a_to_b: Distances,
    pub b_to_a: Distances,
    /// Max of both maxima; mean and RMS over the samples of both directions.
    pub combined: Distances,
    pub seconds: Timings,
    /// Present when an operand was a paged store level.
    pub paging: Option<PagingReport>,
    /// Attribute differences (`--attributes`).
    pub attributes: Option<super::attributes::AttrReport>,
}

/// What paging did (present when an operand is a store level; the JSON
/// report's `paging` object, these fields in this order). Cache figures
/// depend on thread scheduling; everything else in the report is a
/// function of the inputs, options and seed.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PagingReport {
    /// `--mem`.
    pub budget: u64,
    /// What the page cache got: the budget less the batch buffers and, with
    /// an explicit `--mem`, the PLY operands' estimated size.
    pub cache_budget: u64,
    /// Estimated bytes of the PLY operands held whole (mesh, index, plan).
    pub ply_estimate: u64,
    /// Samples per batch.
    pub batch_samples: u64,
    /// Largest resident cache bytes seen (entries and load reservations).
    pub peak_resident: u64,
    /// Node meshes read and indexed.
    pub loads: u64,
    /// Cache lookups answered without a read.
    pub hits: u64,
    pub evictions: u64,
    /// Times the cache could not get under its budget (0 unless a bug).
    pub overcommits: u64,
    /// Bytes read by loads, and by the opening scans.
    pub bytes_read: u64,
    pub scan_bytes: u64,
    /// Parts (cut nodes) of each operand; `null` for one held in memory.
    pub parts: JsonParts,
    /// Threads querying a paged target, A -> B and B -> A (0: in memory).
    pub query_threads: [u64; 2],
    /// Peak RSS of the process (VmHWM), where the OS tells.
    pub peak_rss: Option<u64>,
}

/// A distance limit: absolute, or a percentage of the reference diagonal.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Threshold {
    Absolute(f64),
    Percent(f64),
}

impl Threshold {
    /// `0.01` (absolute) or `0.1%` (of the diagonal); finite and >= 0.
    pub fn parse(s: &str) -> Result<Threshold> {
        let t = s.trim();
        let (num, pct) = match t.strip_suffix('%') {
            Some(n) => (n.trim_end(), true),
            None => (t, false),
        };
        let bad = || Error::Usage(format!("bad threshold '{s}': expected a distance like 0.01 or a percentage of the diagonal like 0.1%"));
        let x: f64 = num.parse().map_err(|_| bad())?;
        if !x.is_finite() || x < 0.0 || num.starts_with('+') {
            return Err(bad());
        }
        Ok(if pct { Threshold::Percent(x) } else { Threshold::Absolute(x) })
    }
    /// The absolute limit for a given diagonal.
    pub fn limit(&self, diagonal: f64) -> f64 {
        match *self {
            Threshold::Absolute(x) => x,
            Threshold::Percent(p) => p / 100.0 * diagonal,
        }
    }
}

impl fmt::Display for Threshold {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Threshold::Absolute(x) => write!(f, "{x}"),
            Threshold::Percent(p) => write!(f, "{p}%"),
        }
    }
}

/// Limits on the combined figures.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Limits {
    pub hausdorff: Option<Threshold>,
    pub rms: Option<Threshold>,
    pub mean: Option<Threshold>,
}

impl Limits {
    /// Parses the three optional CLI strings.
    pub fn parse(hausdorff: Option<&str>, rms: Option<&str>, mean: Option<&str>) -> Result<Limits> {
        let p = |s: Option<&str>| s.map(Threshold::parse).transpose();
        Ok(Limits { hausdorff: p(hausdorff)?, rms: p(rms)?, mean: p(mean)? })
    }
}

/// One threshold checked against the combined figures.
#[derive(Clone, Debug, PartialEq)]
pub struct Check {
    /// `hausdorff`, `rms` or `mean`.
    pub metric: &'static str,
    /// The CLI option, e.g. `--max-hausdorff`.
    pub option: &'static str,
    pub threshold: Threshold,
    /// Absolute limit.
    pub limit: f64,
    pub value: f64,
    pub exceeded: bool,
}

impl Report {
    /// Every given threshold, exceeded or not (value > limit exceeds).
    pub fn check(&self, limits: &Limits) -> Vec<Check> {
        let c = &self.combined;
        [("hausdorff", "--max-hausdorff", limits.hausdorff, c.max), ("rms", "--max-rms", limits.rms, c.rms), ("mean", "--max-mean", limits.mean, c.mean)]
            .into_iter()
            .filter_map(|(metric, option, t, value)| {
                t.map(|threshold| {
                    let limit = threshold.limit(self.diagonal);
                    // A figure that is not a number never passes.
                    Check { metric, option, threshold, limit, value, exceeded: !(value <= limit) }
                })
            })
            .collect()
    }

    fn rel(&self, x: f64) -> f64 {
        if self.diagonal > 0.0 {
            x / self.diagonal
        } else {
            f64::NAN
        }
    }

    /// The JSON report's typed form (see [`JsonReport`]).
    pub fn json(&self, limits: &Limits) -> JsonReport {
        let mesh = |m: &MeshSummary| JsonMesh {
            source: m.source.clone(),
            vertices: m.vertices,
            faces: m.faces,
            area: m.area,
            bbox: JsonBox { min: m.bbox.min, max: m.bbox.max },
            diagonal: m.bbox.diagonal(),
        };
        let dist = |d: &Distances| JsonDistances {
            samples: d.samples,
            vertex_samples: d.vertex_samples,
            edge_samples: d.edge_samples,
            face_samples: d.face_samples,
            max: d.max,
            mean: d.mean,
            rms: d.rms,
            max_rel: self.rel(d.max),
            mean_rel: self.rel(d.mean),
            rms_rel: self.rel(d.rms),
            max_at: d.max_at,
        };
        let checks = self.check(limits);
        JsonReport {
            a: mesh(&self.a),
            b: mesh(&self.b),
            diagonal: self.diagonal,
            diagonal_of: "a".into(),
            union_diagonal: self.union_diagonal,
            seed: self.seed,
            samples_target: self.samples_target,
            a_to_b: dist(&self.a_to_b),
            b_to_a: dist(&self.b_to_a),
            combined: dist(&self.combined),
            hausdorff: self.combined.max,
            hausdorff_rel: self.rel(self.combined.max),
            pass: !checks.iter().any(|c| c.exceeded),
            thresholds: checks
                .into_iter()
                .map(|c| JsonCheck {
                    metric: c.metric.into(),
                    option: c.option.into(),
                    given: c.threshold.to_string(),
                    limit: c.limit,
                    value: c.value,
                    exceeded: c.exceeded,
                })
                .collect(),
            paging: self.paging.clone(),
            attributes: self.attributes,
        }
    }

    /// One JSON object, [`Report::json`] serialised (no timings: a pure
    /// function of the inputs, options and seed, but for `paging`).
    pub fn to_json(&self, limits: &Limits) -> String {
        to_json_string(&self.json(limits))
    }

    /// The human-readable report.
    pub fn table(&self) -> String {
        use std::fmt::Write as _;
        let mut s = String::new();
        let bb = |b: &Aabb| format!("[{:.6}, {:.6}, {:.6}] .. [{:.6}, {:.6}, {:.6}]", b.min[0], b.min[1], b.min[2], b.max[0], b.max[1], b.max[2]);
        for (name, m) in [("A", &self.a), ("B", &self.b)] {
            let _ = writeln!(
                s,
                "{name}: {}: {} faces, {} vertices, area {:.6e}, bbox {}, diagonal {:.6e}",
                m.source,
                m.faces,
                m.vertices,
                m.area,
                bb(&m.bbox),
                m.bbox.diagonal()
            );
        }
        let _ = writeln!(
            s,
            "relative figures: % of A's bbox diagonal {:.6e} (union diagonal {:.6e}); {} samples per direction asked, seed {}",
            self.diagonal, self.union_diagonal, self.samples_target, self.seed
        );
        let _ = writeln!(
            s,
            "{:<9} {:>11} {:>10} {:>10} {:>10} {:>13} {:>13} {:>13} {:>10} {:>10} {:>10}",
            "direction", "samples", "vertex", "edge", "face", "max", "mean", "rms", "max %", "mean %", "rms %"
        );
        for (name, d) in [("A -> B", &self.a_to_b), ("B -> A", &self.b_to_a), ("both", &self.combined)] {
            let _ = writeln!(
                s,
                "{name:<9} {:>11} {:>10} {:>10} {:>10} {:>13.6e} {:>13.6e} {:>13.6e} {:>10.5} {:>10.5} {:>10.5}",
                d.samples,
                d.vertex_samples,
                d.edge_samples,
                d.face_samples,
                d.max,
                d.mean,
                d.rms,
                100.0 * self.rel(d.max),
                100.0 * self.rel(d.mean),
                100.0 * self.rel(d.rms)
            );
        }
        let _ = writeln!(
            s,
            "hausdorff (two-sided): {:.6e} ({:.5}% of diagonal), at [{}, {}, {}]",
            self.combined.max,
            100.0 * self.rel(self.combined.max),
            self.combined.max_at[0],
            self.combined.max_at[1],
            self.combined.max_at[2]
        );
        if let Some(p) = &self.paging {
            let parts = |n: Option<u64>| n.map_or("in memory".to_string(), |n| format!("{n} parts"));
            let _ = writeln!(
                s,
                "paging: --mem {} (cache {}), peak resident {}; A {}, B {}; {} loads ({} read, {} scanned), {} hits, {} evictions; query threads {}/{}",
                crate::progress::mib(p.budget),
                crate::progress::mib(p.cache_budget),
                crate::progress::mib(p.peak_resident),
                parts(p.parts.a),
                parts(p.parts.b),
                p.loads,
                crate::progress::mib(p.bytes_read),
                crate::progress::mib(p.scan_bytes),
                p.hits,
                p.evictions,
                p.query_threads[0],
                p.query_threads[1]
            );
        }
        let t = &self.seconds;
        let q = t.a_to_b + t.b_to_a;
        let _ = write!(
            s,
            "time: load {:.3} s, BVH {:.3} s, A -> B {:.3} s, B -> A {:.3} s; {:.3} M samples/s; peak RSS {}",
            t.load,
            t.bvh,
            t.a_to_b,
            t.b_to_a,
            self.combined.samples as f64 / 1e6 / q.max(1e-9),
            crate::progress::peak_rss().map_or("n/a".to_string(), crate::progress::mib)
        );
        if let Some(a) = &self.attributes {
            for (name, d) in [("A -> B", &a.a_to_b), ("B -> A", &a.b_to_a), ("both", &a.combined)] {
                for (what, f) in [("uv", d.uv), ("colour", d.color)] {
                    if let Some(f) = f {
                        let _ =
                            write!(s, "\nattributes {name}: {what} difference max {:.6e} mean {:.6e} RMS {:.6e} ({} samples)", f.max, f.mean, f.rms, d.samples);
                    }
                }
            }
        }
        s
    }
}

/// The JSON report of `octolod metro --json`: one object on one line, keys
/// in the order of the fields below. It holds no timings, so two runs with
/// the same inputs, options and seed give the same bytes, but for the
/// `paging` object's cache counters and peak RSS, which depend on thread
/// scheduling. Numbers are written in Rust's shortest round-trip form
/// (`0.25`, `3.0`, `1e-7`), and a figure that is not finite as `null`.
/// Relative figures (`*_rel`) are divided by `diagonal`, A's bounding-box
/// diagonal. Reading one back (`Deserialize`, as octolod-bench does) takes
/// `null` figures as NaN; unknown keys are ignored.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JsonReport {
    /// Operand A, the reference.
    pub a: JsonMesh,
    /// Operand B.
    pub b: JsonMesh,
    /// A's bounding-box diagonal: the unit of relative figures and of
    /// percentage thresholds.
    #[serde(deserialize_with = "nullable")]
    pub diagonal: f64,
    /// Whose box `diagonal` is: always `"a"`.
    pub diagonal_of: String,
    /// Diagonal of the union of both boxes (what vcglib's Metro divides by).
    #[serde(deserialize_with = "nullable")]
    pub union_diagonal: f64,
    /// `--seed`.
    pub seed: u64,
    /// Samples per direction asked for (`--samples`, or 10 × the larger
    /// face count).
    pub samples_target: u64,
    /// Samples on A, distances to B.
    pub a_to_b: JsonDistances,
    /// Samples on B, distances to A.
    pub b_to_a: JsonDistances,
    /// Both directions: max of the maxima, mean and RMS over all samples.
    pub combined: JsonDistances,
    /// The two-sided Hausdorff distance (`combined.max`).
    #[serde(deserialize_with = "nullable")]
    pub hausdorff: f64,
    /// `hausdorff / diagonal`.
    #[serde(deserialize_with = "nullable")]
    pub hausdorff_rel: f64,
    /// Every threshold given, in the order hausdorff, rms, mean.
    pub thresholds: Vec<JsonCheck>,
    /// True when no threshold is exceeded.
    pub pass: bool,
    /// Present only when an operand was paged (a store level, or a PLY
    /// over an explicit `--mem`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub paging: Option<PagingReport>,
    /// Present with `--attributes`: uv and colour differences at the
    /// closest point, per direction and combined ([`super::attributes`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub attributes: Option<super::attributes::AttrReport>,
}

/// One operand in [`JsonReport`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JsonMesh {
    /// The operand as given: a PLY path or `STORE@L` (`A`/`B` when
    /// compared in memory through the library).
    pub source: String,
    /// Vertices referenced by triangles (a store level's welded by
    /// bit-identical positions).
    pub vertices: u64,
    pub faces: u64,
    /// Total triangle area.
    #[serde(deserialize_with = "nullable")]
    pub area: f64,
    /// Bounding box of the referenced vertices.
    pub bbox: JsonBox,
    /// The box's diagonal.
    #[serde(deserialize_with = "nullable")]
    pub diagonal: f64,
}

/// An axis-aligned box: `[x, y, z]` corners.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JsonBox {
    #[serde(deserialize_with = "nullable3")]
    pub min: P3,
    #[serde(deserialize_with = "nullable3")]
    pub max: P3,
}

/// The figures of one direction (or both combined) in [`JsonReport`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JsonDistances {
    /// Samples measured: vertex + edge + face samples.
    pub samples: u64,
    pub vertex_samples: u64,
    pub edge_samples: u64,
    pub face_samples: u64,
    /// Largest distance (one-sided Hausdorff; two-sided when combined).
    #[serde(deserialize_with = "nullable")]
    pub max: f64,
    /// Mean distance over the samples.
    #[serde(deserialize_with = "nullable")]
    pub mean: f64,
    /// Root mean square distance over the samples.
    #[serde(deserialize_with = "nullable")]
    pub rms: f64,
    /// `max / diagonal`.
    #[serde(deserialize_with = "nullable")]
    pub max_rel: f64,
    /// `mean / diagonal`.
    #[serde(deserialize_with = "nullable")]
    pub mean_rel: f64,
    /// `rms / diagonal`.
    #[serde(deserialize_with = "nullable")]
    pub rms_rel: f64,
    /// The sample at which `max` was found, `[x, y, z]`.
    #[serde(deserialize_with = "nullable3")]
    pub max_at: P3,
}

/// One threshold checked in [`JsonReport`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JsonCheck {
    /// `hausdorff`, `rms` or `mean`.
    pub metric: String,
    /// The option that set it: `--max-hausdorff`, `--max-rms` or `--max-mean`.
    pub option: String,
    /// The threshold as given back: `0.01` or `0.1%`.
    pub given: String,
    /// The absolute limit (a percentage taken of `diagonal`).
    #[serde(deserialize_with = "nullable")]
    pub limit: f64,
    /// The combined figure checked.
    #[serde(deserialize_with = "nullable")]
    pub value: f64,
    /// `value > limit` (a figure that is not a number is exceeded).
    pub exceeded: bool,
}

/// Parts (cut nodes) of each paged operand, `null` for one in memory.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JsonParts {
    pub a: Option<u64>,
    pub b: Option<u64>,
}

/// A figure written as `null` (not finite) reads back as NaN.
fn nullable<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// [`nullable`] for `[x, y, z]`.
fn nullable3<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<P3, D::Error> {
    Ok(<[Option<f64>; 3]>::deserialize(d)?.map(|x| x.unwrap_or(f64::NAN)))
}

/// serde_json's compact output, numbers in Rust's shortest round-trip
/// `Debug` form (`1e-7` where serde_json would write `0.0000001`) and every
/// control character but `\n`, `\r` and `\t` as `\u00xx`: the bytes the
/// report has always had, so scripts diffing reports see no change.
struct Compact;

impl serde_json::ser::Formatter for Compact {
    fn write_f64<W: ?Sized + std::io::Write>(&mut self, w: &mut W, value: f64) -> std::io::Result<()> {
        // serde_json writes non-finite values as `null` without asking.
        write!(w, "{value:?}")
    }
    fn write_char_escape<W: ?Sized + std::io::Write>(&mut self, w: &mut W, e: serde_json::ser::CharEscape) -> std::io::Result<()> {
        use serde_json::ser::CharEscape;
        match e {
            CharEscape::Backspace => w.write_all(b"\\u0008"),
            CharEscape::FormFeed => w.write_all(b"\\u000c"),
            e => serde_json::ser::CompactFormatter.write_char_escape(w, e),
        }
    }
}

/// `value` as compact JSON with [`Compact`]'s numbers and escapes.
fn to_json_string<T: Serialize>(value: &T) -> String {
    let mut out = Vec::new();
    value.serialize(&mut serde_json::Serializer::with_formatter(&mut out, Compact)).expect("serialising plain structs to memory cannot fail");
    String::from_utf8(out).expect("serde_json writes UTF-8")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thresholds_parse() {
        assert_eq!(Threshold::parse("0.01").unwrap(), Threshold::Absolute(0.01));
        assert_eq!(Threshold::parse("0.1%").unwrap(), Threshold::Percent(0.1));
        assert_eq!(Threshold::parse("1e-3").unwrap(), Threshold::Absolute(1e-3));
        assert_eq!(Threshold::parse("2 %").unwrap(), Threshold::Percent(2.0));
        for bad in ["", "%", "abc", "1%%", "-1", "-0.5%", "nan", "inf", "1x", "+1"] {
            assert!(matches!(Threshold::parse(bad), Err(Error::Usage(_))), "'{bad}' accepted");
        }
        assert_eq!(Threshold::Percent(0.5).limit(4.0), 0.02);
        assert_eq!(Threshold::Absolute(0.5).limit(4.0), 0.5);
    }

    #[test]
    fn json_escapes_and_numbers() {
        assert_eq!(to_json_string(&"a\"b\\c\n"), "\"a\\\"b\\\\c\\n\"");
        assert_eq!(to_json_string(&f64::NAN), "null");
        assert_eq!(to_json_string(&1.0), "1.0");
        assert_eq!(to_json_string(&1e-7), "1e-7");
        // Control characters as the hand-written writer had them.
        assert_eq!(to_json_string(&"\u{8}\u{c}\u{1}\t"), "\"\\u0008\\u000c\\u0001\\t\"");
    }

    /// The report reads back into the same typed form (octolod-bench
    /// reads metro's output this way); `null` figures come back as NaN.
    #[test]
    fn json_reads_back() {
        let d = Distances {
            samples: 10,
            vertex_samples: 3,
            edge_samples: 3,
            face_samples: 4,
            max: 0.5,
            mean: 0.1,
            rms: 0.2,
            max_at: [1.0, f64::NAN, 3.0],
            sum: 1.0,
            sum2: 0.4,
        };
        let m = MeshSummary { source: "a.ply".into(), vertices: 3, faces: 1, area: 0.5, bbox: Aabb { min: [0.0; 3], max: [1.0; 3] } };
        let r = Report {
            a: m.clone(),
            b: MeshSummary { source: "b\"c".into(), ..m },
            diagonal: 3f64.sqrt(),
            union_diagonal: 3f64.sqrt(),
            seed: 7,
            samples_target: 10,
            a_to_b: d,
            b_to_a: d,
            combined: d,
            seconds: Timings::default(),
            paging: Some(PagingReport { budget: 1 << 20, parts: JsonParts { a: Some(4), b: None }, ..Default::default() }),
            attributes: None,
        };
        let limits = Limits::parse(Some("0.1%"), None, None).unwrap();
        let text = r.to_json(&limits);
        let back: JsonReport = serde_json::from_str(&text).unwrap();
        assert!(back.combined.max_at[1].is_nan());
        let mut want = r.json(&limits);
        for j in [&mut want.a_to_b, &mut want.b_to_a, &mut want.combined] {
            j.max_at[1] = 0.0;
        }
        let mut got = back.clone();
        for j in [&mut got.a_to_b, &mut got.b_to_a, &mut got.combined] {
            j.max_at[1] = 0.0;
        }
        assert_eq!(got, want);
        assert_eq!(got.thresholds[0].option, "--max-hausdorff");
        assert_eq!(got.b.source, "b\"c");
        // Written again, the same bytes.
        assert_eq!(to_json_string(&back), text);
    }
}
