//! Generated lightmap UVs measured: the time the unwrap takes and the quality of the
//! atlas it makes, for each mesh named (by default `scenes/bunny.obj` and
//! `scenes/dragon_vrip_res4.ply.gz`).
//!
//! ```text
//! cargo run --release -p aorender --example unwrap_quality [-- [--size N] [--padding P] [--rounds R] [MESH...]]
//! ```
//!
//! For each mesh it prints the wall and CPU seconds (user and system, all threads) of
//! `generate_uvs` (the fastest of `--rounds` runs, 1 by default), then the atlas:
//! - charts, and the crate's utilization (chart texels over the atlas);
//! - coverage: the texels a chart's triangle meets (closed texel squares, as the bake's
//!   conservative rasterisation takes them), and the charts' area, each as a fraction of
//!   the atlas;
//! - overlap: texels met by two charts and points (4 × 4 a texel) strictly inside two
//!   triangles (both 0 for a valid atlas);
//! - distortion, area-weighted over the triangles: area distortion (max(r, 1/r) of a
//!   triangle's share of the UV area over its share of the surface: mean and largest),
//!   angle distortion (σ₁/σ₂ of the map's Jacobian), and the normalised L² stretch of
//!   Sander et al. 2001 ("Texture mapping progressive meshes", §3: 1 for a map that only
//!   scales uniformly);
//! - a hash (blake3) of every coordinate's bits, so two builds or thread counts can be
//!   compared for identical charts.

use aorender::bake::{AssetMesh, TextureOptions, UvWrap, generate_uvs, read_asset};
use glam::{DVec2, DVec3};
use std::path::PathBuf;
use std::time::Instant;

// This example takes no median of rounds.
#[allow(dead_code)]
#[path = "shared/measure.rs"]
mod measure;
use measure::cpu_seconds;

/// One triangle of the atlas: its surface positions, its coordinates in texels (y down
/// the atlas) and its chart.
struct Triangle {
    p: [DVec3; 3],
    uv: [DVec2; 3],
    chart: usize,
}

fn cross(a: DVec2, b: DVec2) -> f64 {
    a.x * b.y - a.y * b.x
}

/// Whether the closed texel square at (x, y) meets the triangle (separating axes: the
/// square's two and the triangle's three edge normals).
fn meets(t: &[DVec2; 3], x: f64, y: f64) -> bool {
    let corners = [DVec2::new(x, y), DVec2::new(x + 1.0, y), DVec2::new(x, y + 1.0), DVec2::new(x + 1.0, y + 1.0)];
    let mut axes = [DVec2::X, DVec2::Y, DVec2::ZERO, DVec2::ZERO, DVec2::ZERO];
    for i in 0..3 {
        let e = t[(i + 1) % 3] - t[i];
        axes[2 + i] = DVec2::new(-e.y, e.x);
    }
    axes.iter().all(|a| {
        let (t0, t1) = t.iter().fold((f64::MAX, f64::MIN), |m, p| (m.0.min(p.dot(*a)), m.1.max(p.dot(*a))));
        let (s0, s1) = corners.iter().fold((f64::MAX, f64::MIN), |m, p| (m.0.min(p.dot(*a)), m.1.max(p.dot(*a))));
        t0 <= s1 && s0 <= t1
    })
}

/// The fan triangles of every face with their charts: faces sharing a new vertex are one
/// chart (union-find over the corners' new vertices).
fn triangles(meshes: &[AssetMesh], uvs: &[aorender::bake::MeshUvs], size: DVec2) -> Vec<Triangle> {
    let mut out = Vec::new();
    let mut base = 0;
    for (m, u) in meshes.iter().zip(uvs) {
        let n = u.uvs.len();
        let mut parent: Vec<usize> = (0..n).collect();
        fn root(parent: &mut [usize], mut i: usize) -> usize {
            while parent[i] != i {
                parent[i] = parent[parent[i]];
                i = parent[i];
            }
            i
        }
        for f in 0..m.face_count() {
            let s = m.face_starts[f] as usize;
            for k in 1..m.face(f).len() {
                let (a, b) = (root(&mut parent, u.corners[s] as usize), root(&mut parent, u.corners[s + k] as usize));
                parent[a] = b;
            }
        }
        // The file's convention to texels, y down: v up for OBJ and PLY.
        let texel = |c: glam::Vec2| {
            let c = c.as_dvec2();
            if m.uv_v_down { c * size } else { DVec2::new(c.x, 1.0 - c.y) * size }
        };
        for f in 0..m.face_count() {
            let s = m.face_starts[f] as usize;
            let face = m.face(f);
            for k in 1..face.len().saturating_sub(1) {
                let corners = [s, s + k, s + k + 1];
                out.push(Triangle {
                    p: corners.map(|c| m.positions[m.face_indices[c] as usize].as_dvec3()),
                    uv: corners.map(|c| texel(u.uvs[u.corners[c] as usize])),
                    chart: base + root(&mut parent, u.corners[s] as usize),
                });
            }
        }
        base += n;
    }
    out
}

