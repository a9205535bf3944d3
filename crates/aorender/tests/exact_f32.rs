//! The device's f32 arithmetic rounds as IEEE 754 does (`shaders/exact.wgsl`, run through
//! `tests/kernels/exact_probe.wgsl`, one operation per invocation):
//!
//! - The correction of a quotient and of a square root gives the correctly rounded result
//!   bit for bit from any approximation within 3 ulps of it, for operands over the whole
//!   f32 range: random bits, the adaptive rule's magnitudes, exact quotients, ties (in
//!   the subnormal range, the only place a quotient of two f32 can tie), perfect squares,
//!   significands at the ends of their binades, overflow and underflow. Lavapipe's own
//!   division and root may be correctly rounded, so these approximations are made on the
//!   host, the correct one moved by −3 … +3 ulps: a correction that did not step, or
//!   stepped the wrong way, returns them unchanged.
//! - `exact_div` and `exact_sqrt`, on the adapter's own approximations, give Rust's `/`
//!   and `sqrt` on the same operands and on zeros, infinities and NaN.
//! - `exact_mul(a, b) - c` is the product rounded before the subtraction, where c is
//!   within a few ulps of the product (a fused result differs there).

mod common;
use common::kernel::{self, TestKernel};
use common::*;

const PROBE_NAME: &str = "exact_probe.wgsl";
const PROBE: &str = include_str!("kernels/exact_probe.wgsl");

/// Xorshift, fixed seed per use.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }

    /// A positive finite f32 from uniform bits: every exponent equally likely, subnormals
    /// included.
    fn positive_bits(&mut self) -> f32 {
        f32::from_bits(1 + self.below(0x7f7f_ffff) as u32)
    }

    /// A random sign on `x`.
    fn signed(&mut self, x: f32) -> f32 {
        if self.next() >> 63 == 1 { -x } else { x }
    }

    /// 10^u, u uniform in [lo, hi).
    fn log_uniform(&mut self, lo: f64, hi: f64) -> f32 {
        10f64.powf(lo + (hi - lo) * (self.next() >> 11) as f64 / (1u64 << 53) as f64) as f32
    }

    /// An f32 with a significand of at most `bits` bits and a power-of-two exponent in
    /// `exponents`.
    fn short(&mut self, bits: u32, exponents: std::ops::Range<i32>) -> f32 {
        let m = (1 + self.below((1 << bits) - 1)) as f64;
        let e = exponents.start + self.below((exponents.end - exponents.start) as u64) as i32;
        (m * 2f64.powi(e)) as f32
    }
}

/// |x| as m × 2^e, m in [2^23, 2^24), for finite nonzero x (exact.wgsl's `exact_unpack`).
fn unpack(x: f32) -> (u32, i32) {
    let bits = x.to_bits() & 0x7fff_ffff;
    match bits >> 23 {
        0 => {
            let shift = bits.leading_zeros() - 8;
            (bits << shift, -149 - shift as i32)
        }
        field => ((bits & 0x7f_ffff) | 0x80_0000, field as i32 - 150),
    }
}

/// m / 2^23 in [1, 2), the significand whose quotients `div_rounded` takes.
fn significand(x: f32) -> f32 {
    unpack(x).0 as f32 / (1u32 << 23) as f32
}

/// x's significand scaled into [1, 4) by the parity of its exponent (`sqrt_rounded`'s).
fn scaled_significand(x: f32) -> f32 {
    let (m, e) = unpack(x);
    let m = if e.rem_euclid(2) == 1 { m } else { 2 * m };
    m as f32 / (1u32 << 23) as f32
}

/// The positive finite `x` moved by `k` ulps.
fn ulps_off(x: f32, k: i32) -> f32 {
    f32::from_bits((x.to_bits() as i32 + k) as u32)
}

