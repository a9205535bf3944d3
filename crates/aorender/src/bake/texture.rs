//! AO baked into textures: every texel whose square a triangle's UV image touches gets AO
//! at surface points under it, and the charts are padded by dilation so that bilinear
//! filtering and mip levels do not mix in the background.
//!
//! - **Coverage** is conservative: a texel is covered when its closed square meets a
//!   triangle in UV space (the separating-axis test of a triangle against a box, in 2-D:
//!   the box's two axes and the triangle's three edge normals; Akenine-Möller, "Fast 3D
//!   triangle-box overlap testing", 2001, reduced to the plane).
//! - **Points.** Each covered texel has `points` positions inside its square, a
//!   Cranley–Patterson rotation of the R2 sequence (Roberts, "The unreasonable
//!   effectiveness of quasirandom sequences", 2018) by a hash of the texel and the seed,
//!   so neighbouring texels are decorrelated (with one point a texel, its centre). A position inside a triangle is traced at
//!   the matching surface point; a position outside every triangle of a texel at the
//!   edge of a chart moves to the nearest point of the nearest triangle. The normal is
//!   the vertex normals interpolated; the position's offset bound is its distance to the
//!   triangle's plane (`plan::triangle_probe`). Each point is a probe with its own sample
//!   sequence; a texel's value is the mean of its points', its standard error theirs
//!   combined.
//! - **Overlaps.** A position strictly inside several triangles (mirrored or stacked
//!   charts) gets a point on each, and the texel is counted as overlapping.
//! - **Padding.** `padding` rounds of dilation: a texel outside the charts takes the mean
//!   of its filled 8-neighbours, so after `padding` rounds every texel within that many
//!   texels (Chebyshev distance) of a chart has a value; covered texels never change.
//!   What is left gets the mean of the covered texels, so coarse mip levels keep it.

use super::asset::AssetMesh;
use super::plan::{Placement, triangle_probe, vertex_normals};
use crate::error::{Error, Result};
use crate::probe::{Probe, ProbeValue};
use glam::{DVec2, Mat3, Vec2, Vec3};

/// The largest side of a texture the bake takes: a map is an image, at most the largest
/// image side.
pub const MAX_TEXTURE_SIZE: u32 = crate::scene::MAX_IMAGE_SIDE;

/// Host bytes a texel needs while the texture is planned and written (its value, standard
/// error, bent normal, coverage, where its points start and the rasteriser's records),
/// beyond its points.
pub const BYTES_PER_TEXEL: u64 = 48;

/// Host bytes a traced point needs at the peak of a bake, measured: about 96 for the
/// point itself (its probe in the plan and in the device's copy, its mesh, its value read
/// back) and 144 for each film slot it has, one, or four with bent normals (the film's
/// f64 sums, the accumulation's exact i128 sums, the block of sums taken from the device
/// and the film read back from them). The 2CylinderEngine's 256² bake, 3.67 million
/// points, peaked at 206 bytes a point without bent normals and 620 with when a render's
/// finish copied its sums; 196 and 350 since: an upper bound.
pub fn bytes_per_point(bent_normals: bool) -> u64 {
    let slots = if bent_normals { 4 } else { 1 };
    96 + 144 * slots
}

/// What to do with texture coordinates outside [0, 1].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum UvWrap {
    /// Follow the file: repeat along a set the file's own textures repeat along (glTF
    /// samplers), refuse otherwise.
    #[default]
    File,
    /// Refuse the mesh.
    Refuse,
    /// Repeat the texture (glTF's default `REPEAT` wrap): a texel takes every surface
    /// point whose coordinates land on it modulo 1.
    Repeat,
}

/// How a texture is baked.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TextureOptions {
    /// Width and height in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// The texture coordinate set baked into (glTF `TEXCOORD_n`; 0 for OBJ and PLY).
    pub uv_set: u32,
    /// Positions (points traced) per texel.
    pub points: u32,
    /// Texels of dilation around the charts.
    pub padding: u32,
    /// Coordinates outside [0, 1].
    pub wrap: UvWrap,
    /// Decorrelates the positions between bakes with different seeds.
    pub seed: u32,
}

impl TextureOptions {
    /// Checks the size and the number of points.
    pub fn validate(&self) -> Result<()> {
        for (name, n) in [("width", self.width), ("height", self.height)] {
            if n == 0 || n > MAX_TEXTURE_SIZE {
                return Err(Error::settings(format!(
                    "texture {name} {n}: a texture side must be 1 to {MAX_TEXTURE_SIZE} texels"
                )));
            }
        }
        if self.points == 0 || self.points > 256 {
            return Err(Error::settings(format!("{} points per texel: expected 1 to 256", self.points)));
        }
        Ok(())
    }

    /// Texels in the texture.
    pub fn texels(&self) -> u64 {
        u64::from(self.width) * u64::from(self.height)
    }
}

/// The meshes (indices into the asset's) baked into one texture, and the glTF material
/// they share.
#[derive(Clone, Debug, PartialEq)]
pub struct TextureTarget {
    /// The material, when the meshes have one.
    pub material: Option<usize>,
    /// The meshes.
    pub meshes: Vec<usize>,
}

/// The textures of an asset's meshes: one per glTF material (and one for the meshes
/// without), one for an OBJ or PLY file; meshes without the set `uv_set` are left out.
pub fn texture_targets<'a>(meshes: impl IntoIterator<Item = &'a AssetMesh>, uv_set: u32) -> Vec<TextureTarget> {
    let mut out: Vec<TextureTarget> = Vec::new();
    for (i, mesh) in meshes.into_iter().enumerate() {
        if mesh.uv_set(uv_set).is_none() {
            continue;
        }
        match out.iter_mut().find(|t| t.material == mesh.material) {
            Some(t) => t.meshes.push(i),
            None => out.push(TextureTarget { material: mesh.material, meshes: vec![i] }),
        }
    }
    out
}

