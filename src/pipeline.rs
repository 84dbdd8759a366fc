//! Whole-pipeline commands: PLY → store (`build`), store → PLY (`extract`
//! of a whole level or of the cut at an error; `simplify` is in
//! [`crate::reduce`]).
//!
//! Takes: paths and typed options from the binaries. Gives: a complete
//! `NAME.octolod/` directory (written under a temporary name and moved into
//! place only when every stage succeeded) with its `store.json` manifest,
//! or one indexed PLY of a cut.

use crate::error::{IoContext, Result};
use crate::io::{AtomicDir, OutputKind};
use crate::lod::{LevelReport, LodOptions};
use crate::octree::OctreeReport;
use crate::ply::write::{PlyWriteOptions, PlyWriter};
use crate::soup::{build_soup, SoupOptions, SoupReport};
use crate::store::{write_index, BuildParams, Cut, IndexedMesh, Manifest, ManifestSeconds, Store};
use crate::mesh::{AttrSet, VertexLayout};
use std::collections::HashMap;
use std::path::Path;
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
    let out = AtomicDir::create(output, OutputKind::Store, opts.force)?;
    let soup_path = out.path().join("input.soup");
    let soup = build_soup(input, &soup_path, &SoupOptions { mem: opts.params.mem, quiet: opts.quiet, ..Default::default() })?;
    let t1 = Instant::now();
    let lo = LodOptions { params: opts.params.clone(), quiet: opts.quiet, ..Default::default() };
    let built = crate::lod::build(&soup_path, out.path(), &lo)?;
    std::fs::remove_file(&soup_path).ctx(&soup_path, "remove")?;
    write_index(out.path(), &built.header, &built.nodes, &built.children, &built.parents)?;
    let total = t0.elapsed().as_secs_f64();
    let levels_s = (total - (t1 - t0).as_secs_f64() - built.octree.seconds).max(0.0);
    let seconds = [(t1 - t0).as_secs_f64(), built.octree.seconds, levels_s, total];
    let disk_bytes = dir_bytes(out.path());
    let report = BuildReport { soup, octree: built.octree, levels: built.levels, nodes: built.nodes.len() as u64, seconds, disk_bytes };
    let manifest = Manifest {
        format: "octolod-store".into(),
        version: crate::store::VERSION,
        input: input.display().to_string(),
        attributes: built.header.attrs.describe(),
        quadric_dim: built.header.attrs.quadric_dim(),
        derived_normals: built.header.derived_normals,
        nodes: report.nodes,
        triangles: report.soup.header.triangles,
        params: opts.params.clone(),
        seconds: ManifestSeconds { soup: seconds[0], partition: seconds[1], levels: seconds[2], total: seconds[3] },
        disk_bytes,
        levels: report.levels.clone(),
    };
    manifest.write(out.path())?;
    out.commit()?;
    Ok(report)
}

fn dir_bytes(d: &Path) -> u64 {
    std::fs::read_dir(d)
        .map(|it| it.filter_map(|e| e.ok()).filter_map(|e| e.metadata().ok()).map(|m| m.len()).sum())
        .unwrap_or(0)
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

/// Writes a cut as one indexed PLY (binary little endian, with the input's
/// attributes). Vertices shared by neighbouring nodes are welded
/// (bit-identical vertices become one) unless `weld` is false, which
/// streams node by node without holding the cut in memory. An existing PLY
/// octolod wrote at `out` is replaced only when `force` is set.
pub fn extract(store: &Store, spec: CutSpec, out: &Path, weld: bool, force: bool) -> Result<(u64, u64)> {
    let cut = spec.cut(store)?;
    let opts = PlyWriteOptions {
        attrs: store.header.attrs,
        index_type: crate::ply::Scalar::U32,
        comments: vec![format!("octolod {} of {}", spec.describe(), store.dir.display())],
        ..Default::default()
    };
    if weld {
        let parts = store.cut_meshes(&cut).collect::<Result<Vec<_>>>()?;
        let m = weld_union(&store.layout, &parts);
        drop(parts);
        write_mesh_ply(out, store.header.attrs, &opts.comments[0], &m, force)?;
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
                w.face(&t.map(|i| i + base)).ctx(out, "write")?;
            }
            base += m.vertices.len() as u32;
        }
        w.finish().ctx(out, "write")?;
        (nv, nf)
    };
    file.commit()?;
    Ok((nv, nf))
}

/// Writes one indexed mesh as a binary little-endian PLY with `attrs`,
/// atomically (an existing PLY octolod wrote is replaced only with `force`).
pub fn write_mesh_ply(out: &Path, attrs: AttrSet, comment: &str, m: &IndexedMesh, force: bool) -> Result<()> {
    let opts = PlyWriteOptions {
        attrs,
        index_type: crate::ply::Scalar::U32,
        comments: vec![comment.to_string()],
        ..Default::default()
    };
    let mut file = crate::io::AtomicFile::create(out, OutputKind::Ply, force)?;
    let mut w = PlyWriter::new(file.writer(), &opts, m.vertices.len() as u64, m.triangles.len() as u64).ctx(out, "write")?;
    for v in &m.vertices {
        w.vertex(v).ctx(out, "write")?;
    }
    for t in &m.triangles {
        w.face(t).ctx(out, "write")?;
    }
    w.finish().ctx(out, "write")?;
    file.commit()
}

/// Concatenates meshes, welding vertices that are bit-identical in `layout`
/// (unreferenced vertices dropped).
pub fn weld_union(layout: &VertexLayout, parts: &[IndexedMesh]) -> IndexedMesh {
    let mut out = IndexedMesh::default();
    let mut map: HashMap<Vec<u8>, u32> = HashMap::new();
    let mut buf = vec![0u8; layout.size];
    for p in parts {
        let mut ids = vec![u32::MAX; p.vertices.len()];
        for t in &p.triangles {
            let nt = t.map(|i| {
                let i = i as usize;
                if ids[i] == u32::MAX {
                    layout.encode(&p.vertices[i], &mut buf);
                    let next = out.vertices.len() as u32;
                    ids[i] = *map.entry(buf.clone()).or_insert_with(|| {
                        out.vertices.push(layout.decode(&buf));
                        next
                    });
                }
                ids[i]
            });
            out.triangles.push(nt);
        }
    }
    out
}
