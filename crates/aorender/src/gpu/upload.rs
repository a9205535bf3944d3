//! The scene on the device: the BVH's nodes and the primitive records uploaded once per
//! session, as storage buffers or read-only storage textures, split into chunks of at
//! most one binding each; and the planes. Requests bind them as they are.

use super::context::GpuContext;
use super::layout::{GpuPlane, node_binding, primitive_binding};
use super::shaders::{GeometryChunks, GeometryStorage, ROW_TEXEL_MULTIPLE, Traversal};
use crate::bvh::{BvhLayout, GpuBvh, GpuPrimitive};
use crate::error::{Error, Result};
use crate::scene::Scene;
use rayon::prelude::*;

/// Writes the bytes of an upload from `offset` into `piece`: each piece's bytes its own,
/// so pieces can be made on any thread.
type Fill<'a> = dyn Fn(usize, &mut [u8]) + Sync + 'a;

/// The scene's geometry on the device, and what the kernel needs to know of it.
#[derive(Debug)]
pub struct GpuScene {
    /// The BVH layout the nodes are in.
    pub layout: BvhLayout,
    /// How nodes and primitives are split into bindings.
    pub chunks: GeometryChunks,
    /// Node chunks, in order.
    nodes: Vec<Geometry>,
    /// Primitive chunks, in order.
    primitives: Vec<Geometry>,
    /// The planes (one zeroed element when there are none).
    pub(crate) planes: wgpu::Buffer,
    /// Number of BVH nodes.
    pub node_count: u32,
    /// Number of planes.
    pub plane_count: u32,
    /// Entries of the traversal stack: the BVH's depth.
    pub stack_size: u32,
    /// A ray per lane or per group of lanes.
    pub traversal: Traversal,
    /// The most traversal loop iterations one ray can take, the planes included.
    pub ray_steps: u64,
    /// The BVH has instances (a second level).
    pub has_instances: bool,
    /// The scene has spheres.
    pub has_spheres: bool,
    /// The scene has triangles, placed once or instanced.
    pub has_triangles: bool,
    /// The scene has planes.
    pub has_planes: bool,
    /// Bytes of the BVH as uploaded: its nodes and primitive records.
    pub bvh_bytes: u64,
    /// What messages about the scene name: its file, or its name.
    pub source: std::path::PathBuf,
}