/// The atlas's measures, printed in one block.
fn report(tris: &[Triangle], w: usize, h: usize) {
    let mut owner = vec![usize::MAX; w * h];
    let mut inside = vec![0u8; 16 * w * h];
    let (mut two_charts, mut two_triangles) = (0usize, 0usize);
    for t in tris {
        let uv = &t.uv;
        let area = cross(uv[1] - uv[0], uv[2] - uv[0]);
        let lo = uv[0].min(uv[1]).min(uv[2]).floor().max(DVec2::ZERO);
        let hi = uv[0].max(uv[1]).max(uv[2]).ceil().min(DVec2::new(w as f64, h as f64));
        for y in lo.y as usize..hi.y as usize {
            for x in lo.x as usize..hi.x as usize {
                if meets(uv, x as f64, y as f64) {
                    let o = &mut owner[y * w + x];
                    if *o != usize::MAX && *o != t.chart && *o != usize::MAX - 1 {
                        two_charts += 1;
                        *o = usize::MAX - 1;
                    } else if *o == usize::MAX {
                        *o = t.chart;
                    }
                }
                for s in 0..16 {
                    let q =
                        DVec2::new(x as f64 + (s % 4) as f64 * 0.25 + 0.125, y as f64 + (s / 4) as f64 * 0.25 + 0.125);
                    // Strictly inside, whichever way the triangle winds.
                    let b = [cross(uv[1] - q, uv[2] - q), cross(uv[2] - q, uv[0] - q), cross(uv[0] - q, uv[1] - q)];
                    if area != 0.0 && b.iter().all(|&c| c * area.signum() > 1e-9 * area.abs()) {
                        let k = (y * w + x) * 16 + s;
                        inside[k] = inside[k].saturating_add(1);
                        if inside[k] == 2 {
                            two_triangles += 1;
                        }
                    }
                }
            }
        }
    }
    let covered = owner.iter().filter(|&&o| o != usize::MAX).count();
    let charts = tris.iter().map(|t| t.chart).collect::<std::collections::HashSet<_>>().len();

    // Distortion, area-weighted: the Jacobian of the map from the triangle's plane to
    // its texels, through its singular values.
    let area3 = |t: &Triangle| 0.5 * (t.p[1] - t.p[0]).cross(t.p[2] - t.p[0]).length();
    let area2 = |t: &Triangle| 0.5 * cross(t.uv[1] - t.uv[0], t.uv[2] - t.uv[0]).abs();
    let total3: f64 = tris.iter().map(area3).sum();
    let total2: f64 = tris.iter().map(area2).sum();
    let (mut area_mean, mut area_max, mut angle_mean, mut stretch) = (0.0, 1.0f64, 0.0, 0.0);
    let (mut weight, mut collapsed) = (0.0, 0usize);
    for t in tris {
        let (a3, a2) = (area3(t), area2(t));
        if a3 <= 0.0 {
            continue;
        }
        // A surface triangle flattened to a line or a point has unbounded distortion:
        // counted apart.
        if a2 <= 0.0 {
            collapsed += 1;
            continue;
        }
        let r = (a2 / total2) / (a3 / total3);
        let d = r.max(1.0 / r);
        area_mean += a3 * d;
        area_max = area_max.max(d);
        // Sander et al.: with q the 3D points and s, t the texel coordinates,
        // S_s = (q1 (t2 − t3) + q2 (t3 − t1) + q3 (t1 − t2)) / 2A, S_t likewise.
        let [s1, s2, s3] = t.uv;
        let a = 0.5 * cross(s2 - s1, s3 - s1);
        let ss = (t.p[0] * (s2.y - s3.y) + t.p[1] * (s3.y - s1.y) + t.p[2] * (s1.y - s2.y)) / (2.0 * a);
        let st = (t.p[0] * (s3.x - s2.x) + t.p[1] * (s1.x - s3.x) + t.p[2] * (s2.x - s1.x)) / (2.0 * a);
        let (e, f, g) = (ss.dot(ss), ss.dot(st), st.dot(st));
        let root = ((e - g) * (e - g) + 4.0 * f * f).sqrt();
        let (big, small) = ((0.5 * (e + g + root)).sqrt(), (0.5 * (e + g - root)).max(0.0).sqrt());
        angle_mean += a3 * if small > 0.0 { big / small } else { 1e12 };
        stretch += a3 * 0.5 * (e + g);
        weight += a3;
    }
    // Normalised: a uniform scale of the surface into the texels has L² stretch 1.
    let l2 = (stretch / weight).sqrt() * (total2 / total3).sqrt();
    println!("  charts {charts}");
    println!(
        "  coverage: {:.4} of the texels met by a chart, {:.4} of the atlas under the charts' area",
        covered as f64 / (w * h) as f64,
        total2 / (w * h) as f64
    );
    println!(
        "  overlap: {two_charts} texels met by two charts, {two_triangles} points inside two triangles; {collapsed} triangles of surface flat in the atlas"
    );
    println!(
        "  distortion: area mean {:.4}, largest {:.2}; angle mean {:.4}; L2 stretch {:.4}",
        area_mean / weight,
        area_max,
        angle_mean / weight,
        l2
    );
}

