//! Gzip on every core, pigz-style: the data is cut into blocks of [`BLOCK_BYTES`], each
//! block deflated on its own rayon task with the 32 KiB before it as its dictionary and
//! ended on a byte boundary (a sync flush), the last one ended as the final block; the
//! blocks' raw deflate streams, one after the other, are the deflate stream of one gzip
//! member, whose CRC-32 is combined from the blocks'. Any gzip or zlib reader reads it.
//!
//! The bytes depend on the data alone: the blocks are cut at fixed offsets from the
//! start of the stream, whatever the thread count and however the data is handed over,
//! so that an output is the same file on any machine's cores. The header is flate2's
//! `GzEncoder`'s (no name, no time, unknown system).

use flate2::{Compress, Compression, Crc, FlushCompress, Status};
use rayon::prelude::*;
use std::io::{self, Write};

/// Bytes of input in one block: large enough that its dictionary and its sync marker
/// cost little (the ratio is within a fraction of a percent of one stream's), small
/// enough that a file of a few megabytes keeps several cores busy.
pub const BLOCK_BYTES: usize = 1 << 20;

/// The window a block's compressor is primed with: deflate's longest distance.
const DICTIONARY_BYTES: usize = 32 << 10;

/// The compression level: zlib's default, as flate2's `Compression::default()`.
const LEVEL: u32 = 6;

/// A gzip stream written to `W` on rayon's threads: [`Write`] takes the data, whole
/// blocks are compressed a round at a time as they fill, and [`GzipWriter::finish`]
/// compresses the rest and writes the trailer. Dropped without `finish`, the stream is
/// left incomplete.
pub struct GzipWriter<W: Write> {
    inner: W,
    /// Data not compressed yet, from a block boundary.
    pending: Vec<u8>,
    /// The last [`DICTIONARY_BYTES`] (or fewer) of the data compressed so far.
    window: Vec<u8>,
    /// The CRC-32 and length (modulo 2³²) of the data compressed so far.
    crc: Crc,
    /// Blocks compressed in one round (two per thread: memory stays a few blocks a core).
    round_blocks: usize,
}

impl<W: Write> GzipWriter<W> {
    /// Starts a gzip stream into `inner`, writing its header at once.
    pub fn new(mut inner: W) -> io::Result<GzipWriter<W>> {
        // flate2's header for the default level: no flags, no time, XFL 0, OS 255.
        inner.write_all(&[0x1f, 0x8b, 8, 0, 0, 0, 0, 0, 0, 255])?;
        let round_blocks = 2 * rayon::current_num_threads().max(1);
        Ok(GzipWriter { inner, pending: Vec::new(), window: Vec::new(), crc: Crc::new(), round_blocks })
    }

    /// Compresses and writes the data still pending as the final block, then the
    /// trailer (CRC-32 and length); returns the inner writer.
    pub fn finish(mut self) -> io::Result<W> {
        self.compress_blocks(true)?;
        let trailer = [self.crc.sum().to_le_bytes(), self.crc.amount().to_le_bytes()].concat();
        self.inner.write_all(&trailer)?;
        Ok(self.inner)
    }

    /// Compresses the whole blocks pending (with `last`, every byte pending, the last
    /// block ended as the stream's final one) on rayon's threads, and writes them in order.
    fn compress_blocks(&mut self, last: bool) -> io::Result<()> {
        let whole = self.pending.len() / BLOCK_BYTES * BLOCK_BYTES;
        let end = if last { self.pending.len() } else { whole };
        let mut starts: Vec<usize> = (0..end).step_by(BLOCK_BYTES).collect();
        if last && end == whole {
            // The final block is empty when the data ends on a block boundary (or is empty).
            starts.push(end);
        }
        let (pending, window) = (&self.pending, &self.window);
        let blocks: Vec<io::Result<(Vec<u8>, Crc)>> = starts
            .par_iter()
            .map(|&start| {
                let block = &pending[start..(start + BLOCK_BYTES).min(end)];
                let dictionary = if start == 0 { &window[..] } else { &pending[start - DICTIONARY_BYTES..start] };
                let is_final = last && start + block.len() == end && start + BLOCK_BYTES > end;
                let mut crc = Crc::new();
                crc.update(block);
                Ok((deflate(dictionary, block, is_final)?, crc))
            })
            .collect();
        for block in blocks {
            let (bytes, crc) = block?;
            self.inner.write_all(&bytes)?;
            self.crc.combine(&crc);
        }
        // The window keeps the data just before the next block.
        let kept = &self.pending[end.saturating_sub(DICTIONARY_BYTES)..end];
        if kept.len() == DICTIONARY_BYTES {
            self.window.clear();
        } else {
            self.window.drain(..(self.window.len() + kept.len()).saturating_sub(DICTIONARY_BYTES));
        }
        self.window.extend_from_slice(kept);
        self.pending.drain(..end);
        Ok(())
    }
}

impl<W: Write> Write for GzipWriter<W> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.pending.extend_from_slice(buf);
        if self.pending.len() >= self.round_blocks * BLOCK_BYTES {
            self.compress_blocks(false)?;
        }
        Ok(buf.len())
    }

    /// Flushes the inner writer. Data short of a whole block stays pending: a block cut
    /// where a flush falls would make the bytes depend on when it was called.
    fn flush(&mut self) -> io::Result<()> {
        self.inner.flush()
    }
}

