//! The loop budget of Mesa's lavapipe: Mesa 22.3 silently ends a SIMD batch of shader
//! invocations after 65,535 loop iterations, counting every iteration any of them runs.
//! The kernel counts its traversal steps against a budget the host works out here, so that
//! a batch never reaches the cap: a traversal that would pass its budget voids its sample,
//! and the pass is rendered again with fewer samples per invocation or reported.

use super::layout::MAX_PASS_SAMPLES;
use crate::sampler::SAMPLER_LOOP_BOUND;

/// Traversal loop iterations one invocation may spend on all its rays together. Mesa
/// 22.3's lavapipe silently ends a SIMD batch of invocations after 65,535 loop
/// iterations, counting every iteration that any of them runs; a traversal that would
/// pass the budget stops and voids its sample, and the pass is rendered again with fewer
/// samples per invocation or reports [`Error::TraversalBudget`].
pub const TRAVERSAL_BUDGET: u32 = 65_000;
/// Mesa 22.3 lavapipe's loop cap per SIMD batch (`LP_MAX_TGSI_LOOP_ITERATIONS`).
pub const LAVAPIPE_LOOP_CAP: u32 = 65_535;
/// The most invocations a CPU driver runs in one SIMD batch (32-bit lanes of a 512-bit
/// vector): where the kernel cannot count a batch's iterations together (no subgroup
/// operations), each invocation's budget is that share of the batch's.
const MAX_BATCH_LANES: u32 = 16;
/// Samples an invocation renders in turn where the BVH alone cannot promise that they
/// fit the loop cap. Each dispatch reads and writes the film and adds its counters once
/// per invocation; a pass that runs out of budget is rendered again with the safe count.
/// The bunny (512², 32 spp, cosine, lavapipe) renders about 10 % faster than with one.
pub const PREFERRED_SAMPLES_PER_INVOCATION: u32 = 16;
/// Loop iterations a sample may take outside the traversal loops: its turn of the
/// kernel's sample loop, the two turns of its ray loop (camera ray, AO ray), the
/// sampler's permutation walks, and the exits of bounded loops.
const SAMPLE_LOOP_OVERHEAD: u32 = SAMPLER_LOOP_BOUND + 10;
/// Iterations of an invocation outside its samples.
const INVOCATION_LOOP_OVERHEAD: u32 = 8;
const _: () = assert!(TRAVERSAL_BUDGET + SAMPLE_LOOP_OVERHEAD + INVOCATION_LOOP_OVERHEAD <= LAVAPIPE_LOOP_CAP);

/// The traversal iterations a SIMD batch of invocations that each render `samples`
/// samples may run: what lavapipe's cap leaves after their other loops, and at most
/// [`TRAVERSAL_BUDGET`].
pub(crate) fn traversal_budget(samples: u32) -> u32 {
    let other = samples.saturating_mul(SAMPLE_LOOP_OVERHEAD).saturating_add(INVOCATION_LOOP_OVERHEAD);
    TRAVERSAL_BUDGET.min(LAVAPIPE_LOOP_CAP.saturating_sub(other))
}

/// The budget the kernel checks `steps` against in a dispatch of `samples` samples of
/// `rays` rays per invocation, a ray taking at most `ray_steps` iterations. Where that
/// worst case fits, nothing can run out: the batch's whole budget. Otherwise, with
/// `shared` steps (the kernel counts a batch's iterations together, `shaders::batch_file`) also the batch's budget, and without, each invocation's share: a batch
/// runs each of its loops as long as its longest lane, so at most min(lanes, rays ×
/// samples) times the count of its busiest invocation.
pub(crate) fn dispatch_budget(samples: u32, rays: u32, ray_steps: u64, shared: bool) -> u32 {
    let batch = traversal_budget(samples);
    let worst = samples as u64 * rays as u64 * ray_steps;
    if shared || worst <= batch as u64 { batch } else { batch / MAX_BATCH_LANES.min(rays.saturating_mul(samples)) }
}

/// How many samples one invocation can render in turn without any chance of running out
/// of budget, given `ray_steps`, the most traversal loop iterations one ray can take
/// (`GpuBvh::ray_steps` plus the planes): one sample's rays take at most `rays` ×
/// `ray_steps`, and a batch's loops as many. At least 1: a sample that alone could exceed
/// the budget is rendered one per invocation, where running out is detected and reported.
pub fn safe_samples_per_invocation(rays: u32, ray_steps: u64) -> u32 {
    let steps = rays as u64 * ray_steps;
    let mut s = 1;
    while s < MAX_PASS_SAMPLES && (s as u64 + 1) * steps <= traversal_budget(s + 1) as u64 {
        s += 1;
    }
    s
}
#[cfg(test)]
mod tests {
    use super::*;

    /// The chosen count fits: its worst-case traversal within the budget, the budget and
    /// the other loops within lavapipe's cap; one more would not fit.
    #[test]
    fn safe_samples_per_invocation_fill_the_loop_cap() {
        for (rays, ray_steps) in [(2, 3), (2, 1), (2, 9), (1, 1762), (2, 1762), (2, 60_000)] {
            let steps = rays as u64 * ray_steps;
            let s = safe_samples_per_invocation(rays, ray_steps);
            let budget = traversal_budget(s);
            assert!(
                budget as u64 + (s * SAMPLE_LOOP_OVERHEAD + INVOCATION_LOOP_OVERHEAD) as u64
                    <= LAVAPIPE_LOOP_CAP as u64
            );
            if s > 1 {
                assert!(s as u64 * steps <= budget as u64, "{s} × {steps} steps > {budget}");
            }
            if s < MAX_PASS_SAMPLES {
                assert!((s as u64 + 1) * steps > traversal_budget(s + 1) as u64, "{} would fit too", s + 1);
            }
        }
        assert_eq!(safe_samples_per_invocation(2, 60_000), 1);
        assert_eq!(traversal_budget(1), TRAVERSAL_BUDGET);
    }

    /// A batch of invocations cannot pass lavapipe's cap. With its iterations counted
    /// together, or where the worst case fits, its budget is the whole of what the cap
    /// leaves. Counted per invocation otherwise, the batch runs at most min(lanes, rays ×
    /// samples) times its busiest invocation's count, so the budget is that share.
    #[test]
    fn dispatch_budgets_keep_a_batch_within_the_cap() {
        for (samples, rays, ray_steps) in
            [(1, 2, 40_000), (16, 2, 1000), (4, 1, 9), (16, 2, 3), (3, 2, 70_000), (64, 1, 2000)]
        {
            let batch = traversal_budget(samples);
            assert_eq!(dispatch_budget(samples, rays, ray_steps, true), batch);
            let own = dispatch_budget(samples, rays, ray_steps, false);
            if samples as u64 * rays as u64 * ray_steps <= batch as u64 {
                assert_eq!(own, batch);
            } else {
                let worst = own as u64 * MAX_BATCH_LANES.min(rays * samples) as u64;
                assert!(worst <= batch as u64, "{samples} × {rays}: {worst} > {batch}");
                assert!(own > 0);
            }
        }
        assert_eq!(dispatch_budget(1, 2, 40_000, false), TRAVERSAL_BUDGET / 2);
        assert_eq!(dispatch_budget(16, 2, 3, false), traversal_budget(16));
    }
}
