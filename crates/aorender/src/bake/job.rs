//! A whole bake as one request: the meshes read and their points planned ([`Bake::new`],
//! before any device is opened), traced on a session ([`Session::bake`]) or added up from
//! shards ([`Bake::merge`]), turned into values or textures ([`Bake::finish`]) and
//! written back ([`Bake::write`]). The command line and the Python module map their
//! options onto a [`BakeRequest`] and do nothing else of the bake.

use super::asset::{
    Asset, AssetMesh, BakeAt, BakedValues, GeneratedUvs, TextureFiles, TextureMap, WriteOptions, format_of, map_path,
};
use super::files::{
    ReadInputs, check_mesh_output, is_conversion, output_path, plan_companions, plan_output, read_object,
};
use super::plan::{BakePlan, Placement};
use super::texture::{
    BakedTexture, Coverage, TextureLayout, TextureOptions, TexturePlan, TextureStats, TextureTarget, UvWrap,
    bytes_per_point,
};
use super::unwrap::generate_uvs;
use crate::accumulation::{Accumulation, merge};
use crate::device::{BvhOptions, DeviceKind};
use crate::error::{Error, Result};
use crate::film::Film;
use crate::output::{FilePlan, write_output};
use crate::probe::{Probe, probe_film_bent_normals, probe_film_values};
use crate::render::{Control, Progress, RenderStats};
use crate::scene::{MeshObject, ReadLimits, Scene, Settings};
use crate::session::Session;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

/// Everything a bake is asked for.
#[derive(Clone, Debug)]
pub struct BakeRequest {
    /// Vertices or faces (ignored by a texture bake).
    pub at: BakeAt,
    /// Samples (AO rays) per vertex, face or texel point.
    pub samples: u32,
    /// The sample indices to trace (a shard of a bake to merge later); `None`: all.
    pub sample_range: Option<Range<u32>>,
    /// Bent normals too, from the same rays.
    pub bent_normals: bool,
    /// Each value's standard error in the written file.
    pub std_error: bool,
    /// AO as a grey vertex colour in PLY output.
    pub colors: bool,
    /// Where the bake is written: a mesh file for a mesh input (or a `.png`/`.exr` map for a
    /// texture bake), a directory for a scene file; `None`: values only, nothing written.
    pub output: Option<PathBuf>,
    /// How messages name the output (`-o` on the command line).
    pub output_name: String,
    /// The output may replace the input.
    pub overwrite: bool,
    /// A bake into a texture instead of into vertices.
    pub texture: Option<TextureRequest>,
    /// Every point traced in one film: a time limit, checkpoints, resuming or a merge need
    /// it; otherwise a texture bake too large for one block is traced a block at a time.
    pub one_film: bool,
    /// The read budget for the mesh files.
    pub limits: ReadLimits,
    /// The hemisphere, sampler, seed and maximum distance; `None`: the scene's.
    pub settings: Option<Settings>,
}

impl BakeRequest {
    /// A bake of `samples` samples at every vertex, values only.
    pub fn new(samples: u32) -> BakeRequest {
        BakeRequest {
            at: BakeAt::Vertices,
            samples,
            sample_range: None,
            bent_normals: false,
            std_error: false,
            colors: false,
            output: None,
            output_name: "output".to_string(),
            overwrite: false,
            texture: None,
            one_film: false,
            limits: ReadLimits::available(),
            settings: None,
        }
    }

    /// The sample indices traced.
    pub fn range(&self) -> Range<u32> {
        self.sample_range.clone().unwrap_or(0..self.samples)
    }
}

/// When a texture bake generates texture coordinates.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum GenerateUvs {
    /// When no mesh has any.
    #[default]
    Auto,
    /// Always, as a new set.
    Always,
    /// Never.
    Never,
}

/// A texture bake's options.
#[derive(Clone, Debug)]
pub struct TextureRequest {
    /// Size, set, points per texel, padding, wrapping (the seed is the scene's).
    pub options: TextureOptions,
    /// When to generate texture coordinates.
    pub generate_uvs: GenerateUvs,
    /// Bits per channel of the PNG maps: 8 or 16.
    pub bit_depth: u8,
    /// Host memory the bake may take, in bytes.
    pub memory_bytes: u64,
}

/// One baked file: the mesh object it comes from, its asset, and where it goes.
#[derive(Clone)]
pub struct BakeTarget {
    /// The scene's object.
    pub object: MeshObject,
    /// Its file, read for baking.
    pub asset: Arc<dyn Asset>,
    /// Where the bake of it is written.
    pub output: PathBuf,
}

/// What unwrapping made, for the statistics.
#[derive(Clone, Debug, serde::Serialize)]
pub struct GeneratedReport {
    /// The set written (glTF TEXCOORD_n; 0 for OBJ and PLY).
    pub set: u32,
    /// Charts in all atlases.
    pub charts: u32,
    /// Atlases made.
    pub atlases: usize,
    /// Fraction of the texture the charts' surface covers.
    pub utilization: f32,
    /// Seconds the unwrap took.
    pub seconds: f64,
}

