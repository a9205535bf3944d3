//! Lightmap texture coordinates for meshes without any, from the `uvunwrap` crate (pure
//! Rust, after xatlas: charts grown by normal cones, LSCM with as-rigid-as-possible
//! refinement, packing of the rasterised charts by shape; each chart's least squares
//! solved by faer's sparse Cholesky, charts in parallel). The meshes of one texture
//! (one glTF material, or the file's one mesh) are unwrapped together into one atlas of
//! the texture's size, their charts at least `2 × padding` texels apart and `padding`
//! texels from the border, so a bake's conservative coverage never puts two charts in
//! one texel and the dilation of one does not reach the next. The atlas is the same run
//! to run and on any thread count; another kind of CPU (other SIMD kernels and cache
//! blocking in the solver) may give other charts.
//!
//! Unwrapping splits vertices along the seams: a generated set gives each face corner a
//! vertex of a new list, each a copy of one of the mesh's (`xref`, xatlas's name) with
//! its coordinates. OBJ keeps them as `vt` lines, PLY as MeshLab's face `texcoord`
//! lists (per corner), glTF as a new `TEXCOORD_n` on primitives whose vertices are
//! split accordingly.

use super::asset::{AssetMesh, GeneratedUvs, MeshUvs};
use super::texture::TextureOptions;
use crate::error::{Error, Result};
use glam::Vec2;

/// A mesh as the unwrapper takes it: positions, fan triangles, each triangle's face.
type Triangulated = (Vec<[f32; 3]>, Vec<u32>, Vec<u32>);

/// Unwraps `meshes` into set `set`: the meshes sharing a material (one texture) share an
/// atlas of `options`' size with charts `max(padding, 1)` texels apart (twice that
/// between charts).
pub fn generate_uvs(meshes: &[AssetMesh], set: u32, options: &TextureOptions) -> Result<GeneratedUvs> {
    options.validate()?;
    let (w, h) = (options.width, options.height);
    let padding = options.padding.max(1);
    let page = w.min(h);
    if page <= 4 * padding {
        return Err(Error::settings(format!(
            "a {w}×{h} texture is too small to unwrap charts into with {padding} texels of padding: choose a larger --texture or less --padding"
        )));
    }
    // Fan triangulation of every face, each triangle marked with its face (a polygon's
    // triangles share a chart, so each corner gets one coordinate).
    let triangulated: Vec<Triangulated> = meshes
        .iter()
        .map(|m| {
            let (mut indices, mut polygons) = (Vec::new(), Vec::new());
            for f in 0..m.face_count() {
                let face = m.face(f);
                for k in 1..face.len().saturating_sub(1) {
                    indices.extend([face[0], face[k], face[k + 1]]);
                    polygons.push(f as u32);
                }
            }
            (m.positions.iter().map(|p| p.to_array()).collect(), indices, polygons)
        })
        .collect();
    let mut groups: Vec<(Option<usize>, Vec<usize>)> = Vec::new();
    for (i, m) in meshes.iter().enumerate() {
        match groups.iter_mut().find(|g| g.0 == m.material) {
            Some(g) => g.1.push(i),
            None => groups.push((m.material, vec![i])),
        }
    }
    let unwrap_options = uvunwrap::Options {
        density: uvunwrap::Density::Auto { page_size: page },
        padding,
        ..uvunwrap::Options::default()
    };
    let mut out = GeneratedUvs { meshes: vec![MeshUvs::default(); meshes.len()], ..GeneratedUvs::default() };
    let mut utilization = 0.0;
    for (_, group) in &groups {
        let inputs: Vec<uvunwrap::MeshInput> = group
            .iter()
            .map(|&i| {
                let (positions, indices, polygons) = &triangulated[i];
                uvunwrap::MeshInput { polygons: Some(polygons), ..uvunwrap::MeshInput::new(positions, indices) }
            })
            .collect();
        let label = &meshes[group[0]].label;
        let atlas = uvunwrap::generate(&inputs, &unwrap_options)
            .map_err(|e| Error::settings(format!("{label}: cannot unwrap the mesh: {e}")))?;
        if atlas.page_count > 1 {
            return Err(Error::settings(format!(
                "{label}: the mesh's {} charts do not fit one {w}×{h} texture with {padding} texels of padding: choose a larger --texture or less --padding",
                atlas.chart_count
            )));
        }
        out.charts += atlas.chart_count;
        out.atlases += 1;
        utilization += atlas.utilization * (atlas.width as f32 * atlas.height as f32) / (w as f32 * h as f32);
        // Page coordinates to the texture's: the page is the texture's top-left corner.
        let scale = Vec2::new(atlas.width as f32 / w as f32, atlas.height as f32 / h as f32);
        for (&i, unwrapped) in group.iter().zip(&atlas.meshes) {
            let mesh = &meshes[i];
            let uvs = unwrapped
                .vertices
                .iter()
                .map(|v| {
                    let c = Vec2::from(v.uv) * scale;
                    if mesh.uv_v_down { c } else { Vec2::new(c.x, 1.0 - c.y) }
                })
                .collect();
            let xref = unwrapped.vertices.iter().map(|v| v.xref).collect();
            let corners = corner_vertices(mesh, &unwrapped.indices, &unwrapped.vertices)?;
            out.meshes[i] = MeshUvs { set, xref, uvs, corners };
        }
    }
    out.utilization = utilization / groups.len().max(1) as f32;
    Ok(out)
}

