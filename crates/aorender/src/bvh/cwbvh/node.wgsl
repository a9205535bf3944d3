//#import lanes.wgsl
// The decoder of obvhs's compressed 8-wide BVH node (Ylitie, Karras & Laine, "Efficient
// Incoherent Ray Traversal on GPUs Through Compressed Wide BVHs", HPG 2017), beside its
// Rust side (mod.rs: CwNodeWords gives the five words, `placed` moves a node's indices to
// its place in the upload): a node's children tested against a ray, their hit bits and the
// nodes and primitives those name. tests/cwbvh_node.rs runs it on the adapter and
// compares every child's box and indices with obvhs's.

// CwNode, obvhs's CwBvhNode as five vec4u words, comes with the generated header.

// The octants a ray's direction runs toward, inverted, in each byte: what a node's child
// metadata is XORed with so that its children come out nearest first.
fn octant_inverse4(d: vec3f) -> u32 {
    return select(0x04040404u, 0u, d.x < 0.0) | select(0x02020202u, 0u, d.y < 0.0)
        | select(0x01010101u, 0u, d.z < 0.0);
}

// max(a, b) and min(a, b). On a CPU adapter as a comparison and a select, which x86
// does in one instruction (maxps, minps), and which gives b where either is NaN;
// lavapipe's max and min add a NaN check and a blend to each.
fn fmax_cpu(a: f32, b: f32) -> f32 {
    if (CPU_LANES) {
        return select(b, a, a > b);
    }
    return max(a, b);
}

fn fmin_cpu(a: f32, b: f32) -> f32 {
    if (CPU_LANES) {
        return select(b, a, a < b);
    }
    return min(a, b);
}

fn byte_at(word: u32, shift: u32) -> f32 {
    return f32((word >> shift) & 0xffu);
}

// The planes of the child whose bytes are at `shift` of `words` (one word per axis), in
// units of t: byte × scale + origin on each axis (the byte times a power of two is exact).
fn child_planes(words: vec3u, shift: u32, scale: vec3f, origin: vec3f) -> vec3f {
    return vec3f(byte_at(words.x, shift), byte_at(words.y, shift), byte_at(words.z, shift)) * scale + origin;
}

// A node's frame for a ray: the planes' scale and origin in units of t (a child's byte b
// on axis a lies at t = b × scale.a + origin.a), and the axes the ray runs toward -axis on.
struct NodeFrame {
    scale: vec3f,
    origin: vec3f,
    neg: vec3<bool>,
}

fn node_frame(n0: vec4u, o: vec3f, inv_d: vec3f) -> NodeFrame {
    let p = bitcast<vec3f>(n0.xyz);
    let e = (vec3u(n0.w, n0.w >> 8u, n0.w >> 16u) & vec3u(0xffu)) << vec3u(23u);
    return NodeFrame(bitcast<vec3f>(e) * inv_d, (p - o) * inv_d, inv_d < vec3f(0.0));
}

// Hit bits of the child whose bytes are at `shift` (0, 8, 16 or 24) of the words of four
// children: their meta bytes, and the low and high planes' bytes on each axis. For an
// inner child one bit at 24 + its traversal priority, for a leaf its primitives' unary
// count at their offset (obvhs's CwBvhNode::intersect_ray).
fn child_hit4(
    meta4: u32, lo: vec3u, hi: vec3u, nf: NodeFrame, oct_inv4: u32, t_max: f32, shift: u32,
) -> u32 {
    let is_inner4 = (meta4 & (meta4 << 1u)) & 0x10101010u;
    let inner_mask4 = (is_inner4 >> 4u) * 0xffu;
    let bit_index4 = (meta4 ^ (oct_inv4 & inner_mask4)) & 0x1f1f1f1fu;
    let child_bits4 = (meta4 >> 5u) & 0x07070707u;
    // Near and far planes swap where the ray runs toward -axis.
    let near = select(lo, hi, nf.neg);
    let far = select(hi, lo, nf.neg);
    return child_hit(near, far, shift, nf.scale, nf.origin, t_max, child_bits4, bit_index4);
}

// Hit bits of the four children whose bytes are in the given words.
fn intersect_children4(meta4: u32, lo: vec3u, hi: vec3u, nf: NodeFrame, oct_inv4: u32, t_max: f32) -> u32 {
    // Unrolled by hand: a loop here would count against lavapipe's iteration cap.
    return child_hit4(meta4, lo, hi, nf, oct_inv4, t_max, 0u)
        | child_hit4(meta4, lo, hi, nf, oct_inv4, t_max, 8u)
        | child_hit4(meta4, lo, hi, nf, oct_inv4, t_max, 16u)
        | child_hit4(meta4, lo, hi, nf, oct_inv4, t_max, 24u);
}

fn child_hit(
    near: vec3u, far: vec3u, shift: u32, scale: vec3f, origin: vec3f, t_max: f32,
    child_bits4: u32, bit_index4: u32,
) -> u32 {
    let tn3 = child_planes(near, shift, scale, origin);
    let tf3 = child_planes(far, shift, scale, origin);
    // On a CPU adapter a NaN plane distance (an overflowed scale times a zero byte)
    // cannot make tn or tf NaN, as the last operands, 0 and t_max, are not: it only
    // loosens the test.
    let tn = fmax_cpu(fmax_cpu(tn3.x, tn3.y), fmax_cpu(tn3.z, 0.0));
    // Widened as in intersect_box.
    let tf = fmin_cpu(fmin_cpu(tf3.x, tf3.y), fmin_cpu(tf3.z, t_max)) * BOX_EXIT_WIDENING;
    if (tn <= tf) {
        return ((child_bits4 >> shift) & 0xffu) << ((bit_index4 >> shift) & 0xffu);
    }
    return 0u;
}

// The words that hold child `slot`'s bytes (0..8, as the node stores them): its metadata
// and its low and high planes on each axis, and where in them its bytes are.
struct ChildWords {
    meta4: u32,
    lo: vec3u,
    hi: vec3u,
    shift: u32,
}

fn child_words(n1: vec4u, n2: vec4u, n3: vec4u, n4: vec4u, slot: u32) -> ChildWords {
    let upper = slot >= 4u;
    let meta4 = select(n1.z, n1.w, upper);
    let lo = select(vec3u(n2.x, n3.x, n4.x), vec3u(n2.y, n3.y, n4.y), upper);
    let hi = select(vec3u(n2.z, n3.z, n4.z), vec3u(n2.w, n3.w, n4.w), upper);
    return ChildWords(meta4, lo, hi, (slot % 4u) * 8u);
}

fn intersect_node(node: CwNode, o: vec3f, inv_d: vec3f, oct_inv4: u32, t_max: f32) -> u32 {
    let nf = node_frame(node.n0, o, inv_d);
    let lo_a = vec3u(node.n2.x, node.n3.x, node.n4.x);
    let lo_b = vec3u(node.n2.y, node.n3.y, node.n4.y);
    let hi_a = vec3u(node.n2.z, node.n3.z, node.n4.z);
    let hi_b = vec3u(node.n2.w, node.n3.w, node.n4.w);
    return intersect_children4(node.n1.z, lo_a, hi_a, nf, oct_inv4, t_max)
        | intersect_children4(node.n1.w, lo_b, hi_b, nf, oct_inv4, t_max);
}

// The node index of inner child `slot` (0..8, as the node stores them) of a node whose
// first child is `first_child` and whose inner children are the bits of `imask`: its
// inner children are stored in slot order.
fn child_node_index(first_child: u32, imask: u32, slot: u32) -> u32 {
    return first_child + countOneBits(imask & ~(0xffffffffu << slot));
}