/// A texture bake's plan.
struct TextureJob {
    options: TextureOptions,
    bit_depth: u8,
    /// The meshes with their generated coordinates, when made.
    generated: Option<(GeneratedUvs, GeneratedReport)>,
    /// The whole plan, or the layout and its blocks for a bake traced a block at a time.
    plan: Option<TexturePlan>,
    blocked: Option<(TextureLayout, Vec<Range<usize>>)>,
    targets: Vec<TextureTarget>,
    /// The meshes, with generated coordinates added (what the blocks are planned from).
    meshes: Vec<AssetMesh>,
}

/// A bake planned: its files read, its points placed, its outputs checked. Nothing is
/// traced yet.
pub struct Bake {
    request: BakeRequest,
    /// The input, for messages.
    input: PathBuf,
    targets: Vec<BakeTarget>,
    plan: BakePlan,
    texture: Option<TextureJob>,
    settings: Settings,
}

/// What tracing (or merging) a bake gave.
pub struct BakeTrace {
    sums: Sums,
    /// Samples per point held.
    pub samples: u32,
    /// Samples that came from the checkpoint resumed.
    pub samples_resumed: u32,
    /// Whether a stop ended it before its samples were done.
    pub interrupted: bool,
    /// For a bake traced in blocks and stopped: the block (from 0) it was stopped in;
    /// nothing of it is kept.
    pub interrupted_block: Option<usize>,
    /// AO rays traced.
    pub rays: u64,
    /// Seconds tracing.
    pub seconds: f64,
    /// Each render's figures (one per block).
    pub renders: Vec<RenderStats>,
    /// The adapter (the shards' adapters for a merge).
    pub adapter: String,
    /// Seconds of host work on the sums (making the film, filling the textures).
    pub host_seconds: f64,
}

enum Sums {
    Film(Film),
    Textures { maps: Vec<BakedTexture>, overlapping: usize, traced: usize },
}

/// A bake's results, ready to write.
pub struct Baked {
    /// Per mesh (each target's meshes in order), its values; empty for a texture bake.
    pub values: Vec<BakedValues>,
    /// The textures (padded), for a texture bake.
    pub maps: Vec<BakedTexture>,
    /// Mean AO over the points (over the covered texels for a texture bake).
    pub mean_ao: f64,
    /// Points baked (texels covered, for a texture bake).
    pub points: usize,
    /// Texels covered by overlapping charts.
    pub overlapping_texels: usize,
}

/// What a texture bake reports.
#[derive(Clone, Debug, serde::Serialize)]
pub struct TextureReport {
    /// Texels across.
    pub width: u32,
    /// Texels down.
    pub height: u32,
    /// The coordinate set baked into.
    pub uv_set: u32,
    /// Textures made.
    pub textures: usize,
    /// Points per texel.
    pub points_per_texel: u32,
    /// Samples per texel.
    pub samples_per_texel: u64,
    /// Padding in texels.
    pub padding: u32,
    /// Bits per channel of the PNG maps.
    pub bit_depth: u8,
    /// Texels covered by overlapping charts.
    pub overlapping_texels: usize,
    /// Triangles not baked (no coordinates at a corner, or of zero area in UV space).
    pub skipped_triangles: usize,
    /// Triangles whose coordinates were wrapped into [0, 1].
    pub wrapped_triangles: usize,
    /// What unwrapping made.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub generated_uvs: Option<GeneratedReport>,
    /// Per texture: covered and padded texels, mean AO, the standard errors' RMS and maximum.
    pub maps: Vec<TextureStats>,
}

/// What [`Bake::write`] wrote.
pub struct Written {
    /// The files, the output first.
    pub files: Vec<PathBuf>,
    /// Notes for the user, each with its file.
    pub notes: Vec<(PathBuf, String)>,
    /// For a texture bake, its figures.
    pub texture: Option<TextureReport>,
}

/// Whether `path` names a texture map file (`.png` or `.exr`) rather than a mesh.
pub fn is_map(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")) || is_exr(path)
}

fn is_exr(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("exr"))
}

/// `path` with its extension replaced by `suffix` (`map.png` → `map_bent_normals.png`):
/// where a map's bent normals go.
pub fn sibling(path: &Path, suffix: &str) -> PathBuf {
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!("{stem}{suffix}"))
}

/// The most bytes of points a texture bake traces at once, when nothing needs all its
/// points in one film: a larger bake is traced a block of texels at a time, so that its
/// memory is its textures' and one block's whatever its size.
const BLOCK_BYTES: u64 = 1 << 30;

