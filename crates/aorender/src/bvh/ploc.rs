//! obvhs's PLOC build, pass for pass, stopped where it stops making progress; and builds
//! that halve the Morton order where it does.
//!
//! PLOC (Meister and Bittner, "Parallel Locally-Ordered Clustering for Bounding Volume
//! Hierarchy Construction", IEEE TVCG 2018) sorts the primitives along a Morton curve and,
//! in passes, merges every pair of neighbours in that order that choose each other as
//! their cheapest partner within a window. On ordinary geometry a pass merges a fifth to
//! two thirds of the nodes, so the build takes O(log n) passes and the tree is O(log n)
//! deep. Where every partner costs the same (primitives with one box: copies of a
//! triangle) or where the boxes are nested along the curve (the fan of one large polygon:
//! every triangle's box holds the polygon's first vertex, and each lies inside the next),
//! every node prefers its neighbour on the same side, and one pair agrees per pass: the
//! build takes n passes of O(n) work and makes a chain n deep (16,384 copies of a
//! triangle: 9.6 s and 16,384 levels).
//!
//! [`build_ploc`] is obvhs 0.4's `PlocBuilder::build_ploc` (its Morton order, window,
//! tie-breaking and node order, so that the BVH of an ordinary input is obvhs's node for
//! node: `tests/bvh_degenerate.rs` compares them) with one change: it gives up at the
//! first pass over at least [`CHECKED_FROM`] nodes that merges fewer than
//! 1/[`MIN_MERGED`] of them. [`build_bvh2`] then halves the Morton order and tries again
//! on each half, down to parts that are built balanced ([`build_balanced`]), so that
//! every input gets a tree O(log n) deep in O(n log n) time.

use super::collapse::bvh2_to_cwbvh;
use super::stages::{Stage, timed};
use obvhs::BvhBuildParams;
use obvhs::aabb::Aabb;
use obvhs::bvh2::reinsertion::ReinsertionOptimizer;
use obvhs::bvh2::{Bvh2, DEFAULT_MAX_STACK_DEPTH, node::Bvh2Node};
use obvhs::cwbvh::CwBvh;
use obvhs::ploc::morton::{morton_encode_u64_unorm, morton_encode_u128_unorm};
use obvhs::ploc::{PlocSearchDistance, SortPrecision};
use rayon::prelude::*;

/// A pass must merge at least 1/`MIN_MERGED` of its nodes for the build to go on. The
/// meshes measured (bunny, dragon at four resolutions, teapot, 2CylinderEngine, every
/// preset) merge at least 0.18 of them in every pass over 256 nodes or more.
pub const MIN_MERGED: usize = 16;

/// Passes over fewer nodes are not checked: the last passes of a build merge few nodes,
/// and cost little. A chain among them is caught by the depth bound.
pub const CHECKED_FROM: usize = 256;

/// The deepest BVH2 over `n` primitives kept from PLOC: 3 ⌈log₂ n⌉ + 8 levels (the meshes
/// measured are at most 2.4 log₂ n deep).
pub fn depth_bound(n: usize) -> usize {
    3 * ceil_log2(n) + 8
}

fn ceil_log2(n: usize) -> usize {
    (usize::BITS - n.max(1).saturating_sub(1).leading_zeros()) as usize
}

/// Nodes from which a pass's search runs on rayon's threads: fewer cost less than the
/// threads' start.
const PARALLEL_FROM: usize = 4000;

fn window(d: PlocSearchDistance) -> usize {
    match d {
        PlocSearchDistance::Minimum => 1,
        PlocSearchDistance::VeryLow => 2,
        PlocSearchDistance::Low => 6,
        PlocSearchDistance::Medium => 14,
        PlocSearchDistance::High => 24,
        PlocSearchDistance::VeryHigh => 32,
    }
}

