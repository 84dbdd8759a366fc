//! Errors with the context a user needs to fix their input: the file, the
//! element, the record and the byte offset (or the line) where it broke.
//!
//! Takes: failures from every stage. Gives: one [`Error`] type whose message
//! reads like `mesh.ply: element 'face' record 12 (byte 345): index 99 out of
//! range (vertex count 50)`.

use std::fmt;
use std::io;
use std::path::{Path, PathBuf};

/// Where in an input file something went wrong.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Location {
    pub file: PathBuf,
    /// 1-based line: of a PLY header (header errors, no offset), or of a
    /// line-based body such as an OBJ (with the byte offset).
    pub line: Option<u64>,
    pub element: Option<String>,
    /// 0-based record index within the element.
    pub record: Option<u64>,
    /// Byte offset from the start of the file.
    pub offset: Option<u64>,
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file.display())?;
        if let Some(l) = self.line {
            write!(f, ": {} {l}", if self.offset.is_some() { "line" } else { "header line" })?;
        }
        if let Some(e) = &self.element {
            write!(f, ": element '{e}'")?;
        }
        if let Some(r) = self.record {
            write!(f, " record {r}")?;
        }
        if let Some(o) = self.offset {
            write!(f, " (byte offset {o})")?;
        }
        Ok(())
    }
}

#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The input is malformed or unsupported.
    #[error("{loc}: {msg}")]
    Input { loc: Location, msg: String },
    /// An operating-system error on a named path.
    #[error("{}: {op}: {source}", path.display())]
    Io { path: PathBuf, op: &'static str, source: io::Error },
    /// Bad arguments or options.
    #[error("{0}")]
    Usage(String),
    /// A signal asked the process to stop (see `io::signal`).
    #[error("interrupted by signal {0}")]
    Interrupted(i32),
    /// Standard output was closed by its reader (`octolod info S | head -1`).
    #[error("standard output closed")]
    ClosedOutput,
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    pub fn input(loc: Location, msg: impl Into<String>) -> Error {
        Error::Input { loc, msg: msg.into() }
    }
    pub fn io(path: impl AsRef<Path>, op: &'static str, source: io::Error) -> Error {
        Error::Io { path: path.as_ref().to_path_buf(), op, source }
    }
    /// The input location, when this is an input error.
    pub fn location(&self) -> Option<&Location> {
        match self {
            Error::Input { loc, .. } => Some(loc),
            _ => None,
        }
    }
}

/// Attach a path and an operation to an `io::Result`.
pub trait IoContext<T> {
    fn ctx(self, path: impl AsRef<Path>, op: &'static str) -> Result<T>;
}

impl<T> IoContext<T> for io::Result<T> {
    fn ctx(self, path: impl AsRef<Path>, op: &'static str) -> Result<T> {
        self.map_err(|e| Error::io(path, op, e))
    }
}
