//! STL input (binary and ascii): see [`super`].
use crate::error::Result;
use crate::ply::read::{BodySink, BodyStats};
use crate::progress::Progress;
use std::path::Path;

/// What a first look at an STL says.
#[derive(Clone, Debug)]
pub struct StlInfo {
    pub binary: bool,
    pub triangles: u64,
    pub bytes: u64,
    pub name: String,
}

pub fn read_info(_path: &Path) -> Result<StlInfo> {
    todo!()
}

pub fn read_body(_path: &Path, _info: &StlInfo, _sink: &mut dyn BodySink, _progress: &Progress) -> Result<BodyStats> {
    todo!()
}

pub fn looks_like_stl(_head: &[u8], _file_len: u64) -> bool {
    false
}