/// The points of a texture bake (or of a block of its texels, [`TextureLayout::plan`])
/// and where their values go.
#[derive(Clone, Debug, Default)]
pub struct TexturePlan {
    /// Texture width.
    pub width: u32,
    /// Texture height.
    pub height: u32,
    /// The textures.
    pub targets: Vec<TextureTarget>,
    /// The probes, texture after texture, texel after texel.
    pub probes: Vec<Probe>,
    /// The index of the first probe among all the bake's (0 for a whole bake): the block's
    /// probes take the sample sequences of points `first_point..`.
    pub first_point: u32,
    /// For each texture, its covered texels (`y * width + x`, increasing).
    texels: Vec<Vec<u32>>,
    /// For each texture, where each covered texel's probes start in `probes` (one more
    /// entry than texels).
    starts: Vec<Vec<u32>>,
    /// For each probe, the mesh (index into `to_file`) it lies on.
    probe_mesh: Vec<u32>,
    /// For each mesh of the targets, in order, world directions into its file's space.
    to_file: Vec<Mat3>,
    /// Covered texels with a position inside several triangles.
    pub overlapping_texels: usize,
    /// Triangles not rasterised: without coordinates of the set at a corner, or of zero
    /// area in UV space.
    pub skipped_triangles: usize,
    /// Triangles with a corner outside [0, 1] in UV space (only with [`UvWrap::Repeat`]).
    pub wrapped_triangles: usize,
}

/// A covered texel's record while rasterising: texel, triangle (index into the list), and
/// which copy of the texture (whole textures along x and y) the triangle met it in.
type Record = (u32, u32, [i32; 2]);

/// Host bytes a rasteriser record takes.
const BYTES_PER_RECORD: u64 = std::mem::size_of::<Record>() as u64;

/// A triangle in texel space, with what places its points.
#[derive(Clone, Debug)]
struct UvTriangle {
    /// Corners in texel units (x right, y down).
    uv: [DVec2; 3],
    /// Vertex indices.
    vertices: [u32; 3],
    /// Mesh (index into the targets' meshes, flattened).
    mesh: u32,
}

/// The charts of a texture bake rasterised: which texels each triangle touches, before
/// any point is placed, so that the points can be placed and traced a block of texels at
/// a time ([`TextureLayout::blocks`], [`TextureLayout::plan`]) with the working set of
/// one block. Covered texels are numbered texture after texture, in texel order.
#[derive(Clone, Debug)]
pub struct TextureLayout {
    /// Texture width.
    pub width: u32,
    /// Texture height.
    pub height: u32,
    /// The textures.
    pub targets: Vec<TextureTarget>,
    options: TextureOptions,
    /// Per texture: its triangles, its records sorted by texel, and where each covered
    /// texel's records start (one more entry than texels).
    parts: Vec<(Vec<UvTriangle>, Vec<Record>, Vec<u32>)>,
    /// For each mesh of the targets, in order, world directions into its file's space.
    to_file: Vec<Mat3>,
    /// For each mesh of the targets, in order, its vertex normals.
    normals: Vec<Vec<Option<Vec3>>>,
    /// Triangles not rasterised (see [`TexturePlan::skipped_triangles`]).
    pub skipped_triangles: usize,
    /// Triangles wrapped (see [`TexturePlan::wrapped_triangles`]).
    pub wrapped_triangles: usize,
    /// Host bytes the layout and the textures it fills take: [`BYTES_PER_TEXEL`] a texel of
    /// each texture, and the rasteriser's records.
    pub bytes: u64,
}

impl TextureLayout {
    /// Rasterises the charts of `meshes` (each with its placement) for textures as
    /// `options` say. `memory` is the bytes the bake may take; textures past it are
    /// refused before anything is rasterised, and their records past it after, with the
    /// figures.
    pub fn new(meshes: &[(&AssetMesh, Placement)], options: &TextureOptions, memory: u64) -> Result<Self> {
        options.validate()?;
        let texel_bytes = options.texels() * BYTES_PER_TEXEL;
        let targets = texture_targets(meshes.iter().map(|(m, _)| *m), options.uv_set);
        if texel_bytes * targets.len().max(1) as u64 > memory {
            let what = format!("its texels ({} textures)", targets.len().max(1));
            return Err(too_large(options, texel_bytes * targets.len().max(1) as u64, memory, &what));
        }
        let (w, h) = (options.width, options.height);
        let mut layout = TextureLayout {
            width: w,
            height: h,
            targets: targets.clone(),
            options: *options,
            parts: Vec::new(),
            to_file: Vec::new(),
            normals: Vec::new(),
            skipped_triangles: 0,
            wrapped_triangles: 0,
            bytes: 0,
        };
        for target in &targets {
            // The triangles, in texel space.
            let mut triangles = Vec::new();
            for &m in &target.meshes {
                let (mesh, placement) = &meshes[m];
                let uv = mesh.uv_set(options.uv_set).expect("targets hold meshes with the set");
                let index = layout.to_file.len() as u32;
                layout.to_file.push(mesh.to_file * Mat3::from_mat4(placement.to_world).inverse());
                layout.normals.push(vertex_normals(mesh, placement).0);
                for f in 0..mesh.face_count() {
                    let start = mesh.face_starts[f] as usize;
                    let face = mesh.face(f);
                    for k in 1..face.len().saturating_sub(1) {
                        let corners = [start, start + k, start + k + 1];
                        let t = corners.map(|c| uv.corners[c]);
                        if t.iter().any(|c| !c.is_finite()) {
                            layout.skipped_triangles += 1;
                            continue;
                        }
                        if t.iter().any(|c| outside_unit(*c)) {
                            if wrap(options, mesh) == UvWrap::Refuse {
                                let bad = t.into_iter().find(|c| outside_unit(*c)).unwrap_or_default();
                                return Err(Error::settings(format!(
                                    "{}: texture coordinates outside [0, 1] (face {f} has ({}, {})) and no texture of the file repeats along set {}: bake with --uv-wrap repeat to wrap them, or remap the UVs",
                                    mesh.label, bad.x, bad.y, options.uv_set
                                )));
                            }
                            layout.wrapped_triangles += 1;
                        }
                        let to_texels = |c: Vec2| {
                            let v = if mesh.uv_v_down { c.y } else { 1.0 - c.y };
                            DVec2::new(f64::from(c.x) * f64::from(w), f64::from(v) * f64::from(h))
                        };
                        let tri = UvTriangle {
                            uv: t.map(to_texels),
                            vertices: corners.map(|c| mesh.face_indices[c]),
                            mesh: index,
                        };
                        if cross(tri.uv[1] - tri.uv[0], tri.uv[2] - tri.uv[0]).abs() < 1e-12 {
                            layout.skipped_triangles += 1;
                            continue;
                        }
                        triangles.push(tri);
                    }
                }
            }
            // Covered texels, each with the triangles touching it.
            let mut records: Vec<Record> = Vec::new();
            for (i, t) in triangles.iter().enumerate() {
                rasterise(t, w, h, |texel, copy| records.push((texel, i as u32, copy)));
            }
            records.sort_unstable();
            records.dedup();
            records.shrink_to_fit();
            let mut groups: Vec<u32> = Vec::new();
            for (i, r) in records.iter().enumerate() {
                if i == 0 || records[i - 1].0 != r.0 {
                    groups.push(i as u32);
                }
            }
            groups.push(records.len() as u32);
            layout.bytes += texel_bytes
                + records.len() as u64 * BYTES_PER_RECORD
                + triangles.len() as u64 * std::mem::size_of::<UvTriangle>() as u64;
            if layout.bytes > memory {
                let what = format!("{} texels' records", groups.len() - 1);
                return Err(too_large(options, layout.bytes, memory, &what));
            }
            layout.parts.push((triangles, records, groups));
        }
        Ok(layout)
    }

