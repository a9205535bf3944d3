//! Writing speed of the image writers: a film of an ambient-occlusion-like image (a smooth
//! gradient with per-pixel noise, as a render at moderate sample counts gives) written as
//! `.png`, `.exr` and `.pfm` at 1920×1080 and 3840×2160, `ROUNDS` times each (default 5),
//! alternating formats; the median wall time of each, its CPU time (user and system, all
//! threads) and the file's size are printed.
//! The files are written to a temporary directory (or `DIR`), atomically as every output.
//! A measurement, not a test.
//!
//! `cargo run --release -p aorender --example write_speed`

use aorender::Film;
use aorender::output::write_image;
use std::time::Instant;

#[path = "shared/measure.rs"]
mod measure;
use measure::{cpu_seconds, median};

/// A film whose means look like an AO render: a gradient with noise of a few percent.
fn film(width: u32, height: u32) -> Film {
    let mut film = Film::new(width, height);
    film.samples = 1;
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    for (i, v) in film.sum.iter_mut().enumerate() {
        state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
        let noise = ((state >> 40) as f64 / (1u64 << 24) as f64 - 0.5) * 0.06;
        let (x, y) = ((i % width as usize) as f64 / width as f64, (i / width as usize) as f64 / height as f64);
        *v = (0.35 + 0.5 * x * (1.0 - 0.4 * y) + noise).clamp(0.0, 1.0);
    }
    film
}

fn main() -> anyhow::Result<()> {
    let rounds: usize = std::env::var("ROUNDS").ok().and_then(|r| r.parse().ok()).unwrap_or(5);
    let temp = tempfile::tempdir()?;
    let dir = std::env::var_os("DIR").map_or_else(|| temp.path().to_path_buf(), std::path::PathBuf::from);
    println!("| size | format | seconds, median of {rounds} (CPU seconds) | MB | MB/s |");
    println!("|---|---|---|---|---|");
    for (w, h) in [(1920, 1080), (3840, 2160)] {
        let film = film(w, h);
        let formats = ["png", "exr", "pfm"];
        let mut times = formats.map(|_| (Vec::new(), Vec::new()));
        for _ in 0..rounds {
            for (format, times) in formats.iter().zip(&mut times) {
                let path = dir.join(format!("write_speed.{format}"));
                let (start, cpu) = (Instant::now(), cpu_seconds());
                write_image(&film, &path)?;
                times.0.push(start.elapsed().as_secs_f64());
                times.1.push(cpu_seconds() - cpu);
            }
        }
        for (format, times) in formats.iter().zip(times) {
            let mb = std::fs::metadata(dir.join(format!("write_speed.{format}")))?.len() as f64 / 1e6;
            let (t, cpu) = (median(times.0), median(times.1));
            println!("| {w}×{h} | {format} | {t:.3} ({cpu:.3}) | {mb:.1} | {:.0} |", mb / t);
        }
    }
    Ok(())
}
