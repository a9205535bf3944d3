//! obvhs 0.4's BVH2 → CWBVH conversion (`obvhs::cwbvh::bvh2_to_cwbvh`), decision for
//! decision and node for node, with less work around the same arithmetic.
//!
//! The conversion (Ylitie, Karras and Laine 2017) fills a table of seven decisions a BVH2
//! node (the cheapest way to make it a leaf, an 8-wide node, or up to seven children of
//! one) bottom-up, then walks it down from the root, making each 8-wide node and ordering
//! its children by the direction of their centres. obvhs fills its table with a default
//! before the walk overwrites every entry (one pass over 56 bytes a node), holds each
//! decision's cost beside its kind (so the inner loops, which read costs only, read twice
//! the bytes) and computes each child's centre eight times when ordering children. Here
//! the table starts as zeroed pages, costs and choices are kept apart, and a centre is
//! computed once; every cost, comparison and node field is obvhs's, in its order, so the
//! CWBVH is the same, bit for bit (`tests/bvh_collapse.rs` compares them).

use super::cwbvh::{node_frame, set_child_box};
use glam::Vec3A;
use obvhs::bvh2::Bvh2;
use obvhs::cwbvh::{CwBvh, node::CwBvhNode};

/// obvhs's cost of a primitive in a leaf, relative to a node's (its `PRIM_COST`).
const PRIM_COST: f32 = 0.3;

/// An empty child slot.
const INVALID: u32 = u32::MAX;

/// No choice made (obvhs's `INVALID` of a distribution).
const NONE: u8 = u8::MAX;

/// What a decision makes of a node: a leaf of its primitives, an 8-wide node, or children
/// handed to the node above.
const LEAF: u8 = 0;
const INTERNAL: u8 = 1;
const DISTRIBUTE: u8 = 2;

/// The directions of the eight child slots: slot s faces the octant whose signs are its
/// bits (x, y, z from the highest; a set bit is negative).
const DIRECTIONS: [Vec3A; 8] = [
    Vec3A::new(1.0, 1.0, 1.0),
    Vec3A::new(1.0, 1.0, -1.0),
    Vec3A::new(1.0, -1.0, 1.0),
    Vec3A::new(1.0, -1.0, -1.0),
    Vec3A::new(-1.0, 1.0, 1.0),
    Vec3A::new(-1.0, 1.0, -1.0),
    Vec3A::new(-1.0, -1.0, 1.0),
    Vec3A::new(-1.0, -1.0, -1.0),
];

/// The conversion of one BVH2: its decision table and the CWBVH made so far.
struct Converter<'a> {
    bvh2: &'a Bvh2,
    nodes: Vec<CwBvhNode>,
    primitive_indices: Vec<u32>,
    /// Seven costs a BVH2 node: of it given to a parent with up to 1..=7 slots.
    costs: Vec<f32>,
    /// For each cost: its kind ([`LEAF`], [`INTERNAL`], [`DISTRIBUTE`]) and the slots it
    /// gives its left and right children.
    choices: Vec<[u8; 3]>,
}

/// obvhs's CWBVH of `bvh2` (leaves of one primitive each) with at most `max_prims_per_leaf`
/// (1 to 3) primitives a leaf and children ordered by direction:
/// `bvh2_to_cwbvh(bvh2, max_prims_per_leaf, true, false)`, bit for bit.
pub fn bvh2_to_cwbvh(bvh2: &Bvh2, max_prims_per_leaf: u32) -> CwBvh {
    if bvh2.nodes.is_empty() {
        return CwBvh::default();
    }
    let count = bvh2.primitive_indices.len();
    let mut nodes = Vec::with_capacity(count);
    nodes.push(CwBvhNode::default());
    let mut converter = Converter {
        bvh2,
        nodes,
        primitive_indices: Vec::with_capacity(count),
        // Every entry is written before it is read: zeroed pages, not a fill.
        costs: vec![0.0; bvh2.nodes.len() * 7],
        choices: vec![[0; 3]; bvh2.nodes.len() * 7],
    };
    converter.cost(0, max_prims_per_leaf);
    converter.convert(0, 0);
    CwBvh {
        nodes: converter.nodes,
        primitive_indices: converter.primitive_indices,
        total_aabb: *bvh2.nodes[0].aabb(),
        exact_node_aabbs: None,
        uses_spatial_splits: bvh2.uses_spatial_splits,
    }
}

