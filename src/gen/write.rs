//! Streaming a generated mesh to a PLY: chunks encoded in parallel, written
//! in order, memory bounded whatever the mesh size.

use super::{GenOptions, Generator};
use crate::error::{IoContext, Result};
use crate::io::AtomicFile;
use crate::ply::write::{PlyEncoder, PlyWriteOptions, PlyWriter};
use crate::ply::Encoding;
use crate::progress::Progress;
use rayon::prelude::*;
use std::io::{self, Write};
use std::path::Path;

/// Target size of one encoded chunk.
const CHUNK_BYTES: usize = 4 << 20;

#[derive(Clone, Copy)]
enum Job {
    Vertices(u64, u64),
    Faces(u64, u64),
}

/// Chunks of about `chunk_bytes` encoded bytes covering all vertices, then all faces.
fn make_jobs(g: &Generator, enc: &PlyEncoder, chunk_bytes: usize) -> Vec<Job> {
    let (nv, nf) = (g.vertex_count(), g.face_count());
    let vchunk = (chunk_bytes / enc.approx_vertex_size().max(1)).clamp(64, 1 << 20) as u64;
    let fchunk = (chunk_bytes / enc.approx_face_size().max(1)).clamp(64, 1 << 20) as u64;
    let mut jobs = Vec::new();
    for a in (0..nv).step_by(vchunk as usize) {
        jobs.push(Job::Vertices(a, (a + vchunk).min(nv)));
    }
    for a in (0..nf).step_by(fchunk as usize) {
        jobs.push(Job::Faces(a, (a + fchunk).min(nf)));
    }
    jobs
}

fn encode(g: &Generator, enc: &PlyEncoder, job: Job, buf: &mut Vec<u8>) -> io::Result<()> {
    buf.clear();
    match job {
        Job::Vertices(a, b) => {
            buf.reserve((b - a) as usize * enc.approx_vertex_size());
            for i in a..b {
                enc.vertex(&g.vertex(i), buf);
            }
        }
        Job::Faces(a, b) => {
            buf.reserve((b - a) as usize * enc.approx_face_size());
            for j in a..b {
                enc.face(&g.face(j), buf)?;
            }
        }
    }
    Ok(())
}

/// Streams the generated mesh as a PLY to `w`: windows of chunks (a few MiB
/// each) are encoded in parallel with rayon while a writer thread writes the
/// finished chunks in order from a bounded queue, so memory stays at about two
/// windows whatever the mesh size. `wopts.attrs` is used as given (see
/// [`write`](fn@write)). Returns the bytes written.
pub fn write_to<W: Write + Send>(g: &Generator, wopts: &PlyWriteOptions, w: W, quiet: bool) -> io::Result<u64> {
    stream(g, wopts, w, quiet, CHUNK_BYTES)
}

