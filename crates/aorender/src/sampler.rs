//! Point samplers: where the 2-D numbers of each sample dimension fall in [0,1)².
//!
//! A sample consumes two dimensions of two numbers each: the pixel jitter (dimension 0)
//! and the hemisphere direction (dimension 1). Every sampler is
//! a pure function of (pixel, sample index, seed, sample count), so a render is
//! reproducible and any range of sample indices can be rendered on its own. Every
//! function here has a twin of the same name in `shaders/sampler.wgsl`.
//!
//! - `independent`: each number uniform and independent of the others.
//! - `stratified`: the square is cut into n×n cells, n = ⌊√spp⌋; each block of n²
//!   consecutive sample indices visits every cell once, in a random order (Kensler's
//!   hashed permutation), jittered inside the cell. Each sample on its own is uniform, so
//!   the estimate is unbiased for any sample count, even one that stops inside a block;
//!   complete blocks get the variance reduction of stratification.
//! - `grid`: the same cells, at their midpoints: the Riemann sum, biased on purpose.
//! - `sobol`: the 2-D Sobol (0,2)-sequence with hash-based Owen scrambling and a shuffled
//!   index (Burley, "Practical Hash-based Owen Scrambling", JCGT 2020). Each dimension
//!   has its own index shuffle and scramble, seeded per pixel, so pixels and dimensions
//!   are decorrelated. Unbiased for any count; best at powers of two.
//!
//! Replicates. The samples of a pixel are cut into replicates of consecutive indices,
//! each an independent randomisation of the point set (randomised quasi-Monte Carlo:
//! Owen, "Monte Carlo theory, methods and examples", ch. 17; L'Ecuyer, "Randomized
//! quasi-Monte Carlo: an introduction for practitioners", 2018). The spread of the
//! replicates' means is an unbiased estimate of the variance of their mean whatever the
//! point set does inside a replicate, which the spread of single samples is not for
//! stratified or Sobol points. `independent` samples are replicates of one sample each;
//! a `stratified` replicate is one block of n² cells; a `sobol` replicate of size
//! 2^m is the first 2^m points of a sequence scrambled and shuffled anew for it.
//! Replicate size 0 is one sequence for all the samples (the best point set, with no
//! valid error estimate); `grid` has no randomness to replicate.

use crate::sampling::{pcg4d, sample_uniforms, u32_to_unit_float};
use glam::UVec4;

/// Most cycle-walking steps of [`permute`]; each step leaves the permutation's range
/// with probability below one half, so the bound is reached with probability below 2⁻³².
pub const PERMUTE_WALK_LIMIT: u32 = 32;
/// Loop iterations one sample's numbers may take on the GPU (two dimensions of
/// [`permute`]); counted against lavapipe's per-invocation loop cap with the traversal.
pub const SAMPLER_LOOP_BOUND: u32 = 2 * PERMUTE_WALK_LIMIT;

/// The largest replicate: the exact accumulation's block ([`crate::film::BLOCK_SAMPLES`]),
/// so that replicates nest in blocks.
pub const MAX_REPLICATE_SAMPLES: u32 = crate::film::BLOCK_SAMPLES;
/// The largest `f32` below one.
pub const ONE_MINUS_EPSILON: f32 = 1.0 - f32::EPSILON / 2.0;

/// Salts that keep the hashes of different uses of one (pixel, seed) apart.
pub(crate) const STRATA_SALT: u32 = 0x5772_a7a1;
pub(crate) const SOBOL_SHUFFLE_SALT: u32 = 0x50b0_15a1;
pub(crate) const SOBOL_SCRAMBLE_SALT: u32 = 0x0e75_c2a1;

/// How the 2-D points of a sample dimension are placed (`--sampler`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Sampler {
    /// Independent uniform numbers.
    #[default]
    Independent,
    /// Jittered n×n cells, n = ⌊√spp⌋, visited in a random order per block.
    Stratified,
    /// Cell midpoints: the Riemann foil, biased.
    Grid,
    /// Owen-scrambled Sobol with a shuffled index: progressive, low discrepancy.
    Sobol,
}

impl Sampler {
    /// Every variant, in CLI order.
    pub const ALL: [Sampler; 4] = [Sampler::Independent, Sampler::Stratified, Sampler::Grid, Sampler::Sobol];

