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
    /// Samples per replicate (see [`crate::Sampler`]): 1 when every sample is independent, 0
    /// when the samples are one replicate (no valid error estimate).
    pub replicate: u32,
    /// Complete replicates in `replicate_sq`, the same for every group.
    pub replicates: u64,
    /// Σ over complete replicates of (the replicate's Σ value)², per group: per pixel for
    /// an image, per point for a probe film; empty unless `replicate` ≥ 2.
    pub replicate_sq: Vec<f64>,
    /// Samples of each pixel, when an adaptive render gave pixels different counts
    /// (`samples` is then the most); empty when every pixel has `samples`.
    pub pixel_samples: Vec<u64>,
    /// Complete replicates of each pixel, likewise (`replicates` is then the fewest).
    pub pixel_replicates: Vec<u64>,
}

/// How a film's error is estimated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ErrorEstimator {
    /// From the spread of independent samples.
    Samples,
    /// From the spread of the means of `count` independently randomised replicates of
    /// `size` samples each.
    Replicates {
        /// Samples per replicate.
        size: u32,
        /// Complete replicates.
        count: u64,
    },
    /// None valid: the samples are one replicate of a low-discrepancy or cell sampler
    /// (the spread of single samples overestimates its error), or too few replicates.
    None,
}

impl ErrorEstimator {
    /// In words, for statistics.
    pub fn describe(&self) -> String {
        match self {
            ErrorEstimator::Samples => "spread of independent samples".into(),
            ErrorEstimator::Replicates { size, count } => {
                format!("spread of the means of {count} independently randomised replicates of {size} samples")
            }
            ErrorEstimator::None => "none: fewer than two independent replicates".into(),
        }
    }

    /// The estimator standard errors are reported with: this one, or without a valid
    /// estimate the spread of single samples (an overestimate for stratified and Sobol
    /// points, and no error at all for the grid's).
    pub fn or_samples(self) -> ErrorEstimator {
        match self {
            ErrorEstimator::None => ErrorEstimator::Samples,
            e => e,
        }
    }

    /// Degrees of freedom of the variance estimate (0 when there is none).
    pub fn degrees_of_freedom(&self, samples: u64) -> u64 {
        match *self {
            ErrorEstimator::Samples => samples.saturating_sub(1),
            ErrorEstimator::Replicates { count, .. } => count.saturating_sub(1),
            ErrorEstimator::None => 0,
        }
    }
}

/// The 97.5 % quantile of Student's t distribution with `dof` degrees of freedom: the
/// half-width of a two-sided 95 % confidence interval in standard errors, when the error
/// estimate has `dof` degrees of freedom ([`ErrorEstimator::degrees_of_freedom`]).
/// Exact table values up to 6, then the Cornish–Fisher expansion about the normal
/// quantile (Abramowitz & Stegun 26.7.5), within 1e-4 of the exact value from 7 on.
pub fn t_quantile_975(dof: u64) -> f64 {
    match dof {
        0 => f64::INFINITY,
        1 => 12.706_204_736,
        2 => 4.302_652_730,
        3 => 3.182_446_305,
        4 => 2.776_445_105,
        5 => 2.570_581_836,
        6 => 2.446_911_851,
        _ => {
            let (z, v) = (1.959_963_985f64, dof as f64);
            let (z3, z5, z7, z9) = (z.powi(3), z.powi(5), z.powi(7), z.powi(9));
            z + (z3 + z) / (4.0 * v)
                + (5.0 * z5 + 16.0 * z3 + 3.0 * z) / (96.0 * v * v)
                + (3.0 * z7 + 19.0 * z5 + 17.0 * z3 - 15.0 * z) / (384.0 * v.powi(3))
                + (79.0 * z9 + 776.0 * z7 + 1482.0 * z5 - 1920.0 * z3 - 945.0 * z) / (92160.0 * v.powi(4))
        }
    }
}

