//! The hemisphere warps and point samplers as distributions, on the CPU and on the adapter.
//!
//! - Chi-square goodness of fit of every warp on a (θ, φ) histogram, in the manner of
//!   pbrt-v3's `Chi2Test`: expected counts from integrating the Rust pdf over each bin,
//!   bins sorted by expected count and pooled below an expected count of 5, the statistic
//!   against χ² with (cells − 1) degrees of freedom, at α = 0.01 with Šidák's correction
//!   over every chi-square test in this file. One function serves the hemisphere and the
//!   sphere, and a negative control (the naive sphere sampler θ = πξ₁) shows it rejects.
//! - Every pdf integrates to one; sample-then-invert returns the input.
//! - The WGSL twins (run through `tests/kernels/sampling_probe.wgsl`, one input per
//!   invocation) give the same directions, pdfs, inverses and sampler numbers as Rust.

mod common;
use common::kernel::{self, TestKernel};

use aorender::sampler::{PointSampler, Sampler, sample_point_uniforms};
use aorender::sampling::{Hemisphere, pcg4d, u32_to_unit_float};
use glam::{UVec4, Vec2, Vec3};
use statrs::distribution::{ChiSquared, ContinuousCDF};
use std::f64::consts::PI;

/// The probe kernel's file name and text.
const PROBE_NAME: &str = "sampling_probe.wgsl";
const PROBE: &str = include_str!("kernels/sampling_probe.wgsl");

/// Family-wise significance level of the chi-square tests.
const SIGNIFICANCE: f64 = 0.01;
/// Chi-square tests in this file, for Šidák's correction: three Rust warps, three WGSL
/// warps, and on the sphere the uniform sampler, the naive one against the uniform pdf
/// and the naive one against its own pdf.
const CHI2_TESTS: u32 = 9;
/// Samples per chi-square test.
const CHI2_SAMPLES: u32 = 1_000_000;
/// Histogram resolution: θ bins over the domain's θ range, φ bins over [0, 2π).
const THETA_BINS: usize = 10;
const PHI_BINS: usize = 20;
/// Cells whose expected count is below this are pooled (pbrt-v3's `minExpFrequency`).
const MIN_EXPECTED: f64 = 5.0;
/// Seed of every pseudo-random input in this file.
const SEED: u32 = 0x2545_f491;
/// The largest f32 below one.
const ONE_MINUS_EPSILON: f32 = 1.0 - f32::EPSILON / 2.0;

/// Šidák-corrected level of one test: 1 − (1 − α)^(1/m).
fn sidak_alpha() -> f64 {
    1.0 - (1.0 - SIGNIFICANCE).powf(1.0 / CHI2_TESTS as f64)
}

/// `n` pseudo-random points of [0,1)², a pure function of (`salt`, index, [`SEED`]).
fn random_points(n: u32, salt: u32) -> Vec<Vec2> {
    (0..n)
        .map(|i| {
            let h = pcg4d(UVec4::new(i, salt, 0x9e37_79b9, SEED));
            Vec2::new(u32_to_unit_float(h.x), u32_to_unit_float(h.y))
        })
        .collect()
}

/// A grid over [0,1)² that includes 0, ½ and the largest float below one, plus the
/// smallest step above 0.
fn grid_points() -> Vec<Vec2> {
    let mut xs: Vec<f32> = (0..64).map(|i| i as f32 / 64.0).collect();
    xs.extend([ONE_MINUS_EPSILON, 1.0 / 16_777_216.0, 0.5 - 1.0 / 16_777_216.0, 0.5 + 1.0 / 8_388_608.0]);
    xs.iter().flat_map(|&x| xs.iter().map(move |&y| Vec2::new(x, y))).collect()
}

// ---------------------------------------------------------------------------------------
// Sphere samplers for the negative control.

/// The naive sphere sampler: θ = πξ₁, φ = 2πξ₂. It crowds the poles: its density is
/// 1/(2π² sin θ) per solid angle, not 1/4π.
fn sample_sphere_naive(u: Vec2) -> Vec3 {
    let theta = std::f32::consts::PI * u.x;
    let phi = 2.0 * std::f32::consts::PI * u.y;
    Vec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos())
}

/// The naive sampler's true density per solid angle, 1/(2π² sin θ).
fn naive_sphere_pdf(w: Vec3) -> f64 {
    let sin_theta = (w.x as f64).hypot(w.y as f64);
    1.0 / (2.0 * PI * PI * sin_theta)
}