impl Bake {
    /// Plans the bake of `scene`'s mesh objects (read from `input`, a mesh file or a scene
    /// file), entering every file it writes in `files` (which already holds the inputs).
    pub fn new(scene: &Scene, input: &Path, request: &BakeRequest, files: &mut FilePlan) -> Result<Bake> {
        Bake::with_inputs(scene, &ReadInputs::default(), input, request, files)
    }

    /// [`Bake::new`] for a scene loaded by [`super::files::load_for_bake`], whose mesh
    /// files it read as `read` holds them: each file is parsed once, for the scene and
    /// the bake (a file `read` lacks is read again).
    pub fn with_inputs(
        scene: &Scene,
        read: &ReadInputs,
        input: &Path,
        request: &BakeRequest,
        files: &mut FilePlan,
    ) -> Result<Bake> {
        let is_scene = input.extension().is_some_and(|e| e.eq_ignore_ascii_case("toml"));
        if scene.mesh_objects.is_empty() {
            return Err(Error::scene(input, "the scene has no mesh objects to bake"));
        }
        let mut request = request.clone();
        let settings = request.settings.clone().unwrap_or_else(|| scene.settings.clone());
        if let Some(t) = request.texture.as_mut() {
            t.options.seed = settings.sampling.seed;
        }
        let output = request.output.clone();
        if request.texture.is_some() && output.is_none() {
            return Err(Error::settings("a texture bake writes its maps: give it an output"));
        }
        let targets = match (&request.texture, &output) {
            (_, None) => read_targets(None, &scene.mesh_objects, is_scene, &request, read)?,
            (None, Some(output)) => read_targets(Some((files, output)), &scene.mesh_objects, is_scene, &request, read)?,
            (Some(_), Some(output)) => {
                if scene.mesh_objects.len() > 1 {
                    return Err(Error::scene(
                        input,
                        format!(
                            "the scene has {} mesh objects: a texture bake takes a scene with one (the others may be spheres, planes…)",
                            scene.mesh_objects.len()
                        ),
                    ));
                }
                let object = scene.mesh_objects[0].clone();
                let asset = match read.get(&object) {
                    Some(asset) => asset,
                    None => Arc::from(read_object(&object, &request.limits)?),
                };
                vec![BakeTarget { object, asset, output: output.clone() }]
            }
        };
        let at = request.at;
        if at == BakeAt::Faces
            && let Some(t) = targets.iter().find(|t| format_of(&t.output).is_some_and(|f| f != "PLY"))
            && output.is_some()
        {
            return Err(Error::output(
                &t.output,
                format!(
                    "{} has no per-face attributes: bake --at faces into a PLY file (-o NAME.ply)",
                    format_of(&t.output).unwrap_or_default()
                ),
            ));
        }
        let mut bake =
            Bake { request, input: input.to_path_buf(), targets, plan: BakePlan::default(), texture: None, settings };
        match bake.request.texture.clone() {
            None => {
                let meshes =
                    bake.targets.iter().flat_map(|t| t.asset.meshes().iter().map(|m| (m, Placement::of(&t.object))));
                bake.plan = BakePlan::new(meshes, at);
                if bake.plan.probes.is_empty() {
                    return Err(Error::scene(
                        input,
                        format!("no {} has a usable normal: nothing to bake", singular(at)),
                    ));
                }
            }
            Some(texture) => bake.plan_texture(texture, files, is_scene)?,
        }
        Ok(bake)
    }

    /// Plans the bake of one mesh given as arrays (no file to write back to), placed as it
    /// is in `scene`.
    pub fn of_mesh(scene: &Scene, mesh: &AssetMesh, request: &BakeRequest) -> Result<Bake> {
        if request.output.is_some() || request.texture.is_some() {
            return Err(Error::scene(
                &scene.name,
                "a scene made from arrays has no file to write back to: bake its vertices or faces and use the values",
            ));
        }
        let plan = BakePlan::new([(mesh, Placement { to_world: glam::Mat4::IDENTITY, instanced: false })], request.at);
        if plan.probes.is_empty() {
            return Err(Error::scene(&scene.name, "nothing has a usable normal to bake"));
        }
        Ok(Bake {
            request: request.clone(),
            input: PathBuf::from(&scene.name),
            targets: Vec::new(),
            plan,
            texture: None,
            settings: request.settings.clone().unwrap_or_else(|| scene.settings.clone()),
        })
    }