impl Converter<'_> {
    /// Fills the seven decisions of node `index` and those below it; returns the
    /// primitives below it (obvhs's `calculate_cost_impl`).
    fn cost(&mut self, index: usize, max_prims_per_leaf: u32) -> u32 {
        let node = &self.bvh2.nodes[index];
        let half_area = node.aabb().half_area();
        let (first, prim_count) = (node.first_index as usize, node.prim_count);
        let row = index * 7;
        if prim_count != 0 {
            assert_eq!(prim_count, 1, "the conversion takes a BVH2 of one primitive a leaf");
            let cost_leaf = half_area * (prim_count as f32) * PRIM_COST;
            self.costs[row..row + 7].fill(cost_leaf);
            for choice in &mut self.choices[row..row + 7] {
                choice[0] = LEAF;
            }
            return prim_count;
        }
        let primitives = self.cost(first, max_prims_per_leaf) + self.cost(first + 1, max_prims_per_leaf);
        let (left, right) = (first * 7, (first + 1) * 7);
        // One slot: a leaf, or an 8-wide node over the children's best split of 7 slots.
        let cost_leaf =
            if primitives <= max_prims_per_leaf { (primitives as f32) * half_area * PRIM_COST } else { f32::INFINITY };
        let mut cost_distribute = f32::INFINITY;
        let (mut to_left, mut to_right) = (NONE, NONE);
        for k in 0..7 {
            let c = self.costs[left + k] + self.costs[right + 6 - k];
            if c < cost_distribute {
                cost_distribute = c;
                (to_left, to_right) = (k as u8, 6 - k as u8);
            }
        }
        let cost_internal = cost_distribute + half_area;
        let (kind, cost) = if cost_leaf < cost_internal { (LEAF, cost_leaf) } else { (INTERNAL, cost_internal) };
        self.costs[row] = cost;
        self.choices[row] = [kind, to_left, to_right];
        // i + 1 slots: the best of i slots, or the children's split of them.
        for i in 1..7 {
            let mut cost_distribute = self.costs[row + i - 1];
            let (mut to_left, mut to_right) = (NONE, NONE);
            for k in 0..i {
                let c = self.costs[left + k] + self.costs[right + i - k - 1];
                if c < cost_distribute {
                    cost_distribute = c;
                    (to_left, to_right) = (k as u8, i as u8 - k as u8 - 1);
                }
            }
            self.costs[row + i] = cost_distribute;
            self.choices[row + i] =
                if to_left != NONE { [DISTRIBUTE, to_left, to_right] } else { self.choices[row + i - 1] };
        }
        primitives
    }

    /// Makes CWBVH node `at` of BVH2 node `index`, then its inner children (obvhs's
    /// `convert_to_cwbvh_impl`).
    fn convert(&mut self, at: usize, index: usize) {
        let mut node = self.nodes[at];
        let aabb = self.bvh2.nodes[index].aabb();
        let (p, e, rcp_e) = node_frame(aabb);
        node.p = p.into();
        node.e = e;

        let mut children = [INVALID; 8];
        let mut child_count = 0;
        self.children(index, &mut children, &mut child_count, 0);
        self.order_children(index, &mut children, child_count);

        node.imask = 0;
        node.primitive_base_idx = self.primitive_indices.len() as u32;
        node.child_base_idx = self.nodes.len() as u32;
        let mut inner = 0;
        let mut primitives = 0u32;
        for (i, &child) in children.iter().enumerate() {
            if child == INVALID {
                continue;
            }
            set_child_box(&mut node, i, self.bvh2.nodes[child as usize].aabb(), p, rcp_e);
            if self.choices[child as usize * 7][0] == LEAF {
                let count = self.push_primitives(child as usize);
                // The three highest bits hold the primitive count in unary.
                node.child_meta[i] = primitives as u8
                    | match count {
                        1 => 0b0010_0000,
                        2 => 0b0110_0000,
                        3 => 0b1110_0000,
                        _ => panic!("a CWBVH leaf of {count} primitives"),
                    };
                primitives += count;
            } else {
                node.imask |= 1 << i;
                node.child_meta[i] = (24 + i as u8) | 0b0010_0000;
                inner += 1;
            }
        }
        self.nodes.resize(self.nodes.len() + inner, CwBvhNode::default());
        self.nodes[at] = node;
        let mut offset = 0;
        for (i, &child) in children.iter().enumerate() {
            if child != INVALID && node.imask & (1 << i) != 0 {
                self.convert(node.child_base_idx as usize + offset, child as usize);
                offset += 1;
            }
        }
    }

    /// Appends the primitives under BVH2 node `index`, left to right; returns how many
    /// (obvhs's `count_primitives`).
    fn push_primitives(&mut self, index: usize) -> u32 {
        let node = self.bvh2.nodes[index];
        if node.is_leaf() {
            self.primitive_indices.push(self.bvh2.primitive_indices[node.first_index as usize]);
            return node.prim_count;
        }
        self.push_primitives(node.first_index as usize) + self.push_primitives(node.first_index as usize + 1)
    }

    /// The children of the 8-wide node made of BVH2 node `index` given `slots` − 1
    /// (obvhs's `get_children`).
    fn children(&self, index: usize, children: &mut [u32; 8], count: &mut usize, slots: usize) {
        let node = &self.bvh2.nodes[index];
        if node.is_leaf() {
            children[*count] = index as u32;
            *count += 1;
            return;
        }
        let [_, to_left, to_right] = self.choices[index * 7 + slots];
        let first = node.first_index as usize;
        for (child, to) in [(first, to_left), (first + 1, to_right)] {
            if self.choices[child * 7 + to as usize][0] == DISTRIBUTE {
                self.children(child, children, count, to as usize);
            } else {
                children[*count] = child as u32;
                *count += 1;
            }
        }
    }

    /// Puts each child in the slot that faces the way its centre lies from the node's,
    /// greedily, cheapest first (obvhs's `order_children`).
    fn order_children(&self, index: usize, children: &mut [u32; 8], count: usize) {
        let p = self.bvh2.nodes[index].aabb().center();
        let mut cost = [[f32::MAX; 8]; 8];
        for (c, row) in cost.iter_mut().enumerate().take(count) {
            let v = self.bvh2.nodes[children[c] as usize].aabb().center() - p;
            for (slot, d) in row.iter_mut().zip(DIRECTIONS) {
                *slot = d.dot(v);
            }
        }
        let mut assignment = [usize::MAX; 8];
        let mut filled = [false; 8];
        loop {
            let (mut min_cost, mut min_slot, mut min_child) = (f32::MAX, usize::MAX, usize::MAX);
            for c in (0..count).filter(|&c| assignment[c] == usize::MAX) {
                for (s, &taken) in filled.iter().enumerate() {
                    if !taken && cost[c][s] < min_cost {
                        (min_cost, min_slot, min_child) = (cost[c][s], s, c);
                    }
                }
            }
            if min_slot == usize::MAX {
                break;
            }
            filled[min_slot] = true;
            assignment[min_child] = min_slot;
        }
        let original = std::mem::replace(children, [INVALID; 8]);
        for (&slot, &child) in assignment.iter().zip(&original).take(count) {
            children[slot] = child;
        }
    }
}