/// The uniform sphere sampler: z = 2ξ₁ − 1, r = √(1 − z²), φ = 2πξ₂.
fn sample_sphere_uniform(u: Vec2) -> Vec3 {
    let z = 2.0 * u.x - 1.0;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * std::f32::consts::PI * u.y;
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// Density of [`sample_sphere_uniform`]: 1/4π.
fn uniform_sphere_pdf(_: Vec3) -> f64 {
    1.0 / (4.0 * PI)
}

// ---------------------------------------------------------------------------------------
// Histograms over (θ, φ), bin integrals of a pdf, and the chi-square test.

/// Where the directions live: θ ∈ [0, π/2] or [0, π], φ ∈ [0, 2π).
#[derive(Clone, Copy, Debug, PartialEq)]
enum Domain {
    Hemisphere,
    Sphere,
}

impl Domain {
    fn theta_max(self) -> f64 {
        match self {
            Domain::Hemisphere => PI / 2.0,
            Domain::Sphere => PI,
        }
    }

    /// The (θ, φ) bin of `w`, or `None` when `w` is outside the domain or not finite.
    fn bin(self, w: Vec3) -> Option<usize> {
        if !w.is_finite() || (self == Domain::Hemisphere && w.z < 0.0) {
            return None;
        }
        let w = w.as_dvec3().normalize();
        let theta = w.z.clamp(-1.0, 1.0).acos();
        let mut phi = w.y.atan2(w.x);
        if phi < 0.0 {
            phi += 2.0 * PI;
        }
        let i = ((theta / self.theta_max() * THETA_BINS as f64) as usize).min(THETA_BINS - 1);
        let j = ((phi / (2.0 * PI) * PHI_BINS as f64) as usize).min(PHI_BINS - 1);
        Some(i * PHI_BINS + j)
    }
}

/// The direction at polar angle θ, azimuth φ.
fn direction(theta: f64, phi: f64) -> Vec3 {
    Vec3::new((theta.sin() * phi.cos()) as f32, (theta.sin() * phi.sin()) as f32, theta.cos() as f32)
}

/// Nodes and weights of 5-point Gauss–Legendre on [−1, 1]: exact for polynomials of
/// degree 9, and no node on an interval's ends (where the naive pdf is infinite).
fn gauss_legendre_5() -> [(f64, f64); 5] {
    let (a, b) = ((5.0 - 2.0 * (10.0f64 / 7.0).sqrt()).sqrt() / 3.0, (5.0 + 2.0 * (10.0f64 / 7.0).sqrt()).sqrt() / 3.0);
    let (wa, wb) = ((322.0 + 13.0 * 70.0f64.sqrt()) / 900.0, (322.0 - 13.0 * 70.0f64.sqrt()) / 900.0);
    [(0.0, 128.0 / 225.0), (-a, wa), (a, wa), (-b, wb), (b, wb)]
}

/// Sub-intervals per bin and axis of the composite rule.
const QUADRATURE_SPLITS: usize = 4;

/// The integral of `pdf` dω = pdf sin θ dθ dφ over every bin (in [`Domain::bin`]
/// order): composite Gauss–Legendre in θ and φ. `pdf` evaluates a batch of directions,
/// so the same rule integrates the Rust pdf and the WGSL one.
fn bin_integrals(domain: Domain, pdf: &dyn Fn(&[Vec3]) -> Vec<f64>) -> Vec<f64> {
    let (d_theta, d_phi) = (domain.theta_max() / THETA_BINS as f64, 2.0 * PI / PHI_BINS as f64);
    // One axis of one bin: (offset from the bin's start, weight) of every node.
    let axis = |width: f64| -> Vec<(f64, f64)> {
        let h = width / QUADRATURE_SPLITS as f64;
        (0..QUADRATURE_SPLITS)
            .flat_map(|s| {
                gauss_legendre_5().into_iter().map(move |(x, w)| ((s as f64 + 0.5 + 0.5 * x) * h, 0.5 * w * h))
            })
            .collect()
    };
    let (theta_nodes, phi_nodes) = (axis(d_theta), axis(d_phi));
    let mut directions = Vec::new();
    let mut weights = Vec::new();
    for i in 0..THETA_BINS {
        for j in 0..PHI_BINS {
            for &(t, wt) in &theta_nodes {
                let theta = i as f64 * d_theta + t;
                for &(p, wp) in &phi_nodes {
                    directions.push(direction(theta, j as f64 * d_phi + p));
                    weights.push(wt * wp * theta.sin());
                }
            }
        }
    }
    let values = pdf(&directions);
    assert_eq!(values.len(), directions.len());
    let per_bin = theta_nodes.len() * phi_nodes.len();
    values
        .chunks(per_bin)
        .zip(weights.chunks(per_bin))
        .map(|(v, w)| v.iter().zip(w).map(|(v, w)| v * w).sum())
        .collect()
}

/// A Rust pdf as a batch evaluator.
fn batch(pdf: impl Fn(Vec3) -> f64) -> impl Fn(&[Vec3]) -> Vec<f64> {
    move |ws| ws.iter().map(|&w| pdf(w)).collect()
}

/// The outcome of one chi-square test.
#[derive(Debug)]
struct Chi2 {
    label: String,
    statistic: f64,
    dof: usize,
    p_value: f64,
    /// Cells folded into the pooled cell.
    pooled: usize,
    /// Samples outside the domain (or not finite).
    outside: u64,
    /// Samples in cells whose expected count is zero.
    in_empty_cells: u64,
}

impl Chi2 {
    fn passes(&self) -> bool {
        self.outside == 0 && self.in_empty_cells == 0 && self.p_value.is_finite() && self.p_value >= sidak_alpha()
    }
}

/// pbrt-v3's `Chi2Test` on the (θ, φ) histogram of `directions` against `pdf`, which it
/// integrates over each bin with [`bin_integrals`]. Prints the figures.
fn chi_square(label: &str, domain: Domain, directions: &[Vec3], pdf: &dyn Fn(Vec3) -> f64) -> Chi2 {
    let n = directions.len() as f64;
    let mut observed = vec![0u64; THETA_BINS * PHI_BINS];
    let mut outside = 0u64;
    for &w in directions {
        match domain.bin(w) {
            Some(b) => observed[b] += 1,
            None => outside += 1,
        }
    }
    let expected: Vec<f64> = bin_integrals(domain, &batch(pdf)).into_iter().map(|p| p * n).collect();
    let mut cells: Vec<usize> = (0..expected.len()).collect();
    cells.sort_by(|&a, &b| expected[a].total_cmp(&expected[b]));
    let (mut pooled_observed, mut pooled_expected, mut pooled) = (0.0f64, 0.0f64, 0usize);
    let (mut statistic, mut cells_used, mut in_empty_cells) = (0.0f64, 0usize, 0u64);
    for c in cells {
        let (o, e) = (observed[c] as f64, expected[c]);
        if e <= 0.0 {
            // pbrt tolerates a handful of samples here for rounding; these pdfs are
            // positive on every bin, so any sample in such a cell is a failure.
            in_empty_cells += observed[c];
        } else if e < MIN_EXPECTED || (pooled_expected > 0.0 && pooled_expected < MIN_EXPECTED) {
            pooled_observed += o;
            pooled_expected += e;
            pooled += 1;
        } else {
            statistic += (o - e) * (o - e) / e;
            cells_used += 1;
        }
    }
    if pooled_expected > 0.0 || pooled_observed > 0.0 {
        statistic += (pooled_observed - pooled_expected).powi(2) / pooled_expected;
        cells_used += 1;
    }
    assert!(cells_used >= 2, "{label}: too few cells for a chi-square test");
    let dof = cells_used - 1;
    let p_value = ChiSquared::new(dof as f64).expect("positive degrees of freedom").sf(statistic);
    let result = Chi2 { label: label.to_string(), statistic, dof, p_value, pooled, outside, in_empty_cells };
    eprintln!(
        "chi2 {:<34} N {:>7}  X² {:>10.2}  dof {:>3}  p {:<10.4e} (α' {:.3e}) pooled {:>2} outside {} -> {}",
        result.label,
        directions.len(),
        result.statistic,
        result.dof,
        result.p_value,
        sidak_alpha(),
        result.pooled,
        result.outside,
        if result.passes() { "pass" } else { "REJECT" }
    );
    result
}

fn assert_passes(r: &Chi2) {
    assert!(
        r.passes(),
        "{}: the sample distribution does not match the pdf: {r:?} (α' = {:e})",
        r.label,
        sidak_alpha()
    );
}

// ---------------------------------------------------------------------------------------
// The probe kernel on the adapter.

/// The probe kernel's entry points on the adapter.
struct Probe(TestKernel);

/// One invocation's two output vectors.
type ProbeOut = [[f32; 4]; 2];

impl Probe {
    fn new() -> Probe {
        Probe(TestKernel::new(PROBE_NAME, PROBE, &["warp", "pdf_at", "points", "sky"], 1))
    }

    /// Runs entry point `entry` once per input with the uniforms (`id`, `seed`,
    /// `strata`) and reads back each invocation's two output vectors.
    fn run(&self, entry: &str, id: u32, seed: u32, strata: u32, inputs: &[[u32; 4]]) -> Vec<ProbeOut> {
        let count = u32::try_from(inputs.len()).expect("fewer than 2^32 inputs");
        self.0.run(entry, [id, seed, strata, count], &[bytemuck::cast_slice(inputs)], count, 1)
    }

    /// The WGSL warp of `h` at each point: (direction, pdf, inverse of the direction).
    fn warp(&self, h: Hemisphere, us: &[Vec2]) -> Vec<(Vec3, f32, Vec2)> {
        let inputs: Vec<[u32; 4]> = us.iter().map(|u| [u.x.to_bits(), u.y.to_bits(), 0, 0]).collect();
        self.run("warp", h.shader_id(), 0, 0, &inputs)
            .into_iter()
            .map(|[a, b]| (Vec3::new(a[0], a[1], a[2]), a[3], Vec2::new(b[0], b[1])))
            .collect()
    }

    /// The WGSL `hemisphere_pdf` of `h` at each direction.
    fn pdf(&self, h: Hemisphere, ws: &[Vec3]) -> Vec<f64> {
        let inputs: Vec<[u32; 4]> = ws.iter().map(|w| [w.x.to_bits(), w.y.to_bits(), w.z.to_bits(), 0]).collect();
        self.run("pdf_at", h.shader_id(), 0, 0, &inputs).into_iter().map(|[a, _]| a[0] as f64).collect()
    }
}

// ---------------------------------------------------------------------------------------
// Tests.

/// Salt of the chi-square inputs of each warp; the WGSL tests add 16 so that every
/// test in the Šidák family draws its own numbers.
fn chi2_salt(h: Hemisphere) -> u32 {
    0xc400 + h.shader_id()
}

#[test]
fn probe_kernel_validates() {
    let module = kernel::validate(PROBE_NAME, &kernel::compose(PROBE_NAME, PROBE));
    for name in ["warp", "pdf_at", "points", "sky"] {
        assert!(module.entry_points.iter().any(|e| e.name == name), "entry point {name} missing");
    }
}

#[test]
fn rust_warps_pass_chi_square() {
    for h in Hemisphere::ALL {
        let directions: Vec<Vec3> =
            random_points(CHI2_SAMPLES, chi2_salt(h)).into_iter().map(|u| h.sample(u)).collect();
        let r = chi_square(&format!("rust {}", h.name()), Domain::Hemisphere, &directions, &|w| h.pdf(w) as f64);
        assert_passes(&r);
    }
}

#[test]
fn wgsl_warps_pass_chi_square() {
    if !common::gpu_available() {
        return;
    }
    let probe = Probe::new();
    for h in Hemisphere::ALL {
        let us = random_points(CHI2_SAMPLES, chi2_salt(h) + 16);
        let directions: Vec<Vec3> = probe.warp(h, &us).into_iter().map(|(w, _, _)| w).collect();
        // Expected counts from the Rust pdf: the WGSL pdf is checked against it separately.
        let r = chi_square(&format!("wgsl {}", h.name()), Domain::Hemisphere, &directions, &|w| h.pdf(w) as f64);
        assert_passes(&r);
    }
}

#[test]
fn chi_square_rejects_the_naive_sphere_sampler() {
    let us = random_points(CHI2_SAMPLES, 0x5900);
    let uniform: Vec<Vec3> = us.iter().map(|&u| sample_sphere_uniform(u)).collect();
    let r = chi_square("sphere uniform vs 1/4π", Domain::Sphere, &uniform, &uniform_sphere_pdf);
    assert_passes(&r);

    let us = random_points(CHI2_SAMPLES, 0x5901);
    let naive: Vec<Vec3> = us.iter().map(|&u| sample_sphere_naive(u)).collect();
    let r = chi_square("sphere naive vs 1/4π", Domain::Sphere, &naive, &uniform_sphere_pdf);
    assert!(r.outside == 0 && r.p_value < sidak_alpha(), "the naive sphere sampler was not rejected: {r:?}");

    // The same samples against the naive sampler's own density pass: the rejection is
    // about the density, not an artefact of the binning near the poles.
    let r = chi_square("sphere naive vs 1/(2π² sin θ)", Domain::Sphere, &naive, &naive_sphere_pdf);
    assert_passes(&r);
}

/// The quadrature's total: each bin's integral is accurate to about 1e-9 (checked against
/// closed forms below), and a pdf evaluated in f32 carries a relative rounding error of a
/// few 1e-8, so 1e-6 leaves a wide margin while catching any normalisation slip.
const PDF_TOTAL_TOLERANCE: f64 = 1e-6;

#[test]
fn pdfs_integrate_to_one() {
    // The quadrature against the closed-form bin integrals of the three densities:
    // uniform (Δφ/2π)(cos θ₀ − cos θ₁), cosine (Δφ/2π)(sin²θ₁ − sin²θ₀), sphere
    // (Δφ/4π)(cos θ₀ − cos θ₁).
    type ClosedForm = fn(f64, f64, f64) -> f64;
    type Density = Box<dyn Fn(Vec3) -> f64>;
    let cases: [(&str, Domain, Density, ClosedForm); 3] = [
        ("uniform hemisphere", Domain::Hemisphere, Box::new(|_| 0.5 / PI), |t0, t1, dp| {
            dp / (2.0 * PI) * (t0.cos() - t1.cos())
        }),
        ("cosine hemisphere", Domain::Hemisphere, Box::new(|w| w.z as f64 / PI), |t0, t1, dp| {
            dp / (2.0 * PI) * (t1.sin().powi(2) - t0.sin().powi(2))
        }),
        ("uniform sphere", Domain::Sphere, Box::new(uniform_sphere_pdf), |t0, t1, dp| {
            dp / (4.0 * PI) * (t0.cos() - t1.cos())
        }),
    ];
    for (name, domain, pdf, closed) in cases {
        let bins = bin_integrals(domain, &|ws| ws.iter().map(|&w| pdf(w)).collect());
        let d_theta = domain.theta_max() / THETA_BINS as f64;
        let worst = bins
            .iter()
            .enumerate()
            .map(|(b, v)| {
                let t0 = (b / PHI_BINS) as f64 * d_theta;
                (v - closed(t0, t0 + d_theta, 2.0 * PI / PHI_BINS as f64)).abs()
            })
            .fold(0.0, f64::max);
        eprintln!("quadrature {name}: worst bin error {worst:.2e}");
        assert!(worst < 1e-8, "{name}: quadrature is off a closed-form bin integral by {worst:e}");
    }

    let mut totals: Vec<(String, f64)> = Hemisphere::ALL
        .iter()
        .map(|&h| {
            let total: f64 = bin_integrals(Domain::Hemisphere, &batch(move |w| h.pdf(w) as f64)).iter().sum();
            (format!("rust {}", h.name()), total)
        })
        .collect();
    totals.push(("sphere uniform".into(), bin_integrals(Domain::Sphere, &batch(uniform_sphere_pdf)).iter().sum()));
    totals.push(("sphere naive".into(), bin_integrals(Domain::Sphere, &batch(naive_sphere_pdf)).iter().sum()));
    for (name, total) in totals {
        eprintln!("pdf integral {name}: 1 {:+.3e}", total - 1.0);
        assert!((total - 1.0).abs() < PDF_TOTAL_TOLERANCE, "{name}: pdf integrates to {total}");
    }
}

#[test]
fn wgsl_pdfs_integrate_to_one() {
    if !common::gpu_available() {
        return;
    }
    let probe = Probe::new();
    for h in Hemisphere::ALL {
        let total: f64 = bin_integrals(Domain::Hemisphere, &|ws| probe.pdf(h, ws)).iter().sum();
        eprintln!("pdf integral wgsl {}: 1 {:+.3e}", h.name(), total - 1.0);
        assert!((total - 1.0).abs() < PDF_TOTAL_TOLERANCE, "wgsl {}: pdf integrates to {total}", h.name());
    }
}

/// Tolerance of sample-then-invert in Rust, per coordinate (φ compared on the circle):
/// the inverses are well conditioned away from the excluded points, and the observed
/// error is a few 1e-7.
const RUST_INVERT_TOLERANCE: f32 = 1e-5;
/// The same for the WGSL inverse of the WGSL direction: WGSL (like Vulkan) allows
/// `atan2` an error of 4096 ulp, so an adapter may miss φ/2π by about 2.5e-4 and
/// still be conforming.
const WGSL_INVERT_TOLERANCE: f32 = 3e-4;

/// How far `back` is from `u`, with the azimuthal coordinate of `h` compared on the
/// circle, and only the radial one where the direction is on the axis (x = y = 0), where
/// the azimuth is undefined (the polar map's centre).
fn invert_error(h: Hemisphere, u: Vec2, w: Vec3, back: Vec2) -> f32 {
    let d = (u - back).abs();
    match h {
        Hemisphere::Uniform | Hemisphere::CosinePolar => {
            let dphi = d.y.min(1.0 - d.y);
            if w.x == 0.0 && w.y == 0.0 { d.x } else { d.x.max(dphi) }
        }
        Hemisphere::Cosine => d.max_element(),
    }
}

fn inversion_inputs() -> Vec<Vec2> {
    let mut us = grid_points();
    us.extend(random_points(100_000, 0x1a00));
    us
}

/// The largest error seen and the input that gave it.
#[derive(Clone, Copy, Debug)]
struct Worst {
    error: f64,
    at: Vec2,
}

impl Worst {
    fn new() -> Worst {
        Worst { error: 0.0, at: Vec2::ZERO }
    }

    fn update(&mut self, error: f64, at: Vec2) {
        // NaN counts as the worst.
        if error.is_nan() || error > self.error {
            *self = Worst { error: if error.is_nan() { f64::INFINITY } else { error }, at };
        }
    }
}

impl std::fmt::Display for Worst {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:.2e} at u = ({:e}, {:e})", self.error, self.at.x, self.at.y)
    }
}

