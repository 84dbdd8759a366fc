//! Inputs: PLY ([`crate::ply`]), STL ([`stl`]), OBJ ([`obj`]) and glTF
//! ([`gltf`]), each read as the PLY body reader reads a PLY.
//!
//! Takes: a path (the format by extension, else by content). Gives: an
//! [`InputHeader`] (format, attributes, counts) and a body reader that
//! calls a [`BodySink`] with every vertex in index order, then every
//! triangle (polygons fan-triangulated, triangles with a repeated corner
//! dropped and counted), in sequential passes over the file (or positioned
//! reads of a glTF's accessors), never holding the mesh in memory — so the
//! soup stage's out-of-core dereference serves every format alike. Faces
//! that choose among several textures (a PLY's `texnumber`, an OBJ's
//! `usemtl`, a glTF primitive's material) give their vertices a material
//! id ([`AttrSet::MATERIAL`]): the texture's index in
//! [`InputHeader::texture_sources`]. Two
//! exceptions, bounded: an OBJ whose corners carry uvs or normals is split
//! into vertices in memory within `--mem`, and a meshopt-compressed glTF
//! buffer view is decoded whole. Bad input is an error naming the file, line or byte
//! offset.

pub mod gltf;
pub mod obj;
pub mod stl;

use crate::error::{Error, Location, Result};
use crate::mesh::AttrSet;
use crate::ply::read::{BodySink, BodyStats, CollectSink};
use crate::ply::PlyHeader;
use crate::progress::Progress;
use std::io::Read;
use std::path::Path;

/// A mesh file format octolod reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Ply,
    Stl,
    Obj,
    Gltf,
}

impl Format {
    pub fn name(self) -> &'static str {
        match self {
            Format::Ply => "PLY",
            Format::Stl => "STL",
            Format::Obj => "OBJ",
            Format::Gltf => "glTF",
        }
    }

    /// By extension (case-insensitive), else by the first bytes.
    pub fn of(path: &Path) -> Result<Format> {
        let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("ply") => return Ok(Format::Ply),
            Some("stl") => return Ok(Format::Stl),
            Some("obj") => return Ok(Format::Obj),
            Some("glb" | "gltf") => return Ok(Format::Gltf),
            _ => {}
        }
        let (f, len) = crate::io::open_regular(path, "open")?;
        let mut head = Vec::with_capacity(512);
        f.take(512).read_to_end(&mut head).map_err(|e| Error::io(path, "read", e))?;
        if head.starts_with(b"ply") {
            Ok(Format::Ply)
        } else if gltf::looks_like_gltf(&head) {
            Ok(Format::Gltf)
        } else if stl::looks_like_stl(&head, len) {
            Ok(Format::Stl)
        } else if obj::looks_like_obj(&head) {
            Ok(Format::Obj)
        } else {
            Err(Error::input(
                Location { file: path.to_path_buf(), offset: Some(0), ..Default::default() },
                "not a mesh file octolod reads (PLY, STL, OBJ or glTF, by extension or content)",
            ))
        }
    }
}

/// What each format's first look found.
#[derive(Clone, Debug)]
pub enum Details {
    Ply(PlyHeader),
    Stl(stl::StlInfo),
    Obj(obj::ObjInfo),
    Gltf(gltf::GltfInfo),
}

/// An input's format, attributes and counts.
#[derive(Clone, Debug)]
pub struct InputHeader {
    pub format: Format,
    pub attrs: AttrSet,
    /// Vertices the body gives (an STL's kept corners; an OBJ's positions,
    /// or its distinct corners when they carry uvs or normals).
    pub vertices: u64,
    /// Faces (an STL's triangles).
    pub faces: u64,
    /// Every vertex comes before the first face (always, but for PLYs that
    /// declare faces first).
    pub vertices_first: bool,
    /// Byte offset of the body (PLY), for errors.
    pub body_offset: u64,
    pub details: Details,
}

impl InputHeader {
    pub fn vertex_count(&self) -> u64 {
        self.vertices
    }
    pub fn face_count(&self) -> u64 {
        self.faces
    }
    /// The PLY header, for a PLY.
    pub fn ply(&self) -> Option<&PlyHeader> {
        match &self.details {
            Details::Ply(h) => Some(h),
            _ => None,
        }
    }