/// A two-sided 95 % confidence interval for the mean of `n` samples of magnitude at most
/// `max_value`, estimated as `mean` with standard error `std_error` and `dof` degrees of
/// freedom: `mean` ± t(dof) `std_error` ([`t_quantile_975`]). When every sample was the
/// same (a zero standard error: every AO ray of a nearly open pixel escaped), the spread
/// says nothing, and the interval is the Jeffreys bound for a binomial proportion with no
/// event (Brown, Cai & DasGupta, "Interval estimation for a binomial proportion", 2001):
/// the samples that would differ have a probability of at most q = χ²₁(0.95) / (2n + 1)
/// (the Beta(½, n + ½) quantile for large n), one-sided because equal samples sit at an
/// end of what the pixel's samples can be, and move the mean towards 0 or `max_value` by
/// at most that share of the distance (samples lie in [min(0, mean), `max_value`]). For
/// stratified samples the chance that every cell misses an event is at most that of
/// independent ones (the product of the cells' chances), and scrambled nets are
/// negatively dependent in the same sense (Wiart, Lemieux & Dong, "On the dependence
/// structure and quality of scrambled (t, m, s)-nets", 2021).
pub fn interval_95(mean: f64, std_error: f64, dof: u64, n: u64, max_value: f64) -> (f64, f64) {
    if std_error > 1e-9 * max_value.abs().max(f64::MIN_POSITIVE) || n == 0 {
        let h = t_quantile_975(dof) * std_error;
        return (mean - h, mean + h);
    }
    let q = (3.841_458_8 / (2.0 * n as f64 + 1.0)).min(1.0);
    // Samples lie in [min(0, mean), max_value]: AO values are not negative, and a
    // background below them is the least a sample can be.
    (mean - q * mean.max(0.0), mean + q * (max_value - mean).max(0.0))
}

/// The standard error of the mean of `n` samples whose sum is `sum`, from `estimator`:
/// with [`ErrorEstimator::Samples`], from Σv² (`sum_sq`); with replicates, from the Σ
/// of their sums' squares (`replicate_sq`) and the spread of their means around the
/// mean of all `n` samples. Samples beyond the complete replicates (a replicate cut
/// short) count as a share of a replicate: the variance per sample is taken from the
/// complete ones. Infinite when there is no estimate.
pub fn standard_error(estimator: ErrorEstimator, n: u64, sum: f64, sum_sq: f64, replicate_sq: f64) -> f64 {
    let nf = n as f64;
    match estimator {
        ErrorEstimator::Samples if n >= 2 => {
            let mean = sum / nf;
            let var = ((sum_sq - nf * mean * mean) / (nf - 1.0)).max(0.0);
            (var / nf).sqrt()
        }
        ErrorEstimator::Replicates { size, count } if count >= 2 && n > 0 => {
            let (b, k) = (size as f64, count as f64);
            let mean = sum / nf;
            // Variance of a replicate's mean: (Σ M² − k M̄²) / (k − 1), M = S / b.
            let var = ((replicate_sq / (b * b) - k * mean * mean) / (k - 1.0)).max(0.0);
            // Of the mean of n samples, n / b replicates' worth.
            (var * b / nf).sqrt()
        }
        _ => f64::INFINITY,
    }
}

impl Film {
    /// An empty accumulation.
    pub fn new(width: u32, height: u32) -> Film {
        let n = width as usize * height as usize;
        Film {
            width,
            height,
            samples: 0,
            sum: vec![0.0; n],
            sum_sq: vec![0.0; n],
            replicate: 1,
            replicates: 0,
            replicate_sq: Vec::new(),
            pixel_samples: Vec::new(),
            pixel_replicates: Vec::new(),
        }
    }

    /// Samples of pixel `i`.
    pub fn samples_of(&self, i: usize) -> u64 {
        self.pixel_samples.get(i).copied().unwrap_or(self.samples)
    }

    /// Complete replicates of pixel `i`.
    pub fn replicates_of(&self, i: usize) -> u64 {
        self.pixel_replicates.get(i).copied().unwrap_or(self.replicates)
    }

    /// Per-pixel estimates (sample means).
    pub fn mean(&self) -> Vec<f64> {
        (0..self.sum.len()).map(|i| self.sum[i] / self.samples_of(i).max(1) as f64).collect()
    }

    /// How [`Film::std_error`] estimates the error.
    pub fn error_estimator(&self) -> ErrorEstimator {
        match self.replicate {
            0 => ErrorEstimator::None,
            1 => ErrorEstimator::Samples,
            size if self.replicates >= 2 => ErrorEstimator::Replicates { size, count: self.replicates },
            _ => ErrorEstimator::None,
        }
    }

