//! Per-pixel sums of sample values and their squares, as a render's passes leave them:
//! the [`Film`] (f64 sums, means, standard errors), a device's sums of one block of
//! samples ([`BlockSums`]) and the exact fixed-point sums of finished blocks
//! ([`ExactSums`]).

/// Per-pixel sums over the samples rendered so far. Pixel `(x, y)` is at `y * width + x`.
#[derive(Clone, Debug, PartialEq)]
pub struct Film {
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Samples in every pixel's sums.
    pub samples: u64,
    /// Σ value.
    pub sum: Vec<f64>,
    /// Σ value².
    pub sum_sq: Vec<f64>,
}

impl Film {
    /// An empty accumulation.
    pub fn new(width: u32, height: u32) -> Film {
        let n = width as usize * height as usize;
        Film { width, height, samples: 0, sum: vec![0.0; n], sum_sq: vec![0.0; n] }
    }

    /// Per-pixel estimates (sample means).
    pub fn mean(&self) -> Vec<f64> {
        let n = self.samples.max(1) as f64;
        self.sum.iter().map(|s| s / n).collect()
    }

    /// Per-pixel standard error of the mean, from the sample variance. It assumes
    /// independent samples: for stratified and Sobol samples it is an overestimate.
    pub fn std_error(&self) -> Vec<f64> {
        let n = self.samples as f64;
        if self.samples < 2 {
            return vec![f64::INFINITY; self.sum.len()];
        }
        self.sum
            .iter()
            .zip(&self.sum_sq)
            .map(|(s, q)| {
                let mean = s / n;
                let var = ((q / n - mean * mean) * n / (n - 1.0)).max(0.0);
                (var / n).sqrt()
            })
            .collect()
    }

    /// Mean over all pixels of the per-pixel estimates.
    pub fn image_mean(&self) -> f64 {
        let m = self.mean();
        m.iter().sum::<f64>() / m.len() as f64
    }
}

/// Samples per block, the unit of exact accumulation: block `k` holds sample indices
/// `256k .. 256k + 256` (cut short by the ends of the rendered range). A device sums one
/// block at a time in its own arithmetic (compensated f32 on the GPU, f64 on the CPU);
/// each finished block is rounded once to a fixed-point integer and added to
/// exact fixed-point sums, where addition is exact, so the result does not depend on how the
/// blocks were grouped into passes, runs or shards.
pub const BLOCK_SAMPLES: u32 = 256;

/// Per-pixel sums of the samples of one block, as the device keeps them.
#[derive(Clone, Debug, PartialEq)]
pub enum BlockSums {
    /// The GPU film's f32 words per pixel: Σv, its Neumaier compensation, Σv², its
    /// compensation.
    Gpu(Vec<[f32; 4]>),
    /// The CPU reference's f64 sums.
    Cpu {
        /// Σv.
        sum: Vec<f64>,
        /// Σv².
        sum_sq: Vec<f64>,
    },
}

impl BlockSums {
    /// Pixels.
    pub fn len(&self) -> usize {
        match self {
            BlockSums::Gpu(words) => words.len(),
            BlockSums::Cpu { sum, .. } => sum.len(),
        }
    }

    /// True when there are no pixels.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Pixel `i`'s (Σv, Σv²); a compensated pair is added in f64, where two f32 add exactly
    /// unless their exponents are more than 29 apart.
    pub fn pixel(&self, i: usize) -> (f64, f64) {
        match self {
            BlockSums::Gpu(words) => {
                let t = words[i];
                (t[0] as f64 + t[1] as f64, t[2] as f64 + t[3] as f64)
            }
            BlockSums::Cpu { sum, sum_sq } => (sum[i], sum_sq[i]),
        }
    }
}

/// Sums that cannot be added: of another size or scale, or out of range (a device that
/// produced a non-finite sum, or a damaged checkpoint). The message names the pixel.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct SumsError(pub String);

/// log2 of the most samples one pixel can accumulate: sample indices are 32-bit.
const MAX_SAMPLES_LOG2: i32 = 32;
/// log2 of the bound on the integers of [`ExactSums`]: 2^32 samples of the largest value
/// stay below it, and i128 holds twice it.
const MAGNITUDE_LOG2: i32 = 125;

/// 2^n as f64, exactly, for n in -1022..=1023.
fn pow2(n: i32) -> f64 {
    debug_assert!((-1022..=1023).contains(&n));
    f64::from_bits(((n + 1023) as u64) << 52)
}

