// Resources of the AO kernel. The structs and bindings are generated from src/gpu/layout.rs
// (the header and resources.wgsl); this file adds the private copies the functions read.
//#import resources.wgsl
//#import exact.wgsl

// Every binding is a storage buffer, none a uniform buffer: Mesa's lavapipe (22.x) inlines
// the uniform-buffer values a shader branches on and recompiles the kernel each time a
// bind group is set, which is every dispatch here (7 ms and 1.2 MB that is never freed,
// per dispatch). tests/shaders.rs keeps uniform buffers out.

// Private copies of frame_binding and dispatch_binding, which every function reads:
// lavapipe reads a storage buffer one lane at a time even where the address is the same
// for all, and the traversal checks its budget at every step. Each entry point calls
// load_constants first.
var<private> frame: Frame;
var<private> dispatch: Dispatch;

fn load_constants() {
    frame = frame_binding;
    dispatch = dispatch_binding;
    opaque_zero = frame.zero;
}
// Bindings 2 and 3, and 8 and up, hold the BVH nodes and the primitives, split into
// chunks that each fit one binding: the composer generates them with load_node and
// load_primitive (src/gpu/shaders.rs, node_bindings.wgsl and primitive_bindings.wgsl).
