//! The two log–log SVG plots (error against throughput, error against
//! output size), one panel per input, drawn by hand.

use crate::report::thousands;
use crate::types::{InputReport, Method, Row};
use std::fmt::Write as _;

#[derive(Clone, Copy)]
enum Marker {
    Circle,
    Square,
    Triangle,
    Diamond,
    Cross,
    TriangleDown,
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
        Method::OctolodCollapse => "#d81b60",
        Method::OctolodCluster => "#6d4c41",
        Method::MeshlabQec => "#546e7a",
    }
}

/// (error vs speed, error vs size): one panel per input, on shared axes.
pub fn plots(inputs: &[InputReport]) -> (String, String) {
    // Colour: method (octolod: shades per setting); shape: octolod setting
    // (peers: circles; `octolod simplify`: downward triangles).
    let markers = [Marker::Square, Marker::Diamond, Marker::Triangle, Marker::Cross];
    let mut settings: Vec<String> = Vec::new();
    for r in inputs.iter().flat_map(|i| &i.rows).filter(|r| r.method == Method::Octolod) {
        if !settings.contains(&r.setting) {
            settings.push(r.setting.clone());
        }
    }
    let make = |x: &dyn Fn(&Row) -> f64, join_peers: bool| -> Vec<Panel> {
        inputs
            .iter()
            .map(|info| {
                let rows = &info.rows;
                let mut keys: Vec<(Method, &str)> = Vec::new();
                for r in rows {
                    if !keys.contains(&(r.method, r.setting.as_str())) {
                        keys.push((r.method, r.setting.as_str()));
                    }
                }
                let series = keys
                    .iter()
                    .map(|&(m, setting)| {
                        let mut rs: Vec<&Row> = rows.iter().filter(|r| r.method == m && r.setting == setting).collect();
                        rs.sort_by_key(|r| std::cmp::Reverse(r.triangles));
                        let points = rs
                            .iter()
                            .filter_map(|r| {
                                let (rms, max) = r.err()?;
                                Some((
                                    x(r),
                                    rms / info.diagonal,
                                    format!(
                                        "{} {}: {} tris, {:.3} M tri/s, RMS {:.3e}, Hausdorff {:.3e}",
                                        r.method.name(),
                                        crate::report::setting_text(r),
                                        thousands(r.triangles),
                                        r.throughput,
                                        rms / info.diagonal,
                                        max / info.diagonal
                                    ),
                                ))
                            })
                            .collect();
                        let k = settings.iter().position(|s| s == setting).unwrap_or(0);
                        let (label, color, marker) = match m {
                            Method::Octolod => (format!("octolod {setting}"), OCTOLOD_COLORS[k % OCTOLOD_COLORS.len()], markers[k % markers.len()]),
                            Method::OctolodCollapse | Method::OctolodCluster => {
                                (format!("octolod simplify {}", m.simplifier().unwrap_or("?")), method_color(m), Marker::TriangleDown)
                            }
                            m => (m.name().to_string(), method_color(m), Marker::Circle),
                        };
                        Series { label, color, marker, points, join: join_peers || m == Method::Octolod }
                    })
                    .collect();
                Panel { title: format!("{}: {} triangles, {}", info.name, thousands(info.triangles), info.attributes), series }
            })
            .collect()
    };
    let speed = svg_plot(
        "RMS error vs throughput",
        "throughput (M input triangles / s, log)",
        "RMS error / bbox diagonal (log)",
        &make(&|r| r.throughput, false),
        "octolod: one build makes every level, so a setting's outputs share its throughput (joined by a line); peers and octolod simplify: one run per output",
    );
    let size = svg_plot(
        "RMS error vs output size",
        "output triangles (log)",
        "RMS error / bbox diagonal (log)",
        &make(&|r| r.triangles as f64, true),
        "peers and octolod simplify are run at each octolod output size",
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
        if m == 1.0 {
            format!("1e{e}")
        } else {
            format!("{m}e{e}")
        }
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
        Marker::TriangleDown => format!(
            "<polygon points=\"{:.1},{:.1} {:.1},{:.1} {:.1},{:.1}\" fill=\"{color}\" stroke=\"white\" stroke-width=\"1\"/>",
            x,
            y + 1.3 * r,
            x - 1.2 * r,
            y - r,
            x + 1.2 * r,
            y - r
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
        let _ = writeln!(s, "<rect x=\"{px0}\" y=\"{py0}\" width=\"{:.1}\" height=\"{:.1}\" fill=\"none\" stroke=\"#333\"/>", px1 - px0, py1 - py0);
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
            let _ = writeln!(s, "<polyline points=\"{}\" fill=\"none\" stroke=\"{}\" stroke-width=\"1.6\" stroke-opacity=\"0.75\"/>", pts.join(" "), se.color);
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
    notes.extend(wrap(&format!("{joined}colour: method, shape: octolod setting (peers: circles, octolod simplify: downward triangles)"), 44));
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
    fn log_axis_ticks() {
        let t = log_ticks(-3.2, -0.9);
        assert!(t.iter().any(|&(v, l)| (v - 1e-3).abs() < 1e-12 && l));
        assert!(t.iter().any(|&(v, l)| (v - 2e-2).abs() < 1e-12 && l));
        assert_eq!(tick_label(0.002), "0.002");
        assert_eq!(tick_label(2e-5), "2e-5");
        assert_eq!(tick_label(20000.0), "20,000");
    }
}
