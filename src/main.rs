//! `octolod` command line: a thin layer over the library's stages.

use clap::{Parser, Subcommand};
use octolod::mesh::Aabb;
use octolod::ply::read::{read_body, BodySink};
use octolod::progress::{peak_rss, Progress};
use octolod::{mem, ply, soup, Result};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(name = "octolod", version, about = "Simplify and view triangle meshes far larger than RAM")]
struct Cli {
    /// No progress bars (they are also hidden when stderr is not a terminal).
    #[arg(long, short, global = true)]
    quiet: bool,
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Turn an indexed PLY into a triangle soup by external sort + dereference.
    Soup {
        input: PathBuf,
        #[arg(short, long)]
        output: PathBuf,
        /// Working-memory budget (e.g. 128M, 2G).
        #[arg(long, default_value = "256M")]
        mem: String,
        /// Use the external-sort path even when the vertices fit in memory.
        #[arg(long)]
        external: bool,
        /// Print the report as JSON on stdout instead of a summary line.
        #[arg(long)]
        json: bool,
    },
    /// Print a PLY's header, element counts, attribute set and bounding box.
    PlyInfo {
        input: PathBuf,
        /// Only parse the header (no bbox, no body validation).
        #[arg(long)]
        header_only: bool,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("octolod: error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.cmd {
        Cmd::Soup { input, output, mem, external, json } => {
            let opts = soup::SoupOptions {
                mem: mem::parse_size(&mem)?,
                quiet: cli.quiet,
                force_external: external,
                max_fan_in: None,
            };
            let rep = soup::build_soup(&input, &output, &opts)?;
            let peak = peak_rss();
            if json {
                println!(
                    "{{\"faces\":{},\"triangles\":{},\"degenerate\":{},\"polygons\":{},\"vertices\":{},\"input_bytes\":{},\"external\":{},\"seconds\":{:.4},\"mb_per_s\":{:.2},\"mtris_per_s\":{:.3},\"peak_rss_bytes\":{},\"mem_budget_bytes\":{},\"corner_runs\":{},\"corner_merge_passes\":{},\"slot_buckets\":{},\"spilled_bytes\":{},\"phase_seconds\":[{:.3},{:.3},{:.3}]}}",
                    rep.body.faces,
                    rep.header.triangles,
                    rep.header.degenerate,
                    rep.body.polygons,
                    rep.body.vertices,
                    rep.input_bytes,
                    rep.external,
                    rep.seconds,
                    rep.input_bytes as f64 / 1e6 / rep.seconds.max(1e-9),
                    rep.body.triangles as f64 / 1e6 / rep.seconds.max(1e-9),
                    peak.unwrap_or(0),
                    opts.mem,
                    rep.sort_by_vertex.runs,
                    rep.sort_by_vertex.merge_passes,
                    rep.slot_buckets,
                    rep.sort_by_vertex.spilled_bytes + rep.bucket_bytes,
                    rep.phase_seconds[0],
                    rep.phase_seconds[1],
                    rep.phase_seconds[2],
                );
            } else {
                println!("{}", rep.summary(peak));
            }
            Ok(())
        }
        Cmd::PlyInfo { input, header_only } => ply_info(&input, header_only, cli.quiet),
    }
}

struct BboxSink {
    bbox: Aabb,
}

impl BodySink for BboxSink {
    fn vertices(&mut self, _first: u64, batch: &[octolod::mesh::Vertex]) -> Result<()> {
        for v in batch {
            self.bbox.add(v.pos);
        }
        Ok(())
    }
    fn triangles(&mut self, _batch: &[[u64; 3]]) -> Result<()> {
        Ok(())
    }
}

fn ply_info(input: &std::path::Path, header_only: bool, quiet: bool) -> Result<()> {
    let h = ply::read_header(input)?;
    println!("file: {}", input.display());
    println!("format: {}", h.encoding.header_name());
    println!("header bytes: {}", h.body_offset);
    for c in &h.comments {
        println!("comment: {c}");
    }
    for e in &h.elements {
        let props: Vec<String> = e
            .props
            .iter()
            .map(|p| match p.ty {
                ply::PropType::Scalar(s) => format!("{} {}", s.name(), p.name),
                ply::PropType::List(c, s) => format!("list {} {} {}", c.name(), s.name(), p.name),
            })
            .collect();
        println!("element {} {}: {}", e.name, e.count, props.join(", "));
    }
    println!("vertices: {}", h.vertex_count());
    println!("faces: {}", h.face_count());
    println!("attributes: {}", h.attrs.describe());
    println!("quadric dimension: {}", h.attrs.quadric_dim());
    if header_only {
        return Ok(());
    }
    let len = std::fs::metadata(input).map(|m| m.len()).unwrap_or(0);
    let progress = Progress::bytes(len, "scanning", quiet);
    let mut sink = BboxSink { bbox: Aabb::EMPTY };
    let t0 = std::time::Instant::now();
    let st = read_body(input, &h, &mut sink, &progress)?;
    let secs = t0.elapsed().as_secs_f64();
    progress.finish();
    let b = sink.bbox;
    println!("triangles (after fan triangulation): {}", st.triangles);
    println!("degenerate triangles: {}", st.degenerate);
    println!("polygons (>3 corners): {}", st.polygons);
    println!(
        "decoded: {} bytes in {:.3} s ({:.1} MB/s, {:.2} M faces/s)",
        st.bytes,
        secs,
        st.bytes as f64 / 1e6 / secs.max(1e-9),
        st.faces as f64 / 1e6 / secs.max(1e-9)
    );
    if b.is_empty() {
        println!("bbox: empty");
    } else {
        println!(
            "bbox: min [{}, {}, {}] max [{}, {}, {}] diagonal {}",
            b.min[0], b.min[1], b.min[2], b.max[0], b.max[1], b.max[2], b.diagonal()
        );
    }
    Ok(())
}
