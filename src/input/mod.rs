//! Input formats beyond PLY: STL ([`stl`]) and OBJ ([`obj`]), each read as
//! the PLY body reader reads a PLY.
//!
//! Takes: a path. Gives: a first look at the file (counts, attributes) and
//! a body reader that calls a [`BodySink`](crate::ply::read::BodySink)
//! with every vertex in index order, then every triangle (polygons
//! fan-triangulated, triangles with a repeated corner dropped and counted),
//! in sequential passes over the file, never holding the mesh in memory —
//! so the soup stage's out-of-core dereference serves every format alike.
//! Bad input is an error naming the file, line or byte offset.

pub mod obj;
pub mod stl;