/// Leaves of `boxes` (one primitive each, primitive `i` at index `i`) in obvhs's Morton
/// order for `precision`.
pub fn sorted_leaves(boxes: &[Aabb], precision: SortPrecision) -> Vec<Bvh2Node> {
    let total = boxes.iter().fold(Aabb::empty(), |mut t, b| {
        t.extend(b.min);
        t.extend(b.max);
        t
    });
    let scale = 1.0 / total.diagonal().as_dvec3();
    let offset = -total.min.as_dvec3() * scale;
    let centre = |b: &Aabb| b.center().as_dvec3() * scale + offset;
    // obvhs sorts (code, index) pairs by code with rayon's unstable sort: the same sort
    // of the same sequence of codes puts equal codes in the same order.
    let order: Vec<u32> = match precision {
        SortPrecision::U64 => {
            let mut keys: Vec<(u64, u32)> =
                boxes.par_iter().enumerate().map(|(i, b)| (morton_encode_u64_unorm(centre(b)), i as u32)).collect();
            keys.par_sort_unstable_by_key(|k| k.0);
            keys.into_iter().map(|k| k.1).collect()
        }
        SortPrecision::U128 => {
            let mut keys: Vec<(u128, u32)> =
                boxes.par_iter().enumerate().map(|(i, b)| (morton_encode_u128_unorm(centre(b)), i as u32)).collect();
            keys.par_sort_unstable_by_key(|k| k.0);
            keys.into_iter().map(|k| k.1).collect()
        }
    };
    order.into_par_iter().map(|i| Bvh2Node::new(boxes[i as usize], 1, i)).collect()
}

/// obvhs's PLOC nodes over `leaves` (Morton-ordered, from [`sorted_leaves`]) with the
/// window and the nearest-neighbour passes of `params`: the root first, children after
/// their parents, a leaf's `first_index` its primitive. `None` at the first pass over
/// [`CHECKED_FROM`] nodes or more that merges fewer than 1/[`MIN_MERGED`] of them.
#[cfg(any(test, feature = "testing"))]
pub fn build_ploc(leaves: Vec<Bvh2Node>, params: &BvhBuildParams) -> Option<Vec<Bvh2Node>> {
    ploc_with_depth(leaves, params).map(|(nodes, _)| nodes)
}

/// [`build_ploc`] and the [`depth`] of its tree, counted as the nodes merge.
fn ploc_with_depth(leaves: Vec<Bvh2Node>, params: &BvhBuildParams) -> Option<(Vec<Bvh2Node>, usize)> {
    let n = leaves.len();
    if n == 0 {
        return Some((Vec::new(), 0));
    }
    let distance = window(params.ploc_search_distance);
    // Every slot is written once below: zeroed pages, not a fill.
    let mut nodes: Vec<Bvh2Node> = bytemuck::zeroed_vec(2 * n - 1);
    let mut insert = nodes.len();
    let mut current = leaves;
    let mut next = Vec::with_capacity(n);
    // The levels of the subtree under each node of `current`, and of `next`.
    let (mut levels, mut next_levels) = (vec![1u32; n], Vec::with_capacity(n));
    let mut merge = vec![0i8; n];
    let mut costs: Vec<f32> = Vec::new();
    let mut passes = 0;
    while current.len() > 1 {
        let count = current.len();
        let cost = |a: usize, b: usize| current[a].aabb().union(current[b].aabb()).half_area();
        if distance == 1 || passes < params.search_depth_threshold {
            // Each node against the next only: towards the cheaper of its two pairs.
            if count < PARALLEL_FROM {
                let mut last = f32::INFINITY;
                for (i, m) in merge[..count - 1].iter_mut().enumerate() {
                    let next = cost(i, i + 1);
                    *m = if last < next { -1 } else { 1 };
                    last = next;
                }
            } else {
                merge[..count - 1].par_iter_mut().enumerate().for_each(|(i, m)| {
                    let last = if i == 0 { f32::INFINITY } else { cost(i - 1, i) };
                    *m = if last < cost(i, i + 1) { -1 } else { 1 };
                });
            }
            merge[count - 1] = -1;
        } else {
            // The cost of each node with each of the `distance` after it, computed once
            // for both ends of the pair.
            costs.resize(count * distance, f32::INFINITY);
            let ahead = |(i, row): (usize, &mut [f32])| {
                for (k, c) in row.iter_mut().enumerate() {
                    *c = if i + k + 1 < count { cost(i, i + k + 1) } else { f32::INFINITY };
                }
            };
            if count < PARALLEL_FROM {
                costs.chunks_mut(distance).enumerate().for_each(ahead);
            } else {
                costs.par_chunks_mut(distance).enumerate().for_each(ahead);
            }
            // The cheapest partner within the window, of equal costs the last.
            let costs = &costs;
            let pick = |(i, m): (usize, &mut i8)| {
                let mut best = (f32::INFINITY, i);
                for other in i.saturating_sub(distance)..i {
                    let c = costs[other * distance + (i - other - 1)];
                    if c <= best.0 {
                        best = (c, other);
                    }
                }
                for (k, &c) in costs[i * distance..(i + 1) * distance].iter().enumerate() {
                    if i + k + 1 < count && c <= best.0 {
                        best = (c, i + k + 1);
                    }
                }
                *m = (best.1 as i64 - i as i64) as i8;
            };
            if count < PARALLEL_FROM {
                merge[..count].iter_mut().enumerate().for_each(pick);
            } else {
                merge[..count].par_iter_mut().enumerate().for_each(pick);
            }
        }
        // Nodes that chose each other merge; the parent takes the first one's place.
        let mut merged = 0;
        for index in 0..count {
            let best = (index as i64 + merge[index] as i64) as usize;
            if best as i64 + merge[best] as i64 != index as i64 {
                next.push(current[index]);
                next_levels.push(levels[index]);
                continue;
            }
            if best > index {
                continue;
            }
            let (left, right) = (current[index], current[best]);
            insert -= 2;
            nodes[insert] = left;
            nodes[insert + 1] = right;
            next.push(Bvh2Node::new(left.aabb().union(right.aabb()), 0, insert as u32));
            next_levels.push(levels[index].max(levels[best]) + 1);
            merged += 2;
        }
        if count >= CHECKED_FROM && merged * MIN_MERGED < count {
            return None;
        }
        std::mem::swap(&mut current, &mut next);
        std::mem::swap(&mut levels, &mut next_levels);
        next.clear();
        next_levels.clear();
        passes += 1;
    }
    debug_assert_eq!(insert, 1);
    nodes[0] = current[0];
    Some((nodes, levels[0] as usize))
}

