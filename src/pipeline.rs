//! Whole-pipeline commands: PLY → store (`build`), store → PLY or glTF (`extract`
//! of a whole level or of the cut at an error; `simplify` is in
//! [`crate::simplify`]).
//!
//! Takes: paths and typed options from the binaries. Gives: a complete
//! `NAME.octolod/` directory (written under a temporary name and moved into
//! place only when every stage succeeded) with its `store.json` manifest,
//! or one indexed PLY (or glTF, by the output's extension) of a cut.

use crate::error::{IoContext, Result};
use crate::gltf::GltfOptions;
use crate::io::{AtomicDir, OutputKind};
use crate::lod::octree::FirstCount;
use crate::lod::octree::OctreeReport;
use crate::lod::Level0Source;
use crate::lod::LodOptions;
use crate::manifest::LevelReport;
use crate::manifest::{BuildParams, Manifest, ManifestSeconds};
use crate::mesh::IndexedMesh;
use crate::mesh::{AttrSet, Vertex, VertexLayout};
use crate::ply::write::{PlyEncoder, PlyWriteOptions, PlyWriter};
use crate::soup::{build_soup_tapped, SoupOptions, SoupReport};
use crate::store::{write_index, Cut, Store};
use rustc_hash::FxHashMap;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// `octolod build`: what to build (recorded in the manifest) and how to
/// behave while doing it.
#[derive(Clone, Debug)]
pub struct BuildOptions {
    pub params: BuildParams,
    pub quiet: bool,
    /// Replace an existing store at the output path (`--force`).
    pub force: bool,
}

impl Default for BuildOptions {
    fn default() -> Self {
        BuildOptions { params: BuildParams::default(), quiet: true, force: false }
    }
}

#[derive(Clone, Debug)]
pub struct BuildReport {
    pub soup: SoupReport,
    pub octree: OctreeReport,
    pub levels: Vec<LevelReport>,
    pub nodes: u64,
    /// Seconds: soup, level-0 partition, levels, total.
    pub seconds: [f64; 4],
    pub disk_bytes: u64,
}

/// PLY → store, every stage under `opts.params.mem`, nodes reduced by
/// `opts.params.simplifier`.
pub fn build_store(input: &Path, output: &Path, opts: &BuildOptions) -> Result<BuildReport> {
    let t0 = Instant::now();
    let _input = crate::io::protect(input);
    let out = AtomicDir::create(output, OutputKind::Store, opts.force)?;
    let soup_path = out.path().join("input.soup");
    let mut lo = LodOptions { params: opts.params.clone(), quiet: opts.quiet, ..Default::default() };
    // On the soup's external path, level 0 is partitioned as the soup is
    // made (its cells counted in phase 2, its triangles routed in phase 3),
    // and the soup file is not written.
    let mut first = FirstCount::routing(&lo.octree(), out.path().join("chunks-0.bin"), input);
    let soup_opts = SoupOptions { mem: opts.params.mem, quiet: opts.quiet, scratch: true, ..Default::default() };
    let soup = build_soup_tapped(input, &soup_path, &soup_opts, Some(&mut first))?;
    let l0 = match soup.written {
        true => None,
        false => first.take_level0(&soup.header)?,
    };
    let t1 = Instant::now();
    // `--normals auto` from the creases the soup's vertex pass saw (as a
    // plan decides it for a sharded build).
    let simplifier = opts.params.simplifier.resolve(soup.header.attrs);
    lo.params.normals = lo.params.normals.resolved(simplifier, soup.smooth_normals);
    let source = match l0 {
        Some(l0) => Level0Source::Routed(l0),
        None => Level0Source::Soup(&soup_path, Some(first)),
    };
    let built = crate::lod::build(source, out.path(), &lo)?;
    if soup.written {
        std::fs::remove_file(&soup_path).ctx(&soup_path, "remove")?;
    }
    write_index(out.path(), &built.header, &built.nodes, &built.children, &built.parents)?;
    let total = t0.elapsed().as_secs_f64();
    // Routed in the soup stage: the routing's time is the partition's.
    let soup_s = (t1 - t0).as_secs_f64() - if soup.written { 0.0 } else { built.octree.seconds };
    let levels_s = (total - soup_s - built.octree.seconds).max(0.0);
    let seconds = [soup_s, built.octree.seconds, levels_s, total];
    // Textures the input names, copied next to the payloads.
    let names = match crate::input::read_header(input, &crate::progress::Progress::hidden()) {
        Ok(h) => h.texture_sources(input, opts.quiet),
        Err(_) => Vec::new(),
    };
    let textures = crate::manifest::TextureRef::copy_all(input, &names, out.path())?;
    for (t, source) in textures.iter().zip(&names) {
        if t.file.is_none() && !opts.quiet && matches!(source, crate::manifest::TextureSource::File(_)) {
            eprintln!("warning: {}: texture '{}' not found beside the input; the store keeps its uvs without it", input.display(), t.name);
        }
    }
    if textures.len() > 1 && !built.header.attrs.material() && !opts.quiet {
        eprintln!(
            "warning: {}: {} textures named but no face says which it uses (a PLY's face `texnumber`, an OBJ's `usemtl`, a glTF's materials): every face draws '{}'",
            input.display(),
            textures.len(),
            textures.iter().find(|t| t.file.is_some()).map_or(textures[0].name.as_str(), |t| t.name.as_str())
        );
    }
    let disk_bytes = dir_bytes(out.path());
    let report = BuildReport { soup, octree: built.octree, levels: built.levels, nodes: built.nodes.len() as u64, seconds, disk_bytes };
    let manifest = Manifest {
        format: "octolod-store".into(),
        version: crate::store::VERSION,
        input: input.display().to_string(),
        attributes: built.header.attrs.describe(),
        quadric_dim: built.quadric_dim,
        derived_normals: built.header.derived_normals,
        nodes: report.nodes,
        triangles: report.soup.header.triangles,
        // The simplifier the levels were made with (`auto` resolved).
        params: BuildParams { simplifier, normals: built.normals, ..opts.params.clone() },
        seconds: ManifestSeconds { soup: seconds[0], partition: seconds[1], levels: seconds[2], total: seconds[3] },
        disk_bytes,
        levels: report.levels.clone(),
        textures,
    };
    manifest.write(out.path())?;
    out.commit()?;
    Ok(report)
}