    /// The name used on the command line, in scene files and in stats.
    pub fn name(self) -> &'static str {
        match self {
            Sampler::Independent => "independent",
            Sampler::Stratified => "stratified",
            Sampler::Grid => "grid",
            Sampler::Sobol => "sobol",
        }
    }

    /// The variant called `name`.
    pub fn from_name(name: &str) -> Option<Sampler> {
        Sampler::ALL.into_iter().find(|s| s.name() == name)
    }

    /// The id the shader switches on (`SAMPLER_*`).
    pub fn shader_id(self) -> u32 {
        match self {
            Sampler::Independent => 0,
            Sampler::Stratified => 1,
            Sampler::Grid => 2,
            Sampler::Sobol => 3,
        }
    }

    /// Whether every sample is uniform on its own, so the mean is unbiased for any count.
    pub fn is_unbiased(self) -> bool {
        self != Sampler::Grid
    }

    /// Samples per replicate of a render (module doc): `requested` (checked by
    /// [`Sampler::check_replicate`]), or by default one replicate of every sample (0) for
    /// `stratified` and `sobol`, whose best point set is one sequence, and replicates of
    /// one sample for `independent` (which may be batched too, for an adaptive render's
    /// decisions: its numbers do not depend on it); always 0 for `grid`.
    pub fn replicate_samples(self, requested: Option<u32>) -> u32 {
        match self {
            Sampler::Independent => requested.filter(|&r| r > 0).unwrap_or(1),
            Sampler::Grid => 0,
            Sampler::Stratified | Sampler::Sobol => requested.unwrap_or(0),
        }
    }

    /// The largest replicate size this sampler allows that cuts `spp` samples into at
    /// least `replicates` replicates (a power of two for `sobol`, of four for
    /// `stratified`, at most `MAX_REPLICATE_SAMPLES`, at least 1); 0 for `grid`.
    pub fn replicate_for(self, spp: u32, replicates: u32) -> u32 {
        let step = match self {
            Sampler::Grid => return 0,
            Sampler::Stratified => 4,
            Sampler::Independent | Sampler::Sobol => 2,
        };
        let mut r = 1;
        while r * step <= MAX_REPLICATE_SAMPLES && (r * step) as u64 * replicates as u64 <= spp as u64 {
            r *= step;
        }
        r
    }

    /// Checks that `replicate` samples per replicate can be asked of this sampler (any
    /// size for `grid`, which ignores it).
    pub fn check_replicate(self, replicate: u32) -> Result<(), ReplicateError> {
        let ok = match self {
            Sampler::Grid => true,
            Sampler::Independent | Sampler::Sobol => {
                replicate == 0 || (replicate.is_power_of_two() && replicate <= MAX_REPLICATE_SAMPLES)
            }
            Sampler::Stratified => {
                replicate == 0
                    || (replicate.is_power_of_two()
                        && replicate.trailing_zeros().is_multiple_of(2)
                        && replicate <= MAX_REPLICATE_SAMPLES)
            }
        };
        if ok { Ok(()) } else { Err(ReplicateError { sampler: self, replicate }) }
    }

    /// Cells per axis of a render of `spp` samples per pixel and `replicate` samples per
    /// replicate: for `stratified` √replicate, or ⌊√spp⌋ when one replicate holds every
    /// sample (replicate 0); for `grid` ⌊√spp⌋; else 1. At most 46,340, so that the cell
    /// count stays below 2³¹.
    pub fn strata_per_axis(self, spp: u32, replicate: u32) -> u32 {
        match self {
            Sampler::Stratified if replicate > 0 => replicate.isqrt(),
            Sampler::Stratified | Sampler::Grid => spp.max(1).isqrt().min(46_340),
            Sampler::Independent | Sampler::Sobol => 1,
        }
    }
}

/// A replicate size a sampler cannot use ([`Sampler::check_replicate`]): the message says
/// which sizes it can.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{replicate} samples per replicate for the {} sampler: use {}", sampler.name(), self.allowed())]
pub struct ReplicateError {
    /// The sampler asked.
    pub sampler: Sampler,
    /// The samples per replicate it cannot use.
    pub replicate: u32,
}