    /// The texture images the input names, in order, each once: files
    /// relative to its folder (a PLY's `comment TextureFile` lines,
    /// MeshLab's convention; an OBJ's materials' `map_Kd` through its
    /// `mtllib` files, an MTL that cannot be read naming none; a glTF's
    /// base colour images by URI) or images inside it (a glTF's in a
    /// buffer: PNG or JPEG).
    ///
    /// A vertex's material id ([`crate::mesh::Vertex::material`]) is its
    /// faces' texture's index in this list, which the build copies into
    /// the store manifest's `textures` in the same order. The OBJ and glTF
    /// readers number their materials by the very list given here
    /// ([`obj::ObjInfo::textures`], [`gltf::GltfInfo::images`], made once
    /// with the slot map), so the two cannot disagree: an OBJ face after
    /// `usemtl M` gets the slot of M's `map_Kd`, a glTF primitive that of
    /// its material's base colour image; faces without a textured material
    /// get [`crate::mesh::Vertex::NO_TEXTURE`]. A glTF image in a buffer
    /// that cannot be read keeps its slot (a warning unless `quiet`) under
    /// a name that is never a file, so the store records it without a
    /// copy and later slots stay where the vertices point.
    pub fn texture_sources(&self, input: &Path, quiet: bool) -> Vec<crate::manifest::TextureSource> {
        use crate::manifest::TextureSource;
        let files = |names: Vec<String>| names.into_iter().map(TextureSource::File).collect::<Vec<_>>();
        match &self.details {
            // Not deduplicated: a face's `texnumber` indexes the comments
            // as written (a name given twice is two slots, two copies).
            Details::Ply(h) => files(crate::ply::texture_files(&h.comments)),
            // Listed once each by the reader, which numbers the materials
            // by this list.
            Details::Obj(i) => files(i.textures.clone()),
            Details::Gltf(g) => g
                .images
                .iter()
                .map(|im| match im {
                    gltf::GltfImage::File(u) => TextureSource::File(u.clone()),
                    gltf::GltfImage::Embedded { index, name, .. } => {
                        let name = name.clone().unwrap_or_else(|| format!("images[{index}]"));
                        let got = gltf::image_bytes(input, *index).and_then(|b| match crate::gltf::image_mime(&b) {
                            Some(m) => Ok((b, if m == "image/png" { "png" } else { "jpg" })),
                            None => Err(crate::Error::Usage(format!("{}: images[{index}] is neither PNG nor JPEG", input.display()))),
                        });
                        match got {
                            Ok((bytes, ext)) => TextureSource::Embedded { name, ext, bytes },
                            Err(e) => {
                                if !quiet {
                                    eprintln!("warning: {e}; the store keeps its uvs without that texture");
                                }
                                // Its slot stays, without a copy, so later slots keep their
                                // material ids.
                                TextureSource::Missing(format!("{name} (images[{index}], unreadable)"))
                            }
                        }
                    }
                })
                .collect(),
            Details::Stl(_) => Vec::new(),
        }
    }
}

/// Reads what the input says of itself: a PLY's header, an STL's header
/// (binary) or one counting pass (ascii), an OBJ's counting pass.
pub fn read_header(path: &Path, progress: &Progress) -> Result<InputHeader> {
    Ok(match Format::of(path)? {
        Format::Ply => {
            let h = crate::ply::read_header(path)?;
            InputHeader {
                format: Format::Ply,
                attrs: h.attrs,
                vertices: h.vertex_count(),
                faces: h.face_count(),
                vertices_first: h.face_elem.is_some_and(|f| h.vertex_elem < f),
                body_offset: h.body_offset,
                details: Details::Ply(h),
            }
        }
        Format::Stl => {
            let i = stl::read_info(path)?;
            let faces = i.triangles;
            InputHeader {
                format: Format::Stl,
                attrs: AttrSet::POSITION_ONLY,
                vertices: 3 * faces,
                faces,
                vertices_first: true,
                body_offset: 0,
                details: Details::Stl(i),
            }
        }
        Format::Obj => {
            let i = obj::read_info(path, progress)?;
            InputHeader {
                format: Format::Obj,
                attrs: i.attrs,
                vertices: i.vertices,
                faces: i.faces,
                vertices_first: true,
                body_offset: 0,
                details: Details::Obj(i),
            }
        }
        Format::Gltf => {
            let i = gltf::read_info(path)?;
            InputHeader {
                format: Format::Gltf,
                attrs: i.attrs,
                vertices: i.vertices,
                faces: i.triangles,
                vertices_first: true,
                body_offset: 0,
                details: Details::Gltf(i),
            }
        }
    })
}

/// Streams the body to `sink`: every vertex in index order, then every
/// triangle. `mem` bounds what a reader may hold (an OBJ's attribute
/// tables and corners); a reader that spills (an OBJ's corners out of
/// core) does so in a scratch directory it makes inside `scratch`.
pub fn read_body(path: &Path, header: &InputHeader, mem: u64, scratch: &Path, sink: &mut dyn BodySink, progress: &Progress) -> Result<BodyStats> {
    match &header.details {
        Details::Ply(h) => crate::ply::read::read_body(path, h, sink, progress),
        Details::Stl(i) => stl::read_body(path, i, sink, progress),
        Details::Obj(i) => obj::read_body(path, i, mem, scratch, sink, progress),
        Details::Gltf(i) => gltf::read_body(path, i, sink, progress),
    }
}

/// A whole input in memory (tests, metro, the benchmark's peers). An
/// STL's corners are welded here (bit-equal positions, numbered in order
/// of first appearance), so every format gives an indexed mesh;
/// `BodyStats::vertices` stays the corners the file held.
pub fn read_all(path: &Path, mem: u64) -> Result<(InputHeader, CollectSink, BodyStats)> {
    let header = read_header(path, &Progress::hidden())?;
    let mut sink = CollectSink::default();
    let stats = read_body(path, &header, mem, &std::env::temp_dir(), &mut sink, &Progress::hidden())?;
    sink.split_wedges();
    if header.format == Format::Stl {
        sink = weld(sink);
    }
    Ok((header, sink, stats))
}

/// `sink`'s bit-equal positions made one vertex.
fn weld(sink: CollectSink) -> CollectSink {
    let mut w = crate::geom::Welder::with_capacity(sink.vertices.len() / 2);
    let mut vertices = Vec::with_capacity(sink.vertices.len() / 2);
    let map: Vec<u64> = sink.vertices.iter().map(|v| w.id(v.pos, |_| vertices.push(*v)) as u64).collect();
    let triangles = sink.triangles.iter().map(|t| t.map(|i| map[i as usize])).collect();
    CollectSink { vertices, triangles, ..Default::default() }
}