/// Bytes of the files directly in `d` (a store's size on disk).
pub(crate) fn dir_bytes(d: &Path) -> u64 {
    std::fs::read_dir(d).map(|it| it.filter_map(|e| e.ok()).filter_map(|e| e.metadata().ok()).map(|m| m.len()).sum()).unwrap_or(0)
}

/// Which cut to extract.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CutSpec {
    /// The whole level L.
    Level(u8),
    /// The cut at object-space error E.
    MaxError(f64),
}

impl CutSpec {
    pub fn cut(&self, store: &Store) -> Result<Cut> {
        match *self {
            CutSpec::Level(l) => {
                store.check_level(l)?;
                Ok(store.level_cut(l))
            }
            CutSpec::MaxError(e) => Ok(store.error_cut(e)),
        }
    }

    pub fn describe(&self) -> String {
        match self {
            CutSpec::Level(l) => format!("level {l}"),
            CutSpec::MaxError(e) => format!("max error {e:e}"),
        }
    }
}

/// Writes a cut as one indexed mesh, by `out`'s extension: `.glb` or
/// `.gltf` (+ `.bin`) as glTF 2.0 with default [`GltfOptions`] (see
/// [`extract_as`]), anything else as PLY (binary little endian, with the
/// input's attributes). Vertices shared by neighbouring nodes are welded
/// (bit-identical vertices become one) unless `weld` is false, which
/// streams node by node without holding the cut in memory. An existing
/// output octolod wrote at `out` is replaced only when `force` is set.
pub fn extract(store: &Store, spec: CutSpec, out: &Path, weld: bool, force: bool) -> Result<(u64, u64)> {
    extract_as(store, spec, out, weld, force, &GltfOptions::default())
}