    /// Covered texels of all textures (a texel whose points all lack a usable normal is
    /// left out when its points are placed).
    pub fn covered_texels(&self) -> usize {
        self.parts.iter().map(|(_, _, g)| g.len() - 1).sum()
    }

    /// Points placed: `points` a covered texel (and one more on each further surface a
    /// position lies inside of, where charts overlap).
    pub fn nominal_points(&self) -> u64 {
        self.covered_texels() as u64 * u64::from(self.options.points)
    }

    /// The covered texels (by their numbers) cut into consecutive blocks of at most
    /// `points` nominal points each (at least one texel a block).
    pub fn blocks(&self, points: u64) -> Vec<std::ops::Range<usize>> {
        let per_texel = u64::from(self.options.points);
        let texels = (points / per_texel).max(1) as usize;
        let n = self.covered_texels();
        (0..n.div_ceil(texels)).map(|b| b * texels..((b + 1) * texels).min(n)).collect()
    }

    /// The plan of the points of covered texels `texels` (by their numbers): placed as in
    /// a whole bake, their probes numbered from `first_point` (the points of the texels
    /// before them).
    pub fn plan(
        &self,
        meshes: &[(&AssetMesh, Placement)],
        texels: std::ops::Range<usize>,
        first_point: u32,
    ) -> TexturePlan {
        let options = &self.options;
        let (w, h) = (self.width, self.height);
        let mut plan = TexturePlan {
            width: w,
            height: h,
            targets: self.targets.clone(),
            first_point,
            to_file: self.to_file.clone(),
            skipped_triangles: self.skipped_triangles,
            wrapped_triangles: self.wrapped_triangles,
            ..TexturePlan::default()
        };
        let mut numbered = 0;
        let mut first_mesh = 0u32;
        for (target, (triangles, records, groups)) in self.targets.iter().zip(&self.parts) {
            let count = groups.len() - 1;
            let range =
                texels.start.saturating_sub(numbered).min(count)..texels.end.saturating_sub(numbered).min(count);
            numbered += count;
            let (mut covered, mut starts) = (Vec::new(), vec![plan.probes.len() as u32]);
            for g in range {
                let group = &records[groups[g] as usize..groups[g + 1] as usize];
                let texel = group[0].0;
                let (x, y) = (texel % w, texel / w);
                let mut overlapping = false;
                for k in 0..options.points {
                    let at = DVec2::new(f64::from(x), f64::from(y)) + position(options, texel, k);
                    // The position in the copy of the texture each triangle met the texel in.
                    let copy = |c: [i32; 2]| at + DVec2::new(f64::from(c[0] * w as i32), f64::from(c[1] * h as i32));
                    let inside: Vec<(u32, [f64; 3])> = group
                        .iter()
                        .filter_map(|&(_, t, c)| {
                            let b = barycentric(&triangles[t as usize], copy(c))?;
                            (b.iter().all(|&c| c > 1e-9)).then_some((t, b))
                        })
                        .collect();
                    let chosen = if inside.is_empty() {
                        let corner = |c: [i32; 2]| copy(c) - position(options, texel, k);
                        vec![nearest(group.iter().map(|&(_, t, c)| (t, copy(c), corner(c))), triangles)]
                    } else {
                        overlapping |= inside.len() > 1;
                        inside
                    };
                    for (t, b) in chosen {
                        let tri = &triangles[t as usize];
                        let m = (tri.mesh - first_mesh) as usize;
                        let (mesh, placement) = &meshes[target.meshes[m]];
                        let normal = interpolate_normal(&self.normals[tri.mesh as usize], tri.vertices, b);
                        let Some(normal) = normal else { continue };
                        plan.probes.push(triangle_probe(mesh, placement, tri.vertices, [b[1], b[2]], normal));
                        plan.probe_mesh.push(tri.mesh);
                    }
                }
                if plan.probes.len() as u32 == *starts.last().expect("starts has one entry") {
                    // No usable normal at any position: the texel stays uncovered.
                    continue;
                }
                plan.overlapping_texels += usize::from(overlapping);
                covered.push(texel);
                starts.push(plan.probes.len() as u32);
            }
            first_mesh += target.meshes.len() as u32;
            plan.texels.push(covered);
            plan.starts.push(starts);
        }
        plan.probes.shrink_to_fit();
        plan.probe_mesh.shrink_to_fit();
        plan
    }

    /// The textures before any texel is baked: every texel background.
    pub fn blank_textures(&self, bent: bool) -> Vec<BakedTexture> {
        self.targets.iter().map(|_| BakedTexture::blank(self.width, self.height, bent)).collect()
    }
}