impl ReplicateError {
    /// The sizes the sampler accepts, in words.
    fn allowed(&self) -> String {
        match self.sampler {
            Sampler::Stratified => {
                // The powers of four up to the largest replicate: "1, 4, 16, 64 or 256".
                let sizes: Vec<String> = std::iter::successors(Some(1u32), |n| n.checked_mul(4))
                    .take_while(|&n| n <= MAX_REPLICATE_SAMPLES)
                    .map(|n| n.to_string())
                    .collect();
                let (last, rest) = sizes.split_last().expect("1 is a replicate size");
                format!("0 (one replicate) or {} or {last} (n x n cells, n a power of two)", rest.join(", "))
            }
            _ => format!("0 (one replicate) or a power of two up to {MAX_REPLICATE_SAMPLES}"),
        }
    }
}

/// A sampler with its seed and cell count: what one render draws its numbers from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PointSampler {
    /// The placement.
    pub sampler: Sampler,
    /// The render's seed.
    pub seed: u32,
    /// Cells per axis ([`Sampler::strata_per_axis`]).
    pub strata: u32,
    /// Samples per replicate ([`Sampler::replicate_samples`]); 0 for one sequence.
    pub replicate: u32,
}

impl PointSampler {
    /// The sampler of a render of `spp` samples per pixel in replicates of `replicate`
    /// samples ([`Sampler::replicate_samples`]).
    pub fn new(sampler: Sampler, seed: u32, spp: u32, replicate: u32) -> PointSampler {
        PointSampler { sampler, seed, strata: sampler.strata_per_axis(spp, replicate), replicate }
    }

    /// The numbers of sample `index` of pixel `(px, py)`: (jitter x, jitter y,
    /// hemisphere ξ₁, ξ₂), each in [0, 1).
    pub fn uniforms(&self, px: u32, py: u32, index: u32) -> [f32; 4] {
        let s = self.sampler.shader_id();
        sample_point_uniforms(s, px, py, index, self.seed, self.strata, self.replicate)
    }
}

/// [`PointSampler::uniforms`] by sampler id: the twin of the WGSL function.
pub fn sample_point_uniforms(
    sampler: u32,
    px: u32,
    py: u32,
    index: u32,
    seed: u32,
    strata: u32,
    replicate: u32,
) -> [f32; 4] {
    let independent = sample_uniforms(px, py, index, seed);
    if sampler == Sampler::Sobol.shader_id() {
        // Replicate k is the first points of a sequence of its own; replicate 0's is the
        // sequence of a render in one replicate.
        let (k, i) = index.checked_div(replicate).map_or((0, index), |k| (k, index % replicate));
        let shuffle = pcg4d(UVec4::new(px, py, seed, SOBOL_SHUFFLE_SALT.wrapping_add(k)));
        let scramble = pcg4d(UVec4::new(px, py, seed, SOBOL_SCRAMBLE_SALT.wrapping_add(k)));
        let a = sobol_2d(i, shuffle.x, scramble.x, scramble.y);
        let b = sobol_2d(i, shuffle.y, scramble.z, scramble.w);
        return [a[0], a[1], b[0], b[1]];
    }
    if sampler == Sampler::Stratified.shader_id() || sampler == Sampler::Grid.shader_id() {
        let cells = strata * strata;
        let block = index / cells;
        let keys = pcg4d(UVec4::new(px, py, block, seed ^ STRATA_SALT));
        let jitter = if sampler == Sampler::Grid.shader_id() { [0.5; 4] } else { independent };
        let j = index % cells;
        let a = stratum_point(permute(j, cells, keys.x), strata, [jitter[0], jitter[1]]);
        let b = stratum_point(permute(j, cells, keys.y), strata, [jitter[2], jitter[3]]);
        return [a[0], a[1], b[0], b[1]];
    }
    independent
}

/// The point at `jitter` ∈ [0,1)² inside cell `cell` of an n×n grid (row-major).
pub fn stratum_point(cell: u32, n: u32, jitter: [f32; 2]) -> [f32; 2] {
    let inv = 1.0 / n as f32;
    let x = ((cell % n) as f32 + jitter[0]) * inv;
    let y = ((cell / n) as f32 + jitter[1]) * inv;
    // (n − 1 + a jitter just below 1) / n can round up to 1.
    [x.min(ONE_MINUS_EPSILON), y.min(ONE_MINUS_EPSILON)]
}