impl GpuScene {
    /// Uploads `bvh` (built from `scene`) and the scene's planes, the geometry in
    /// `storage`, to be traced as `traversal` says (`None`: the adapter's preference where
    /// the scene allows it). The primitive records are made from the scene a piece at a
    /// time, straight into the upload.
    pub fn upload(
        ctx: &GpuContext,
        scene: &Scene,
        bvh: &GpuBvh,
        storage: GeometryStorage,
        traversal: Option<Traversal>,
    ) -> Result<GpuScene> {
        let stack = ctx.stack_entries(bvh.layout);
        if bvh.depth > stack {
            let other = match bvh.layout {
                BvhLayout::Bvh2 => ", and so does the cwbvh layout (`--bvh-layout cwbvh`)",
                BvhLayout::Cwbvh => "",
            };
            return Err(Error::scene(
                scene.source(),
                format!(
                    "its {} BVH is {} levels deep, past the {stack} the GPU kernel's traversal stack holds; \
                     the CPU reference (`--device cpu`) renders it{other}",
                    bvh.layout.name(),
                    bvh.depth,
                ),
            ));
        }
        // The BVH2 layout flattens instances.
        let has_instances = bvh.layout == BvhLayout::Cwbvh && !scene.instances.is_empty();
        let cooperative = ctx.cooperative_traversal() && bvh.layout == BvhLayout::Cwbvh && !has_instances;
        let traversal = match traversal {
            Some(Traversal::Cooperative) if !cooperative => {
                return Err(Error::Gpu(format!(
                    "the cooperative traversal needs subgroups of 8 lanes or a multiple ({}), the {} layout ({}) \
                     and a scene without instances ({})",
                    if ctx.cooperative_traversal() { "the adapter has them" } else { "the adapter has none" },
                    BvhLayout::Cwbvh.name(),
                    bvh.layout.name(),
                    if has_instances { "it has some" } else { "it has none" },
                )));
            }
            Some(t) => t,
            None if cooperative => ctx.preferred_traversal(),
            None => Traversal::PerLane,
        };
        let node_size = bvh.layout.node_size();
        let record_count = bvh.records.len();
        let chunks = geometry_chunks(ctx, storage, bvh.layout, bvh.node_count as usize, record_count)?;
        let nodes: Vec<Geometry> = chunk_ranges(bvh.node_count as usize, chunks.nodes_per_chunk)
            .map(|r| {
                let bytes = &bvh.node_bytes[r.start * node_size..r.end * node_size];
                Geometry::upload(ctx, "BVH nodes", bytes.len(), node_size, chunks, &|at, out| {
                    out.copy_from_slice(&bytes[at..at + out.len()])
                })
            })
            .collect::<Result<_>>()?;
        let prim_size = std::mem::size_of::<GpuPrimitive>();
        let primitives: Vec<Geometry> = chunk_ranges(record_count, chunks.primitives_per_chunk)
            .map(|r| {
                Geometry::upload(ctx, "primitives", r.len() * prim_size, prim_size, chunks, &|at, out| {
                    fill_records(out, |records: &mut [GpuPrimitive]| {
                        bvh.records.write(scene, r.start + at / prim_size, records)
                    })
                })
            })
            .collect::<Result<_>>()?;
        let planes: Vec<GpuPlane> = scene.planes.iter().map(GpuPlane::from).collect();
        let planes = storage_buffer(ctx, "planes", bytemuck::cast_slice(&planes), std::mem::size_of::<GpuPlane>())?;
        ctx.take_error()?;
        Ok(GpuScene {
            layout: bvh.layout,
            chunks,
            nodes,
            primitives,
            planes,
            node_count: bvh.node_count,
            plane_count: scene.planes.len() as u32,
            stack_size: bvh.stack_size(),
            traversal,
            ray_steps: bvh.ray_steps(scene) + scene.planes.len() as u64,
            has_instances,
            has_spheres: !scene.spheres.is_empty(),
            has_triangles: !scene.triangles.is_empty() || !scene.instances.is_empty(),
            has_planes: !scene.planes.is_empty(),
            bvh_bytes: bvh.bytes(),
            source: scene.source(),
        })
    }

    /// Bindings holding the BVH nodes and the primitives.
    pub fn geometry_bindings(&self) -> u32 {
        (self.nodes.len() + self.primitives.len()) as u32
    }

    /// The geometry's bind group entries: node chunks, then primitive chunks.
    pub(crate) fn bind_group_entries(&self) -> Vec<wgpu::BindGroupEntry<'_>> {
        let nodes = self.nodes.iter().enumerate().map(|(k, g)| (node_binding(k as u32), g));
        let prims = self.primitives.iter().enumerate().map(|(k, g)| (primitive_binding(k as u32), g));
        nodes.chain(prims).map(|(binding, g)| wgpu::BindGroupEntry { binding, resource: g.resource() }).collect()
    }

    /// The geometry's bindings, held apart from the scene: a target binds them again
    /// when it lists its live pixels.
    pub(crate) fn bindings(&self) -> GeometryBindings {
        let nodes = self.nodes.iter().enumerate().map(|(k, g)| (node_binding(k as u32), g.clone()));
        let prims = self.primitives.iter().enumerate().map(|(k, g)| (primitive_binding(k as u32), g.clone()));
        GeometryBindings(nodes.chain(prims).collect())
    }

    /// Bytes of device memory the geometry and the planes take.
    pub fn device_bytes(&self) -> u64 {
        self.planes.size() + self.nodes.iter().chain(&self.primitives).map(Geometry::bytes).sum::<u64>()
    }
}

/// The bindings of a scene's node and primitive chunks (handles to the scene's buffers or
/// textures, not copies).
#[derive(Clone, Debug)]
pub(crate) struct GeometryBindings(Vec<(u32, Geometry)>);

impl GeometryBindings {
    /// The bind group entries of the chunks.
    pub(crate) fn entries(&self) -> Vec<wgpu::BindGroupEntry<'_>> {
        self.0.iter().map(|(binding, g)| wgpu::BindGroupEntry { binding: *binding, resource: g.resource() }).collect()
    }
}