/// [`extract`] with the glTF options (`--quantize`, `--compress`), which
/// are refused for a PLY output. A store with PNG or JPEG textures (and
/// uvs) gets every one embedded in the glTF's buffer, each face drawing
/// its material's ([`crate::gltf`]), unless `gltf.textures` names others
/// (an image of another kind is left out, with a warning, and its faces
/// drawn untextured: glTF core takes only those two). A glTF is written
/// from the welded cut in memory as one primitive per material, or, with
/// `weld` false, streamed in two passes over the nodes with one primitive
/// per material per run of whole nodes of at most
/// [`crate::gltf::STREAM_GROUP_VERTICES`] vertices (only that run in memory).
pub fn extract_as(store: &Store, spec: CutSpec, out: &Path, weld: bool, force: bool, gltf: &GltfOptions) -> Result<(u64, u64)> {
    if crate::gltf::Container::of(out).is_none() {
        if gltf.quantize || gltf.compress {
            return Err(crate::Error::Usage(format!(
                "--quantize and --compress apply to glTF outputs (.glb, .gltf); {} would be written as PLY",
                out.display()
            )));
        }
        return extract_ply(store, spec, out, weld, force);
    }
    crate::gltf::check_output(out, force)?;
    let cut = spec.cut(store)?;
    let name = format!("octolod {} of {}", spec.describe(), store.dir.display());
    let attrs = store.header.attrs;
    // The store's textures go inside the glTF: one self-contained output.
    let embedded;
    let gltf = if gltf.textures.is_empty() && attrs.uv() {
        let textures = crate::manifest::store_textures(&store.dir)
            .into_iter()
            .map(|slot| {
                let (file, path) = slot?;
                crate::gltf::GltfTexture::embed_file(&path, file.rsplit_once('.').map_or(&file[..], |p| p.0))
                    .map_err(|e| eprintln!("warning: {e}; {} is written without that texture", out.display()))
                    .ok()
            })
            .collect();
        embedded = GltfOptions { textures, ..gltf.clone() };
        &embedded
    } else {
        gltf
    };
    if weld {
        let parts = store.cut_meshes(&cut).collect::<Result<Vec<_>>>()?;
        let m = weld_union(&store.layout, &parts);
        drop(parts);
        return crate::gltf::write_mesh(out, &m, attrs, gltf, force, &name);
    }
    crate::gltf::write_parts(out, attrs, gltf, force, &name, crate::gltf::STREAM_GROUP_VERTICES, || store.cut_meshes(&cut))
}

/// [`extract`] to a PLY.
fn extract_ply(store: &Store, spec: CutSpec, out: &Path, weld: bool, force: bool) -> Result<(u64, u64)> {
    let cut = spec.cut(store)?;
    let mut opts = mesh_ply_options(store.header.attrs, &format!("octolod {} of {}", spec.describe(), store.dir.display()));
    opts.comments.extend(texture_comments(store, out));
    if weld {
        let parts = store.cut_meshes(&cut).collect::<Result<Vec<_>>>()?;
        let m = weld_union(&store.layout, &parts);
        drop(parts);
        write_mesh_ply_with(out, &opts, &m, force)?;
        return Ok((m.vertices.len() as u64, m.triangles.len() as u64));
    }
    let mut file = crate::io::AtomicFile::create(out, OutputKind::Ply, force)?;
    let (nv, nf) = {
        // PLY puts all vertices before all faces: two passes over the nodes.
        let (mut nv, mut nf) = (0u64, 0u64);
        for m in store.cut_meshes(&cut) {
            let m = m?;
            nv += m.vertices.len() as u64;
            nf += m.triangles.len() as u64;
        }
        let mut w = PlyWriter::new(file.writer(), &opts, nv, nf).ctx(out, "write")?;
        for m in store.cut_meshes(&cut) {
            for v in &m?.vertices {
                w.vertex(v).ctx(out, "write")?;
            }
        }
        let mut base = 0u32;
        for m in store.cut_meshes(&cut) {
            let m = m?;
            for t in &m.triangles {
                w.face_material(&t.map(|i| i + base), m.vertices[t[0] as usize].material).ctx(out, "write")?;
            }
            base += m.vertices.len() as u32;
        }
        w.finish().ctx(out, "write")?;
        (nv, nf)
    };
    file.commit()?;
    Ok((nv, nf))
}

/// How every indexed PLY octolod writes from a store is encoded: binary
/// little endian, the input's attributes, `uint` indices, one comment.
pub fn mesh_ply_options(attrs: AttrSet, comment: &str) -> PlyWriteOptions {
    PlyWriteOptions { attrs, index_type: crate::ply::Scalar::U32, comments: vec![comment.to_string()], ..Default::default() }
}

/// Writes one indexed mesh as a binary little-endian PLY with `attrs`,
/// atomically (an existing PLY octolod wrote is replaced only with `force`).
pub fn write_mesh_ply(out: &Path, attrs: AttrSet, comment: &str, m: &IndexedMesh, force: bool) -> Result<()> {
    write_mesh_ply_with(out, &mesh_ply_options(attrs, comment), m, force)
}