/// `bytes` as a gzip file, compressed as [`GzipWriter`] compresses.
pub fn gzip(bytes: &[u8]) -> io::Result<Vec<u8>> {
    let mut writer = GzipWriter::new(Vec::with_capacity(bytes.len() / 3 + 64))?;
    writer.write_all(bytes)?;
    writer.finish()
}

/// The raw deflate stream of `block` after `dictionary`: ended on a byte boundary by a
/// sync flush, or as the stream's final block when `last`.
fn deflate(dictionary: &[u8], block: &[u8], last: bool) -> io::Result<Vec<u8>> {
    let mut compress = Compress::new(Compression::new(LEVEL), false);
    if !dictionary.is_empty() {
        compress.set_dictionary(dictionary).map_err(io::Error::other)?;
    }
    let flush = if last { FlushCompress::Finish } else { FlushCompress::Sync };
    let mut out = Vec::with_capacity(block.len() / 2 + 1024);
    loop {
        let consumed = compress.total_in() as usize;
        let status = compress.compress_vec(&block[consumed..], &mut out, flush).map_err(io::Error::other)?;
        let done = if last {
            status == Status::StreamEnd
        } else {
            // A sync flush is complete once it returns with output space to spare.
            compress.total_in() as usize == block.len() && out.len() < out.capacity()
        };
        if done {
            return Ok(out);
        }
        out.reserve(out.capacity().max(4096));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flate2::read::{GzDecoder, MultiGzDecoder};
    use std::io::Read;

    /// Text like a baked PLY's: numbers that repeat enough to compress, not trivially.
    fn ply_like(bytes: usize) -> Vec<u8> {
        let mut out = Vec::with_capacity(bytes + 64);
        let mut state = 12345u64;
        while out.len() < bytes {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            let x = (state >> 40) as f32 / (1u64 << 24) as f32;
            writeln!(out, "{x} {} {} 0.5", x * 2.0, (state >> 60) as u8).unwrap();
        }
        out.truncate(bytes);
        out
    }

    fn gunzip(bytes: &[u8]) -> Vec<u8> {
        let mut out = Vec::new();
        // A single-member reader: the file must be one gzip member, not several.
        GzDecoder::new(bytes).read_to_end(&mut out).unwrap();
        let mut again = Vec::new();
        MultiGzDecoder::new(bytes).read_to_end(&mut again).unwrap();
        assert_eq!(out, again, "data after the first member");
        out
    }

    fn compressed_on(threads: usize, data: &[u8], piece: usize) -> Vec<u8> {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            let mut writer = GzipWriter::new(Vec::new()).unwrap();
            for p in data.chunks(piece.max(1)) {
                writer.write_all(p).unwrap();
            }
            writer.finish().unwrap()
        })
    }

    #[test]
    fn the_stream_reads_back_as_the_data_at_every_length_around_block_boundaries() {
        let data = ply_like(3 * BLOCK_BYTES + 100);
        let lengths = [0, 1, 1000, BLOCK_BYTES - 1, BLOCK_BYTES, BLOCK_BYTES + 1, 2 * BLOCK_BYTES, data.len()];
        for n in lengths {
            let gz = gzip(&data[..n]).unwrap();
            assert_eq!(gunzip(&gz), &data[..n], "{n} bytes");
            let trailer = &gz[gz.len() - 8..];
            let mut crc = Crc::new();
            crc.update(&data[..n]);
            assert_eq!(trailer[..4], crc.sum().to_le_bytes(), "{n} bytes: CRC-32");
            assert_eq!(trailer[4..], (n as u32).to_le_bytes(), "{n} bytes: length");
        }
    }

    #[test]
    fn the_bytes_are_the_same_on_any_thread_count_and_for_any_write_sizes() {
        let data = ply_like(9 * BLOCK_BYTES + 12345);
        let one = compressed_on(1, &data, data.len());
        assert_eq!(gunzip(&one), data);
        for (threads, piece) in [(1, 1000), (2, data.len()), (2, 4096), (3, 777_777), (8, BLOCK_BYTES)] {
            assert!(compressed_on(threads, &data, piece) == one, "{threads} threads, writes of {piece} bytes");
        }
    }

    #[test]
    fn blocks_primed_with_the_previous_data_compress_as_well_as_one_stream() {
        // Data that repeats across block boundaries compresses only when each block
        // sees the window before it.
        let unit = ply_like(20_000);
        let data: Vec<u8> = unit.iter().copied().cycle().take(4 * BLOCK_BYTES).collect();
        let ours = gzip(&data).unwrap();
        let mut one_stream = flate2::write::GzEncoder::new(Vec::new(), Compression::default());
        one_stream.write_all(&data).unwrap();
        let one_stream = one_stream.finish().unwrap();
        assert_eq!(gunzip(&ours), data);
        assert!(
            ours.len() < one_stream.len() + 64 * 4,
            "{} bytes against one stream's {}",
            ours.len(),
            one_stream.len()
        );
    }

    #[test]
    fn the_header_is_flate2s() {
        let ours = gzip(b"abc").unwrap();
        let theirs = flate2::write::GzEncoder::new(Vec::new(), Compression::default()).finish().unwrap();
        assert_eq!(ours[..10], theirs[..10]);
    }
}