    fn plan_texture(&mut self, texture: TextureRequest, files: &mut FilePlan, is_scene: bool) -> Result<()> {
        let input = self.input.clone();
        let output = self.request.output.clone().unwrap_or_default();
        let mut options = texture.options;
        let generated = self.generated_uvs(&texture, &output, &mut options)?;
        let target = &self.targets[0];
        let mut meshes = target.asset.meshes().to_vec();
        if let Some((g, _)) = &generated {
            for (m, uvs) in meshes.iter_mut().zip(&g.meshes) {
                m.uv_sets.push(uvs.uv_set());
            }
        }
        let placement = Placement::of(&target.object);
        let placed: Vec<(&AssetMesh, Placement)> = meshes.iter().map(|m| (m, placement)).collect();
        let in_input = |e: Error| Error::scene(&input, e.to_string().trim_start_matches("invalid settings: "));
        let layout = TextureLayout::new(&placed, &options, texture.memory_bytes).map_err(in_input)?;
        if layout.targets.len() > 1 && is_map(&output) {
            return Err(Error::scene(
                &input,
                format!(
                    "its meshes use {} materials, each baked into its own texture: bake into a .glb or .gltf file",
                    layout.targets.len()
                ),
            ));
        }
        let blocks = self.texture_blocks(&layout, &options, texture.memory_bytes)?;
        let (plan, blocked) = if blocks.len() <= 1 {
            (Some(layout.plan(&placed, 0..layout.covered_texels(), 0)), None)
        } else {
            (None, Some((layout, blocks)))
        };
        drop(placed);
        if plan.as_ref().is_some_and(|p| p.probes.is_empty()) {
            return Err(Error::scene(&input, "no triangle covers a texel with a usable normal: nothing to bake"));
        }
        let targets = match (&plan, &blocked) {
            (Some(tp), _) => tp.targets.clone(),
            (None, Some((layout, _))) => layout.targets.clone(),
            _ => Vec::new(),
        };
        if !is_map(&output) {
            let written = TextureFiles {
                maps: targets.len(),
                bent_normals: self.request.bent_normals,
                generated_uvs: generated.is_some(),
            };
            let t = &self.targets[0];
            let name = self.request.output_name.clone();
            plan_companions(files, &t.object, &*t.asset, (&t.output, &name), is_scene, Some(&written))?;
        }
        self.texture =
            Some(TextureJob { options, bit_depth: texture.bit_depth, generated, plan, blocked, targets, meshes });
        Ok(())
    }

    /// Unwraps the asset's meshes when the request asks for it (auto: when no mesh has any
    /// texture coordinates) and points `options` at the new set; checked before any ray.
    fn generated_uvs(
        &self,
        texture: &TextureRequest,
        output: &Path,
        options: &mut TextureOptions,
    ) -> Result<Option<(GeneratedUvs, GeneratedReport)>> {
        let input = &self.input;
        let meshes = self.targets[0].asset.meshes();
        let any = meshes.iter().any(|m| !m.uv_sets.is_empty());
        let generate = match texture.generate_uvs {
            GenerateUvs::Never => false,
            GenerateUvs::Auto => !any,
            GenerateUvs::Always => true,
        };
        if !generate {
            if !meshes.iter().any(|m| m.uv_set(options.uv_set).is_some()) {
                let never =
                    if texture.generate_uvs == GenerateUvs::Never && !any { " (--generate-uvs never)" } else { "" };
                let message = no_uv_message(&meshes.iter().collect::<Vec<_>>(), options.uv_set);
                return Err(Error::scene(input, format!("{message}{never}")));
            }
            return Ok(None);
        }
        let gltf = format_of(output) == Some("glTF");
        if any && !gltf {
            return Err(Error::scene(
                input,
                format!(
                    "the mesh has texture coordinates, and {} files hold one set: bake into them (--generate-uvs auto), or convert the mesh to glTF",
                    format_of(input).unwrap_or("these")
                ),
            ));
        }
        if is_map(output) {
            return Err(Error::output(
                output,
                format!(
                    "the mesh has no texture coordinates, and a map alone would lose the generated ones: write the mesh (-o NAME.{}) to get both, or --generate-uvs never",
                    input.extension().and_then(|e| e.to_str()).unwrap_or("glb")
                ),
            ));
        }
        // A new set after the file's own (glTF numbers them from 0 without gaps).
        let set = meshes.iter().flat_map(|m| m.uv_sets.iter().map(|s| s.set + 1)).max().unwrap_or(0);
        let start = Instant::now();
        let generated = generate_uvs(meshes, set, options)
            .map_err(|e| Error::scene(input, e.to_string().trim_start_matches("invalid settings: ")))?;
        let report = GeneratedReport {
            set,
            charts: generated.charts,
            atlases: generated.atlases,
            utilization: generated.utilization,
            seconds: start.elapsed().as_secs_f64(),
        };
        options.uv_set = set;
        Ok(Some((generated, report)))
    }