/// Nodes over `leaves` that halve their order at every node (⌈log₂ n⌉ + 1 levels, a
/// primitive a leaf), root first, children after their parents.
pub fn build_balanced(leaves: &[Bvh2Node]) -> Vec<Bvh2Node> {
    let mut nodes = Vec::with_capacity((2 * leaves.len()).saturating_sub(1));
    if !leaves.is_empty() {
        nodes.push(Bvh2Node::default());
        balanced_into(leaves, 0, &mut nodes);
    }
    nodes
}

/// Writes the balanced tree over `leaves` into `nodes[slot]` and after the end.
fn balanced_into(leaves: &[Bvh2Node], slot: usize, nodes: &mut Vec<Bvh2Node>) {
    // (slot, range of leaves); a node's two children are appended together.
    let mut work = vec![(slot, 0..leaves.len())];
    let mut inner = Vec::new();
    while let Some((slot, range)) = work.pop() {
        if range.len() == 1 {
            nodes[slot] = leaves[range.start];
            continue;
        }
        let mid = range.start + range.len() / 2;
        let first = nodes.len();
        nodes.extend([Bvh2Node::default(); 2]);
        nodes[slot] = Bvh2Node::new(Aabb::empty(), 0, first as u32);
        inner.push(slot);
        work.push((first + 1, mid..range.end));
        work.push((first, range.start..mid));
    }
    // Children come after their parents: the boxes, from the last inner node back.
    for &i in inner.iter().rev() {
        let c = nodes[i].first_index as usize;
        nodes[i] = Bvh2Node::new(nodes[c].aabb().union(nodes[c + 1].aabb()), 0, c as u32);
    }
}

/// Nodes over `leaves` (Morton-ordered): obvhs's PLOC where it progresses and stays
/// within [`depth_bound`], else built in parts ([`split_into`]).
fn build_parts(leaves: &[Bvh2Node], params: &BvhBuildParams, slot: usize, nodes: &mut Vec<Bvh2Node>) {
    match ploc_with_depth(leaves.to_vec(), params).filter(|(_, d)| *d <= depth_bound(leaves.len())) {
        Some((part, _)) => attach(&part, slot, nodes),
        None => split_into(leaves, params, slot, nodes),
    }
}

/// The two halves of `leaves` under one node, each built by [`build_parts`]; a part too
/// small for PLOC to be checked on is built balanced.
fn split_into(leaves: &[Bvh2Node], params: &BvhBuildParams, slot: usize, nodes: &mut Vec<Bvh2Node>) {
    let n = leaves.len();
    if n < 2 * CHECKED_FROM {
        return balanced_into(leaves, slot, nodes);
    }
    let first = nodes.len();
    nodes.extend([Bvh2Node::default(); 2]);
    build_parts(&leaves[..n / 2], params, first, nodes);
    build_parts(&leaves[n / 2..], params, first + 1, nodes);
    nodes[slot] = Bvh2Node::new(nodes[first].aabb().union(nodes[first + 1].aabb()), 0, first as u32);
}