#[test]
fn rust_sample_then_invert_returns_the_input() {
    for h in Hemisphere::ALL {
        let mut worst = Worst::new();
        for u in inversion_inputs() {
            let w = h.sample(u);
            worst.update(invert_error(h, u, w, h.invert(w)) as f64, u);
        }
        eprintln!("invert rust {}: worst error {worst}", h.name());
        assert!(worst.error < RUST_INVERT_TOLERANCE as f64, "rust {}: invert(sample(u)) is off by {worst}", h.name());
    }
}

/// Per-component tolerance of WGSL against Rust.
const PARITY_TOLERANCE: f64 = 1e-6;

/// WGSL `sample_hemisphere`, `hemisphere_pdf` and `invert_hemisphere` against Rust on
/// the same numbers.
///
/// Direction components must agree within [`PARITY_TOLERANCE`] and the pdf of the same u
/// relatively within it. (The cosine warps take z from the exact disk radius, so z does
/// not inherit the platform's sin/cos rounding, which √(1 − x² − y²) would amplify to
/// ~3e-4 at the horizon.) The pdf *function* is also compared at one direction (WGSL
/// `hemisphere_pdf` of the WGSL direction against the Rust pdf of that direction). The
/// inverse is the WGSL inverse of the WGSL direction.
#[test]
fn wgsl_warps_match_rust_and_invert() {
    if !common::gpu_available() {
        return;
    }
    let probe = Probe::new();
    let us = inversion_inputs();
    let mut failures = Vec::new();
    for h in Hemisphere::ALL {
        let gpu = probe.warp(h, &us);
        let (mut worst_xy, mut worst_z) = (Worst::new(), Worst::new());
        let (mut worst_pdf_same_w, mut worst_pdf_same_u, mut worst_inv) = (Worst::new(), Worst::new(), Worst::new());
        let mut identical = 0;
        for (&u, &(w_gpu, pdf_gpu, back_gpu)) in us.iter().zip(&gpu) {
            let w_cpu = h.sample(u);
            let pdf_cpu = h.pdf(w_cpu) as f64;
            let (g, c) = (w_gpu.as_dvec3(), w_cpu.as_dvec3());
            let dxy = (g.x - c.x).abs().max((g.y - c.y).abs());
            let dz = (g.z - c.z).abs();
            let pdf_gpu = pdf_gpu as f64;
            let rel = |a: f64, b: f64| if a == b { 0.0 } else { (a - b).abs() / b.abs() };
            let dpdf_same_w = rel(pdf_gpu, h.pdf(w_gpu) as f64);
            let dpdf_same_u = rel(pdf_gpu, pdf_cpu);
            let inv = invert_error(h, u, w_gpu, back_gpu) as f64;
            worst_xy.update(dxy, u);
            worst_z.update(dz, u);
            worst_pdf_same_w.update(dpdf_same_w, u);
            worst_pdf_same_u.update(dpdf_same_u, u);
            worst_inv.update(inv, u);
            if w_gpu.to_array().map(f32::to_bits) == w_cpu.to_array().map(f32::to_bits) && pdf_gpu == pdf_cpu {
                identical += 1;
            }
            let ok = dxy <= PARITY_TOLERANCE
                && dz <= PARITY_TOLERANCE
                && dpdf_same_u <= PARITY_TOLERANCE
                && dpdf_same_w <= PARITY_TOLERANCE
                && inv < WGSL_INVERT_TOLERANCE as f64;
            if !ok && failures.len() < 40 {
                failures.push(format!(
                    "{} u = ({:e}, {:e}) [bits {:#010x} {:#010x}]: wgsl w = {:?} pdf {:e} inverse {:?}; \
                     rust w = {:?} pdf {:e} inverse {:?}",
                    h.name(),
                    u.x,
                    u.y,
                    u.x.to_bits(),
                    u.y.to_bits(),
                    w_gpu.to_array(),
                    pdf_gpu,
                    back_gpu.to_array(),
                    w_cpu.to_array(),
                    pdf_cpu,
                    h.invert(w_cpu).to_array()
                ));
            }
        }
        eprintln!(
            "parity {}: {} inputs, {identical} bit-identical in direction and pdf\n  \
             |Δx|,|Δy| worst {worst_xy}\n  |Δz| worst {worst_z}\n  \
             pdf rel. (same direction) worst {worst_pdf_same_w}\n  pdf rel. (same u) worst {worst_pdf_same_u}\n  \
             wgsl inverse of wgsl direction: worst error {worst_inv}",
            h.name(),
            us.len(),
        );
    }
    assert!(failures.is_empty(), "WGSL warps differ from Rust:\n{}", failures.join("\n"));
}