    /// The blocks of covered texels a texture bake traces one after another: one when its
    /// points fit [`BLOCK_BYTES`] (and `memory`); several otherwise, unless the request
    /// needs every point in one film, when the bake must fit `memory` whole. Refused, with
    /// the figures, when it cannot fit.
    fn texture_blocks(
        &self,
        layout: &TextureLayout,
        options: &TextureOptions,
        memory: u64,
    ) -> Result<Vec<Range<usize>>> {
        let input = &self.input;
        let per_point = bytes_per_point(self.request.bent_normals);
        let points = layout.nominal_points();
        let room = memory.saturating_sub(layout.bytes);
        let gib = |b: u64| b as f64 / (1u64 << 30) as f64;
        if points > u64::from(u32::MAX) {
            // A point's sample sequence is numbered by a 32-bit index.
            return Err(Error::scene(
                input,
                format!(
                    "a {}×{} texture with {} points per texel has {points} points, more than the 2³² a bake numbers, and would need {:.2} GiB traced at once: choose a smaller --texture or fewer --texel-points",
                    options.width,
                    options.height,
                    options.points,
                    gib(layout.bytes + points * per_point)
                ),
            ));
        }
        if self.request.one_film || self.request.sample_range.is_some() {
            if points * per_point > room {
                return Err(Error::scene(
                    input,
                    format!(
                        "a {}×{} texture with {} points per texel needs {:.2} GiB for its textures and {points} points, more than the {:.2} GiB of memory available; with a time limit, checkpoints, a sample range or a merge every point is traced at once: choose a smaller --texture or fewer --texel-points, or leave those out to trace in blocks",
                        options.width,
                        options.height,
                        options.points,
                        gib(layout.bytes + points * per_point),
                        gib(memory)
                    ),
                ));
            }
            return Ok(std::iter::once(0..layout.covered_texels()).collect());
        }
        let block = room.min(BLOCK_BYTES) / per_point;
        if block < u64::from(options.points) {
            return Err(Error::scene(
                input,
                format!(
                    "a {}×{} texture needs {:.2} GiB for its textures and the points of a texel, more than the {:.2} GiB of memory available: choose a smaller --texture or fewer --texel-points",
                    options.width,
                    options.height,
                    gib(layout.bytes + u64::from(options.points) * per_point),
                    gib(memory)
                ),
            ));
        }
        Ok(layout.blocks(block))
    }

    /// The request, as planned (a texture bake's seed is the scene's).
    pub fn request(&self) -> &BakeRequest {
        &self.request
    }

    /// The files baked.
    pub fn targets(&self) -> &[BakeTarget] {
        &self.targets
    }

    /// The vertex or face plan (empty for a texture bake).
    pub fn plan(&self) -> &BakePlan {
        &self.plan
    }

    /// The points traced in one film; empty for a texture bake traced in blocks.
    pub fn probes(&self) -> &[Probe] {
        match &self.texture {
            Some(t) => t.plan.as_ref().map_or(&[], |p| &p.probes),
            None => &self.plan.probes,
        }
    }

    /// Blocks traced one after another (1 unless a texture bake is traced in blocks).
    pub fn blocks(&self) -> usize {
        self.texture.as_ref().and_then(|t| t.blocked.as_ref()).map_or(1, |(_, b)| b.len())
    }

    /// Meshes baked.
    pub fn mesh_count(&self) -> usize {
        match &self.texture {
            Some(t) => t.targets.iter().map(|t| t.meshes.len()).sum(),
            None => self.plan.mesh_count(),
        }
    }

    /// Points (vertices, faces or covered texels) baked, as planned.
    pub fn points(&self) -> usize {
        match &self.texture {
            Some(t) => t.plan.as_ref().map_or(0, TexturePlan::covered_texels),
            None => self.plan.entry_count(),
        }
    }

    /// The texture options, for a texture bake (the set is the generated one where made).
    pub fn texture_options(&self) -> Option<&TextureOptions> {
        self.texture.as_ref().map(|t| &t.options)
    }

    /// The accumulation this bake's samples make: what a checkpoint resumed or the shards
    /// merged must match.
    pub fn expected(&self, scene: &Scene, kind: DeviceKind, bvh: &BvhOptions) -> Result<Accumulation> {
        let r = &self.request;
        Accumulation::probes(scene, self.probes(), r.samples, r.range(), &self.settings, r.bent_normals, kind, bvh)
    }

    /// The bake from shards' accumulations (each a sample range of this bake, read with
    /// their files' names), their sums added exactly; they must hold all its samples.
    pub fn merge(&self, shards: &[(PathBuf, Accumulation)], expected: &Accumulation) -> Result<BakeTrace> {
        let Some((first, shard)) = shards.first() else {
            return Err(Error::checkpoint("merge", "no accumulations given"));
        };
        let diff = shard.settings().differences(expected.settings());
        if !diff.is_empty() {
            return Err(Error::checkpoint(
                first,
                format!("holds samples of another bake: {} (checkpoint's value first)", diff.join("; ")),
            ));
        }
        let start = Instant::now();
        let merged = merge(shards)?;
        let samples = self.request.samples;
        if merged.first != 0 || merged.end != samples {
            return Err(Error::checkpoint(
                first,
                format!(
                    "the shards hold samples {}..{}, not all 0..{samples} of the bake's {samples}",
                    merged.first, merged.end
                ),
            ));
        }
        Ok(BakeTrace {
            samples: merged.end - merged.first,
            samples_resumed: 0,
            interrupted: false,
            interrupted_block: None,
            rays: 0,
            seconds: 0.0,
            renders: Vec::new(),
            adapter: merged.shards.iter().map(|s| s.adapter.clone()).collect::<Vec<_>>().join(", "),
            host_seconds: start.elapsed().as_secs_f64(),
            sums: Sums::Film(merged.film),
        })
    }

