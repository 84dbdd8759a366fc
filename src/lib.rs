//! octolod: out-of-core simplification and viewing of triangle meshes far
//! larger than RAM.
//!
//! Data flow, one module per stage:
//! `ply` (stream PLY) → `soup` (out-of-core dereference into a triangle
//! soup) → `octree` (level-0 partition) → `lod` (levels of detail, with
//! `quadric`) → `store` → `view`, plus `simplify` (one mesh of the size or
//! error asked, from a store) and `metro`; `shard` runs the same build as
//! shards on many machines and merges them.
//! Shared plumbing: [`mesh`] (attribute model), [`geom`] (closest points,
//! BVH), [`color`] (sRGB), [`error`], [`io`], [`progress`], [`extsort`], [`mem`].

// `!(x > 0.0)`, `!(v <= limit)`: negated comparisons are the crate's way to
// reject NaN along with the out-of-range values (`x <= 0.0` lets NaN pass).
#![allow(clippy::neg_cmp_op_on_partial_ord, reason = "negated float comparisons deliberately reject NaN")]

pub mod color;
pub mod error;
pub mod extsort;
pub mod gen;
pub mod geom;
pub mod gltf;
pub mod input;
pub mod io;
pub mod mem;
pub mod mesh;
pub mod metro;
pub mod pipeline;
pub mod ply;
pub mod progress;
pub mod quadric;
pub mod serve;
pub mod shard;

pub mod lod;
pub mod manifest;
pub mod simplify;

pub mod soup;
pub mod store;
pub mod tiles;
pub mod view;

pub use error::{Error, Result};