pub(super) fn stream<W: Write + Send>(g: &Generator, wopts: &PlyWriteOptions, w: W, quiet: bool, chunk_bytes: usize) -> io::Result<u64> {
    let (nv, nf) = (g.vertex_count(), g.face_count());
    let mut pw = PlyWriter::new(w, wopts, nv, nf)?;
    let enc = pw.encoder().clone();
    let total_bytes = match (enc.vertex_record_size(), enc.face_record_size(3)) {
        (Some(vs), Some(fs)) if enc.encoding() != Encoding::Ascii => Some(pw.bytes_written() + nv * vs as u64 + nf * fs as u64),
        _ => None,
    };
    let progress = match total_bytes {
        Some(n) => Progress::bytes(n, "generate", quiet),
        None => Progress::items(nv + nf, "generate", quiet),
    };
    let jobs = make_jobs(g, &enc, chunk_bytes);
    // Encoders work on windows of `window` chunks in parallel; a dedicated
    // writer thread takes finished chunks in order from a bounded queue, so
    // writing overlaps encoding and at most ~2 windows are in memory.
    let window = rayon::current_num_threads().clamp(2, 16);
    let by_bytes = total_bytes.is_some();
    let (to_writer, queue) = std::sync::mpsc::sync_channel::<(Job, Vec<u8>)>(window);
    let (recycle, spare) = std::sync::mpsc::channel::<Vec<u8>>();
    std::thread::scope(|scope| -> io::Result<u64> {
        let progress = &progress;
        let writer = scope.spawn(move || -> io::Result<PlyWriter<W>> {
            for (job, buf) in queue {
                let n = match job {
                    Job::Vertices(a, b) => {
                        pw.raw_vertices(&buf, b - a)?;
                        b - a
                    }
                    Job::Faces(a, b) => {
                        pw.raw_faces(&buf, b - a)?;
                        b - a
                    }
                };
                progress.inc(if by_bytes { buf.len() as u64 } else { n });
                let _ = recycle.send(buf);
            }
            Ok(pw)
        });
        let mut encoded = Ok(());
        'outer: for group in jobs.chunks(window) {
            let mut next: Vec<(Job, Vec<u8>)> = group.iter().map(|&j| (j, spare.try_recv().unwrap_or_default())).collect();
            // Each window is a safe point for signals.
            if crate::io::signal::interrupted().is_some() {
                encoded = Err(io::Error::new(io::ErrorKind::Interrupted, "interrupted by a signal"));
                break;
            }
            encoded = next.par_iter_mut().try_for_each(|(job, buf)| encode(g, &enc, *job, buf));
            if encoded.is_err() {
                break;
            }
            for item in next {
                if to_writer.send(item).is_err() {
                    break 'outer; // the writer failed; its error is reported below
                }
            }
        }
        drop(to_writer);
        let pw = writer.join().expect("writer thread panicked")?;
        encoded?;
        progress.finish();
        let n = pw.bytes_written();
        pw.finish()?;
        Ok(n)
    })
}

/// Streams the mesh for `opts` to a PLY at `path` (atomically: the file
/// appears only when complete), with a progress bar by bytes unless `quiet`.
/// The vertex attributes written are `opts.attrs` (they replace
/// `wopts.attrs`); everything else comes from `wopts`. Returns bytes written.
/// An existing PLY that octolod wrote is replaced only when `force` is set.
pub fn write(opts: &GenOptions, wopts: &PlyWriteOptions, path: &Path, quiet: bool, force: bool) -> Result<u64> {
    let g = Generator::new(opts);
    let wopts = PlyWriteOptions { attrs: opts.attrs, ..wopts.clone() };
    let mut file = AtomicFile::create(path, crate::io::OutputKind::Ply, force)?;
    let n = write_to(&g, &wopts, file.writer(), quiet).ctx(path, "write")?;
    file.commit()?;
    Ok(n)
}

/// The formats besides PLY the generator writes: inputs for the other
/// readers (`src/input/`) at any size, for their tests and speed reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OtherFormat {
    /// `v` (with `r g b` when the mesh has colours), `vt`, `vn` lines,
    /// then faces `v`, `v/vt`, `v//vn` or `v/vt/vn` by the same index.
    Obj,
    StlBinary,
    StlAscii,
}

#[derive(Clone, Copy)]
enum Section {
    V,
    Vt,
    Vn,
    F,
}

