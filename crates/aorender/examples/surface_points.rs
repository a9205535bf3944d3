//! AO at points that are not vertices: points sampled uniformly on a mesh's triangles
//! (area-weighted, uniform in each triangle, with the triangle's normal), computed in f64
//! and rounded to f32 as a data-set pipeline hands them over, against the same points
//! moved 10⁻⁶ × the bounding-box diagonal along their normals; and the texels of a texture
//! bake (generated UVs, one point a texel at its centre) against probes at the same points
//! and normals.
//!
//! ```text
//! cargo run --release -p aorender --example surface_points [-- [cpu|gpu] [MESH]]
//! ```
//!
//! It prints, for the sampled points taken as given (their rays starting exactly at them)
//! and found on their surfaces (`Session::locate`, what `aorender probe` and the Python
//! module do): the mean AO at 256 samples, the points below 0.05, and the share that
//! differ from the moved points by more than 0.3; then, for a 1024² bake with one point a
//! texel and 64 samples, the texels below 0.3 and how many of them a probe at the same
//! point and normal (found on its surface, 1024 samples) reads above 0.6. The mesh is
//! `scenes/bunny.obj` by default; the device the CPU reference.

use aorender::bake::{Placement, TextureOptions, TexturePlan, UvWrap, generate_uvs, read_asset};
use aorender::{BvhOptions, Control, Device, Probe, ProbeValue, Scene, Session, Settings, SurfaceTolerance};
use glam::{DVec3, Mat4};
use std::path::PathBuf;

/// splitmix64: a fixed stream of numbers in [0, 1).
struct Numbers(u64);

impl Numbers {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
}

fn mean(values: &[ProbeValue]) -> f64 {
    values.iter().map(|v| v.mean).sum::<f64>() / values.len() as f64
}

fn main() -> aorender::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let device = match args.first().map(String::as_str) {
        Some("gpu") => Device::gpu(None)?,
        _ => Device::cpu(),
    };
    let path = args
        .get(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scenes/bunny.obj"));
    let scene = Scene::load(&path)?;
    let bounds = scene.bounds().expect("a mesh");
    let diagonal = (bounds.max - bounds.min).as_dvec3().length();
    let triangles: Vec<[DVec3; 3]> = scene.triangles.iter().map(|t| t.v.map(|v| v.as_dvec3())).collect();
    let session = Session::new(&device, scene, &BvhOptions::default())?;
    let settings = Settings::default();

    // 20,000 points uniform on the surface, with their triangles' normals.
    let mut cdf = Vec::with_capacity(triangles.len());
    let mut total = 0.0;
    for t in &triangles {
        total += (t[1] - t[0]).cross(t[2] - t[0]).length();
        cdf.push(total);
    }
    let mut rng = Numbers(1);
    let (mut points, mut moved) = (Vec::new(), Vec::new());
    for _ in 0..20_000 {
        let u = rng.next() * total;
        let t = triangles[cdf.partition_point(|&c| c < u).min(triangles.len() - 1)];
        let (r1, r2) = (rng.next().sqrt(), rng.next());
        let p = t[0] * (1.0 - r1) + t[1] * (r1 * (1.0 - r2)) + t[2] * (r1 * r2);
        let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize();
        points.push(Probe::new(p.as_vec3(), n.as_vec3())?);
        moved.push(Probe::new((p + 1e-6 * diagonal * n).as_vec3(), n.as_vec3())?);
    }
    let located = session.locate(&points, SurfaceTolerance::Relative)?;
    let moved_located = session.locate(&moved, SurfaceTolerance::Relative)?.probes;
    let reference = session.probe(&moved_located, 256, &settings)?.values;
    println!(
        "{} points on {} ({} triangles), 256 samples; moved by 1e-6 x diagonal: mean {:.4}",
        points.len(),
        path.display(),
        triangles.len(),
        mean(&reference)
    );
    for (name, probes) in [("as given", &points), ("found on their surfaces", &located.probes)] {
        let values = session.probe(probes, 256, &settings)?.values;
        let dark = values.iter().filter(|v| v.mean < 0.05).count();
        let apart = values.iter().zip(&reference).filter(|(a, b)| (a.mean - b.mean).abs() > 0.3).count();
        println!(
            "  {name}: mean {:.4}, {dark} below 0.05, {:.2} % differ from the moved points by more than 0.3",
            mean(&values),
            100.0 * apart as f64 / values.len() as f64
        );
    }
    println!("  {} points on no surface within the tolerance", located.off_surface());

    // A 1024² bake into generated UVs, the texel's centre its one point, 64 samples.
    let asset = read_asset(&path)?;
    let options =
        TextureOptions { width: 1024, height: 1024, uv_set: 0, points: 1, padding: 4, wrap: UvWrap::File, seed: 0 };
    let generated = generate_uvs(asset.meshes(), 0, &options)?;
    let mut meshes = asset.meshes().to_vec();
    for (m, uvs) in meshes.iter_mut().zip(&generated.meshes) {
        m.uv_sets.push(uvs.uv_set());
    }
    let placed: Vec<_> = meshes.iter().map(|m| (m, Placement { to_world: Mat4::IDENTITY, instanced: false })).collect();
    let plan = TexturePlan::new(&placed, &options, false, u64::MAX)?;
    let mut render = session.probe_render(&plan.probes, 64, None, &settings, false)?;
    render.run(&mut Control::default())?;
    let texels = render.finish()?.accumulation.probe_values()?;
    let dark: Vec<usize> = (0..texels.len()).filter(|&k| texels[k].mean < 0.3).collect();
    let again: Vec<Probe> =
        dark.iter().map(|&k| Probe::new(plan.probes[k].position, plan.probes[k].normal)).collect::<Result<_, _>>()?;
    let again = session.locate(&again, SurfaceTolerance::Relative)?.probes;
    let probed = session.probe(&again, 1024, &settings)?.values;
    let isolated = probed.iter().filter(|v| v.mean > 0.6).count();
    println!(
        "1024² texture, 1 point x 64 samples a texel: {} texels, mean {:.4}, {} below 0.3, {isolated} of them read above 0.6 by a probe at the same point and normal",
        texels.len(),
        mean(&texels),
        dark.len()
    );
    Ok(())
}