impl TexturePlan {
    /// The plan of baking `meshes` (each with its placement) into textures as `options` say,
    /// every point at once. `memory` is the bytes the plan may take; a plan past it is
    /// refused before any point is placed, with the figures.
    pub fn new(meshes: &[(&AssetMesh, Placement)], options: &TextureOptions, bent: bool, memory: u64) -> Result<Self> {
        let layout = TextureLayout::new(meshes, options, memory)?;
        let points = layout.nominal_points();
        let needed = layout.bytes + points * bytes_per_point(bent);
        if needed > memory {
            return Err(too_large(options, needed, memory, &format!("{points} points")));
        }
        Ok(layout.plan(meshes, 0..layout.covered_texels(), 0))
    }

    /// Covered texels of all textures.
    pub fn covered_texels(&self) -> usize {
        self.texels.iter().map(Vec::len).sum()
    }

    /// The baked textures from the probes' estimates (`values[k]` of `probes[k]`) and, when
    /// given, their mean escaped directions (world space), padded by `padding` texels.
    pub fn textures(&self, values: &[ProbeValue], bent: Option<&[Vec3]>, padding: u32) -> Vec<BakedTexture> {
        let mut maps: Vec<BakedTexture> =
            self.targets.iter().map(|_| BakedTexture::blank(self.width, self.height, bent.is_some())).collect();
        self.fill(&mut maps, values, bent);
        for map in &mut maps {
            map.pad(padding);
        }
        maps
    }

    /// Writes the covered texels of this plan into `maps` (one per target) from the
    /// probes' estimates (`values[k]` of `probes[k]`) and, when given, their mean escaped
    /// directions (world space).
    pub fn fill(&self, maps: &mut [BakedTexture], values: &[ProbeValue], bent: Option<&[Vec3]>) {
        for ((texels, starts), t) in self.texels.iter().zip(&self.starts).zip(maps.iter_mut()) {
            for (i, &texel) in texels.iter().enumerate() {
                let range = starts[i] as usize..starts[i + 1] as usize;
                let n = range.len() as f64;
                let texel = texel as usize;
                t.ao[texel] = (values[range.clone()].iter().map(|v| v.mean).sum::<f64>() / n) as f32;
                t.std_error[texel] =
                    (values[range.clone()].iter().map(|v| v.std_error * v.std_error).sum::<f64>().sqrt() / n) as f32;
                t.coverage[texel] = Coverage::Covered;
                if let (Some(out), Some(bent)) = (t.bent_normals.as_mut(), bent) {
                    let sum: Vec3 = range
                        .map(|k| {
                            let b = bent[k];
                            let b = if b.length_squared() > 1e-12 { b } else { self.probes[k].normal };
                            (self.to_file[self.probe_mesh[k] as usize] * b).normalize_or_zero()
                        })
                        .sum();
                    out[texel] = sum.normalize_or_zero();
                }
            }
        }
    }
}

fn too_large(options: &TextureOptions, needed: u64, memory: u64, what: &str) -> Error {
    let gib = |b: u64| b as f64 / (1u64 << 30) as f64;
    Error::settings(format!(
        "a {}×{} texture with {} points per texel needs {:.2} GiB for {what}, more than the {:.2} GiB of memory available: choose a smaller --texture or fewer --texel-points",
        options.width,
        options.height,
        options.points,
        gib(needed),
        gib(memory)
    ))
}

/// How `mesh`'s coordinates outside [0, 1] are taken: [`UvWrap::File`] resolved.
fn wrap(options: &TextureOptions, mesh: &AssetMesh) -> UvWrap {
    match options.wrap {
        UvWrap::File if mesh.repeating_sets.contains(&options.uv_set) => UvWrap::Repeat,
        UvWrap::File => UvWrap::Refuse,
        w => w,
    }
}

/// Whether a coordinate lies outside [0, 1] by more than rounding.
fn outside_unit(c: Vec2) -> bool {
    const SLACK: f32 = 1e-5;
    c.min_element() < -SLACK || c.max_element() > 1.0 + SLACK
}

fn cross(a: DVec2, b: DVec2) -> f64 {
    a.x * b.y - a.y * b.x
}

/// Calls `covered` with every texel (`y * w + x`) whose closed square meets the triangle,
/// and the copy of the texture it met it in.
fn rasterise(t: &UvTriangle, w: u32, h: u32, mut covered: impl FnMut(u32, [i32; 2])) {
    let lo = t.uv[0].min(t.uv[1]).min(t.uv[2]);
    let hi = t.uv[0].max(t.uv[1]).max(t.uv[2]);
    let (mut x0, mut y0) = (lo.x.floor() as i64, lo.y.floor() as i64);
    let (mut x1, mut y1) = (hi.x.ceil() as i64 - 1, hi.y.ceil() as i64 - 1);
    // A corner on a texel's edge touches the texels on both sides.
    x1 = x1.max(hi.x.floor() as i64);
    y1 = y1.max(hi.y.floor() as i64);
    // Coordinates within rounding of [0, 1] stay in the texture.
    if lo.x > -0.5 && hi.x < f64::from(w) + 0.5 {
        (x0, x1) = (x0.max(0), x1.min(i64::from(w) - 1));
    }
    if lo.y > -0.5 && hi.y < f64::from(h) + 0.5 {
        (y0, y1) = (y0.max(0), y1.min(i64::from(h) - 1));
    }
    // Each edge's outward normal (away from the third corner).
    let area = cross(t.uv[1] - t.uv[0], t.uv[2] - t.uv[0]);
    let edges: [(DVec2, DVec2); 3] = std::array::from_fn(|i| {
        let (a, b) = (t.uv[i], t.uv[(i + 1) % 3]);
        let d = b - a;
        let n = if area > 0.0 { DVec2::new(d.y, -d.x) } else { DVec2::new(-d.y, d.x) };
        (a, n)
    });
    for y in y0..=y1 {
        for x in x0..=x1 {
            let min = DVec2::new(x as f64, y as f64);
            // The square is past an edge when its corner nearest the inside is.
            let separated = edges.iter().any(|&(a, n)| {
                let nearest = DVec2::new(
                    if n.x > 0.0 { min.x } else { min.x + 1.0 },
                    if n.y > 0.0 { min.y } else { min.y + 1.0 },
                );
                (nearest - a).dot(n) > 0.0
            });
            if !separated {
                let (xw, yw) = (x.rem_euclid(i64::from(w)) as u32, y.rem_euclid(i64::from(h)) as u32);
                let copy = [x.div_euclid(i64::from(w)) as i32, y.div_euclid(i64::from(h)) as i32];
                covered(yw * w + xw, copy);
            }
        }
    }
}