/// Streams the mesh for `opts` as an OBJ or STL to `path` (atomically;
/// never replacing an existing file): chunks encoded in parallel, written
/// in order, memory bounded whatever the size. Numbers are the shortest
/// text that reads back to the same float32 (float64 for `POS_F64`
/// positions). Returns bytes written.
pub fn write_other(opts: &GenOptions, format: OtherFormat, path: &Path, quiet: bool) -> Result<u64> {
    let g = Generator::new(opts);
    let a = opts.attrs;
    let (nv, nf) = (g.vertex_count(), g.face_count());
    let mut sections = Vec::new();
    if format == OtherFormat::Obj {
        sections.push((Section::V, nv));
        if a.uv() {
            sections.push((Section::Vt, nv));
        }
        if a.normal() {
            sections.push((Section::Vn, nv));
        }
    }
    sections.push((Section::F, nf));
    let per = 1u64 << 16;
    let jobs: Vec<(Section, u64, u64)> = sections.iter().flat_map(|&(s, n)| (0..n).step_by(per as usize).map(move |x| (s, x, (x + per).min(n)))).collect();
    let progress = Progress::items(jobs.len() as u64, "generate", quiet);
    let mut file = AtomicFile::create(path, crate::io::OutputKind::Ply, false)?;
    let mut written = 0u64;
    {
        let mut w = std::io::BufWriter::with_capacity(crate::io::SEQ_BUF, file.writer());
        let head: Vec<u8> = match format {
            OtherFormat::Obj => format!("# octolod-gen shape {} tris {} seed {}\n", opts.shape.name(), opts.tris, opts.seed).into_bytes(),
            OtherFormat::StlBinary => {
                let mut h = vec![b' '; 80];
                h[..11].copy_from_slice(b"octolod-gen");
                h.extend_from_slice(&u32::try_from(nf).map_err(|_| crate::Error::Usage("a binary STL holds at most 2^32-1 triangles".into()))?.to_le_bytes());
                h
            }
            OtherFormat::StlAscii => b"solid octolod-gen\n".to_vec(),
        };
        w.write_all(&head).ctx(path, "write")?;
        written += head.len() as u64;
        let window = rayon::current_num_threads().clamp(2, 16);
        for group in jobs.chunks(window) {
            crate::io::signal::check()?;
            let bufs: Vec<Vec<u8>> = group.par_iter().map(|&(s, x, y)| encode_other(&g, format, s, x, y)).collect();
            for b in bufs {
                w.write_all(&b).ctx(path, "write")?;
                written += b.len() as u64;
                progress.inc(1);
            }
        }
        if format == OtherFormat::StlAscii {
            w.write_all(b"endsolid octolod-gen\n").ctx(path, "write")?;
            written += 21;
        }
        w.flush().ctx(path, "write")?;
    }
    file.commit()?;
    progress.finish();
    Ok(written)
}

fn encode_other(g: &Generator, format: OtherFormat, s: Section, x: u64, y: u64) -> Vec<u8> {
    use std::fmt::Write as _;
    let a = g.attrs();
    let mut t = String::with_capacity((y - x) as usize * 48);
    let c = |v: f64| if a.pos_f64() { format!("{v}") } else { format!("{}", v as f32) };
    match (format, s) {
        (OtherFormat::Obj, Section::V) => {
            for i in x..y {
                let v = g.vertex(i);
                let _ = write!(t, "v {} {} {}", c(v.pos[0]), c(v.pos[1]), c(v.pos[2]));
                if a.color() {
                    let _ = write!(t, " {} {} {}", v.color[0] as f32 / 255.0, v.color[1] as f32 / 255.0, v.color[2] as f32 / 255.0);
                }
                t.push('\n');
            }
        }
        (_, Section::Vt) => {
            for i in x..y {
                let v = g.vertex(i);
                let _ = writeln!(t, "vt {} {}", v.uv[0], v.uv[1]);
            }
        }
        (_, Section::Vn) => {
            for i in x..y {
                let v = g.vertex(i);
                let _ = writeln!(t, "vn {} {} {}", v.normal[0], v.normal[1], v.normal[2]);
            }
        }
        (OtherFormat::Obj, Section::F) => {
            for j in x..y {
                let f = g.face(j).map(|i| i as u64 + 1);
                t.push('f');
                for i in f {
                    let _ = match (a.uv(), a.normal()) {
                        (false, false) => write!(t, " {i}"),
                        (true, false) => write!(t, " {i}/{i}"),
                        (false, true) => write!(t, " {i}//{i}"),
                        (true, true) => write!(t, " {i}/{i}/{i}"),
                    };
                }
                t.push('\n');
            }
        }
        (OtherFormat::StlBinary, _) => {
            let mut b = Vec::with_capacity((y - x) as usize * 50);
            for j in x..y {
                b.extend_from_slice(&[0u8; 12]);
                for i in g.face(j) {
                    for p in g.vertex(i as u64).pos {
                        b.extend_from_slice(&(p as f32).to_le_bytes());
                    }
                }
                b.extend_from_slice(&[0, 0]);
            }
            return b;
        }
        (OtherFormat::StlAscii, _) => {
            for j in x..y {
                t.push_str("facet normal 0 0 0\n outer loop\n");
                for i in g.face(j) {
                    let p = g.vertex(i as u64).pos;
                    let _ = writeln!(t, "  vertex {} {} {}", p[0] as f32, p[1] as f32, p[2] as f32);
                }
                t.push_str(" endloop\nendfacet\n");
            }
        }
    }
    t.into_bytes()
}
