//! A CWBVH over many primitives, built in octree cells so the build's workspace stays
//! bounded.
//!
//! obvhs's PLOC builder and its BVH2 → CWBVH conversion hold about 300 bytes a primitive
//! at their peak (two node arrays and the Morton codes, then the BVH2 and the conversion's
//! table of decisions), eight times a triangle. Above `chunk` primitives the build here
//! sorts the primitives' centroids along a Morton curve, cuts the curve at octree cell
//! boundaries until no cell holds more than `chunk` primitives, builds each cell with
//! obvhs (one cell a thread at a time) and joins the cells under 8-wide nodes quantized
//! and ordered the way obvhs makes its own (Ylitie, Karras and Laine 2017). The workspace
//! is then the sorted keys (8 bytes a primitive) and ~320 bytes × `chunk` for each cell
//! being built, with no more cells at once than threads, nor than one per 16 cells' worth of
//! primitives or what 64 MiB holds, whichever is more.

use super::cwbvh::{inner_node, placed};
use super::ploc::cwbvh_over;
use super::quality::BuildQuality;
use super::stages::{Stage, timed};
use glam::{UVec3, Vec3A};
use obvhs::aabb::Aabb;
use obvhs::cwbvh::{CwBvh, node::CwBvhNode};
use rayon::prelude::*;
use rdst::RadixSort;
use std::ops::Range;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Bits of each axis in the Morton code; a cell finer than 2⁻¹⁰ of the centroids' box is
/// cut by count instead.
const MORTON_BITS: u32 = 10;

/// Builds a CWBVH over primitives `0..count`, whose boxes `aabb` gives, in octree cells of
/// at most `chunk` primitives. `None` when `count` is 0.
pub fn build_cwbvh_in_cells(
    count: usize,
    aabb: &(dyn Fn(usize) -> Aabb + Sync),
    quality: BuildQuality,
    chunk: usize,
) -> Option<CwBvh> {
    assert!(count <= u32::MAX as usize, "primitive ids are 32-bit");
    let chunk = chunk.max(1);
    if count == 0 {
        return None;
    }
    if count <= chunk {
        let mut bvh = build_cell(&(0..count as u32).collect::<Vec<_>>(), aabb, quality);
        bvh.primitive_indices.shrink_to_fit();
        return Some(bvh);
    }

    let mut cells = Vec::new();
    let (keys, plan) = timed(Stage::Cells, || {
        let keys = morton_keys(count, aabb);
        let plan = plan(&keys, 0..count, 0, chunk, &mut cells);
        (keys, plan)
    });

    let lanes = rayon::current_num_threads().min(cell_lanes(count, chunk)).max(1);
    let next = AtomicUsize::new(0);
    let built: Vec<(usize, CwBvh)> = (0..lanes)
        .into_par_iter()
        .flat_map_iter(|_| {
            std::iter::from_fn(|| {
                let c = next.fetch_add(1, Ordering::Relaxed);
                let range = cells.get(c)?.clone();
                let ids: Vec<u32> = keys[range].iter().map(|&k| k as u32).collect();
                Some((c, build_cell(&ids, aabb, quality)))
            })
        })
        .collect();
    drop(keys);
    Some(timed(Stage::Join, || join(built, &plan)))
}

/// Bytes of a cell's workspace at its peak, per primitive of the cell (the module's note).
const CELL_BYTES_PER_PRIMITIVE: usize = 320;

/// Workspace the cells being built may hold whatever the mesh's size.
const LANE_WORKSPACE_FLOOR: usize = 64 << 20;

/// The most cells of at most `chunk` primitives built at once for `count` primitives:
/// each lane builds one at a time, so no more than this many workspaces are live. One
/// lane per 16 cells' worth of primitives keeps them within ~20 bytes a primitive, and
/// [`LANE_WORKSPACE_FLOOR`] lets a smaller mesh use as many lanes as fit in it (12 cells
/// of 16,384 primitives): a cell's conversion to 8-wide nodes runs on its lane's thread
/// alone, so lanes are what a build's threads can share.
fn cell_lanes(count: usize, chunk: usize) -> usize {
    let by_mesh = count / chunk / 16;
    let by_floor = LANE_WORKSPACE_FLOOR / (CELL_BYTES_PER_PRIMITIVE * chunk);
    by_mesh.max(by_floor)
}