/// Position `k` of the texel `texel` inside its square, in [0, 1)²: the R2 sequence
/// rotated by a hash of the texel and the seed; the centre when there is one point.
fn position(options: &TextureOptions, texel: u32, k: u32) -> DVec2 {
    if options.points == 1 {
        // One point: the texel's centre, where a map is sampled.
        return DVec2::splat(0.5);
    }
    // 1/φ₂ and 1/φ₂², φ₂ the plastic number (Roberts 2018).
    const A: [f64; 2] = [0.754_877_666_246_692_8, 0.569_840_290_998_053_2];
    let h1 = hash(texel ^ hash(options.seed ^ 0x9e37_79b9));
    let h2 = hash(h1 ^ 0x85eb_ca6b);
    let shift = [f64::from(h1) / 4_294_967_296.0, f64::from(h2) / 4_294_967_296.0];
    let k = f64::from(k);
    DVec2::new((shift[0] + k * A[0]).fract(), (shift[1] + k * A[1]).fract())
}

/// A 32-bit integer hash (Wellons' "lowbias32").
fn hash(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x7feb_352d);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846c_a68b);
    x ^ (x >> 16)
}

/// The barycentric coordinates of `p` (texel space) in `t`.
fn barycentric(t: &UvTriangle, p: DVec2) -> Option<[f64; 3]> {
    let area = cross(t.uv[1] - t.uv[0], t.uv[2] - t.uv[0]);
    if area == 0.0 {
        return None;
    }
    let b1 = cross(p - t.uv[0], t.uv[2] - t.uv[0]) / area;
    let b2 = cross(t.uv[1] - t.uv[0], p - t.uv[0]) / area;
    Some([1.0 - b1 - b2, b1, b2])
}

/// The nearest point to `p` over the parts of the `candidates` (triangle, `p` in the
/// copy of the texture it met the texel in) inside the texel `square` (its corner, in
/// that copy): (triangle, barycentrics).
fn nearest(candidates: impl Iterator<Item = (u32, DVec2, DVec2)>, triangles: &[UvTriangle]) -> (u32, [f64; 3]) {
    let candidates: Vec<(u32, DVec2, DVec2)> = candidates.collect();
    let mut best = (u32::MAX, [1.0, 0.0, 0.0], f64::INFINITY);
    for &(i, p, square) in &candidates {
        let t = &triangles[i as usize];
        let part = clip(t.uv, square);
        let c = (0..part.len())
            .map(|k| closest_on_segment(part[k], part[(k + 1) % part.len()], p))
            .min_by(|a, b| (*a - p).length_squared().total_cmp(&(*b - p).length_squared()));
        let Some(c) = c else { continue };
        let d = (c - p).length_squared();
        if d < best.2
            && let Some(b) = barycentric(t, c)
        {
            best = (i, b.map(|x| x.clamp(0.0, 1.0)), d);
        }
    }
    if best.0 == u32::MAX {
        // A triangle that only touches the texel along its border can clip to nothing
        // by rounding: its nearest point then.
        for &(i, p, _) in &candidates {
            let t = &triangles[i as usize];
            let c = (0..3)
                .map(|k| closest_on_segment(t.uv[k], t.uv[(k + 1) % 3], p))
                .min_by(|a, b| (*a - p).length_squared().total_cmp(&(*b - p).length_squared()))
                .expect("three edges");
            let d = (c - p).length_squared();
            if d < best.2
                && let Some(b) = barycentric(t, c)
            {
                best = (i, b.map(|x| x.clamp(0.0, 1.0)), d);
            }
        }
    }
    let s: f64 = best.1.iter().sum();
    (best.0, best.1.map(|x| x / s))
}

/// The triangle `t` clipped to the closed unit square at `corner` (Sutherland–Hodgman):
/// a convex polygon, empty when they do not meet.
fn clip(t: [DVec2; 3], corner: DVec2) -> Vec<DVec2> {
    let mut poly: Vec<DVec2> = t.to_vec();
    let planes = [(0, corner.x, 1.0), (0, corner.x + 1.0, -1.0), (1, corner.y, 1.0), (1, corner.y + 1.0, -1.0)];
    for (axis, at, sign) in planes {
        let inside = |p: DVec2| sign * (p[axis] - at) >= 0.0;
        let mut out = Vec::with_capacity(poly.len() + 1);
        for i in 0..poly.len() {
            let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
            if inside(a) {
                out.push(a);
            }
            if inside(a) != inside(b) {
                let s = (at - a[axis]) / (b[axis] - a[axis]);
                out.push(a + s * (b - a));
            }
        }
        poly = out;
        if poly.is_empty() {
            break;
        }
    }
    poly
}

/// The point of the segment `ab` nearest to `p`.
fn closest_on_segment(a: DVec2, b: DVec2, p: DVec2) -> DVec2 {
    let d = b - a;
    let len = d.length_squared();
    if len == 0.0 {
        return a;
    }
    a + d * ((p - a).dot(d) / len).clamp(0.0, 1.0)
}

/// The vertex normals interpolated at barycentrics `b`; `None` when unusable.
fn interpolate_normal(normals: &[Option<Vec3>], vertices: [u32; 3], b: [f64; 3]) -> Option<Vec3> {
    let mut n = glam::DVec3::ZERO;
    for (v, w) in vertices.iter().zip(b) {
        if let Some(normal) = normals[*v as usize] {
            n += w * normal.as_dvec3().normalize();
        }
    }
    let n = n.as_vec3();
    (n.is_finite() && n.length_squared() > 1e-12).then_some(n)
}

/// What a texel of a baked texture holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Coverage {
    /// Baked: a chart covers it.
    Covered,
    /// Filled by dilation.
    Padded,
    /// Neither: the mean of the covered texels.
    Background,
}