/// `comment TextureFile` lines for a PLY written at `out` from `store`:
/// the store's copies of the input's textures (MeshLab's convention), as
/// paths relative to `out`'s folder where the store lies inside it, else
/// absolute. Nothing is copied next to `out`, so no file there is touched.
pub fn texture_comments(store: &Store, out: &Path) -> Vec<String> {
    texture_lines(store, out, false)
}

/// `comment TextureFile` lines for a PLY written at `out` from a mesh
/// made of `store`'s (`simplify`): the input's own texture files where
/// they still are beside it (a `simplify` store is scratch, dropped with
/// its copies), else the store's copies; paths as [`texture_comments`]
/// writes them.
pub fn source_texture_comments(store: &Store, out: &Path) -> Vec<String> {
    texture_lines(store, out, true)
}

/// [`texture_comments`] (`originals` false) and
/// [`source_texture_comments`] (true): one line per texture the manifest
/// lists, its path shown relative to `out`'s folder when inside it.
fn texture_lines(store: &Store, out: &Path, originals: bool) -> Vec<String> {
    let Ok(m) = crate::manifest::Manifest::read(&store.dir) else { return Vec::new() };
    let input_dir = crate::io::parent_dir(Path::new(&m.input));
    let base = crate::io::parent_dir(out).canonicalize().ok();
    let dir = store.dir.canonicalize().unwrap_or_else(|_| store.dir.clone());
    m.textures
        .iter()
        .map(|t| {
            let original = input_dir.join(&t.name);
            let path = match &t.file {
                _ if originals && original.is_file() => original.canonicalize().unwrap_or(original),
                Some(f) => dir.join(f),
                None => std::path::PathBuf::from(&t.name),
            };
            let shown = base.as_ref().and_then(|b| path.strip_prefix(b).ok()).map(Path::to_path_buf).unwrap_or(path);
            format!("TextureFile {}", shown.display())
        })
        .collect()
}

/// [`write_mesh_ply`] with the PLY options given.
pub fn write_mesh_ply_with(out: &Path, opts: &PlyWriteOptions, m: &IndexedMesh, force: bool) -> Result<()> {
    let mut file = crate::io::AtomicFile::create(out, OutputKind::Ply, force)?;
    let mut w = PlyWriter::new(file.writer(), opts, m.vertices.len() as u64, m.triangles.len() as u64).ctx(out, "write")?;
    for v in &m.vertices {
        w.vertex(v).ctx(out, "write")?;
    }
    for t in &m.triangles {
        w.face_material(t, m.vertices[t[0] as usize].material).ctx(out, "write")?;
    }
    w.finish().ctx(out, "write")?;
    file.commit()
}

/// A PLY written part by part whose counts are known only at the end (the
/// same bytes as [`write_mesh_ply`] of the same mesh): vertex and face
/// records are encoded as they come into two scratch files next to the
/// output, then [`SpooledPly::finish`] writes the header with the final
/// counts and copies both behind it. Holds only its I/O buffers.
pub struct SpooledPly {
    file: crate::io::AtomicFile,
    attrs: AttrSet,
    enc: PlyEncoder,
    buf: Vec<u8>,
    vertices: Spool,
    faces: Spool,
    _scratch: crate::io::ScratchDir,
}

/// One scratch file of records and how many it holds.
struct Spool {
    path: PathBuf,
    w: std::io::BufWriter<std::fs::File>,
    count: u64,
}

impl Spool {
    fn create(path: PathBuf) -> Result<Spool> {
        let f = std::fs::File::create(&path).ctx(&path, "create")?;
        Ok(Spool { w: std::io::BufWriter::with_capacity(crate::io::SEQ_BUF, f), path, count: 0 })
    }

    fn put(&mut self, rec: &[u8]) -> Result<()> {
        self.count += 1;
        self.w.write_all(rec).ctx(&self.path, "write")
    }