/// Puts `part` (root first) into `nodes[slot]` and its other nodes after the end.
fn attach(part: &[Bvh2Node], slot: usize, nodes: &mut Vec<Bvh2Node>) {
    // Node j > 0 of the part goes to base + j.
    let base = nodes.len() as u32 - 1;
    nodes[slot] = moved(&part[0], base);
    nodes.extend(part[1..].iter().map(|n| moved(n, base)));
}

/// `n` with its children `base` further on (a leaf, whose index is its primitive's, as it is).
fn moved(n: &Bvh2Node, base: u32) -> Bvh2Node {
    let mut n = *n;
    if n.prim_count == 0 {
        n.first_index += base;
    }
    n
}

/// Levels of the tree of `nodes` (root first): 1 for a single leaf, 0 for none.
pub fn depth(nodes: &[Bvh2Node]) -> usize {
    if nodes.is_empty() {
        return 0;
    }
    let mut deepest = 0;
    let mut stack = vec![(0usize, 1usize)];
    while let Some((i, d)) = stack.pop() {
        deepest = deepest.max(d);
        let n = &nodes[i];
        if n.prim_count == 0 {
            stack.push((n.first_index as usize, d + 1));
            stack.push((n.first_index as usize + 1, d + 1));
        }
    }
    deepest
}

/// How a BVH2 was built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Built {
    /// By obvhs's PLOC, whole: node for node obvhs's tree.
    Ploc,
    /// In parts under halves of the Morton order: PLOC stopped, or its tree was too deep.
    Parts,
}

/// A BVH2 over `boxes` (primitive `i` at index `i`): with `whole`, obvhs's PLOC tree
/// where it progresses and is at most [`depth_bound`] deep; else, or without `whole`,
/// built in parts, which is at most [`depth_bound`] deep.
pub fn build_bvh2(boxes: &[Aabb], params: &BvhBuildParams, whole: bool) -> (Bvh2, Built) {
    let n = boxes.len();
    if whole {
        let leaves = timed(Stage::Leaves, || sorted_leaves(boxes, params.sort_precision));
        let tree = timed(Stage::Ploc, || ploc_with_depth(leaves, params).filter(|(_, d)| *d <= depth_bound(n)));
        if let Some((nodes, depth)) = tree {
            return (bvh2_of_depth(n, nodes, depth), Built::Ploc);
        }
    }
    let leaves = sorted_leaves(boxes, params.sort_precision);
    let mut nodes = Vec::with_capacity((2 * n).saturating_sub(1));
    if n > 0 {
        nodes.push(Bvh2Node::default());
        split_into(&leaves, params, 0, &mut nodes);
    }
    (bvh2(n, nodes), Built::Parts)
}

/// A balanced BVH2 over `boxes` ([`build_balanced`] of their Morton order).
pub fn build_balanced_bvh2(boxes: &[Aabb], precision: SortPrecision) -> Bvh2 {
    bvh2(boxes.len(), build_balanced(&sorted_leaves(boxes, precision)))
}

/// obvhs's `Bvh2` of `nodes` over `n` primitives whose leaves index them directly.
fn bvh2(n: usize, nodes: Vec<Bvh2Node>) -> Bvh2 {
    let depth = depth(&nodes);
    bvh2_of_depth(n, nodes, depth)
}

/// [`bvh2`] of `nodes` whose [`depth`] is `depth`.
fn bvh2_of_depth(n: usize, nodes: Vec<Bvh2Node>, depth: usize) -> Bvh2 {
    Bvh2 {
        nodes,
        primitive_indices: (0..n as u32).collect(),
        children_are_ordered_after_parents: true,
        max_depth: DEFAULT_MAX_STACK_DEPTH.max(depth + 1),
        ..Bvh2::default()
    }
}

/// The deepest CWBVH over `n` primitives kept from [`build_bvh2`]: 2 ⌈log₂ n / 3⌉ + 3
/// levels (twice a full 8-wide tree's, plus 3; the meshes measured take at most
/// 1.3 ⌈log₂ n / 3⌉ + 4).
pub fn cwbvh_depth_bound(n: usize) -> u32 {
    2 * ceil_log2(n).div_ceil(3) as u32 + 3
}