/// Element `i` of a random permutation of `0..l` chosen by `p`: Kensler, "Correlated
/// Multi-Jittered Sampling" (Pixar 2013), a hashed bijection on the next power of two
/// with cycle walking (at most [`PERMUTE_WALK_LIMIT`] steps).
pub fn permute(i: u32, l: u32, p: u32) -> u32 {
    let mut w = l.wrapping_sub(1);
    w |= w >> 1;
    w |= w >> 2;
    w |= w >> 4;
    w |= w >> 8;
    w |= w >> 16;
    let mut i = i;
    for _ in 0..PERMUTE_WALK_LIMIT {
        i ^= p;
        i = i.wrapping_mul(0xe170893d);
        i ^= p >> 16;
        i ^= (i & w) >> 4;
        i ^= p >> 8;
        i = i.wrapping_mul(0x0929eb3f);
        i ^= p >> 23;
        i ^= (i & w) >> 1;
        i = i.wrapping_mul(1 | p >> 27);
        i = i.wrapping_mul(0x6935fa69);
        i ^= (i & w) >> 11;
        i = i.wrapping_mul(0x74dcb303);
        i ^= (i & w) >> 2;
        i = i.wrapping_mul(0x9e501cc3);
        i ^= (i & w) >> 2;
        i = i.wrapping_mul(0xc860a3df);
        i &= w;
        i ^= i >> 5;
        if i < l {
            break;
        }
    }
    (i + p % l) % l
}

/// Hash-based Owen scrambling of the bits of `v`, most significant first (pbrt-v4's
/// `FastOwenScrambler`, after Burley 2020 and Vegdahl): bit k is flipped by a hash of
/// the bits above it, so an aligned block of 2ᵏ values maps onto an aligned block.
pub fn nested_uniform_scramble(v: u32, seed: u32) -> u32 {
    let mut v = v.reverse_bits();
    v ^= v.wrapping_mul(0x3d20adea);
    v = v.wrapping_add(seed);
    v = v.wrapping_mul((seed >> 16) | 1);
    v ^= v.wrapping_mul(0x05526c56);
    v ^= v.wrapping_mul(0x53a22864);
    v.reverse_bits()
}

/// The second Sobol dimension (generator x + 1, the Pascal matrix mod 2) as a 32-bit
/// fraction. By Lucas's theorem index bit k feeds output digit j iff j's bits are a
/// subset of k's, a transform that takes five mask-and-shift steps instead of a loop.
pub fn sobol_dim1(index: u32) -> u32 {
    let mut y = index;
    y ^= (y & 0xaaaa_aaaa) >> 1;
    y ^= (y & 0xcccc_cccc) >> 2;
    y ^= (y & 0xf0f0_f0f0) >> 4;
    y ^= (y & 0xff00_ff00) >> 8;
    y ^= (y & 0xffff_0000) >> 16;
    y.reverse_bits()
}