    /// Flushes, then hands the records to `put` in chunks of whole records
    /// (`rec` bytes each) with their count.
    fn copy_out(self, rec: usize, mut put: impl FnMut(&[u8], u64) -> std::io::Result<()>) -> Result<()> {
        let Spool { path, w, count } = self;
        drop(w.into_inner().map_err(|e| e.into_error()).ctx(&path, "write")?);
        let mut f = std::fs::File::open(&path).ctx(&path, "open")?;
        let per = (crate::io::SEQ_BUF / rec).max(1) as u64;
        let mut buf = vec![0u8; per as usize * rec];
        let mut left = count;
        while left > 0 {
            let k = left.min(per);
            let b = &mut buf[..k as usize * rec];
            f.read_exact(b).ctx(&path, "read")?;
            put(b, k).ctx(&path, "copy")?;
            left -= k;
        }
        Ok(())
    }
}

impl SpooledPly {
    /// Checks `out` (see [`crate::io::AtomicFile::create`]) and starts the
    /// temp output and the scratch files.
    pub fn create(out: &Path, attrs: AttrSet, force: bool) -> Result<SpooledPly> {
        let file = crate::io::AtomicFile::create(out, OutputKind::Ply, force)?;
        let scratch = crate::io::scratch_dir(out)?;
        Ok(SpooledPly {
            file,
            attrs,
            enc: PlyEncoder::new(&mesh_ply_options(attrs, "")),
            buf: Vec::with_capacity(64),
            vertices: Spool::create(scratch.path().join("vertices"))?,
            faces: Spool::create(scratch.path().join("faces"))?,
            _scratch: scratch,
        })
    }

    /// Vertices and triangles written so far.
    pub fn counts(&self) -> (u64, u64) {
        (self.vertices.count, self.faces.count)
    }

    pub fn vertex(&mut self, v: &Vertex) -> Result<()> {
        self.buf.clear();
        self.enc.vertex(v, &mut self.buf);
        self.vertices.put(&self.buf)
    }

    /// One triangle and its material (its corner 0's; the `texnumber`
    /// of a mesh with materials).
    pub fn face(&mut self, t: &[u32; 3], material: u16) -> Result<()> {
        self.buf.clear();
        self.enc.face_material(t, material, &mut self.buf).ctx(&self.faces.path, "encode")?;
        self.faces.put(&self.buf)
    }

    /// Writes the header (with `comment`) and the records into the output
    /// and moves it into place.
    pub fn finish(self, comments: &[String]) -> Result<()> {
        let SpooledPly { mut file, attrs, enc, vertices, faces, _scratch, .. } = self;
        let out = file.dest().to_path_buf();
        let opts = PlyWriteOptions { comments: comments.to_vec(), ..mesh_ply_options(attrs, "") };
        let mut w = PlyWriter::new(file.writer(), &opts, vertices.count, faces.count).ctx(&out, "write")?;
        vertices.copy_out(enc.vertex_record_size().expect("binary"), |b, n| w.raw_vertices(b, n))?;
        faces.copy_out(enc.face_record_size(3).expect("binary"), |b, n| w.raw_faces(b, n))?;
        w.finish().ctx(&out, "write")?;
        file.commit()
    }
}

/// Welds meshes added one part at a time: vertices bit-identical in the
/// layout (position and attributes) become one, within a part always and
/// across parts where the caller says so; the rest is emitted as it comes,
/// so only the vertices welded across parts are remembered. Vertices are
/// numbered in order of first use; unreferenced ones are dropped.
pub struct VertexWelder<'a> {
    layout: &'a VertexLayout,
    across: FxHashMap<Vec<u8>, u32>,
    next: u32,
}