    /// Per-pixel standard error of the mean (`standard_error`), valid for every sampler
    /// whose samples are in two or more replicates. Without a valid estimate
    /// ([`ErrorEstimator::None`]) it is the spread of single samples, which overestimates
    /// the error of stratified and Sobol points (the grid's is not an error at all).
    pub fn std_error(&self) -> Vec<f64> {
        let estimator = self.error_estimator().or_samples();
        (0..self.sum.len())
            .map(|i| {
                let r = self.replicate_sq.get(i).copied().unwrap_or(0.0);
                let e = match estimator {
                    ErrorEstimator::Replicates { size, .. } => {
                        ErrorEstimator::Replicates { size, count: self.replicates_of(i) }
                    }
                    e => e,
                };
                standard_error(e, self.samples_of(i), self.sum[i], self.sum_sq[i], r)
            })
            .collect()
    }

    /// Estimated root-mean-square error of the image against its converged value: the
    /// root of the mean of the per-pixel variances of the mean, when the error estimate is
    /// valid ([`Film::error_estimator`]).
    pub fn rmse_estimate(&self) -> Option<f64> {
        if self.error_estimator() == ErrorEstimator::None || self.sum.is_empty() {
            return None;
        }
        let se = self.std_error();
        let ms = se.iter().map(|e| e * e).sum::<f64>() / se.len() as f64;
        ms.is_finite().then(|| ms.sqrt())
    }

    /// A one-sided 99 % upper bound on the image's realised root-mean-square error,
    /// from [`Film::rmse_estimate`]. With per-pixel variances v (estimated with d degrees
    /// of freedom), the realised mean square error fluctuates around Σv / P with a
    /// relative standard deviation √(2 / P_eff), P_eff = (Σv)² / Σv², and the estimate
    /// around it with √(2 / (d P_eff)) (normal errors); the RMSE's relative deviation is
    /// half the mean square's, and the bound adds 2.326 of both (99 %, so that renders
    /// stopped by it meet their target in well over 95 % of seeds). What a render that stops
    /// at an error target (`Control::target`) compares with the target.
    pub fn rmse_bound(&self) -> Option<f64> {
        let rmse = self.rmse_estimate()?;
        let v: Vec<f64> = self.std_error().iter().map(|e| e * e).collect();
        let (sum, sum_sq) = (v.iter().sum::<f64>(), v.iter().map(|x| x * x).sum::<f64>());
        if sum_sq == 0.0 {
            return Some(rmse);
        }
        let p_eff = sum * sum / sum_sq;
        let d = self.error_estimator().degrees_of_freedom(self.samples).max(1) as f64;
        Some(rmse * (1.0 + 2.326 * ((1.0 + 1.0 / d) / (2.0 * p_eff)).sqrt()))
    }

    /// Per-pixel two-sided 95 % confidence intervals of the means ([`interval_95`]), for
    /// samples of magnitude at most `max_value`; `None` without a valid error estimate.
    pub fn intervals_95(&self, max_value: f64) -> Option<Vec<(f64, f64)>> {
        let estimator = self.error_estimator();
        if estimator == ErrorEstimator::None {
            return None;
        }
        let (mean, se) = (self.mean(), self.std_error());
        Some(
            (0..mean.len())
                .map(|i| {
                    let n = self.samples_of(i);
                    let dof = match estimator {
                        ErrorEstimator::Replicates { .. } => self.replicates_of(i).saturating_sub(1),
                        e => e.degrees_of_freedom(n),
                    };
                    interval_95(mean[i], se[i], dof, n, max_value)
                })
                .collect(),
        )
    }