/// Point `index` of a 2-D Owen-scrambled Sobol sequence: the index shuffled by
/// `shuffle_seed` (a nested scramble, which keeps power-of-two prefixes (0,m,2)-nets),
/// then each coordinate scrambled by its own seed.
pub fn sobol_2d(index: u32, shuffle_seed: u32, seed_x: u32, seed_y: u32) -> [f32; 2] {
    let i = nested_uniform_scramble(index, shuffle_seed);
    let x = nested_uniform_scramble(i.reverse_bits(), seed_x);
    let y = nested_uniform_scramble(sobol_dim1(i), seed_y);
    [u32_to_unit_float(x), u32_to_unit_float(y)]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sobol_dim1_by_directions(mut i: u32) -> u32 {
        let (mut x, mut v) = (0u32, 1u32 << 31);
        while i != 0 {
            if i & 1 != 0 {
                x ^= v;
            }
            i >>= 1;
            v ^= v >> 1;
        }
        x
    }

    #[test]
    fn sobol_dim1_matches_its_direction_numbers() {
        for i in (0..4096u32).chain((0..4096u32).map(|k| pcg4d(UVec4::new(k, 1, 2, 3)).x)) {
            assert_eq!(sobol_dim1(i), sobol_dim1_by_directions(i), "index {i}");
        }
    }

    #[test]
    fn unscrambled_sobol_prefixes_are_0_m_2_nets() {
        // Every power-of-two prefix puts one point in each elementary interval of every shape.
        for m in 0..=10u32 {
            let n = 1u32 << m;
            for split in 0..=m {
                let (bx, by) = (1u32 << split, 1u32 << (m - split));
                let mut seen = vec![false; n as usize];
                for i in 0..n {
                    let (x, y) = (i.reverse_bits() as u64, sobol_dim1(i) as u64);
                    let cell = ((x * bx as u64) >> 32) + bx as u64 * ((y * by as u64) >> 32);
                    assert!(!seen[cell as usize], "m {m}, {bx}x{by}: two points in cell {cell}");
                    seen[cell as usize] = true;
                }
            }
        }
    }

    #[test]
    fn scrambled_shuffled_sobol_prefixes_stay_nets() {
        for (shuffle, sx, sy) in [(0u32, 0u32, 0u32), (0x1234_5678, 0x9abc_def0, 0x0fed_cba9), (7, 11, 13)] {
            for m in [2u32, 5, 8] {
                let n = 1u32 << m;
                let mut seen = vec![false; n as usize];
                let b = 1u32 << (m / 2);
                let c = n / b;
                for i in 0..n {
                    let p = sobol_2d(i, shuffle, sx, sy);
                    let cell = (p[0] * b as f32) as u32 + b * (p[1] * c as f32) as u32;
                    assert!(!seen[cell as usize], "seeds {shuffle:x}: m {m}: cell {cell} twice");
                    seen[cell as usize] = true;
                }
            }
        }
    }

    #[test]
    fn permute_is_a_bijection() {
        for l in (1..=70u32).chain([255, 256, 257, 1000, 4096]) {
            for p in [0u32, 1, 0xdead_beef, 0x8000_0000, u32::MAX] {
                let mut seen = vec![false; l as usize];
                for i in 0..l {
                    let j = permute(i, l, p);
                    assert!(j < l && !seen[j as usize], "l {l}, p {p:x}: {i} -> {j}");
                    seen[j as usize] = true;
                }
            }
        }
    }

    #[test]
    fn cell_samplers_visit_every_cell_once_per_block() {
        for spp in [1u32, 4, 9, 10, 16, 17, 256] {
            for sampler in [Sampler::Stratified, Sampler::Grid] {
                let s = PointSampler::new(sampler, 42, spp, 0);
                let n = s.strata;
                assert!(n * n <= spp && (n + 1) * (n + 1) > spp, "spp {spp}: n {n}");
                for (px, py) in [(0, 0), (3, 9)] {
                    for block in 0..2u32 {
                        let mut seen = [vec![false; (n * n) as usize], vec![false; (n * n) as usize]];
                        for j in 0..n * n {
                            let u = s.uniforms(px, py, block * n * n + j);
                            for d in 0..2 {
                                let (x, y) = (u[2 * d], u[2 * d + 1]);
                                let cell = (x * n as f32) as usize + n as usize * (y * n as f32) as usize;
                                assert!(!seen[d][cell], "{sampler:?} spp {spp}: cell {cell} twice");
                                seen[d][cell] = true;
                                if sampler == Sampler::Grid {
                                    let fx = x * n as f32 - (x * n as f32).floor();
                                    assert!((fx - 0.5).abs() < 1e-4, "grid point off the midpoint: {x}");
                                }
                            }
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn numbers_stay_below_one() {
        for sampler in Sampler::ALL {
            for spp in [1u32, 2, 16, 1 << 20] {
                let s = PointSampler::new(sampler, 5, spp, sampler.replicate_for(spp, 16));
                for i in (0..2000u32).chain([u32::MAX - 1, u32::MAX]) {
                    for v in s.uniforms(i % 7, i / 7, i) {
                        assert!((0.0..1.0).contains(&v), "{sampler:?}: {v}");
                    }
                }
            }
        }
        assert_eq!(stratum_point(3, 4, [ONE_MINUS_EPSILON; 2])[0], ONE_MINUS_EPSILON);
    }

    #[test]
    fn independent_is_the_plain_hash() {
        let s = PointSampler::new(Sampler::Independent, 9, 64, 1);
        assert_eq!(s.uniforms(3, 4, 5), sample_uniforms(3, 4, 5, 9));
    }
}