#[test]
fn wgsl_point_samplers_match_rust() {
    if !common::gpu_available() {
        return;
    }
    let probe = Probe::new();
    // Pixels: a small block, 4K corners and the extremes; indices: the first blocks, around
    // 2^20 and 2^31, the top of the range, and pseudo-random ones.
    let mut pixels: Vec<(u32, u32)> = (0..6).flat_map(|y| (0..6).map(move |x| (x, y))).collect();
    pixels.extend([(3839, 2159), (1919, 0), (0, 1079), (65_535, 65_536), (u32::MAX, u32::MAX), (u32::MAX, 0)]);
    let mut indices: Vec<u32> = (0..40).collect();
    indices.extend([1023, 1024, 1025, (1 << 20) - 1, 1 << 20, (1 << 20) + 1, 1 << 31, u32::MAX - 1, u32::MAX]);
    indices.extend((0..16u32).map(|k| pcg4d(UVec4::new(k, 0x77, 1, SEED)).x));
    let mut inputs: Vec<[u32; 4]> =
        pixels.iter().flat_map(|&(px, py)| indices.iter().map(move |&i| [px, py, i, 0])).collect();
    inputs.extend((0..8_000u32).map(|k| {
        let h = pcg4d(UVec4::new(k, 0x78, 2, SEED));
        [h.x % 4096, h.y % 4096, if k % 2 == 0 { h.z } else { h.z % 4096 }, 0]
    }));

    // (sampler, spp, samples per replicate): one replicate, the defaults, and others.
    let mut configs: Vec<(Sampler, u32, u32)> = vec![
        (Sampler::Independent, 64, 1),
        (Sampler::Sobol, 64, 0),
        (Sampler::Sobol, 64, 4),
        (Sampler::Sobol, 1 << 20, 1),
    ];
    configs.push((Sampler::Sobol, 1 << 20, 256));
    for spp in [1u32, 16, 17, 1024, 1 << 20] {
        configs.push((Sampler::Stratified, spp, 0));
        configs.push((Sampler::Stratified, spp, Sampler::Stratified.replicate_for(spp, 16)));
        configs.push((Sampler::Grid, spp, 0));
    }
    // Every input whose numbers are not bit-identical, with whether it is beyond tolerance.
    let mut differing: Vec<(bool, String)> = Vec::new();
    let (mut all_identical, mut all_total) = (0usize, 0usize);
    for (sampler, spp, replicate) in configs {
        let (mut identical, mut worst, mut total) = (0usize, 0.0f64, 0usize);
        let inputs: Vec<[u32; 4]> = inputs.iter().map(|&[px, py, i, _]| [px, py, i, replicate]).collect();
        for seed in [0u32, 42, 0xdead_beef, u32::MAX] {
            let s = PointSampler::new(sampler, seed, spp, replicate);
            let gpu = probe.run("points", sampler.shader_id(), seed, s.strata, &inputs);
            for (&[px, py, index, _], [g, _]) in inputs.iter().zip(&gpu) {
                let c = sample_point_uniforms(sampler.shader_id(), px, py, index, seed, s.strata, replicate);
                let d = g
                    .iter()
                    .zip(&c)
                    .map(|(a, b)| (a - b).abs() as f64)
                    .fold(0.0, |m, x| if x.is_nan() { f64::INFINITY } else { m.max(x) });
                total += 1;
                worst = worst.max(d);
                if g.map(f32::to_bits) == c.map(f32::to_bits) {
                    identical += 1;
                } else {
                    differing.push((
                        d > PARITY_TOLERANCE,
                        format!(
                            "{} spp {spp} (strata {}) seed {seed:#x} pixel ({px}, {py}) index {index}: \
                             wgsl {g:?} rust {c:?}",
                            sampler.name(),
                            s.strata
                        ),
                    ));
                }
            }
        }
        eprintln!(
            "parity sampler {:<11} spp {:>7} replicate {replicate:>3}: {total} samples, {identical} bit-identical, \
             worst |Δ| {worst:.2e}",
            sampler.name(),
            spp
        );
        all_identical += identical;
        all_total += total;
    }
    eprintln!("parity samplers: {all_identical} of {all_total} samples bit-identical");
    for (_, f) in differing.iter().take(20) {
        eprintln!("  not bit-identical: {f}");
    }
    let out_of_tolerance: Vec<&str> = differing.iter().filter(|(bad, _)| *bad).map(|(_, f)| f.as_str()).collect();
    assert!(
        out_of_tolerance.is_empty(),
        "{} WGSL sampler outputs differ from Rust by more than {PARITY_TOLERANCE:e}:\n{}",
        out_of_tolerance.len(),
        out_of_tolerance[..out_of_tolerance.len().min(40)].join("\n")
    );
}