/// The CWBVH of the cells `built` (with their indices in build order) under the nodes of `plan`.
fn join(mut built: Vec<(usize, CwBvh)>, plan: &Part) -> CwBvh {
    built.sort_unstable_by_key(|(c, _)| *c);
    let boxes: Vec<Aabb> = built.iter().map(|(_, b)| b.total_aabb).collect();
    let sizes: Vec<(usize, usize)> = built.iter().map(|(_, b)| (b.nodes.len(), b.primitive_indices.len())).collect();
    // Where everything goes, then the nodes made here and the cells' roots, then the
    // cells' other nodes and primitives, each cell into its own range, over threads.
    let mut layout = Layout { nodes: 1, primitives: 0, inner: Vec::new(), places: Vec::new() };
    plan.lay_out(0, &boxes, &sizes, &mut layout);
    let mut nodes: Vec<CwBvhNode> = bytemuck::zeroed_vec(layout.nodes);
    let mut primitive_indices: Vec<u32> = bytemuck::zeroed_vec(layout.primitives);
    for (slot, node) in layout.inner {
        nodes[slot] = node;
    }
    // Node j > 0 of a cell moves to node_base + j; its root to its slot.
    let bases = |place: &CellPlace| ((place.node_start - 1) as u32, place.prim_start as u32);
    for place in &layout.places {
        let (node_base, prim_base) = bases(place);
        nodes[place.slot] = placed(&built[place.cell].1.nodes[0], node_base, prim_base);
    }
    let mut built: Vec<Option<CwBvh>> = built.into_iter().map(|(_, b)| Some(b)).collect();
    let mut jobs = Vec::with_capacity(layout.places.len());
    let (mut node_rest, mut prim_rest) = (&mut nodes[..], &mut primitive_indices[..]);
    let mut node_end = 0;
    for place in &layout.places {
        let cell = built[place.cell].take().expect("each cell is placed once");
        let (node_base, prim_base) = bases(place);
        let (_, rest) = std::mem::take(&mut node_rest).split_at_mut(place.node_start - node_end);
        let (body, rest) = rest.split_at_mut(cell.nodes.len() - 1);
        let (prims, prim_after) = std::mem::take(&mut prim_rest).split_at_mut(cell.primitive_indices.len());
        (node_rest, prim_rest, node_end) = (rest, prim_after, place.node_start + body.len());
        jobs.push((cell, body, prims, node_base, prim_base));
    }
    jobs.into_par_iter().for_each(|(cell, body, prims, node_base, prim_base)| {
        for (to, from) in body.iter_mut().zip(&cell.nodes[1..]) {
            *to = placed(from, node_base, prim_base);
        }
        prims.copy_from_slice(&cell.primitive_indices);
    });
    CwBvh {
        nodes,
        primitive_indices,
        total_aabb: plan.bounds(&boxes),
        exact_node_aabbs: None,
        uses_spatial_splits: false,
    }
}

/// Where the join of the cells puts everything: the nodes and primitives laid out so far,
/// the inner nodes made above the cells (with their indices) and each cell's place.
struct Layout {
    nodes: usize,
    primitives: usize,
    inner: Vec<(usize, CwBvhNode)>,
    places: Vec<CellPlace>,
}

/// Where one cell goes: its root at `slot` (in its parent's children), its other nodes
/// from `node_start` and its primitives from `prim_start`, after those laid out before it.
struct CellPlace {
    cell: usize,
    slot: usize,
    node_start: usize,
    prim_start: usize,
}

/// obvhs's CWBVH over primitives `ids` ([`cwbvh_over`]: O(log n) deep whatever the
/// boxes), its primitive indices mapped back to those ids.
fn build_cell(ids: &[u32], aabb: &(dyn Fn(usize) -> Aabb + Sync), quality: BuildQuality) -> CwBvh {
    let boxes: Vec<Aabb> = timed(Stage::Leaves, || ids.iter().map(|&i| aabb(i as usize)).collect());
    let mut bvh = cwbvh_over(&boxes, &quality.params());
    for p in &mut bvh.primitive_indices {
        *p = ids[*p as usize];
    }
    // The conversion reserves a node per primitive; a cell keeps only what it uses.
    bvh.nodes.shrink_to_fit();
    bvh
}