/// How `nodes` nodes and `primitives` primitives split into chunks of at most one binding
/// each in `storage`, or an error with the numbers when the adapter has too few bindings
/// per shader stage for them.
fn geometry_chunks(
    ctx: &GpuContext,
    storage: GeometryStorage,
    layout: BvhLayout,
    nodes: usize,
    primitives: usize,
) -> Result<GeometryChunks> {
    let node_size = layout.node_size();
    let prim_size = std::mem::size_of::<GpuPrimitive>();
    // Texels in a texture row (0 for buffers), and the bytes one binding holds at most.
    let (row_texels, chunk_bytes) = match storage {
        GeometryStorage::Buffers => (0, ctx.max_chunk_bytes()),
        GeometryStorage::Textures => {
            let [width, rows] = ctx.max_texture_size();
            let row = width / ROW_TEXEL_MULTIPLE * ROW_TEXEL_MULTIPLE;
            if row == 0 {
                return Err(Error::Gpu(format!(
                    "textures of {width} texels are too narrow for the geometry: it needs {ROW_TEXEL_MULTIPLE}"
                )));
            }
            (row, row as u64 * rows as u64 * 16)
        }
    };
    // An element is a whole number of texels and a row a whole number of elements, so
    // a texture holds exactly chunk_bytes / size of them.
    let per_chunk = |size: usize| (chunk_bytes / size as u64).clamp(1, u32::MAX as u64) as u32;
    let (nodes_per_chunk, primitives_per_chunk) = (per_chunk(node_size), per_chunk(prim_size));
    let chunks = GeometryChunks {
        storage,
        node_chunks: (nodes.div_ceil(nodes_per_chunk as usize) as u32).max(1),
        nodes_per_chunk,
        primitive_chunks: (primitives.div_ceil(primitives_per_chunk as usize) as u32).max(1),
        primitives_per_chunk,
        row_texels,
    };
    let (allowed, limit_name) = ctx.geometry_bindings(storage);
    let needed = (nodes * node_size + primitives * prim_size) as u64;
    if chunks.node_chunks + chunks.primitive_chunks > allowed {
        let limit = allowed as u64 * chunk_bytes;
        return Err(Error::TooLarge { what: "the BVH nodes and primitives", needed, limit, limit_name });
    }
    let per_kind = ctx.geometry_chunks_per_kind();
    if chunks.node_chunks.max(chunks.primitive_chunks) > per_kind {
        return Err(Error::TooLarge {
            what: "the BVH nodes and primitives",
            needed,
            limit: 2 * per_kind as u64 * chunk_bytes,
            limit_name: "max_bindings_per_bind_group (chunk k of the nodes and of the primitives binds at 2k + 6 \
                         and 2k + 7) × the bytes of a chunk",
        });
    }
    Ok(chunks)
}

/// `bytes` in chunks of `per_chunk` elements of `element` bytes; one empty chunk when
/// `bytes` is empty.
fn chunk_ranges(count: usize, per_chunk: u32) -> impl Iterator<Item = std::ops::Range<usize>> {
    let per_chunk = (per_chunk as usize).max(1);
    let chunks = count.div_ceil(per_chunk).max(1);
    (0..chunks).map(move |k| k * per_chunk..((k + 1) * per_chunk).min(count))
}

/// Bytes filled at a time when an upload is made piece by piece.
const UPLOAD_PIECE: usize = 1 << 20;

/// Pieces of an upload made at once, on rayon's threads.
const UPLOAD_BATCH: usize = 16;

/// A read-only storage buffer; `element` is the size of one array element in the shader.
pub(crate) fn storage_buffer(
    ctx: &GpuContext,
    label: &'static str,
    bytes: &[u8],
    element: usize,
) -> Result<wgpu::Buffer> {
    storage_mapped(ctx, label, bytes.len(), element, Contents::Bytes(bytes))
}

/// What a buffer written through its mapping holds.
enum Contents<'a> {
    /// These bytes, copied piece by piece.
    Bytes(&'a [u8]),
    /// The bytes `fill(offset, piece)` makes, a piece at a time.
    Made(&'a Fill<'a>),
}