/// One baked texture: row-major, row 0 the image's top.
#[derive(Clone, Debug, PartialEq)]
pub struct BakedTexture {
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
    /// AO per texel, 1 fully open.
    pub ao: Vec<f32>,
    /// Standard error per texel (0 outside the charts).
    pub std_error: Vec<f32>,
    /// What each texel holds.
    pub coverage: Vec<Coverage>,
    /// Unit bent normals in the file's space, when asked for.
    pub bent_normals: Option<Vec<Vec3>>,
}

impl BakedTexture {
    /// A texture of `width` × `height` background texels (with room for bent normals when
    /// `bent`).
    pub fn blank(width: u32, height: u32, bent: bool) -> BakedTexture {
        let n = width as usize * height as usize;
        BakedTexture {
            width,
            height,
            ao: vec![0.0; n],
            std_error: vec![0.0; n],
            coverage: vec![Coverage::Background; n],
            bent_normals: bent.then(|| vec![Vec3::ZERO; n]),
        }
    }

    /// Fills `rounds` rings of texels around the charts with the mean of their filled
    /// 8-neighbours, then the rest with the covered texels' mean.
    pub fn pad(&mut self, rounds: u32) {
        let (w, h) = (self.width as i64, self.height as i64);
        for _ in 0..rounds {
            let mut fills = Vec::new();
            for y in 0..h {
                for x in 0..w {
                    let i = (y * w + x) as usize;
                    if self.coverage[i] != Coverage::Background {
                        continue;
                    }
                    let (mut sum, mut bent, mut n) = (0.0f64, Vec3::ZERO, 0);
                    for (dx, dy) in [(-1, -1), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)] {
                        let (nx, ny) = (x + dx, y + dy);
                        if nx < 0 || ny < 0 || nx >= w || ny >= h {
                            continue;
                        }
                        let j = (ny * w + nx) as usize;
                        if self.coverage[j] != Coverage::Background {
                            sum += f64::from(self.ao[j]);
                            bent += self.bent_normals.as_ref().map_or(Vec3::ZERO, |b| b[j]);
                            n += 1;
                        }
                    }
                    if n > 0 {
                        fills.push((i, (sum / f64::from(n)) as f32, bent.normalize_or_zero()));
                    }
                }
            }
            if fills.is_empty() {
                break;
            }
            for (i, ao, bent) in fills {
                self.ao[i] = ao;
                self.coverage[i] = Coverage::Padded;
                if let Some(b) = self.bent_normals.as_mut() {
                    b[i] = bent;
                }
            }
        }
        let covered: Vec<f32> =
            self.ao.iter().zip(&self.coverage).filter(|(_, c)| **c == Coverage::Covered).map(|(a, _)| *a).collect();
        let mean = if covered.is_empty() { 1.0 } else { covered.iter().sum::<f32>() / covered.len() as f32 };
        for (a, c) in self.ao.iter_mut().zip(&self.coverage) {
            if *c == Coverage::Background {
                *a = mean;
            }
        }
    }

    /// The PNG of the AO: greyscale, linear, 8 or 16 bits.
    pub fn ao_png(&self, bits: u8) -> Result<Vec<u8>> {
        let image = match bits {
            8 => image::DynamicImage::ImageLuma8(
                image::GrayImage::from_raw(self.width, self.height, self.ao.iter().map(|&a| unorm8(a)).collect())
                    .expect("one value per texel"),
            ),
            _ => image::DynamicImage::ImageLuma16(
                image::ImageBuffer::from_raw(self.width, self.height, self.ao.iter().map(|&a| unorm16(a)).collect())
                    .expect("one value per texel"),
            ),
        };
        encode(image, image::ImageFormat::Png)
    }

    /// The PNG of the bent normals, `n / 2 + 1/2` in RGB (as a tangent-space normal map
    /// is encoded, but in the file's object space), 8 or 16 bits; `None` without them.
    pub fn bent_png(&self, bits: u8) -> Option<Result<Vec<u8>>> {
        let b = self.bent_normals.as_ref()?;
        let channels = b.iter().flat_map(|n| (n.to_array()).map(|c| c * 0.5 + 0.5));
        let image = match bits {
            8 => image::DynamicImage::ImageRgb8(
                image::RgbImage::from_raw(self.width, self.height, channels.map(unorm8).collect())
                    .expect("three values per texel"),
            ),
            _ => image::DynamicImage::ImageRgb16(
                image::ImageBuffer::from_raw(self.width, self.height, channels.map(unorm16).collect())
                    .expect("three values per texel"),
            ),
        };
        Some(encode(image, image::ImageFormat::Png))
    }

    /// The OpenEXR float map, three channels: R the AO, G its standard error, B 1 on the
    /// charts and 0 elsewhere.
    pub fn ao_exr(&self) -> Result<Vec<u8>> {
        let pixels = self
            .ao
            .iter()
            .zip(&self.std_error)
            .zip(&self.coverage)
            .flat_map(|((&a, &e), &c)| [a, e, if c == Coverage::Covered { 1.0 } else { 0.0 }])
            .collect();
        let image = image::Rgb32FImage::from_raw(self.width, self.height, pixels).expect("three values per texel");
        encode(image::DynamicImage::ImageRgb32F(image), image::ImageFormat::OpenExr)
    }

    /// Statistics of the covered texels' values and standard errors.
    pub fn stats(&self) -> TextureStats {
        let (mut n, mut sum, mut sq, mut max) = (0usize, 0.0f64, 0.0f64, 0.0f32);
        for i in 0..self.ao.len() {
            if self.coverage[i] == Coverage::Covered {
                n += 1;
                sum += f64::from(self.ao[i]);
                sq += f64::from(self.std_error[i]).powi(2);
                max = max.max(self.std_error[i]);
            }
        }
        let padded = self.coverage.iter().filter(|c| **c == Coverage::Padded).count();
        TextureStats {
            covered_texels: n,
            padded_texels: padded,
            mean_ao: if n > 0 { sum / n as f64 } else { 1.0 },
            rms_std_error: if n > 0 { (sq / n as f64).sqrt() } else { 0.0 },
            max_std_error: f64::from(max),
        }
    }
}

