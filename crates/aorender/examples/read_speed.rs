//! Reading speed of the mesh readers: each PLY file given is read by the element-at-a-time
//! reader and by the bulk readers in turn (any other mesh file, such as OBJ, by its one
//! reader, with the triangles placed, in the bulk column), `ROUNDS` times (default 5), and the median
//! speed of each is printed in MB/s of the file's bytes (compressed bytes for `.gz`): of
//! wall time, and of CPU time (user and system, all threads: the speed per core, which a
//! machine shared with other work changes less than the wall time).
//! A measurement, not a test: it asserts only that both readers give the same mesh.
//! `READERS=bulk` times the bulk readers alone (for a profiler). `READER=bake` times the
//! bake's PLY reader instead of the scene loader's: the whole file kept, every property in
//! its own type, one element and one `str::parse` at a time against runs and fast parsers.
//!
//! `cargo run --release -p aorender --features testing --example read_speed -- FILE.ply [FILE.ply.gz ...]`

use aorender::bake::{Asset, PlyAsset};
use aorender::scene::{ReadLimits, load_mesh, read_ply_mesh};
use std::time::Instant;

#[path = "shared/measure.rs"]
mod measure;
use measure::{cpu_seconds, median};

fn main() -> anyhow::Result<()> {
    let rounds: usize = std::env::var("ROUNDS").ok().and_then(|r| r.parse().ok()).unwrap_or(5);
    let limits = ReadLimits::from_env()?;
    let bulk_only = std::env::var("READERS").is_ok_and(|r| r == "bulk");
    let bake = std::env::var("READER").is_ok_and(|r| r == "bake");
    let options = aorender::scene::LoadOptions { limits: limits.clone(), allow_external_uris: false };
    println!("| file | MB | element at a time, MB/s (per CPU second) | bulk, MB/s (per CPU second) | speed-up |");
    println!("|---|---|---|---|---|");
    for arg in std::env::args().skip(1) {
        let path = std::path::Path::new(&arg);
        let mb = std::fs::metadata(path)?.len() as f64 / 1e6;
        let ply = arg.ends_with(".ply") || arg.ends_with(".ply.gz");
        let mut times = [[Vec::new(), Vec::new()], [Vec::new(), Vec::new()]];
        for _ in 0..rounds {
            for fast in [false, true] {
                if !fast && (bulk_only || !ply) {
                    continue;
                }
                let (start, cpu) = (Instant::now(), cpu_seconds());
                let triangles = if ply && bake {
                    let asset = if fast {
                        PlyAsset::read_with(path, &options)?
                    } else {
                        PlyAsset::read_reference(path, &options)?
                    };
                    asset.meshes()[0].face_indices.len() / 3
                } else if ply {
                    read_ply_mesh(path, &limits, fast)?.1.len()
                } else {
                    load_mesh(path, 1.0, &glam::Mat4::IDENTITY)?.len()
                };
                times[fast as usize][0].push(start.elapsed().as_secs_f64());
                times[fast as usize][1].push(cpu_seconds() - cpu);
                anyhow::ensure!(triangles > 0, "{arg}: no triangles");
            }
        }
        anyhow::ensure!(
            bulk_only || !ply || bake || read_ply_mesh(path, &limits, false)? == read_ply_mesh(path, &limits, true)?,
            "{arg}: meshes differ"
        );
        let speeds = times.map(
            |[wall, cpu]| {
                if wall.is_empty() { [f64::NAN; 2] } else { [mb / median(wall), mb / median(cpu)] }
            },
        );
        let [[r, rc], [b, bc]] = speeds;
        let name = path.file_name().map_or(arg.clone(), |n| n.to_string_lossy().to_string());
        println!("| {name} | {mb:.1} | {r:.0} ({rc:.0}) | {b:.0} ({bc:.0}) | {:.1}× |", b / r);
    }
    Ok(())
}