/// Finite nonzero operand pairs over the whole range, with the kinds of result they give
/// counted so that every kind is known to be there.
fn quotient_operands() -> Vec<(f32, f32)> {
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let mut v = Vec::new();
    // Random bits: every binade, subnormals, overflow and underflow.
    for _ in 0..6000 {
        let (a, b) = (rng.positive_bits(), rng.positive_bits());
        v.push((rng.signed(a), rng.signed(b)));
    }
    // The adaptive rule's magnitudes: variances, means, counts.
    for _ in 0..3000 {
        let (a, b) = (rng.log_uniform(-14.0, 7.0), rng.log_uniform(-14.0, 7.0));
        v.push((a, b));
    }
    // Exact quotients: a = b c with short significands.
    for _ in 0..1000 {
        let (b, c) = (rng.short(12, -60..60), rng.short(12, -60..60));
        v.push((rng.signed(b * c), b));
    }
    // Ties in the subnormal range: a / b = (2j + 1) 2^-150.
    for _ in 0..1000 {
        let m = 1 + 2 * rng.below(1 << 9) as u32;
        let t = 1 + rng.below(100) as i32;
        let j = rng.below(1 << 12) as u32;
        let b = (m as f64 * 2f64.powi(t)) as f32;
        let a = ((2 * j + 1) as f64 * m as f64 * 2f64.powi(t - 150)) as f32;
        v.push((a, b));
    }
    // Significands at the ends of their binade, at exponents that keep, overflow and
    // underflow the result.
    let ends = [0u32, 1, 2, 0x40_0000, 0x7f_fffd, 0x7f_fffe, 0x7f_ffff];
    for &ma in &ends {
        for &mb in &ends {
            for (fa, fb) in [(127, 127), (200, 60), (254, 127), (254, 126), (10, 140), (1, 126), (0, 20)] {
                let (a, b) = (f32::from_bits(fa << 23 | ma), f32::from_bits(fb << 23 | mb));
                if a != 0.0 && b != 0.0 {
                    v.push((a, b));
                }
            }
        }
    }
    v.extend([(f32::MAX, 1.0 - f32::EPSILON / 2.0), (f32::MAX, 1.0), (f32::MIN_POSITIVE, 2.0 - f32::EPSILON)]);
    v.extend([(f32::from_bits(1), 2.0), (f32::from_bits(3), 2.0), (f32::from_bits(1), 1.5), (1.0, 3.0), (-1.0, 10.0)]);
    let results: Vec<f32> = v.iter().map(|&(a, b)| a / b).collect();
    let count = |f: &dyn Fn(f32) -> bool| results.iter().filter(|&&q| f(q)).count();
    let ties = v.iter().filter(|&&(a, b)| is_tie(a as f64 / b as f64)).count();
    let kinds = [
        ("infinite", count(&|q| q.is_infinite())),
        ("zero", count(&|q| q == 0.0)),
        ("subnormal", count(&|q| q.is_subnormal())),
        ("normal", count(&|q| q.is_normal())),
        ("exact", v.iter().filter(|&&(a, b)| (a / b) as f64 == a as f64 / b as f64).count()),
        ("ties", ties),
    ];
    for (kind, n) in kinds {
        assert!(n >= 10, "only {n} {kind} quotients among the operands");
    }
    v
}

/// Whether the f64 `q` (an exact quotient) lies halfway between two adjacent f32.
fn is_tie(q: f64) -> bool {
    let r = q as f32 as f64;
    if r == q || !r.is_finite() {
        return false;
    }
    let other = if r < q { f32::from_bits((r as f32).to_bits() + 1) } else { f32::from_bits((r as f32).to_bits() - 1) };
    // Both neighbours are f32, their midpoint is exact in f64.
    (r + other as f64) / 2.0 == q
}

/// Positive finite operands of a square root over the whole range.
fn root_operands() -> Vec<f32> {
    let mut rng = Rng(0x2545_f491_4f6c_dd1d);
    let mut v: Vec<f32> = (0..8000).map(|_| rng.positive_bits()).collect();
    v.extend((0..3000).map(|_| rng.log_uniform(-20.0, 9.0)));
    v.extend((0..500).map(|_| f32::from_bits(1 + rng.below(0x7f_ffff) as u32)));
    // Perfect squares.
    v.extend((0..1000).map(|_| rng.short(12, -80..60)).map(|y| y * y));
    // Perfect squares of subnormal results' roots and significands at binade ends.
    for m in [0u32, 1, 2, 0x40_0000, 0x7f_fffe, 0x7f_ffff] {
        for field in [0u32, 1, 2, 3, 126, 127, 128, 129, 253, 254] {
            let x = f32::from_bits(field << 23 | m);
            if x > 0.0 {
                v.push(x);
            }
        }
    }
    v.extend([f32::MAX, f32::MIN_POSITIVE, f32::from_bits(1), 2.0, 3.0, 0.5]);
    let exact = v.iter().filter(|&&x| ((x.sqrt() as f64) * (x.sqrt() as f64)) == x as f64).count();
    let subnormal = v.iter().filter(|x| x.is_subnormal()).count();
    assert!(exact >= 100 && subnormal >= 100, "{exact} perfect squares, {subnormal} subnormal operands");
    v
}

fn words(operands: impl Iterator<Item = [f32; 3]>) -> Vec<u8> {
    operands.flat_map(|o| [o[0].to_bits(), o[1].to_bits(), o[2].to_bits(), 0]).flat_map(u32::to_le_bytes).collect()
}

/// Runs `entry` on `operands` and returns the results.
fn run(probe: &TestKernel, entry: &str, operands: &[[f32; 3]]) -> Vec<f32> {
    let count = operands.len() as u32;
    let bits: Vec<u32> = probe.run(entry, [count, 0, 0, 0], &[&words(operands.iter().copied())], count, 1);
    bits.into_iter().map(f32::from_bits).collect()
}

