//! A gzip file inflated on a thread of its own ([`Inflated`]), so that a reader parses one
//! block while the next is being inflated: on two cores or more, a read of a `.gz` file
//! takes about the longer of inflating and parsing rather than their sum.
//!
//! The thread inflates with the same calls as a reader inflating in place (flate2's
//! `MultiGzDecoder` over zlib-rs, asked for 64 KiB at a time), so the bytes delivered, and
//! where an error stops them, are the same. Blocks travel over a bounded channel and come
//! back to be refilled, so the memory is a few blocks whatever the file's size. Dropping
//! the reader stops the thread and waits for it: no thread outlives a read, failed or not.

use flate2::read::MultiGzDecoder;
use std::fs::File;
use std::io::{self, BufRead, BufReader, Read};
use std::sync::mpsc::{Receiver, SyncSender, TryRecvError, sync_channel};
use std::thread::JoinHandle;

/// Bytes the decoder is asked for at a time, the read buffer of an inline reader.
const REQUEST_BYTES: usize = 1 << 16;

/// Bytes of inflated data in a block handed over, at least (the last one of the stream
/// excepted), and less than one request more.
const BLOCK_BYTES: usize = 4 * REQUEST_BYTES;

/// Blocks inflated ahead of the reader at most.
const BLOCKS_AHEAD: usize = 4;

/// What the inflating thread sends.
enum Message {
    /// The next bytes of the stream (never empty).
    Block(Vec<u8>),
    /// The stream ended cleanly.
    End,
    /// The decoder's error: the stream ends here.
    Failed(io::Error),
}

/// The inflated bytes of a gzip file (all its members, as `MultiGzDecoder` reads them),
/// inflated on a thread of its own.
pub(crate) struct Inflated {
    /// `None` once dropped, which stops the thread.
    blocks: Option<Receiver<Message>>,
    /// Blocks handed back to the thread to refill.
    spare: SyncSender<Vec<u8>>,
    block: Vec<u8>,
    /// The bytes of `block` not yet consumed start here.
    at: usize,
    /// How the stream ended, once it has: `None` cleanly, else the error's kind and text,
    /// returned again on every later read.
    ended: Option<Option<(io::ErrorKind, String)>>,
    thread: Option<JoinHandle<()>>,
}

impl Inflated {
    /// Starts inflating `file` on a new thread; gives the file back where no thread can be
    /// started.
    pub(crate) fn start(file: File) -> std::result::Result<Inflated, File> {
        let (block_tx, blocks) = sync_channel(BLOCKS_AHEAD);
        let (spare, spare_rx) = sync_channel(BLOCKS_AHEAD + 2);
        // The file is handed over only once the thread runs: a failed spawn gives it back.
        let (file_tx, file_rx) = sync_channel::<File>(1);
        let thread = std::thread::Builder::new().name("aorender-inflate".into()).spawn(move || {
            if let Ok(file) = file_rx.recv() {
                inflate(file, &block_tx, &spare_rx);
            }
        });
        match thread {
            Ok(thread) => {
                // The thread waits on the channel, which has room for the file.
                let sent = file_tx.send(file);
                debug_assert!(sent.is_ok(), "the inflating thread has just started");
                Ok(Inflated {
                    blocks: Some(blocks),
                    spare,
                    block: Vec::new(),
                    at: 0,
                    ended: None,
                    thread: Some(thread),
                })
            }
            Err(_) => Err(file),
        }
    }

    /// The error a read after the end returns: the stream's error again, or none.
    fn after_end(&self) -> io::Result<()> {
        match &self.ended {
            Some(Some((kind, text))) => Err(io::Error::new(*kind, text.clone())),
            _ => Ok(()),
        }
    }
}

/// The thread's work: inflates `file` into blocks sent over `blocks`, reusing those that
/// come back on `spare`, until the stream ends, fails, or the reader has gone.
fn inflate(file: File, blocks: &SyncSender<Message>, spare: &Receiver<Vec<u8>>) {
    let mut decoder = MultiGzDecoder::new(BufReader::with_capacity(REQUEST_BYTES, file));
    loop {
        let mut block = match spare.try_recv() {
            Ok(block) => block,
            Err(TryRecvError::Empty | TryRecvError::Disconnected) => Vec::with_capacity(BLOCK_BYTES + REQUEST_BYTES),
        };
        // Every request is a whole 64 KiB, as an inline reader's, after a short one too.
        block.resize(BLOCK_BYTES + REQUEST_BYTES, 0);
        let mut filled = 0;
        let mut end = None;
        while filled < BLOCK_BYTES {
            match decoder.read(&mut block[filled..filled + REQUEST_BYTES]) {
                Ok(0) => {
                    end = Some(Message::End);
                    break;
                }
                Ok(n) => filled += n,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => {
                    end = Some(Message::Failed(e));
                    break;
                }
            }
        }
        block.truncate(filled);
        // A failed send: the reader has gone, and nothing more is wanted.
        if filled > 0 && blocks.send(Message::Block(block)).is_err() {
            return;
        }
        if let Some(end) = end {
            let _ = blocks.send(end);
            return;
        }
    }
}

