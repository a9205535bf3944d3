//! Reading mesh files, plain or gzip-compressed (`.gz`, decompressed as it is read), with
//! a bound on the bytes the stream can still deliver: a count declared in a file's header
//! reserves no more memory than the rest of the file could fill.

use crate::error::{Error, Result};
use flate2::read::MultiGzDecoder;
use std::fs::File;
use std::io::{self, BufRead, BufReader, Read};
use std::path::Path;

/// Largest ratio of decompressed to compressed size DEFLATE can reach: a 258-byte match
/// costs at least 2 bits, 258 × 8 / 2 = 1032 (zlib's technical notes give 1032:1).
const MAX_DEFLATE_RATIO: u64 = 1032;

/// Read buffer size.
const BUFFER_BYTES: usize = 1 << 16;

/// True when `path` names a gzip-compressed file (`.gz`).
pub(crate) fn is_gzip(path: &Path) -> bool {
    path.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("gz"))
}

/// A mesh file opened for reading, decompressed on the fly when it is gzipped. Counts
/// the bytes consumed, and keeps the first error of the underlying stream so that a
/// parser's "unexpected end" can be told apart from a corrupt or truncated gzip stream.
pub(crate) struct Input {
    inner: Box<dyn BufRead>,
    gzip: bool,
    consumed: u64,
    /// Upper bound on the bytes the whole stream can deliver.
    max_total: u64,
    /// The stream ends here for the reader (for headers of bounded length).
    limit: u64,
    stream_error: Option<String>,
}

impl Input {
    /// Opens `path`; a `.gz` file is decompressed as it is read.
    pub(crate) fn open(path: &Path) -> Result<Input> {
        let file = File::open(path).map_err(|e| Error::scene(path, e))?;
        let len = file.metadata().map_err(|e| Error::scene(path, e))?.len();
        let gzip = is_gzip(path);
        let (inner, max_total): (Box<dyn BufRead>, u64) = if gzip {
            let decoder = MultiGzDecoder::new(BufReader::with_capacity(BUFFER_BYTES, file));
            (Box::new(BufReader::with_capacity(BUFFER_BYTES, decoder)), len.saturating_mul(MAX_DEFLATE_RATIO))
        } else {
            (Box::new(BufReader::with_capacity(BUFFER_BYTES, file)), len)
        };
        Ok(Input { inner, gzip, consumed: 0, max_total, limit: u64::MAX, stream_error: None })
    }

    /// Upper bound on the bytes still to come: exact for a plain file, the DEFLATE limit
    /// for a gzipped one.
    pub(crate) fn remaining_bound(&self) -> u64 {
        self.max_total.saturating_sub(self.consumed)
    }

    /// Bytes consumed so far.
    pub(crate) fn consumed(&self) -> u64 {
        self.consumed
    }

    /// Makes the stream end, for the reader, `bytes` bytes after the start; `None` lifts
    /// the limit.
    pub(crate) fn set_limit(&mut self, bytes: Option<u64>) {
        self.limit = bytes.unwrap_or(u64::MAX);
    }

    /// True when the limit of [`Input::set_limit`] has been reached.
    pub(crate) fn at_limit(&self) -> bool {
        self.consumed >= self.limit
    }

    /// The first error of the file or the gzip stream, in one line, if there was one.
    pub(crate) fn stream_error(&self) -> Option<&str> {
        self.stream_error.as_deref()
    }

    /// Reads everything that is left. Memory grows with the bytes actually read.
    pub(crate) fn read_all(mut self, path: &Path) -> Result<Vec<u8>> {
        let mut bytes = Vec::new();
        if !self.gzip {
            bytes.reserve_exact(usize::try_from(self.remaining_bound()).unwrap_or(0));
        }
        if let Err(e) = self.read_to_end(&mut bytes) {
            return Err(Error::scene(path, self.stream_error.take().unwrap_or_else(|| e.to_string())));
        }
        Ok(bytes)
    }

    fn record(&mut self, e: io::Error) -> io::Error {
        if self.stream_error.is_none() {
            self.stream_error = Some(if self.gzip {
                format!("invalid or truncated gzip data: {e}")
            } else {
                format!("cannot read the file: {e}")
            });
        }
        e
    }
}

impl Read for Input {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let allowed = usize::try_from(self.limit.saturating_sub(self.consumed)).unwrap_or(usize::MAX);
        let want = buf.len().min(allowed);
        let n = match self.inner.read(&mut buf[..want]) {
            Ok(n) => n,
            Err(e) => return Err(self.record(e)),
        };
        self.consumed += n as u64;
        Ok(n)
    }
}

impl BufRead for Input {
    fn fill_buf(&mut self) -> io::Result<&[u8]> {
        let allowed = usize::try_from(self.limit.saturating_sub(self.consumed)).unwrap_or(usize::MAX);
        // Two steps so that an error can be recorded without holding the buffer's borrow.
        if let Err(e) = self.inner.fill_buf() {
            return Err(self.record(e));
        }
        let buf = self.inner.fill_buf()?;
        Ok(&buf[..buf.len().min(allowed)])
    }

    fn consume(&mut self, amount: usize) {
        self.inner.consume(amount);
        self.consumed += amount as u64;
    }
}

/// A message from a parsing crate in one line of at most about 200 characters: line
/// breaks and control characters become spaces, runs of white space one space.
pub(crate) fn one_line(message: &str) -> String {
    const MAX_CHARS: usize = 200;
    let cleaned: String = message.chars().map(|c| if c.is_control() { ' ' } else { c }).collect();
    let mut words = cleaned.split_whitespace();
    let mut out = String::new();
    for word in words.by_ref() {
        if out.chars().count() + word.chars().count() > MAX_CHARS {
            out.push_str(" …");
            break;
        }
        if !out.is_empty() {
            out.push(' ');
        }
        out.push_str(word);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_line_collapses_breaks_and_truncates() {
        assert_eq!(
            one_line("Couldn't parse.\n\tString: 'x'\r\n\tError: bad"),
            "Couldn't parse. String: 'x' Error: bad"
        );
        let long = "word ".repeat(100);
        let short = one_line(&long);
        assert!(short.ends_with('…') && short.chars().count() <= 202, "{short}");
    }
}
