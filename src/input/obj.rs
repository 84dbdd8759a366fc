//! OBJ input: see [`super`].
use crate::error::Result;
use crate::mesh::AttrSet;
use crate::ply::read::{BodySink, BodyStats};
use crate::progress::Progress;
use std::path::Path;

/// What a first pass over an OBJ says.
#[derive(Clone, Debug)]
pub struct ObjInfo {
    pub positions: u64,
    pub texcoords: u64,
    pub normals: u64,
    pub faces: u64,
    pub corners: u64,
    pub attrs: AttrSet,
    pub vertices: u64,
    pub mtllibs: Vec<String>,
    pub bytes: u64,
}

pub fn read_info(_path: &Path, _progress: &Progress) -> Result<ObjInfo> {
    todo!()
}

pub fn read_body(_path: &Path, _info: &ObjInfo, _mem: u64, _sink: &mut dyn BodySink, _progress: &Progress) -> Result<BodyStats> {
    todo!()
}

pub fn looks_like_obj(_head: &[u8]) -> bool {
    false
}