/// Sorted keys: a 30-bit Morton code of each primitive's centroid above its 32-bit id.
fn morton_keys(count: usize, aabb: &(dyn Fn(usize) -> Aabb + Sync)) -> Vec<u64> {
    let bounds = (0..count)
        .into_par_iter()
        .map(|i| {
            let c = aabb(i).center();
            Aabb::new(c, c)
        })
        .reduce(Aabb::empty, |a, b| a.union(&b));
    let cells = (1u32 << MORTON_BITS) as f32;
    let scale = cells / (bounds.max - bounds.min).max(Vec3A::splat(f32::MIN_POSITIVE));
    let mut keys: Vec<u64> = (0..count)
        .into_par_iter()
        .map(|i| {
            // `as` saturates: NaN and negatives go to 0, the far face to the last cell.
            let q = ((aabb(i).center() - bounds.min) * scale).as_uvec3().min(UVec3::splat((1 << MORTON_BITS) - 1));
            (morton3(q) as u64) << 32 | i as u64
        })
        .collect();
    // Distinct keys (the id is in them): any sort gives this order.
    keys.radix_sort_unstable();
    keys
}

/// Interleaves the low 10 bits of each axis, x highest in each group of three.
fn morton3(q: UVec3) -> u32 {
    fn spread(v: u32) -> u32 {
        let mut v = v & 0x3ff;
        v = (v | v << 16) & 0x0300_00ff;
        v = (v | v << 8) & 0x0300_f00f;
        v = (v | v << 4) & 0x030c_30c3;
        (v | v << 2) & 0x0924_9249
    }
    spread(q.x) << 2 | spread(q.y) << 1 | spread(q.z)
}

/// The shape of the joined tree above the cells.
enum Part {
    /// A cell, built by obvhs: its index in build order.
    Cell(usize),
    /// A node made here over two to eight parts.
    Node(Vec<Part>),
}

/// Cuts `range` of the sorted keys at the octree level `level` (0 = the whole box) until
/// each piece holds at most `chunk` primitives; pushes the cells in order.
fn plan(keys: &[u64], range: Range<usize>, level: u32, chunk: usize, cells: &mut Vec<Range<usize>>) -> Part {
    if range.len() <= chunk {
        cells.push(range);
        return Part::Cell(cells.len() - 1);
    }
    let pieces: Vec<Range<usize>> = if level == MORTON_BITS {
        // Centroids this close together: cut by count.
        let step = range.len().div_ceil(8);
        range.clone().step_by(step).map(|s| s..(s + step).min(range.end)).collect()
    } else {
        let shift = 32 + 3 * (MORTON_BITS - 1 - level);
        let octant = |k: u64| (k >> shift) & 7;
        let mut pieces = Vec::new();
        let mut start = range.start;
        for o in 0..8 {
            let end = start + keys[start..range.end].partition_point(|&k| octant(k) <= o);
            if end > start {
                pieces.push(start..end);
            }
            start = end;
        }
        pieces
    };
    if pieces.len() == 1 {
        return plan(keys, range, level + 1, chunk, cells);
    }
    let next = (level + 1).min(MORTON_BITS);
    Part::Node(pieces.into_iter().map(|r| plan(keys, r, next, chunk, cells)).collect())
}

impl Part {
    fn bounds(&self, cell_boxes: &[Aabb]) -> Aabb {
        match self {
            Part::Cell(c) => cell_boxes[*c],
            Part::Node(parts) => parts.iter().fold(Aabb::empty(), |b, p| b.union(&p.bounds(cell_boxes))),
        }
    }

    /// Lays this part out: its root at node `slot`, the rest after the end of `layout`,
    /// each node's inner children contiguous in slot order, a cell's nodes (of `sizes`:
    /// nodes and primitives by cell) after its root's place, in depth-first order.
    fn lay_out(&self, slot: usize, cell_boxes: &[Aabb], sizes: &[(usize, usize)], layout: &mut Layout) {
        match self {
            Part::Cell(c) => {
                let (node_start, prim_start) = (layout.nodes, layout.primitives);
                layout.places.push(CellPlace { cell: *c, slot, node_start, prim_start });
                layout.nodes += sizes[*c].0 - 1;
                layout.primitives += sizes[*c].1;
            }
            Part::Node(parts) => {
                let boxes: Vec<Aabb> = parts.iter().map(|p| p.bounds(cell_boxes)).collect();
                let node_box = boxes.iter().fold(Aabb::empty(), |b, c| b.union(c));
                let slots = child_slots(&node_box, &boxes);
                // A node's inner children are stored contiguously, in slot order.
                let mut order: Vec<usize> = (0..parts.len()).collect();
                order.sort_unstable_by_key(|&c| slots[c]);
                let base = layout.nodes;
                layout.nodes += parts.len();
                let children: Vec<(usize, Aabb)> = order.iter().map(|&c| (slots[c], boxes[c])).collect();
                layout.inner.push((slot, inner_node(&node_box, &children, base as u32, layout.primitives as u32)));
                for (rank, &c) in order.iter().enumerate() {
                    parts[c].lay_out(base + rank, cell_boxes, sizes, layout);
                }
            }
        }
    }
}