    /// The values (or padded textures) from what was traced.
    pub fn finish(&self, trace: BakeTrace) -> Result<Baked> {
        let (film, texture) = match (trace.sums, &self.texture) {
            (Sums::Textures { mut maps, overlapping, traced: _ }, Some(t)) => {
                for map in &mut maps {
                    map.pad(t.options.padding);
                }
                let points = maps.iter().map(|m| m.coverage.iter().filter(|c| **c == Coverage::Covered).count()).sum();
                return Ok(Baked {
                    values: Vec::new(),
                    mean_ao: mean_of(&maps),
                    maps,
                    points,
                    overlapping_texels: overlapping,
                });
            }
            (Sums::Film(film), t) => (film, t),
            (Sums::Textures { .. }, None) => return Err(Error::settings("a texture's sums for a bake into vertices")),
        };
        let values = probe_film_values(&film);
        let bent = probe_film_bent_normals(&film);
        drop(film);
        let traced = values.len().max(1) as f64;
        let mean_ao = values.iter().map(|v| v.mean).sum::<f64>() / traced;
        match texture {
            Some(t) => {
                let tp = t.plan.as_ref().expect("a texture bake in one film has its plan");
                let maps = tp.textures(&values, bent.as_deref(), t.options.padding);
                Ok(Baked {
                    values: Vec::new(),
                    mean_ao: mean_of(&maps),
                    points: tp.covered_texels(),
                    maps,
                    overlapping_texels: tp.overlapping_texels,
                })
            }
            None => Ok(Baked {
                values: self.plan.values(&values, bent.as_deref()),
                maps: Vec::new(),
                mean_ao,
                points: self.plan.entry_count(),
                overlapping_texels: 0,
            }),
        }
    }

    /// Writes the bake where the request says, each file atomically (nothing for a
    /// request without an output).
    pub fn write(&self, baked: &Baked, samples: u32) -> Result<Written> {
        let Some(output) = &self.request.output else {
            return Ok(Written { files: Vec::new(), notes: Vec::new(), texture: None });
        };
        if let Some(t) = &self.texture {
            return self.write_texture(t, baked, output, samples);
        }
        let r = &self.request;
        let options = WriteOptions { at: r.at, std_error: r.std_error, colors: r.colors };
        let mut rest = baked.values.as_slice();
        let mut notes = Vec::new();
        for t in &self.targets {
            let (values, others) = rest.split_at(t.asset.meshes().len().min(rest.len()));
            rest = others;
            make_parent(&t.output)?;
            let written = if is_conversion(&t.object.path, &t.output) {
                super::convert::write(&t.output, t.asset.meshes(), values, &options)?
            } else {
                t.asset.write(&t.output, values, &options)?
            };
            notes.extend(written.into_iter().map(|n| (t.output.clone(), n)));
        }
        Ok(Written { files: self.targets.iter().map(|t| t.output.clone()).collect(), notes, texture: None })
    }

    /// Writes a texture bake's maps as the output asks: the map alone, or the mesh
    /// referencing them (with generated coordinates, when made).
    fn write_texture(&self, t: &TextureJob, baked: &Baked, output: &Path, samples: u32) -> Result<Written> {
        let options = &t.options;
        let maps = &baked.maps;
        let layout_counts = match (&t.plan, &t.blocked) {
            (Some(p), _) => (p.skipped_triangles, p.wrapped_triangles),
            (None, Some((l, _))) => (l.skipped_triangles, l.wrapped_triangles),
            _ => (0, 0),
        };
        let report = TextureReport {
            width: options.width,
            height: options.height,
            uv_set: options.uv_set,
            textures: maps.len(),
            points_per_texel: options.points,
            samples_per_texel: u64::from(options.points) * u64::from(samples),
            padding: options.padding,
            bit_depth: t.bit_depth,
            overlapping_texels: baked.overlapping_texels,
            skipped_triangles: layout_counts.0,
            wrapped_triangles: layout_counts.1,
            generated_uvs: t.generated.as_ref().map(|(_, r)| r.clone()),
            maps: maps.iter().map(|m| m.stats()).collect(),
        };
        let mut files = vec![output.to_path_buf()];
        let mut notes = Vec::new();
        make_parent(output)?;
        if is_map(output) {
            let map = &maps[0];
            let bytes = if is_exr(output) { map.ao_exr()? } else { map.ao_png(t.bit_depth)? };
            if let Some(png) = map.bent_png(t.bit_depth).transpose()? {
                let path = sibling(output, "_bent_normals.png");
                write_output(&path, &png)?;
                files.push(path);
            }
            write_output(output, &bytes)?;
        } else {
            let mut encoded = Vec::with_capacity(maps.len());
            for (map, target) in maps.iter().zip(&t.targets) {
                encoded.push(TextureMap {
                    material: target.material,
                    meshes: target.meshes.clone(),
                    uv_set: options.uv_set,
                    png: map.ao_png(t.bit_depth)?,
                    bent_png: map.bent_png(t.bit_depth).transpose()?,
                    repeat: options.wrap == UvWrap::Repeat || layout_counts.1 > 0,
                });
            }
            let generated = t.generated.as_ref().map(|(g, _)| g);
            let written = self.targets[0].asset.write_textures(output, &encoded, generated)?;
            notes.extend(written.into_iter().map(|n| (output.to_path_buf(), n)));
            if format_of(output) != Some("glTF") {
                files.push(map_path(output, "ao"));
                if self.request.bent_normals {
                    files.push(map_path(output, "bent_normals"));
                }
            }
        }
        Ok(Written { files, notes, texture: Some(report) })
    }
}