    /// Mean over all pixels of the per-pixel estimates.
    pub fn image_mean(&self) -> f64 {
        let m = self.mean();
        m.iter().sum::<f64>() / m.len() as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn t_quantiles_match_the_tables() {
        // Student's t, 97.5 % (two-sided 95 %), from the standard tables.
        for (dof, t) in [(5, 2.570_582), (7, 2.364_624), (15, 2.131_450), (30, 2.042_272), (63, 1.998_341)] {
            assert!((t_quantile_975(dof) - t).abs() < 1e-4, "dof {dof}: {} against {t}", t_quantile_975(dof));
        }
        assert!((t_quantile_975(1 << 30) - 1.959_964).abs() < 1e-6);
    }

    #[test]
    fn replicate_error_is_the_spread_of_replicate_means() {
        // Replicates of 4 samples with means 0.25, 0.5, 0.75, 0.5: mean 0.5, their
        // variance (1/16 + 0 + 1/16 + 0) / 3 = 1/24, standard error √(1/24 / 4).
        let sums = [1.0, 2.0, 3.0, 2.0];
        let rsq: f64 = sums.iter().map(|s| s * s).sum();
        let e = ErrorEstimator::Replicates { size: 4, count: 4 };
        let se = standard_error(e, 16, 8.0, 0.0, rsq);
        assert!((se - (1.0f64 / 96.0).sqrt()).abs() < 1e-15, "{se}");
        assert_eq!(standard_error(ErrorEstimator::Replicates { size: 4, count: 1 }, 4, 1.0, 0.0, 1.0), f64::INFINITY);
    }
}

/// The bits a device film slot's last word holds while its pixel is inactive (an
/// adaptive render has stopped sampling it): a NaN no sum produces. The GPU kernel skips
/// such a slot; the slot reads back as empty.
pub const INACTIVE_SLOT_BITS: u32 = 0x7fc0_0a0d;

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
    /// Σ (replicate's Σv)² over complete replicates, per group ([`Film::replicate_sq`]),
    /// in quanta of 2^(`sq_exponent` + [`REPLICATE_SQ_SHIFT`]); empty when the samples
    /// are not replicated.
    pub replicate_sq: Vec<i128>,
    /// Complete replicates in `replicate_sq`.
    pub replicates: u64,
    /// Samples of each pixel's finished blocks, once an adaptive render has stopped
    /// sampling some pixels; empty while every pixel has the same.
    pub pixel_samples: Vec<u32>,
    /// Complete replicates of each pixel, likewise.
    pub pixel_replicates: Vec<u32>,
    /// The pixels an adaptive render has stopped sampling (empty: none).
    pub stopped: Vec<bool>,
}

/// log2 of the ratio of the quantum of [`ExactSums::replicate_sq`] to that of Σv²: the
/// squares of 2^32 / b replicates of b samples add to at most 2^32 b times a sample's
/// largest square, and b is at most 256 = 2^8.
pub const REPLICATE_SQ_SHIFT: i32 = 8;

impl ExactSums {
    /// Zero sums for samples of magnitude at most `max_value`.
    pub fn new(width: u32, height: u32, max_value: f64) -> ExactSums {
        let (sum_exponent, sq_exponent) = ExactSums::exponents(max_value);
        let n = width as usize * height as usize;
        ExactSums {
            width,
            height,
            sum_exponent,
            sq_exponent,
            sum: vec![0; n],
            sum_sq: vec![0; n],
            replicate_sq: Vec::new(),
            replicates: 0,
            pixel_samples: Vec::new(),
            pixel_replicates: Vec::new(),
            stopped: Vec::new(),
        }
    }

    /// Empties the sums, keeping their size and scale.
    pub fn clear(&mut self) {
        self.sum.fill(0);
        self.sum_sq.fill(0);
        self.replicate_sq.fill(0);
        self.replicates = 0;
        self.pixel_samples.clear();
        self.pixel_replicates.clear();
        self.stopped.clear();
    }

    /// Keeps counts per pixel from now on, every pixel starting from `samples` samples
    /// and the common count of replicates (nothing to do when it already does).
    pub fn count_per_pixel(&mut self, samples: u32) {
        if self.pixel_samples.is_empty() {
            self.pixel_samples = vec![samples; self.sum.len()];
            self.pixel_replicates = vec![self.replicates as u32; self.sum.len()];
            self.stopped = vec![false; self.sum.len()];
        }
    }