impl BufRead for Inflated {
    fn fill_buf(&mut self) -> io::Result<&[u8]> {
        if self.at == self.block.len() {
            if self.ended.is_some() {
                self.after_end()?;
                return Ok(&[]);
            }
            let message = match &self.blocks {
                Some(blocks) => blocks.recv().ok(),
                None => None,
            };
            match message {
                Some(Message::Block(block)) => {
                    let used = std::mem::replace(&mut self.block, block);
                    self.at = 0;
                    // A full channel: the thread has enough to fill, let this one go.
                    let _ = self.spare.try_send(used);
                }
                Some(Message::End) => {
                    self.ended = Some(None);
                    return Ok(&[]);
                }
                Some(Message::Failed(e)) => {
                    self.ended = Some(Some((e.kind(), e.to_string())));
                    return Err(e);
                }
                None => {
                    // The thread stopped without a word: it panicked.
                    let text = "the thread inflating the file stopped".to_string();
                    self.ended = Some(Some((io::ErrorKind::Other, text)));
                    self.after_end()?;
                }
            }
        }
        Ok(&self.block[self.at..])
    }

    fn consume(&mut self, amount: usize) {
        self.at = (self.at + amount).min(self.block.len());
    }
}

impl Read for Inflated {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let available = self.fill_buf()?;
        let n = available.len().min(buf.len());
        buf[..n].copy_from_slice(&available[..n]);
        self.consume(n);
        Ok(n)
    }
}

impl Drop for Inflated {
    fn drop(&mut self) {
        // Closing the channel first makes a thread waiting to send give up.
        drop(self.blocks.take());
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn gzip(bytes: &[u8]) -> Vec<u8> {
        let mut encoder = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        encoder.write_all(bytes).unwrap();
        encoder.finish().unwrap()
    }

    /// Everything an inline decoder delivers from `path` through a 64 KiB buffer, and its
    /// error's text if it stopped on one.
    fn inline(path: &std::path::Path) -> (Vec<u8>, Option<String>) {
        let decoder = MultiGzDecoder::new(BufReader::with_capacity(REQUEST_BYTES, File::open(path).unwrap()));
        drain(BufReader::with_capacity(REQUEST_BYTES, decoder))
    }

    fn drain(mut reader: impl BufRead) -> (Vec<u8>, Option<String>) {
        let mut out = Vec::new();
        loop {
            match reader.fill_buf() {
                Ok([]) => return (out, None),
                Ok(b) => {
                    let n = b.len();
                    out.extend_from_slice(b);
                    reader.consume(n);
                }
                Err(e) => return (out, Some(e.to_string())),
            }
        }
    }

    #[test]
    fn inflated_blocks_are_the_inline_decoders_bytes_and_errors() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("f.gz");
        // Incompressible and compressible parts, many blocks long, in two members.
        let mut data: Vec<u8> = (0..3_000_000u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8).collect();
        data.extend((0..2_000_000u32).map(|i| (i / 1000) as u8));
        let mut compressed = gzip(&data[..1_234_567]);
        compressed.extend(gzip(&data[1_234_567..]));
        let mut cases = vec![compressed.clone()];
        // Cut at several places, a corrupt byte in the data and in the trailer.
        cases.extend([10, compressed.len() / 3, compressed.len() - 5].map(|end| compressed[..end].to_vec()));
        for at in [compressed.len() / 2, compressed.len() - 6] {
            let mut bad = compressed.clone();
            bad[at] ^= 0x55;
            cases.push(bad);
        }
        let mut failed = 0;
        for (k, bytes) in cases.iter().enumerate() {
            std::fs::write(&path, bytes).unwrap();
            let (want, error) = inline(&path);
            let (got, got_error) = drain(Inflated::start(File::open(&path).unwrap()).ok().unwrap());
            assert!(want == got, "case {k}: {} bytes inline, {} inflated", want.len(), got.len());
            assert_eq!(error, got_error, "case {k}");
            if k == 0 {
                assert!(got == data && error.is_none());
            }
            failed += usize::from(got_error.is_some());
        }
        assert_eq!(failed, cases.len() - 1, "every damaged stream fails");
    }

    #[test]
    fn a_reader_dropped_early_stops_its_thread() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("f.gz");
        std::fs::write(&path, gzip(&vec![7u8; 64 << 20])).unwrap();
        let mut reader = Inflated::start(File::open(&path).unwrap()).ok().unwrap();
        let mut first = [0u8; 100];
        reader.read_exact(&mut first).unwrap();
        assert!(first == [7; 100]);
        // The thread is waiting with its blocks full: dropping the reader must end it.
        let thread = reader.thread.take().unwrap();
        drop(reader);
        let start = std::time::Instant::now();
        while !thread.is_finished() && start.elapsed().as_secs() < 30 {
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
        assert!(thread.is_finished(), "the inflating thread outlived its reader");
        thread.join().unwrap();
    }
}