/// Writes the records `fill` makes into `out`, bytes of whole records: straight in where
/// `out` is aligned for them (mapped memory is), else through records of their own.
pub(crate) fn fill_records<T: bytemuck::Pod>(out: &mut [u8], fill: impl FnOnce(&mut [T])) {
    match bytemuck::try_cast_slice_mut::<u8, T>(out) {
        Ok(records) => fill(records),
        Err(_) => {
            let mut piece = vec![T::zeroed(); out.len() / std::mem::size_of::<T>()];
            fill(&mut piece);
            out.copy_from_slice(bytemuck::cast_slice(&piece));
        }
    }
}

/// A read-only storage buffer of `len` bytes written through its mapping by `fill(offset,
/// piece)` (pieces of whole elements, on rayon's threads), so no copy of the whole is
/// needed on the host.
pub(crate) fn storage_filled(
    ctx: &GpuContext,
    label: &'static str,
    len: usize,
    element: usize,
    fill: &Fill<'_>,
) -> Result<wgpu::Buffer> {
    storage_mapped(ctx, label, len, element, Contents::Made(fill))
}

/// A read-only storage buffer of `len` bytes of `contents`, written through its mapping:
/// bytes given are copied in at once; bytes made are made in pieces of whole elements of
/// about [`UPLOAD_PIECE`] bytes on rayon's threads.
fn storage_mapped(
    ctx: &GpuContext,
    label: &'static str,
    len: usize,
    element: usize,
    contents: Contents<'_>,
) -> Result<wgpu::Buffer> {
    // A binding may not be empty: absent data is one zeroed element (wgpu zeroes buffers).
    let size = len.max(element) as u64;
    ctx.check_size(label, size)?;
    let buffer = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size,
        usage: wgpu::BufferUsages::STORAGE,
        mapped_at_creation: true,
    });
    if len > 0 {
        let mut view = buffer
            .slice(..len as u64)
            .get_mapped_range_mut()
            .map_err(|e| ctx.fault(format!("cannot write the mapped {label} buffer: {e}")))?;
        match contents {
            Contents::Bytes(bytes) => view.copy_from_slice(bytes),
            Contents::Made(fill) => {
                // A batch of pieces made on threads, then copied in (a view of mapped
                // memory stays on its thread); the batch's buffers are reused.
                let step = (UPLOAD_PIECE / element).max(1) * element;
                let batch = step * UPLOAD_BATCH;
                let mut made: Vec<Vec<u8>> = vec![Vec::new(); UPLOAD_BATCH];
                for at in (0..len).step_by(batch) {
                    let end = (at + batch).min(len);
                    let count = (end - at).div_ceil(step);
                    made[..count].par_iter_mut().enumerate().for_each(|(k, piece)| {
                        let from = at + k * step;
                        piece.resize(step.min(end - from), 0);
                        fill(from, piece);
                    });
                    for (k, piece) in made[..count].iter().enumerate() {
                        let from = at + k * step;
                        view.slice(from..from + piece.len()).copy_from_slice(piece);
                    }
                }
            }
        }
    }
    buffer.unmap();
    Ok(buffer)
}

/// One chunk of nodes or primitives on the device.
#[derive(Clone, Debug)]
enum Geometry {
    Buffer(wgpu::Buffer),
    Texture(wgpu::TextureView, u64),
}

impl Geometry {
    /// Uploads `len` bytes, elements of `element` bytes, as `chunks` says; `fill(offset,
    /// piece)` writes them a piece at a time.
    fn upload(
        ctx: &GpuContext,
        label: &'static str,
        len: usize,
        element: usize,
        chunks: GeometryChunks,
        fill: &Fill<'_>,
    ) -> Result<Geometry> {
        match chunks.storage {
            GeometryStorage::Buffers => storage_filled(ctx, label, len, element, fill).map(Geometry::Buffer),
            GeometryStorage::Textures => texels(ctx, label, len, element, chunks.row_texels, fill),
        }
    }

    fn resource(&self) -> wgpu::BindingResource<'_> {
        match self {
            Geometry::Buffer(b) => b.as_entire_binding(),
            Geometry::Texture(view, _) => wgpu::BindingResource::TextureView(view),
        }
    }

    fn bytes(&self) -> u64 {
        match self {
            Geometry::Buffer(b) => b.size(),
            Geometry::Texture(_, bytes) => *bytes,
        }
    }
}