/// Levels of a CWBVH: the depth of its deepest inner node, the root 1.
pub fn cwbvh_depth(bvh: &CwBvh) -> u32 {
    // A node's inner children are stored contiguously from child_base_idx.
    let mut depth = 0;
    let mut stack = vec![(0usize, 1u32)];
    while let Some((i, d)) = stack.pop() {
        depth = depth.max(d);
        let n = &bvh.nodes[i];
        for k in 0..n.imask.count_ones() as usize {
            stack.push((n.child_base_idx as usize + k, d + 1));
        }
    }
    depth
}

/// obvhs's CWBVH over `boxes` (`obvhs::cwbvh::builder::build_cwbvh`: PLOC, reinsertion,
/// conversion with up to three primitives a leaf), node for node on an ordinary input; on
/// one where PLOC stops or makes a tree too deep, the BVH2 built in parts, not reinserted
/// (reinsertion can deepen it again), then converted; and if that CWBVH is deeper than
/// [`cwbvh_depth_bound`], the balanced one's.
pub fn cwbvh_over(boxes: &[Aabb], params: &BvhBuildParams) -> CwBvh {
    let leaf = params.max_prims_per_leaf.clamp(1, 3);
    let (mut bvh2, built) = build_bvh2(boxes, params, true);
    if built == Built::Ploc {
        timed(Stage::Reinsertion, || {
            ReinsertionOptimizer::default().run(&mut bvh2, params.reinsertion_batch_ratio, None)
        });
    }
    let bvh = timed(Stage::Collapse, || bvh2_to_cwbvh(&bvh2, leaf));
    if cwbvh_depth(&bvh) <= cwbvh_depth_bound(boxes.len()) {
        return bvh;
    }
    drop(bvh2);
    bvh2_to_cwbvh(&build_balanced_bvh2(boxes, params.sort_precision), leaf)
}

/// obvhs's BVH2 over `boxes` (`obvhs::bvh2::builder::build_bvh2`: PLOC, reinsertion, leaf
/// collapse, reinsertion), node for node on an ordinary input; on one where PLOC stops or
/// makes a tree too deep, or reinsertion deepens it past [`depth_bound`], the BVH2 built
/// in parts, its leaves collapsed.
pub fn bvh2_over(boxes: &[Aabb], params: &BvhBuildParams) -> Bvh2 {
    let collapse = |bvh: &mut Bvh2| {
        obvhs::bvh2::leaf_collapser::collapse(
            bvh,
            params.max_prims_per_leaf.clamp(1, 255),
            params.collapse_traversal_cost,
        )
    };
    let (mut bvh, built) = build_bvh2(boxes, params, true);
    if built == Built::Ploc {
        let mut reinsertion = ReinsertionOptimizer::default();
        reinsertion.run(&mut bvh, params.reinsertion_batch_ratio, None);
        collapse(&mut bvh);
        let ratio = params.reinsertion_batch_ratio * params.post_collapse_reinsertion_batch_ratio_multiplier;
        reinsertion.run(&mut bvh, ratio, None);
        if depth(&bvh.nodes) <= depth_bound(boxes.len()) {
            return bvh;
        }
        bvh = build_bvh2(boxes, params, false).0;
    }
    collapse(&mut bvh);
    bvh
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3A;

    /// `n` boxes from a fixed random sequence, some of them copies of others.
    fn boxes(n: usize) -> Vec<Aabb> {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut uniform = move || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        let mut out: Vec<Aabb> = Vec::with_capacity(n);
        for i in 0..n {
            if i % 7 == 3 {
                out.push(out[i / 2]);
                continue;
            }
            let c = Vec3A::new(uniform(), uniform(), uniform());
            out.push(Aabb::new(c, c + Vec3A::new(uniform(), uniform(), uniform()) * 0.05));
        }
        out
    }

    #[test]
    fn the_depth_counted_while_merging_is_the_trees() {
        // Across the checked size and the threads' threshold, for every window.
        for n in [1, 2, 3, 255, 256, 257, PARALLEL_FROM - 1, PARALLEL_FROM + 1, 20_000] {
            for params in
                [BvhBuildParams::fastest_build(), BvhBuildParams::medium_build(), BvhBuildParams::slow_build()]
            {
                let leaves = sorted_leaves(&boxes(n), params.sort_precision);
                let (nodes, levels) = ploc_with_depth(leaves, &params).expect("random boxes merge");
                assert_eq!(nodes.len(), 2 * n - 1);
                assert_eq!(levels, depth(&nodes), "{n} boxes");
            }
        }
    }
}