fn main() -> aorender::Result<()> {
    let (mut size, mut padding, mut rounds, mut paths) = (2048u32, 4u32, 1usize, Vec::new());
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut number = |name: &str| -> u32 {
            args.next().and_then(|v| v.parse().ok()).unwrap_or_else(|| panic!("{name} takes a number"))
        };
        match a.as_str() {
            "--size" => size = number("--size"),
            "--padding" => padding = number("--padding"),
            "--rounds" => rounds = number("--rounds").max(1) as usize,
            _ => paths.push(PathBuf::from(a)),
        }
    }
    if paths.is_empty() {
        let scenes = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
        paths = vec![scenes.join("bunny.obj"), scenes.join("dragon_vrip_res4.ply.gz")];
    }
    let options =
        TextureOptions { width: size, height: size, uv_set: 0, points: 1, padding, wrap: UvWrap::File, seed: 0 };
    println!("{size}² atlas, {padding} texels of padding, {} rayon threads", rayon::current_num_threads());
    for path in &paths {
        let asset = read_asset(path)?;
        let meshes = asset.meshes();
        let faces: usize = meshes.iter().map(|m| m.face_count()).sum();
        let (mut wall, mut cpu, mut generated) = (f64::MAX, f64::MAX, None);
        for _ in 0..rounds {
            let (start, cpu_start) = (Instant::now(), cpu_seconds());
            let g = generate_uvs(meshes, 0, &options)?;
            wall = wall.min(start.elapsed().as_secs_f64());
            cpu = cpu.min(cpu_seconds() - cpu_start);
            if let Some(previous) = &generated {
                assert_eq!(previous, &g, "{}: the unwrap differs from one run to the next", path.display());
            }
            generated = Some(g);
        }
        let g = generated.expect("one round");
        let mut hash = blake3::Hasher::new();
        for m in &g.meshes {
            for c in &m.corners {
                hash.update(&m.uvs[*c as usize].x.to_bits().to_le_bytes());
                hash.update(&m.uvs[*c as usize].y.to_bits().to_le_bytes());
            }
        }
        println!("{} ({faces} faces): unwrap {wall:.3} s wall, {cpu:.3} s CPU", path.display());
        println!("  crate's count {} charts, utilization {:.4}", g.charts, g.utilization);
        let tris = triangles(meshes, &g.meshes, DVec2::new(size as f64, size as f64));
        report(&tris, size as usize, size as usize);
        println!("  coordinates' hash {}", &hash.finalize().to_hex()[..16]);
    }
    Ok(())
}
