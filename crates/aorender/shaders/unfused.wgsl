// Products kept apart from the sums they feed (intersect.wgsl's edge functions).

// 1.0 as the kernel reads it at run time (`Frame.one` through bindings.wgsl's
// load_constants, or a test probe's parameter); zero until the entry point sets it, so a
// kernel that forgets misses every triangle.
var<private> runtime_one: f32;

// The product a, rounded on its own: the compiler cannot drop a * runtime_one (it cannot
// know the value is 1), and a product cannot fuse into another product, so a sum of
// unfused products rounds each product as written (naga's SPIR-V has no NoContraction).
fn unfused(a: f32) -> f32 {
    return a * runtime_one;
}
