//! Speed of the BVH build: each scene or mesh given is loaded once, then its CWBVH is
//! built `ROUNDS` times (default 5) and converted to the GPU's layout, and the median
//! of each figure is printed: wall seconds and CPU seconds (user and system, all threads)
//! of the build and of the conversion, and of each stage of the build its wall seconds
//! summed over the threads that ran it (cells are built side by side: their stages count
//! once a cell) and its CPU seconds (of the process, or of the threads that built the
//! cells, on Linux), with its share of the build's CPU seconds. On a machine shared with
//! other work the CPU seconds move less than the wall's. A measurement, not a test: it asserts
//! nothing. `RAYON_NUM_THREADS` sets the threads; `QUALITY` the preset (default medium).
//! The BLAKE3 hash of the nodes and primitive indices printed with it tells whether two
//! builds made the same trees, bit for bit.
//!
//! Then the conversion of one BVH2 over all the scene's primitives to a CWBVH, obvhs's
//! (`obvhs::cwbvh::bvh2_to_cwbvh`) and the build's (`bvh::collapse`) in turn, `ROUNDS`
//! times each: the median CPU seconds of each, and whether they made the same tree.
//!
//! `cargo run --release -p aorender --features testing --example bvh_build -- FILE [FILE ...]`

use aorender::Scene;
use aorender::bvh::build::primitive_aabbs;
use aorender::bvh::collapse;
use aorender::bvh::ploc::build_bvh2;
use aorender::bvh::stages::{self, Stage};
use aorender::bvh::{BuildQuality, GpuBvh, build_cwbvh};
use std::time::Instant;

#[path = "shared/measure.rs"]
mod measure;
use measure::{cpu_seconds, median};

fn main() -> anyhow::Result<()> {
    let rounds: usize = std::env::var("ROUNDS").ok().and_then(|r| r.parse().ok()).unwrap_or(5).max(1);
    let quality = match std::env::var("QUALITY").as_deref() {
        Ok("fastest") => BuildQuality::Fastest,
        Ok("fast") => BuildQuality::Fast,
        Ok("slow") => BuildQuality::Slow,
        _ => BuildQuality::Medium,
    };
    println!("{} threads, {quality:?} quality, median of {rounds} rounds", rayon::current_num_threads());
    for path in std::env::args().skip(1) {
        let scene = Scene::load(std::path::Path::new(&path))?;
        let (mut wall, mut cpu, mut layout_wall, mut layout_cpu) = (vec![], vec![], vec![], vec![]);
        let mut per_stage: Vec<(Vec<f64>, Vec<f64>)> = vec![(vec![], vec![]); Stage::ALL.len()];
        let (mut nodes, mut hash) = (0, String::new());
        stages::take();
        for _ in 0..rounds {
            let (start, cpu_start) = (Instant::now(), cpu_seconds());
            let bvh = build_cwbvh(&scene, quality);
            wall.push(start.elapsed().as_secs_f64());
            cpu.push(cpu_seconds() - cpu_start);
            for (k, (_, w, c)) in stages::take().into_iter().enumerate() {
                per_stage[k].0.push(w);
                per_stage[k].1.push(c);
            }
            let (start, cpu_start) = (Instant::now(), cpu_seconds());
            let gpu = GpuBvh::from_cwbvh(&scene, &bvh);
            layout_wall.push(start.elapsed().as_secs_f64());
            layout_cpu.push(cpu_seconds() - cpu_start);
            nodes = gpu.node_count;
            let mut hasher = blake3::Hasher::new();
            for b in bvh.top.iter().chain(&bvh.meshes) {
                hasher.update(bytemuck::cast_slice(&b.nodes));
                hasher.update(bytemuck::cast_slice(&b.primitive_indices));
            }
            hash = hasher.finalize().to_hex()[..16].to_string();
            drop((bvh, gpu));
        }
        let build_cpu = median(cpu.clone());
        println!("\n{path}: {} triangles, {nodes} CWBVH nodes, trees {hash}", scene.triangles.len());
        println!("| stage | wall seconds | CPU seconds | share of the build's CPU |");
        println!("|---|---|---|---|");
        for (stage, (w, c)) in Stage::ALL.iter().zip(per_stage) {
            let c = median(c);
            println!("| {} | {:.3} | {c:.3} | {:.0} % |", stage.name(), median(w), 100.0 * c / build_cpu);
        }
        println!("| build | {:.3} | {build_cpu:.3} | 100 % |", median(wall));
        println!("| GPU layout | {:.3} | {:.3} | |", median(layout_wall), median(layout_cpu));

        let params = obvhs::BvhBuildParams::medium_build();
        let boxes = primitive_aabbs(&scene.flattened());
        let (mut bvh2, _) = build_bvh2(&boxes, &params, true);
        obvhs::bvh2::reinsertion::ReinsertionOptimizer::default().run(&mut bvh2, params.reinsertion_batch_ratio, None);
        let (mut theirs, mut ours, mut same) = (vec![], vec![], true);
        for _ in 0..rounds {
            let start = cpu_seconds();
            let a = obvhs::cwbvh::bvh2_to_cwbvh::bvh2_to_cwbvh(&bvh2, 3, true, false);
            theirs.push(cpu_seconds() - start);
            let start = cpu_seconds();
            let b = collapse::bvh2_to_cwbvh(&bvh2, 3);
            ours.push(cpu_seconds() - start);
            same &= a.nodes == b.nodes && a.primitive_indices == b.primitive_indices;
        }
        println!(
            "conversion of one BVH2 of {} nodes, CPU seconds: obvhs {:.3}, the build's {:.3}; the same tree: {same}",
            bvh2.nodes.len(),
            median(theirs),
            median(ours)
        );
    }
    Ok(())
}
