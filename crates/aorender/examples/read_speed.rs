//! Reading speed of the PLY readers: each file given is read by the element-at-a-time
//! reader and by the bulk readers in turn, `ROUNDS` times (default 5), and the median
//! speed of each is printed in MB/s of the file's bytes (compressed bytes for `.gz`).
//! A measurement, not a test: it asserts only that both readers give the same mesh.
//!
//! `cargo run --release -p aorender --example read_speed -- FILE.ply [FILE.ply.gz ...]`

use aorender::scene::{ReadLimits, read_ply_mesh};
use std::time::Instant;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> anyhow::Result<()> {
    let rounds: usize = std::env::var("ROUNDS").ok().and_then(|r| r.parse().ok()).unwrap_or(5);
    let limits = ReadLimits::from_env()?;
    println!("| file | MB | element at a time, MB/s | bulk, MB/s | speed-up |");
    println!("|---|---|---|---|---|");
    for arg in std::env::args().skip(1) {
        let path = std::path::Path::new(&arg);
        let mb = std::fs::metadata(path)?.len() as f64 / 1e6;
        let (mut reference, mut bulk) = (Vec::new(), Vec::new());
        for _ in 0..rounds {
            for (fast, times) in [(false, &mut reference), (true, &mut bulk)] {
                let start = Instant::now();
                let mesh = read_ply_mesh(path, &limits, fast)?;
                times.push(start.elapsed().as_secs_f64());
                anyhow::ensure!(!mesh.1.is_empty(), "{arg}: no triangles");
            }
        }
        anyhow::ensure!(
            read_ply_mesh(path, &limits, false)? == read_ply_mesh(path, &limits, true)?,
            "{arg}: meshes differ"
        );
        let (r, b) = (median(reference), median(bulk));
        let name = path.file_name().map_or(arg.clone(), |n| n.to_string_lossy().to_string());
        println!("| {name} | {mb:.1} | {:.0} | {:.0} | {:.1}× |", mb / r, mb / b, r / b);
    }
    Ok(())
}