impl Session {
    /// Traces `bake`'s points on this session (made from the scene the bake was planned
    /// from), continuing `resume` when given, under `control` (stop, time limit, progress,
    /// checkpoints). A texture bake too large for one film is traced a block of texels at
    /// a time, each block's points taking the sample sequences they have in the whole
    /// bake; a stop then ends it keeping nothing ([`BakeTrace::interrupted_block`]).
    pub fn bake(&self, bake: &Bake, resume: Option<Accumulation>, control: &mut Control) -> Result<BakeTrace> {
        let r = &bake.request;
        if let Some(t) = &bake.texture
            && let Some((layout, blocks)) = &t.blocked
        {
            return self.bake_blocks(bake, t, (layout, blocks), control);
        }
        let resumed = resume.as_ref().map_or(0, |a| a.samples());
        let mut render =
            self.probe_render(bake.probes(), r.samples, r.sample_range.clone(), &bake.settings, r.bent_normals)?;
        if let Some(acc) = resume {
            render.resume(acc)?;
        }
        render.run(control)?;
        let out = render.finish()?;
        let acc = out.accumulation;
        let start = Instant::now();
        // The film `finish` made of this accumulation, not a second one.
        let film = out.film;
        Ok(BakeTrace {
            samples: acc.samples(),
            samples_resumed: resumed,
            interrupted: out.stats.interrupted,
            interrupted_block: None,
            rays: acc.ao_rays(),
            seconds: acc.render_seconds(),
            adapter: out.stats.adapter.clone(),
            renders: vec![out.stats],
            host_seconds: start.elapsed().as_secs_f64(),
            sums: Sums::Film(film),
        })
    }

    fn bake_blocks(
        &self,
        bake: &Bake,
        t: &TextureJob,
        (layout, blocks): (&TextureLayout, &[Range<usize>]),
        control: &mut Control,
    ) -> Result<BakeTrace> {
        let samples = bake.request.samples;
        let bent_normals = bake.request.bent_normals;
        let placement = Placement::of(&bake.targets[0].object);
        let meshes: Vec<(&AssetMesh, Placement)> = t.meshes.iter().map(|m| (m, placement)).collect();
        let mut maps = layout.blank_textures(bent_normals);
        let (mut first, mut overlapping, mut traced) = (0u32, 0, 0);
        let (mut rays, mut seconds, mut host_seconds) = (0u64, 0.0f64, 0.0f64);
        let mut renders = Vec::new();
        let total = samples * blocks.len() as u32;
        for (b, block) in blocks.iter().enumerate() {
            let plan = layout.plan(&meshes, block.clone(), first);
            if plan.probes.is_empty() {
                continue;
            }
            let done = b as u32 * samples;
            let mut outer = control.progress.as_deref_mut();
            let mut on_progress = |p: &Progress| {
                if let Some(f) = outer.as_deref_mut() {
                    f(&Progress {
                        samples_done: done + p.samples_done,
                        samples_total: total,
                        rays: rays + p.rays,
                        elapsed: seconds + p.elapsed,
                    })
                }
            };
            let mut inner = Control { stop: control.stop, progress: Some(&mut on_progress), ..Control::default() };
            let mut render =
                self.probe_render_from(&plan.probes, first, samples, None, &bake.settings, bent_normals)?;
            render.run(&mut inner)?;
            let out = render.finish()?;
            if out.stats.interrupted {
                renders.push(out.stats);
                return Ok(BakeTrace {
                    sums: Sums::Textures { maps: Vec::new(), overlapping, traced },
                    samples: 0,
                    samples_resumed: 0,
                    interrupted: true,
                    interrupted_block: Some(b),
                    rays,
                    seconds,
                    adapter: self.setup().adapter.name.clone(),
                    renders,
                    host_seconds,
                });
            }
            let acc = &out.accumulation;
            (rays, seconds) = (rays + acc.ao_rays(), seconds + acc.render_seconds());
            let start = Instant::now();
            let values = probe_film_values(&out.film);
            let bent = probe_film_bent_normals(&out.film);
            renders.push(out.stats);
            plan.fill(&mut maps, &values, bent.as_deref());
            host_seconds += start.elapsed().as_secs_f64();
            overlapping += plan.overlapping_texels;
            traced += plan.probes.len();
            first += plan.probes.len() as u32;
        }
        if traced == 0 {
            return Err(Error::scene(&bake.input, "no triangle covers a texel with a usable normal: nothing to bake"));
        }
        Ok(BakeTrace {
            sums: Sums::Textures { maps, overlapping, traced },
            samples,
            samples_resumed: 0,
            interrupted: false,
            interrupted_block: None,
            rays,
            seconds,
            adapter: renders.last().map(|r| r.adapter.clone()).unwrap_or_default(),
            renders,
            host_seconds,
        })
    }
}