/// Asserts that every result has the bits of `expected` (any NaN for a NaN).
fn assert_bits(what: &str, operands: &[[f32; 3]], got: &[f32], expected: impl Fn([f32; 3]) -> f32) {
    let wrong: Vec<String> = operands
        .iter()
        .zip(got)
        .filter(|&(&o, &g)| {
            let e = expected(o);
            !(e.to_bits() == g.to_bits() || (e.is_nan() && g.is_nan()))
        })
        .map(|(&o, &g)| {
            format!("{o:?} ({:08x?}): {g:e} ({:08x}), not {:e}", o.map(f32::to_bits), g.to_bits(), expected(o))
        })
        .collect();
    assert!(
        wrong.is_empty(),
        "{what}: {} of {} wrong, first {:?}",
        wrong.len(),
        operands.len(),
        &wrong[..wrong.len().min(5)]
    );
}

#[test]
fn probe_kernel_validates() {
    kernel::validate(PROBE_NAME, &kernel::compose(PROBE_NAME, PROBE));
}

fn probe() -> TestKernel {
    TestKernel::new(PROBE_NAME, PROBE, &["divide_from", "root_from", "divide", "root", "multiply_subtract"], 1)
}

#[test]
fn quotients_are_corrected_to_the_rounded_ones_from_3_ulps_off() {
    if !gpu_available() {
        return;
    }
    let probe = probe();
    let operands: Vec<[f32; 3]> = quotient_operands()
        .into_iter()
        .flat_map(|(a, b)| (-3..=3).map(move |k| [a, b, ulps_off(significand(a) / significand(b), k)]))
        .collect();
    let got = run(&probe, "divide_from", &operands);
    assert_bits("a / b from a quotient of significands up to 3 ulps off", &operands, &got, |[a, b, _]| a / b);
}

#[test]
fn roots_are_corrected_to_the_rounded_ones_from_3_ulps_off() {
    if !gpu_available() {
        return;
    }
    let probe = probe();
    let operands: Vec<[f32; 3]> = root_operands()
        .into_iter()
        .flat_map(|x| (-3..=3).map(move |k| [x, 0.0, ulps_off(scaled_significand(x).sqrt(), k)]))
        .collect();
    let got = run(&probe, "root_from", &operands);
    assert_bits("sqrt(x) from a root of its significand up to 3 ulps off", &operands, &got, |[x, _, _]| x.sqrt());
}

/// Zeros, infinities, NaN and finite values of both signs, every pair of them.
fn specials() -> Vec<f32> {
    let tiny = f32::from_bits(5);
    vec![0.0, -0.0, f32::INFINITY, f32::NEG_INFINITY, f32::NAN, 1.0, -3.0, f32::MIN_POSITIVE, tiny, -tiny, f32::MAX]
}

#[test]
fn division_and_root_on_the_adapter_are_rusts() {
    if !gpu_available() {
        return;
    }
    let probe = probe();
    let s = specials();
    let mut quotients: Vec<[f32; 3]> = quotient_operands().into_iter().map(|(a, b)| [a, b, 0.0]).collect();
    quotients.extend(s.iter().flat_map(|&a| s.iter().map(move |&b| [a, b, 0.0])));
    let got = run(&probe, "divide", &quotients);
    assert_bits("exact_div", &quotients, &got, |[a, b, _]| a / b);
    let mut roots: Vec<[f32; 3]> = root_operands().into_iter().map(|x| [x, 0.0, 0.0]).collect();
    roots.extend(s.iter().chain(&[-1.0, -f32::from_bits(3)]).map(|&x| [x, 0.0, 0.0]));
    let got = run(&probe, "root", &roots);
    assert_bits("exact_sqrt", &roots, &got, |[x, _, _]| x.sqrt());
}

#[test]
fn products_are_rounded_before_the_sums_they_feed() {
    if !gpu_available() {
        return;
    }
    let probe = probe();
    let mut rng = Rng(0x6a09_e667_f3bc_c908);
    let operands: Vec<[f32; 3]> = (0..20_000)
        .map(|_| {
            let a = rng.log_uniform(-10.0, 10.0);
            let (a, b) = (rng.signed(a), rng.log_uniform(-10.0, 10.0));
            let p = a * b;
            [a, b, f32::from_bits((p.to_bits() as i32 + rng.below(5) as i32 - 2) as u32)]
        })
        .collect();
    // Where c is near a b, a fused a b − c is the product's rounding error, not 0 or ulps.
    let fused_differs = operands.iter().filter(|&&[a, b, c]| a.mul_add(b, -c) != a * b - c).count();
    assert!(fused_differs > 10_000, "only {fused_differs} operands tell a fused result apart");
    let got = run(&probe, "multiply_subtract", &operands);
    assert_bits("exact_mul(a, b) - c", &operands, &got, |[a, b, c]| a * b - c);
}