    /// Adds `count` complete replicates whose sums are `sums` (`count` per group, group
    /// after group), each squared in f64 and rounded once to the quantum. An error names
    /// the first group whose square is out of range.
    pub fn add_replicates(&mut self, sums: &[f64], count: u64) -> Result<(), SumsError> {
        let groups = sums.len() / count.max(1) as usize;
        if self.replicate_sq.is_empty() {
            self.replicate_sq = vec![0; groups];
        }
        if groups != self.replicate_sq.len() || sums.len() as u64 != groups as u64 * count {
            return Err(SumsError(format!(
                "{} replicate sums added to {} groups of {count}",
                sums.len(),
                self.replicate_sq.len()
            )));
        }
        let e = self.sq_exponent + REPLICATE_SQ_SHIFT;
        for (g, chunk) in sums.chunks_exact(count.max(1) as usize).enumerate() {
            for &s in chunk {
                let bad = || SumsError(format!("group {g}: a replicate's sum {s} is out of range"));
                let q = quantize(s * s, e).ok_or_else(bad)?;
                self.replicate_sq[g] = self.replicate_sq[g].checked_add(q).ok_or_else(bad)?;
            }
        }
        self.replicates += count;
        Ok(())
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
        if self.replicate_sq.is_empty() {
            self.replicate_sq = vec![0; other.replicate_sq.len()];
        }
        if !other.replicate_sq.is_empty() && other.replicate_sq.len() != self.replicate_sq.len() {
            return Err(SumsError("replicate sums of another size".into()));
        }
        let pairs = self.sum.iter_mut().zip(&other.sum).chain(self.sum_sq.iter_mut().zip(&other.sum_sq));
        for (a, b) in pairs.chain(self.replicate_sq.iter_mut().zip(&other.replicate_sq)) {
            *a = a.checked_add(*b).ok_or_else(|| SumsError("a sum overflowed".into()))?;
        }
        if self.pixel_samples.len() != other.pixel_samples.len() {
            return Err(SumsError("sums counted per pixel added to sums counted per image".into()));
        }
        let counts = self.pixel_samples.iter_mut().zip(&other.pixel_samples);
        for (a, b) in counts.chain(self.pixel_replicates.iter_mut().zip(&other.pixel_replicates)) {
            *a = a.checked_add(*b).ok_or_else(|| SumsError("a sample count overflowed".into()))?;
        }
        self.replicates += other.replicates;
        Ok(())
    }

    /// Σv and Σv² over the slots `range`, added exactly and rounded once to f64.
    pub fn sum_range(&self, range: std::ops::Range<usize>) -> (f64, f64) {
        let (qs, qq) = (pow2(self.sum_exponent), pow2(self.sq_exponent));
        let sum: i128 = self.sum[range.clone()].iter().sum();
        let sum_sq: i128 = self.sum_sq[range].iter().sum();
        (sum as f64 * qs, sum_sq as f64 * qq)
    }

    /// The sums as a [`Film`] of `samples` samples per pixel in replicates of
    /// `replicate` samples (each sum rounded once to f64).
    pub fn to_film(&self, samples: u64, replicate: u32) -> Film {
        let (qs, qq) = (pow2(self.sum_exponent), pow2(self.sq_exponent));
        let qr = pow2(self.sq_exponent + REPLICATE_SQ_SHIFT);
        Film {
            width: self.width,
            height: self.height,
            samples,
            sum: self.sum.iter().map(|&s| s as f64 * qs).collect(),
            sum_sq: self.sum_sq.iter().map(|&q| q as f64 * qq).collect(),
            replicate,
            replicates: self.replicate_count(),
            replicate_sq: self.replicate_sq.iter().map(|&q| q as f64 * qr).collect(),
            pixel_samples: self.pixel_samples.iter().map(|&n| n as u64).collect(),
            pixel_replicates: self.pixel_replicates.iter().map(|&n| n as u64).collect(),
        }
    }

    /// Complete replicates: the fewest of any pixel when counted per pixel.
    pub fn replicate_count(&self) -> u64 {
        self.pixel_replicates.iter().min().map_or(self.replicates, |&k| k as u64)
    }
}

/// `x` / 2^`exponent` rounded to the nearest integer (halves away from zero); `None`
/// when `x` is not finite or the result is not below 2^125 in magnitude.
fn quantize(x: f64, exponent: i32) -> Option<i128> {
    let y = (x * pow2(-exponent)).round();
    (y.abs() < pow2(MAGNITUDE_LOG2)).then_some(y as i128)
}