/// Per-pixel sums of finished blocks in fixed point: Σv of pixel `i` is
/// `sum[i]` × 2^`sum_exponent`, Σv² is `sum_sq[i]` × 2^`sq_exponent`. The quanta are set
/// from the largest value a sample can take so that 2^32 samples fit; they are about
/// 2^-93 of that value, far below f64's resolution of any sum of samples. Integer
/// addition is associative: blocks added in any order or grouping give the same bits.
#[derive(Clone, Debug, PartialEq)]
pub struct ExactSums {
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Exponent of the quantum of `sum`.
    pub sum_exponent: i32,
    /// Exponent of the quantum of `sum_sq`.
    pub sq_exponent: i32,
    /// Σv in quanta.
    pub sum: Vec<i128>,
    /// Σv² in quanta.
    pub sum_sq: Vec<i128>,
}

impl ExactSums {
    /// Zero sums for samples of magnitude at most `max_value`.
    pub fn new(width: u32, height: u32, max_value: f64) -> ExactSums {
        let (sum_exponent, sq_exponent) = ExactSums::exponents(max_value);
        let n = width as usize * height as usize;
        ExactSums { width, height, sum_exponent, sq_exponent, sum: vec![0; n], sum_sq: vec![0; n] }
    }

    /// The quanta's exponents for samples of magnitude at most `max_value` (taken as at
    /// least 1; non-finite is taken as the largest f32 doubled).
    pub fn exponents(max_value: f64) -> (i32, i32) {
        let v = if max_value.is_finite() { max_value.max(1.0) } else { 2.0 * f32::MAX as f64 };
        // The smallest e with 2^e ≥ v: at most 129 for any f32 value doubled.
        let mut e = 0;
        while e < 256 && pow2(e) < v {
            e += 1;
        }
        (e + MAX_SAMPLES_LOG2 - MAGNITUDE_LOG2, 2 * e + MAX_SAMPLES_LOG2 - MAGNITUDE_LOG2)
    }

    /// Adds a finished block, each pixel's sums rounded to the nearest quantum. An error
    /// names the first pixel whose sum is not finite or out of range.
    pub fn add_block(&mut self, block: &BlockSums) -> Result<(), SumsError> {
        if block.len() != self.sum.len() {
            return Err(SumsError(format!("a block of {} pixels added to sums of {}", block.len(), self.sum.len())));
        }
        let w = self.width.max(1) as usize;
        for i in 0..self.sum.len() {
            let (s, q) = block.pixel(i);
            let bad = || {
                SumsError(format!("pixel ({}, {}): a sum of samples ({s}, squares {q}) is out of range", i % w, i / w))
            };
            let s = quantize(s, self.sum_exponent).ok_or_else(bad)?;
            let q = quantize(q, self.sq_exponent).ok_or_else(bad)?;
            self.sum[i] = self.sum[i].checked_add(s).ok_or_else(bad)?;
            self.sum_sq[i] = self.sum_sq[i].checked_add(q).ok_or_else(bad)?;
        }
        Ok(())
    }

    /// Adds the sums of other samples of the same pixels, exactly.
    pub fn add(&mut self, other: &ExactSums) -> Result<(), SumsError> {
        if (other.width, other.height, other.sum_exponent, other.sq_exponent)
            != (self.width, self.height, self.sum_exponent, self.sq_exponent)
        {
            return Err(SumsError("sums of another size or scale".into()));
        }
        for (a, b) in self.sum.iter_mut().zip(&other.sum).chain(self.sum_sq.iter_mut().zip(&other.sum_sq)) {
            *a = a.checked_add(*b).ok_or_else(|| SumsError("a sum overflowed".into()))?;
        }
        Ok(())
    }

    /// Σv and Σv² over the slots `range`, added exactly and rounded once to f64.
    pub fn sum_range(&self, range: std::ops::Range<usize>) -> (f64, f64) {
        let (qs, qq) = (pow2(self.sum_exponent), pow2(self.sq_exponent));
        let sum: i128 = self.sum[range.clone()].iter().sum();
        let sum_sq: i128 = self.sum_sq[range].iter().sum();
        (sum as f64 * qs, sum_sq as f64 * qq)
    }

    /// The sums as a [`Film`] of `samples` samples per pixel (each rounded once to f64).
    pub fn to_film(&self, samples: u64) -> Film {
        let (qs, qq) = (pow2(self.sum_exponent), pow2(self.sq_exponent));
        Film {
            width: self.width,
            height: self.height,
            samples,
            sum: self.sum.iter().map(|&s| s as f64 * qs).collect(),
            sum_sq: self.sum_sq.iter().map(|&q| q as f64 * qq).collect(),
        }
    }
}

/// `x` / 2^`exponent` rounded to the nearest integer (halves away from zero); `None`
/// when `x` is not finite or the result is not below 2^125 in magnitude.
fn quantize(x: f64, exponent: i32) -> Option<i128> {
    let y = (x * pow2(-exponent)).round();
    (y.abs() < pow2(MAGNITUDE_LOG2)).then_some(y as i128)
}