/// The slot of each child: slot s faces the direction whose signs are s's bits (x, y, z
/// from the highest; a set bit is negative), and children are placed greedily, cheapest
/// first, where their centre lies furthest against it, as obvhs's `order_children` does,
/// so a ray's octant visits them near to far.
fn child_slots(node_box: &Aabb, boxes: &[Aabb]) -> Vec<usize> {
    let centre = node_box.center();
    let direction = |s: usize| {
        Vec3A::new(
            if s & 4 != 0 { -1.0 } else { 1.0 },
            if s & 2 != 0 { -1.0 } else { 1.0 },
            if s & 1 != 0 { -1.0 } else { 1.0 },
        )
    };
    let mut slot_of = vec![usize::MAX; boxes.len()];
    let mut filled = [false; 8];
    loop {
        let mut best: Option<(f32, usize, usize)> = None;
        for (c, b) in boxes.iter().enumerate().filter(|(c, _)| slot_of[*c] == usize::MAX) {
            let v = b.center() - centre;
            for s in (0..8).filter(|&s| !filled[s]) {
                let cost = direction(s).dot(v);
                if best.is_none_or(|(m, _, _)| cost < m) {
                    best = Some((cost, s, c));
                }
            }
        }
        let Some((_, s, c)) = best else { break };
        filled[s] = true;
        slot_of[c] = s;
    }
    slot_of
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_are_built_as_many_at_once_as_the_mesh_or_the_floor_allows() {
        // 320 bytes × 16,384 primitives a cell: 12 cells in 64 MiB.
        const CELL: usize = 1 << 14;
        assert_eq!(cell_lanes(69_451, CELL), 12, "the bunny (69 k triangles): 12 cells at once");
        assert_eq!(cell_lanes(871_306, CELL), 12, "the dragon (871 k triangles): 12 cells at once");
        assert_eq!(cell_lanes(31_366_834, CELL), 119, "31 M triangles: one lane per 16 cells' worth");
        assert_eq!(cell_lanes(10, 4), LANE_WORKSPACE_FLOOR / (CELL_BYTES_PER_PRIMITIVE * 4));
    }

    #[test]
    fn the_morton_keys_are_the_sequential_sort_on_any_number_of_threads() {
        // Boxes on a grid, so that many centroids share a Morton code, and a spread.
        let aabb = |i: usize| {
            let c = if i.is_multiple_of(3) {
                Vec3A::new((i % 17) as f32, (i % 5) as f32, 0.0)
            } else {
                Vec3A::new((i as f32 * 0.37).sin(), (i as f32 * 0.11).cos(), i as f32 * 1e-4)
            };
            Aabb::new(c, c + 0.01)
        };
        for count in [1, 2, 1000, 100_003] {
            // The one-thread reference: each key computed in turn, then a comparison sort.
            let mut bounds = Aabb::empty();
            for i in 0..count {
                bounds.extend(aabb(i).center());
            }
            let scale = (1u32 << MORTON_BITS) as f32 / (bounds.max - bounds.min).max(Vec3A::splat(f32::MIN_POSITIVE));
            let mut expected: Vec<u64> = (0..count)
                .map(|i| {
                    let q =
                        ((aabb(i).center() - bounds.min) * scale).as_uvec3().min(UVec3::splat((1 << MORTON_BITS) - 1));
                    (morton3(q) as u64) << 32 | i as u64
                })
                .collect();
            expected.sort_unstable();
            for threads in [1, 2, 3, 8] {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a thread pool");
                let keys = pool.install(|| morton_keys(count, &aabb));
                assert!(keys == expected, "{count} keys on {threads} threads");
            }
        }
    }
}