/// Bytes of the staging buffer a texture's rows go through, filled again for each round of
/// rows: the rows are not staged in fresh memory a piece at a time (`queue.write_texture`),
/// whose first touch cost more than the copies on lavapipe.
const TEXEL_STAGING: usize = 32 << 20;

/// An `Rgba32Uint` texture `row_texels` wide holding `len` bytes row after row (elements
/// of `element` bytes never straddle rows: `row_texels` is a multiple of their texels; the
/// last row is padded with zeros), made by `fill(offset, piece)` a row at a time on
/// rayon's threads and copied through one staging buffer, [`TEXEL_STAGING`] bytes of rows
/// at a time.
fn texels(
    ctx: &GpuContext,
    label: &'static str,
    len: usize,
    element: usize,
    row_texels: u32,
    fill: &Fill<'_>,
) -> Result<Geometry> {
    const TEXEL: usize = 16;
    debug_assert_eq!(len % TEXEL, 0);
    let row_bytes = row_texels as usize * TEXEL;
    debug_assert_eq!(row_bytes % element, 0);
    let rows = len.div_ceil(row_bytes).max(1);
    let max = ctx.device.limits().max_texture_dimension_2d;
    if rows > max as usize {
        return Err(Error::TooLarge {
            what: label,
            needed: len as u64,
            limit: max as u64 * row_bytes as u64,
            limit_name: "max_texture_dimension_2d² texels of 16 bytes",
        });
    }
    let texture = ctx.device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d { width: row_texels, height: rows as u32, depth_or_array_layers: 1 },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Rgba32Uint,
        usage: wgpu::TextureUsages::STORAGE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    // A copy's rows start at multiples of the copy alignment in the staging buffer.
    let stride = row_bytes.next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT as usize);
    let round = (TEXEL_STAGING / stride).clamp(1, rows);
    let staging = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("texture staging"),
        size: (round * stride) as u64,
        usage: wgpu::BufferUsages::MAP_WRITE | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: true,
    });
    // A batch of rows is made on threads, then copied in (a mapped view is written on its
    // thread); the batch's buffers are reused, so the host holds a few of them at a time.
    let mut made: Vec<Vec<u8>> = vec![Vec::new(); UPLOAD_BATCH.min(round)];
    for first in (0..rows).step_by(round) {
        let count = round.min(rows - first);
        if first > 0 {
            ctx.map_for_write(&staging)?;
        }
        {
            let mut view = staging
                .slice(..(count * stride) as u64)
                .get_mapped_range_mut()
                .map_err(|e| ctx.fault(format!("cannot write the mapped {label} staging buffer: {e}")))?;
            for batch in (0..count).step_by(made.len()) {
                let batch_rows = made.len().min(count - batch);
                made[..batch_rows].par_iter_mut().enumerate().for_each(|(k, row)| {
                    let at = (first + batch + k) * row_bytes;
                    let bytes = row_bytes.min(len - at);
                    row.resize(row_bytes, 0);
                    if bytes > 0 {
                        fill(at, &mut row[..bytes]);
                    }
                    row[bytes..].fill(0);
                });
                for (k, row) in made[..batch_rows].iter().enumerate() {
                    let to = (batch + k) * stride;
                    view.slice(to..to + row_bytes).copy_from_slice(row);
                }
            }
        }
        staging.unmap();
        let mut encoder = ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(label) });
        encoder.copy_buffer_to_texture(
            wgpu::TexelCopyBufferInfo {
                buffer: &staging,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(stride as u32),
                    rows_per_image: Some(count as u32),
                },
            },
            wgpu::TexelCopyTextureInfo {
                texture: &texture,
                mip_level: 0,
                origin: wgpu::Origin3d { x: 0, y: first as u32, z: 0 },
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::Extent3d { width: row_texels, height: count as u32, depth_or_array_layers: 1 },
        );
        ctx.submit([encoder.finish()])?;
    }
    // The copies done, the staging buffer goes before the next texture is written and
    // before the render or bake allocates its own.
    ctx.wait()?;
    drop(staging);
    let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
    Ok(Geometry::Texture(view, rows as u64 * row_bytes as u64))
}
