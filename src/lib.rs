//! octolod: out-of-core simplification and viewing of triangle meshes far
//! larger than RAM.
//!
//! Data flow, one module per stage:
//! `ply` (stream PLY) → `soup` (external sort + dereference into a triangle
//! soup) → `octree` (disk-backed partition) → simplify/`quadric` → `store`
//! → view, plus metro.
//! Shared plumbing: [`mesh`] (attribute model), [`error`], [`io`],
//! [`progress`], [`extsort`], [`mem`].

pub mod error;
pub mod extsort;
pub mod gen;
pub mod io;
pub mod mem;
pub mod mesh;
pub mod metro;
pub mod octree;
pub mod pipeline;
pub mod ply;
pub mod progress;
pub mod quadric;

pub mod lod;

pub mod soup;
pub mod store;
pub mod view;

pub use error::{Error, Result};