/// The new vertex of every face corner, from the unwrapped fan triangles (`indices`,
/// three per triangle in the order [`generate_uvs`] made them). A corner the fan
/// triangles of a face give different coordinates (a polygon too bent to flatten in one
/// chart) is refused.
fn corner_vertices(mesh: &AssetMesh, indices: &[u32], vertices: &[uvunwrap::OutputVertex]) -> Result<Vec<u32>> {
    let mut corners = vec![u32::MAX; mesh.face_indices.len()];
    let mut t = 0;
    for f in 0..mesh.face_count() {
        let start = mesh.face_starts[f] as usize;
        let n = mesh.face(f).len();
        for k in 1..n.saturating_sub(1) {
            for (corner, &new) in [start, start + k, start + k + 1].into_iter().zip(&indices[3 * t..3 * t + 3]) {
                let old = corners[corner];
                if old != u32::MAX && old != new && vertices[old as usize].uv != vertices[new as usize].uv {
                    return Err(Error::settings(format!(
                        "{}: face {f} is too bent to unwrap in one piece: triangulate the mesh first",
                        mesh.label
                    )));
                }
                if old == u32::MAX {
                    corners[corner] = new;
                }
            }
            t += 1;
        }
    }
    // Corners of faces with fewer than three corners have no triangle: any vertex of theirs.
    for (c, v) in corners.iter_mut().zip(&mesh.face_indices) {
        if *c == u32::MAX {
            *c = vertices.iter().position(|o| o.xref == *v).unwrap_or(0) as u32;
        }
    }
    Ok(corners)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::texture::UvWrap;
    use glam::Vec3;

    /// A cube of six quads, vertices shared between faces.
    fn cube() -> AssetMesh {
        let positions: Vec<Vec3> =
            (0..8).map(|i| Vec3::new((i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32)).collect();
        let faces = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
        AssetMesh {
            label: "cube".into(),
            positions,
            face_starts: (0..=6).map(|f| 4 * f).collect(),
            face_indices: faces.iter().flatten().copied().collect(),
            ..AssetMesh::default()
        }
    }

    #[test]
    fn quads_get_one_coordinate_per_corner_inside_the_texture() {
        let o = TextureOptions { width: 64, height: 32, uv_set: 0, points: 1, padding: 2, wrap: UvWrap::File, seed: 0 };
        let mesh = cube();
        let g = generate_uvs(std::slice::from_ref(&mesh), 0, &o).unwrap();
        let uvs = &g.meshes[0];
        assert_eq!(uvs.corners.len(), 24);
        for (&c, &v) in uvs.corners.iter().zip(&mesh.face_indices) {
            assert_eq!(uvs.xref[c as usize], v, "a corner's new vertex copies its own");
        }
        // Inside the texture by the padding (2 texels of 64 across, of 32 down).
        for c in &uvs.uvs {
            assert!(c.x >= 2.0 / 64.0 - 1e-6 && c.x <= 1.0 - 2.0 / 64.0 + 1e-6, "{c}");
            assert!(c.y >= 2.0 / 32.0 - 1e-6 && c.y <= 1.0 - 2.0 / 32.0 + 1e-6, "{c}");
        }
        assert!(g.charts >= 1 && g.atlases == 1);
    }

    /// The bunny's atlas is the same run to run and on one or three threads: charts are
    /// solved in parallel, each on one thread, and gathered in order.
    #[test]
    fn the_bunny_unwraps_the_same_on_any_thread_count() {
        let bunny = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/bunny.obj");
        let asset = super::super::files::read_asset(&bunny).unwrap();
        let o =
            TextureOptions { width: 256, height: 256, uv_set: 0, points: 1, padding: 2, wrap: UvWrap::File, seed: 0 };
        let on = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| generate_uvs(asset.meshes(), 0, &o)).unwrap()
        };
        let one = on(1);
        assert!(one.charts > 10, "{} charts", one.charts);
        assert_eq!(one.meshes[0].corners.len(), asset.meshes()[0].face_indices.len());
        for (run, threads) in [(1, 3), (2, 3), (3, 1)] {
            let other = on(threads);
            assert!(other == one, "run {run} on {threads} threads: another atlas ({} charts)", other.charts);
        }
    }

    #[test]
    fn too_small_a_texture_is_refused_in_one_line() {
        let o = TextureOptions { width: 8, height: 8, uv_set: 0, points: 1, padding: 4, wrap: UvWrap::File, seed: 0 };
        let e = generate_uvs(&[cube()], 0, &o).unwrap_err().to_string();
        assert!(e.contains("too small") && !e.contains('\n'), "{e}");
    }
}