impl<'a> VertexWelder<'a> {
    pub fn new(layout: &'a VertexLayout) -> VertexWelder<'a> {
        VertexWelder { layout, across: FxHashMap::default(), next: 0 }
    }

    /// Adds `part`, welding across parts the vertices `across` picks: gives
    /// the vertices new to the output (in order) and the part's triangles
    /// in output numbering.
    pub fn add(&mut self, part: &IndexedMesh, across: impl Fn(&Vertex) -> bool) -> (Vec<Vertex>, Vec<[u32; 3]>) {
        let size = self.layout.size;
        let mut enc = vec![0u8; part.vertices.len() * size];
        for (v, b) in part.vertices.iter().zip(enc.chunks_exact_mut(size)) {
            self.layout.encode(v, b);
        }
        let mut within: FxHashMap<&[u8], u32> = FxHashMap::default();
        let mut ids = vec![u32::MAX; part.vertices.len()];
        let mut new = Vec::new();
        let mut tris = Vec::with_capacity(part.triangles.len());
        for t in &part.triangles {
            tris.push(t.map(|i| {
                let i = i as usize;
                if ids[i] == u32::MAX {
                    let key = &enc[i * size..(i + 1) * size];
                    let next = &mut self.next;
                    let mut emit = || {
                        new.push(self.layout.decode(key));
                        *next += 1;
                        *next - 1
                    };
                    ids[i] = if across(&part.vertices[i]) {
                        match self.across.get(key) {
                            Some(&id) => id,
                            None => {
                                let id = emit();
                                self.across.insert(key.to_vec(), id);
                                id
                            }
                        }
                    } else {
                        *within.entry(key).or_insert_with(emit)
                    };
                }
                ids[i]
            }));
        }
        (new, tris)
    }
}

/// Concatenates meshes, welding vertices that are bit-identical in `layout`
/// (unreferenced vertices dropped).
pub fn weld_union<M: std::borrow::Borrow<IndexedMesh>>(layout: &VertexLayout, parts: impl IntoIterator<Item = M>) -> IndexedMesh {
    let mut w = VertexWelder::new(layout);
    let mut out = IndexedMesh::default();
    for p in parts {
        let (v, t) = w.add(p.borrow(), |_| true);
        out.vertices.extend(v);
        out.triangles.extend(t);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f64, y: f64, c: u8) -> Vertex {
        Vertex { pos: [x, y, 0.25], normal: [0.0, 0.0, 1.0], color: [c, 2, 3, 4], uv: [x as f32, 0.5], material: 0 }
    }

    /// Two parts sharing an edge (one copy of it with another colour),
    /// each holding a duplicate vertex of its own.
    fn parts() -> Vec<IndexedMesh> {
        let a = IndexedMesh { vertices: vec![v(0.0, 0.0, 1), v(1.0, 0.0, 1), v(0.0, 1.0, 1), v(0.0, 0.0, 1)], triangles: vec![[0, 1, 2], [3, 2, 1]] };
        let b = IndexedMesh {
            vertices: vec![v(1.0, 0.0, 1), v(0.0, 1.0, 9), v(1.0, 1.0, 1), v(1.0, 1.0, 1), v(7.0, 7.0, 1)],
            triangles: vec![[0, 2, 1], [3, 1, 0]],
        };
        vec![a, b]
    }

    #[test]
    fn spooled_ply_writes_the_bytes_write_mesh_ply_writes() {
        let d = tempfile::tempdir().unwrap();
        for attrs in [AttrSet(0), AttrSet(AttrSet::POS_F64 | AttrSet::NORMAL | AttrSet::COLOR | AttrSet::ALPHA | AttrSet::UV)] {
            let layout = VertexLayout::new(attrs);
            let whole = weld_union(&layout, parts());
            let (a, b) = (d.path().join("a.ply"), d.path().join("b.ply"));
            write_mesh_ply(&a, attrs, "octolod test", &whole, true).unwrap();
            // Welded across parts everywhere: the same mesh, spooled.
            let mut p = SpooledPly::create(&b, attrs, true).unwrap();
            let mut w = VertexWelder::new(&layout);
            for part in parts() {
                let (vs, ts) = w.add(&part, |_| true);
                vs.iter().try_for_each(|x| p.vertex(x)).unwrap();
                ts.iter().try_for_each(|t| p.face(t, 0)).unwrap();
            }
            assert_eq!(p.counts(), (whole.vertices.len() as u64, whole.triangles.len() as u64));
            p.finish(&["octolod test".to_string()]).unwrap();
            assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap(), "{attrs:?}");
            // Scratch files gone, only the two outputs left.
            assert_eq!(std::fs::read_dir(d.path()).unwrap().count(), 2);
        }
    }

    #[test]
    fn the_welder_welds_across_parts_only_where_asked() {
        let layout = VertexLayout::new(AttrSet(AttrSet::COLOR));
        let count = |across: fn(&Vertex) -> bool| {
            let mut w = VertexWelder::new(&layout);
            parts().iter().map(|p| w.add(p, across).0.len()).sum::<usize>()
        };
        // Within a part always (the duplicates), across only where asked; the
        // recoloured copy and the unreferenced vertex never count.
        assert_eq!(count(|_| true), 5);
        assert_eq!(count(|_| false), 6);
        assert_eq!(count(|v| v.pos[1] == 0.0), 5);
        assert_eq!(weld_union(&layout, parts()).vertices.len(), 5);
    }
}