impl BakeTrace {
    /// Points traced (for a texture bake in blocks, over all its blocks; else the film's).
    pub fn points_traced(&self, bake: &Bake) -> usize {
        match &self.sums {
            Sums::Textures { traced, .. } => *traced,
            Sums::Film(_) => bake.probes().len(),
        }
    }
}

/// The mean AO over the covered texels of `maps`.
fn mean_of(maps: &[BakedTexture]) -> f64 {
    let stats: Vec<TextureStats> = maps.iter().map(|m| m.stats()).collect();
    let covered: usize = stats.iter().map(|m| m.covered_texels).sum();
    stats.iter().map(|m| m.mean_ao * m.covered_texels as f64).sum::<f64>() / covered.max(1) as f64
}

/// Makes the directories `path` goes in.
fn make_parent(path: &Path) -> Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| Error::output(dir, format!("cannot create the directory: {e}")))?;
    }
    Ok(())
}

/// The files to bake: each mesh object's file, read once. With an output (`files` and
/// the output path): for a mesh input, its one object into it; for a scene file, each
/// mesh object into the directory under its file's name (with the object's number added
/// when the file is placed by several objects); the outputs entered in `files`.
fn read_targets(
    mut out: Option<(&mut FilePlan, &PathBuf)>,
    objects: &[MeshObject],
    is_scene: bool,
    request: &BakeRequest,
    read: &ReadInputs,
) -> Result<Vec<BakeTarget>> {
    let mut assets: Vec<(PathBuf, Arc<dyn Asset>)> = Vec::new();
    let mut targets = Vec::with_capacity(objects.len());
    for object in objects {
        let asset = match assets.iter().find(|(p, _)| *p == object.path) {
            Some((_, a)) => a.clone(),
            None => {
                let a: Arc<dyn Asset> = match read.get(object) {
                    Some(a) => a,
                    None => Arc::from(read_object(object, &request.limits)?),
                };
                assets.push((object.path.clone(), a.clone()));
                a
            }
        };
        let output = match out.as_mut() {
            Some((plan, output)) => {
                let path = output_path(objects, object, is_scene, output);
                check_mesh_output(&object.path, &path, request.overwrite)?;
                let name = &request.output_name;
                if is_scene {
                    plan_output(plan, object, &path, is_scene, request.overwrite, name)?;
                }
                plan_companions(plan, object, &*asset, (&path, name), is_scene, None)?;
                path
            }
            None => PathBuf::new(),
        };
        targets.push(BakeTarget { object: object.clone(), asset, output });
    }
    Ok(targets)
}

/// `vertex` or `face`.
pub fn singular(at: BakeAt) -> &'static str {
    match at {
        BakeAt::Vertices => "vertex",
        BakeAt::Faces => "face",
    }
}

/// Why nothing can be baked into a texture: no mesh has the set.
fn no_uv_message(meshes: &[&AssetMesh], set: u32) -> String {
    let mut sets: Vec<u32> = meshes.iter().flat_map(|m| m.uv_sets.iter().map(|s| s.set)).collect();
    sets.sort_unstable();
    sets.dedup();
    let others = if sets.is_empty() {
        "it has none".to_string()
    } else {
        format!(
            "it has set{} {}",
            if sets.len() == 1 { "" } else { "s" },
            sets.iter().map(u32::to_string).collect::<Vec<_>>().join(", ")
        )
    };
    let hint = if sets.is_empty() {
        "generate them (--generate-uvs auto), or unwrap the mesh first"
    } else {
        "choose one with --uv-set, or generate a new set (--generate-uvs always)"
    };
    format!("no mesh has texture coordinates of set {set} ({others}): {hint}")
}
