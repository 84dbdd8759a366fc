//! Sequential buffered input over a regular file: the binary and ascii
//! body readers' (PLY, STL) one way to read a file, with absolute offsets
//! for their errors.

use crate::error::{Error, Result};
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

/// Sequential buffered input that tracks absolute file offsets. Readers
/// parse `buf[pos..end]` in place and advance `pos`.
pub(crate) struct SeqInput {
    file: File,
    /// The file's size when opened.
    pub len: u64,
    pub buf: Vec<u8>,
    pub pos: usize,
    pub end: usize,
    /// File offset of `buf[0]`.
    pub base: u64,
    pub eof: bool,
    pub path: PathBuf,
}

impl SeqInput {
    /// Opens `path` (a regular file) at `offset` with a `buf`-byte buffer.
    pub fn open(path: &Path, offset: u64, buf: usize) -> Result<SeqInput> {
        let (mut file, len) = super::open_regular(path, "open")?;
        if offset > 0 {
            file.seek(SeekFrom::Start(offset)).map_err(|e| Error::io(path, "seek", e))?;
        }
        Ok(SeqInput { file, len, buf: vec![0; buf.max(1)], pos: 0, end: 0, base: offset, eof: false, path: path.to_path_buf() })
    }

    #[inline]
    pub fn offset(&self) -> u64 {
        self.base + self.pos as u64
    }

    #[inline]
    pub fn avail(&self) -> usize {
        self.end - self.pos
    }

    /// Makes at least `n` bytes available; false when the file ends first.
    #[inline]
    pub fn ensure(&mut self, n: usize) -> Result<bool> {
        if self.end - self.pos >= n {
            Ok(true)
        } else {
            self.refill(n)
        }
    }

    /// Moves the unread bytes to the front and reads until `n` are
    /// available or the file ends; grows the buffer only when `n` is
    /// larger than it (bounded by the callers: a record or a token).
    #[cold]
    pub fn refill(&mut self, n: usize) -> Result<bool> {
        if self.pos > 0 {
            self.buf.copy_within(self.pos..self.end, 0);
            self.base += self.pos as u64;
            self.end -= self.pos;
            self.pos = 0;
        }
        if n > self.buf.len() {
            self.buf.resize(n.next_power_of_two(), 0);
        }
        while self.end < n && !self.eof {
            let got = self.file.read(&mut self.buf[self.end..]).map_err(|e| Error::io(&self.path, "read", e))?;
            if got == 0 {
                self.eof = true;
            }
            self.end += got;
        }
        Ok(self.end - self.pos >= n)
    }

    /// Skips ascii whitespace so that offsets name a record's first token.
    pub fn skip_ws(&mut self) -> Result<()> {
        while self.ensure(1)? && self.buf[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        Ok(())
    }

    /// True when no byte is left.
    pub fn at_eof(&mut self) -> Result<bool> {
        Ok(!self.ensure(1)?)
    }
}