/// Statistics of a baked texture.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct TextureStats {
    /// Texels on the charts.
    pub covered_texels: usize,
    /// Texels filled by dilation.
    pub padded_texels: usize,
    /// Mean AO of the covered texels.
    pub mean_ao: f64,
    /// Root mean square of the covered texels' standard errors: the map's noise.
    pub rms_std_error: f64,
    /// Largest standard error of a covered texel.
    pub max_std_error: f64,
}

fn unorm8(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

fn unorm16(v: f32) -> u16 {
    (v.clamp(0.0, 1.0) * 65535.0).round() as u16
}

fn encode(image: image::DynamicImage, format: image::ImageFormat) -> Result<Vec<u8>> {
    let mut buf = std::io::Cursor::new(Vec::new());
    image.write_to(&mut buf, format).map_err(|e| Error::settings(format!("cannot encode the texture: {e}")))?;
    Ok(buf.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Mat4;

    fn options(size: u32, points: u32, padding: u32) -> TextureOptions {
        TextureOptions { width: size, height: size, uv_set: 0, points, padding, wrap: UvWrap::File, seed: 0 }
    }

    /// A mesh of triangles in the plane z = 0 whose positions are their UVs (v up).
    fn flat(triangles: &[[[f32; 2]; 3]]) -> AssetMesh {
        let corners: Vec<Vec2> = triangles.iter().flatten().map(|&c| Vec2::from(c)).collect();
        AssetMesh {
            label: "flat".into(),
            positions: corners.iter().map(|c| c.extend(0.0)).collect(),
            normals: Some(vec![Vec3::Z; corners.len()]),
            face_starts: (0..=triangles.len() as u32).map(|k| 3 * k).collect(),
            face_indices: (0..corners.len() as u32).collect(),
            uv_sets: vec![super::super::asset::UvSet { set: 0, corners }],
            ..AssetMesh::default()
        }
    }

    fn placed(mesh: &AssetMesh) -> Vec<(&AssetMesh, Placement)> {
        vec![(mesh, Placement { to_world: Mat4::IDENTITY, instanced: false })]
    }

    fn plan(mesh: &AssetMesh, o: &TextureOptions) -> Result<TexturePlan> {
        TexturePlan::new(&placed(mesh), o, false, u64::MAX)
    }

    #[test]
    fn coverage_is_every_texel_a_triangle_touches_and_no_other() {
        let tri = [[0.11f32, 0.07], [0.83, 0.31], [0.29, 0.92]];
        let mesh = flat(&[tri]);
        let o = options(16, 1, 0);
        let p = plan(&mesh, &o).unwrap();
        let covered: std::collections::BTreeSet<u32> = p.texels[0].iter().copied().collect();
        let t = tri.map(|c| DVec2::new(c[0] as f64 * 16.0, (1.0 - c[1] as f64) * 16.0));
        for y in 0..16 {
            for x in 0..16 {
                // Independently of the separating axes: the triangle clipped to the square.
                let meets = !clip(t, DVec2::new(x as f64, y as f64)).is_empty();
                assert_eq!(covered.contains(&(y * 16 + x)), meets, "texel ({x}, {y})");
            }
        }
    }

    #[test]
    fn points_lie_on_the_triangle_under_their_texel() {
        let tri = [[0.0f32, 0.0], [1.0, 0.0], [0.0, 1.0]];
        let o = options(8, 4, 0);
        let p = plan(&flat(&[tri]), &o).unwrap();
        for (i, &texel) in p.texels[0].iter().enumerate() {
            let (x, y) = ((texel % 8) as f32, (texel / 8) as f32);
            for k in p.starts[0][i]..p.starts[0][i + 1] {
                let probe = p.probes[k as usize];
                let q = probe.position;
                // Positions are the UVs with v up: texel rows run down.
                let (u, v) = (q.x * 8.0, (1.0 - q.y) * 8.0);
                assert!(q.z.abs() <= probe.error, "off the plane by {} > {}", q.z, probe.error);
                assert!(q.x >= -1e-6 && q.y >= -1e-6 && q.x + q.y <= 1.0 + 1e-6, "outside the triangle: {q}");
                assert!(
                    u >= x - 1e-4 && u <= x + 1.0 + 1e-4 && v >= y - 1e-4 && v <= y + 1.0 + 1e-4,
                    "{q} not under ({x}, {y})"
                );
                assert_eq!(probe.normal, Vec3::Z);
            }
            assert_eq!(p.starts[0][i + 1] - p.starts[0][i], 4);
        }
        assert_eq!(p.overlapping_texels, 0);
    }

    #[test]
    fn positions_differ_between_texels_and_seeds() {
        assert_eq!(position(&options(8, 1, 0), 10, 0), DVec2::splat(0.5));
        let o = options(8, 4, 0);
        let a: Vec<DVec2> = (0..4).map(|k| position(&o, 10, k)).collect();
        let b: Vec<DVec2> = (0..4).map(|k| position(&o, 11, k)).collect();
        let c: Vec<DVec2> = (0..4).map(|k| position(&TextureOptions { seed: 1, ..o }, 10, k)).collect();
        assert_ne!(a, b);
        assert_ne!(a, c);
        assert!(a.iter().all(|p| p.x >= 0.0 && p.x < 1.0 && p.y >= 0.0 && p.y < 1.0));
    }

    #[test]
    fn mirrored_charts_are_counted_and_both_surfaces_baked() {
        // Two triangles, one the mirror image of the other in space, on the same UVs.
        let tri = [[0.1f32, 0.1], [0.9, 0.1], [0.1, 0.9]];
        let mut mesh = flat(&[tri, tri]);
        for p in &mut mesh.positions[3..] {
            p.x = -p.x;
        }
        mesh.normals = Some(vec![Vec3::Z; 6]);
        let p = plan(&mesh, &options(8, 2, 0)).unwrap();
        assert!(p.overlapping_texels > 0);
        let both = (0..p.texels[0].len()).filter(|&i| p.starts[0][i + 1] - p.starts[0][i] > 2).count();
        assert_eq!(both, p.overlapping_texels);
        // Every texel strictly inside the chart holds a point on each surface.
        assert!(p.probes.iter().any(|q| q.position.x < -0.2) && p.probes.iter().any(|q| q.position.x > 0.2));
    }

    #[test]
    fn coordinates_outside_the_unit_square_are_refused_or_wrapped() {
        let tri = [[0.5f32, 0.5], [1.5, 0.5], [0.5, 1.25]];
        let e = plan(&flat(&[tri]), &options(8, 1, 0)).unwrap_err().to_string();
        assert!(e.contains("outside [0, 1]") && e.contains("--uv-wrap repeat") && !e.contains('\n'), "{e}");
        let o = TextureOptions { wrap: UvWrap::Refuse, ..options(8, 1, 0) };
        let repeating = AssetMesh { repeating_sets: vec![0], ..flat(&[tri]) };
        assert!(plan(&repeating, &o).is_err(), "refused whatever the file says");
        // The file's own wrap: its textures repeat along set 0.
        assert_eq!(plan(&repeating, &options(8, 1, 0)).unwrap().wrapped_triangles, 1);
        let o = TextureOptions { wrap: UvWrap::Repeat, ..options(8, 1, 0) };
        let p = plan(&flat(&[tri]), &o).unwrap();
        assert_eq!(p.wrapped_triangles, 1);
        assert!(p.texels[0].iter().all(|&t| t < 64));
        // Texels of x 0..3 hold the part past u = 1.
        assert!(p.texels[0].iter().any(|&t| t % 8 < 3));
    }

    /// A wrapped triangle whose edge lies on a texel's border (u = 1.5 at 16 texels) still
    /// gives that texel a point on the triangle (it once had none, and the plan failed).
    #[test]
    fn a_triangle_along_a_texels_border_gives_it_a_point() {
        let mesh = flat(&[[[0.0, 0.0], [1.5, 1.0], [1.5, 0.0]]]);
        let o = TextureOptions { wrap: UvWrap::Repeat, ..options(16, 4, 0) };
        let p = plan(&mesh, &o).unwrap();
        assert_eq!(p.starts[0].len(), p.texels[0].len() + 1);
        for q in &p.probes {
            assert!(q.position.x >= -1e-6 && q.position.x <= 1.5 + 1e-6 && q.position.y <= q.position.x / 1.5 + 1e-6);
        }
    }

    #[test]
    fn sizes_and_memory_are_checked_before_any_work() {
        let mesh = flat(&[[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]]);
        for size in [0, MAX_TEXTURE_SIZE + 1] {
            assert!(
                plan(&mesh, &options(size, 1, 0))
                    .unwrap_err()
                    .to_string()
                    .contains(&format!("1 to {MAX_TEXTURE_SIZE} texels"))
            );
        }
        let e = TexturePlan::new(&placed(&mesh), &options(1024, 4, 0), false, 1 << 20).unwrap_err().to_string();
        assert!(e.contains("1024×1024") && e.contains("GiB") && !e.contains('\n'), "{e}");
        // The texels fit, their points do not.
        let e = TexturePlan::new(&placed(&mesh), &options(256, 16, 0), false, 8 << 20).unwrap_err().to_string();
        assert!(e.contains("points"), "{e}");
    }

    /// Padding fills every texel within `padding` (Chebyshev) of a chart, and leaves the
    /// covered texels as they were.
    #[test]
    fn padding_fills_the_ring_and_keeps_the_charts() {
        let tri = [[0.3f32, 0.3], [0.6, 0.35], [0.4, 0.62]];
        let o = options(32, 1, 0);
        let p = plan(&flat(&[tri]), &o).unwrap();
        let values: Vec<ProbeValue> = (0..p.probes.len())
            .map(|k| ProbeValue { mean: 0.2 + 0.6 * ((k * 37) % 11) as f64 / 10.0, std_error: 0.01, samples: 1 })
            .collect();
        let bare = &p.textures(&values, None, 0)[0];
        for padding in [1, 3, 6] {
            let t = &p.textures(&values, None, padding)[0];
            for y in 0..32i32 {
                for x in 0..32i32 {
                    let i = (y * 32 + x) as usize;
                    if bare.coverage[i] == Coverage::Covered {
                        assert_eq!(t.coverage[i], Coverage::Covered);
                        assert_eq!(t.ao[i], bare.ao[i], "padding {padding} changed covered texel ({x}, {y})");
                        continue;
                    }
                    let near = (-(padding as i32)..=padding as i32).any(|dy| {
                        (-(padding as i32)..=padding as i32).any(|dx| {
                            let (nx, ny) = (x + dx, y + dy);
                            (0..32).contains(&nx)
                                && (0..32).contains(&ny)
                                && bare.coverage[(ny * 32 + nx) as usize] == Coverage::Covered
                        })
                    });
                    assert_eq!(t.coverage[i] == Coverage::Padded, near, "padding {padding}: texel ({x}, {y})");
                    assert!(t.ao[i] >= 0.2 && t.ao[i] <= 0.8);
                }
            }
        }
    }

    #[test]
    fn maps_encode_at_the_requested_size_and_depth() {
        let o = options(16, 1, 2);
        let p = plan(&flat(&[[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]]), &o).unwrap();
        let values = vec![ProbeValue { mean: 0.5, std_error: 0.0, samples: 1 }; p.probes.len()];
        let bent = vec![Vec3::Z; p.probes.len()];
        let t = &p.textures(&values, Some(&bent), 2)[0];
        for (bits, color) in [(8, image::ColorType::L8), (16, image::ColorType::L16)] {
            let img = image::load_from_memory(&t.ao_png(bits).unwrap()).unwrap();
            assert_eq!((img.width(), img.height(), img.color()), (16, 16, color));
        }
        let bent = image::load_from_memory(&t.bent_png(8).unwrap().unwrap()).unwrap().to_rgb8();
        assert_eq!(bent.get_pixel(0, 15).0, [128, 128, 255]);
        let exr = image::load_from_memory(&t.ao_exr().unwrap()).unwrap();
        assert_eq!(exr.color(), image::ColorType::Rgb32F, "no alpha channel");
        let exr = exr.to_rgba32f();
        assert_eq!(exr.get_pixel(0, 15).0, [0.5, 0.0, 1.0, 1.0]);
    }
}
