//! Files written as rows: blocks of rows formatted on rayon's threads, a round of a few
//! blocks per thread at a time, and written in order, so that the bytes (and the first
//! error) are a row-at-a-time write's.

use rayon::prelude::*;
use std::io::{self, Write};
use std::sync::atomic::{AtomicUsize, Ordering};

/// Writes rows `0..rows` to `out`, each appended to a buffer by `put(row, buffer)`, in
/// blocks of `block_rows` formatted in parallel and written in order. An error is the
/// first row's that fails, and nothing after the block before it is written.
pub fn write_rows(
    out: &mut dyn Write,
    rows: usize,
    block_rows: usize,
    put: &(dyn Fn(usize, &mut Vec<u8>) -> io::Result<()> + Sync),
) -> io::Result<()> {
    let block_rows = block_rows.max(1);
    // Two blocks a thread: memory stays a few blocks a core whatever the file's size.
    let round = 2 * rayon::current_num_threads().max(1);
    let starts: Vec<usize> = (0..rows).step_by(block_rows).collect();
    // The longest block so far: later blocks start that large instead of growing to it.
    let longest = AtomicUsize::new(0);
    for firsts in starts.chunks(round) {
        let texts: Vec<io::Result<Vec<u8>>> = firsts
            .par_iter()
            .map(|&first| {
                let mut text = Vec::with_capacity(longest.load(Ordering::Relaxed));
                for row in first..(first + block_rows).min(rows) {
                    put(row, &mut text)?;
                }
                longest.fetch_max(text.len(), Ordering::Relaxed);
                Ok(text)
            })
            .collect();
        for text in texts {
            out.write_all(&text?)?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rows_come_in_order_and_the_first_error_stops_the_write() {
        let put = |row: usize, out: &mut Vec<u8>| -> io::Result<()> {
            if row == 777 || row == 900 {
                return Err(io::Error::other(format!("row {row}")));
            }
            writeln!(out, "{row}")
        };
        let pool = rayon::ThreadPoolBuilder::new().num_threads(3).build().unwrap();
        let mut out = Vec::new();
        pool.install(|| write_rows(&mut out, 500, 7, &put)).unwrap();
        let expected: String = (0..500).map(|r| format!("{r}\n")).collect();
        assert_eq!(String::from_utf8(out).unwrap(), expected);

        let mut out = Vec::new();
        let error = pool.install(|| write_rows(&mut out, 1000, 10, &put)).unwrap_err();
        assert_eq!(error.to_string(), "row 777");
        // Whole blocks before the failing one are written, nothing from it on.
        let expected: String = (0..770).map(|r| format!("{r}\n")).collect();
        assert_eq!(String::from_utf8(out).unwrap(), expected);
    }
}