/// `sample_overcast` in WGSL against Rust on the same numbers: every sky sampling, both
/// normalisations, a black and a grey ground, normals from the zenith to the nadir.
#[test]
fn wgsl_overcast_sky_matches_rust() {
    use aorender::sky::{Sky, SkyModel, SkyNormalise, SkySampling, sample_overcast};
    if !common::gpu_available() {
        return;
    }
    let probe = Probe::new();
    let us = random_points(4096, 0x5c00);
    let mut failures = Vec::new();
    let mut checks = 0;
    for sampling in SkySampling::ALL {
        for normalise in SkyNormalise::ALL {
            for ground in [0.0f32, 0.5] {
                let sky =
                    Sky { model: SkyModel::Overcast, sampling, normalise, ground_albedo: ground, ..Sky::default() };
                if sky.validate().is_err() {
                    continue;
                }
                let (id, code) = (sky.shader_id(), normalise.code() as u32);
                let normals: Vec<Vec3> = (0..us.len())
                    .map(|k| {
                        let beta = (k % 37) as f32 / 36.0 * std::f32::consts::PI;
                        Vec3::new(beta.sin(), beta.cos(), 0.0)
                    })
                    .collect();
                let inputs: Vec<[u32; 4]> = us
                    .iter()
                    .zip(&normals)
                    .map(|(u, n)| [u.x.to_bits(), u.y.to_bits(), n.x.to_bits(), n.y.to_bits()])
                    .collect();
                let gpu = probe.run("sky", id, code, ground.to_bits(), &inputs);
                for ((&u, &n), [a, b]) in us.iter().zip(&normals).zip(gpu) {
                    checks += 1;
                    let cpu = sample_overcast(id, code, Vec3::Y, ground, Hemisphere::Cosine, n, u);
                    let dw = (Vec3::new(a[0], a[1], a[2]) - cpu.w).abs().max_element();
                    let dv = (a[3] - cpu.open).abs().max((b[0] - cpu.blocked).abs());
                    // acos_poly and the square roots in f32 on both sides; the values are at most 6.
                    if !(dw <= 1e-5 && dv <= 1e-5) && failures.len() < 20 {
                        failures.push(format!(
                            "{} {} ground {ground} n {n} u {u}: wgsl {a:?} {b:?}, rust {cpu:?}",
                            sampling.name(),
                            normalise.name()
                        ));
                    }
                }
            }
        }
    }
    assert!(checks > 40_000, "only {checks} checks");
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
