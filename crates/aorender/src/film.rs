//! Per-pixel sums of sample values and their squares, as a render's passes leave them:
//! the [`Film`] (f64 sums, means, standard errors), a device's sums of one block of
//! samples ([`BlockSums`]) and the exact fixed-point sums of finished blocks
//! ([`ExactSums`]).

use rayon::prelude::*;
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
    /// Complete replicates of each pixel, likewise (`replicates` is then the fewest of the
    /// pixels not `exact`).
    pub pixel_replicates: Vec<u64>,
    /// Pixels whose value is exact: an adaptive render's background pixels (their camera
    /// rays see no geometry), stopped after their first replicate. Their standard error is
    /// 0; empty when there are none.
    pub exact: Vec<bool>,
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

/// A two-sided 95 % confidence interval for the mean of `n` samples that lie in
/// [min(0, `mean`), `upper`], estimated as `mean` with standard error `std_error` and `dof`
/// degrees of freedom.
///
/// With a spread, it is Wilson's score interval ("Probable inference, the law of
/// succession, and statistical inference", JASA 1927) for the mean's share p of the
/// range, with the effective sample size of Korn & Graubard ("Confidence intervals for
/// proportions with small expected number of positive counts estimated from survey data",
/// Survey Methodology 1998): n* = p̂(1 − p̂) / v̂ from the estimated variance v̂ of p̂, and
/// Student's t quantile for its `dof` ([`t_quantile_975`]). For samples of 0 or the
/// range's end (the cosine estimators' visibility times an albedo) it is Wilson's interval
/// itself; for replicates' means or weighted samples n* counts what their spread is
/// worth. It is the set of p with (p̂ − p)² ≤ t² p (1 − p) / n*: where the Wald interval
/// p̂ ± t √v̂ takes the variance at p̂, which near the range's ends is too small and
/// undercovers (Brown, Cai & DasGupta, "Interval estimation for a binomial proportion",
/// Statistical Science 2001), it takes the variance each candidate p would have, and far
/// from the ends it is the t interval.
///
/// When every sample was the same (a zero standard error: every AO ray of a nearly open
/// pixel escaped), the spread says nothing, and the interval is the Jeffreys bound for a
/// binomial proportion with no event (Brown, Cai & DasGupta 2001): the samples that would
/// differ have a probability of at most q = χ²₁(0.95) / (2n + 1) (the Beta(½, n + ½)
/// quantile for large n), one-sided because equal samples sit at an end of what the
/// pixel's samples can be, and move the mean towards 0 or `upper` by at most that share
/// of the distance. For stratified samples the chance that every cell misses an event is
/// at most that of independent ones (the product of the cells' chances), and scrambled
/// nets are negatively dependent in the same sense (Wiart, Lemieux & Dong, "On the
/// dependence structure and quality of scrambled (t, m, s)-nets", 2021).
pub fn interval_95(mean: f64, std_error: f64, dof: u64, n: u64, upper: f64) -> (f64, f64) {
    // Samples lie in [min(0, mean), upper]: AO values are not negative, and a background
    // below them is the least a sample can be.
    interval_95_within(mean, std_error, dof, n, mean.min(0.0), upper)
}

/// [`interval_95`] for samples that lie in [`lower`, `upper`].
pub fn interval_95_within(mean: f64, std_error: f64, dof: u64, n: u64, lower: f64, upper: f64) -> (f64, f64) {
    if n == 0 || !std_error.is_finite() {
        return (f64::NEG_INFINITY, f64::INFINITY);
    }
    if std_error > 1e-9 * upper.abs().max(f64::MIN_POSITIVE) {
        let t = t_quantile_975(dof);
        let (lo, hi) = (lower.min(mean), upper.max(mean));
        let range = hi - lo;
        let p = (mean - lo) / range;
        let v = (std_error / range).powi(2);
        let spread = p * (1.0 - p);
        if !(range > 0.0 && spread > 0.0 && spread.is_finite()) {
            let h = t * std_error;
            return (mean - h, mean + h);
        }
        // k = t² / n*: the score equation's (1 + k) p² − (2p̂ + k) p + p̂² = 0.
        let k = t * t * v / spread;
        let centre = (p + 0.5 * k) / (1.0 + k);
        let half = (k * (spread + 0.25 * k)).sqrt() / (1.0 + k);
        return (lo + range * (centre - half).max(0.0), lo + range * (centre + half).min(1.0));
    }
    let q = (3.841_458_8 / (2.0 * n as f64 + 1.0)).min(1.0);
    (mean - q * mean.max(0.0), mean + q * (upper - mean).max(0.0))
}

/// What one sample of a pixel or point can be, for its confidence interval
/// ([`interval_95`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SampleRange {
    /// 0 or the albedo of what the camera ray hit, at most this (the cosine estimators,
    /// whose samples are an albedo times a visibility, with no background): a pixel's
    /// samples lie in [0, ρ], and ρ = Σv² / Σv once one of them is not 0.
    Binary(f64),
    /// Anywhere from min(0, the mean) to this (the uniform estimator's weights
    /// 2 ρ cos θ, or a background).
    Bounded(f64),
    /// Anywhere from minus this to this (the overcast sky's control variate, whose
    /// samples are the open value less a weight where the ray is blocked).
    Signed(f64),
}

impl SampleRange {
    /// The range of a render's samples with `hemisphere`, a `background` and samples of
    /// magnitude at most `max_value`.
    pub fn of(hemisphere: crate::sampling::Hemisphere, background: f32, max_value: f64) -> SampleRange {
        match hemisphere {
            crate::sampling::Hemisphere::Cosine | crate::sampling::Hemisphere::CosinePolar if background == 0.0 => {
                SampleRange::Binary(max_value)
            }
            _ => SampleRange::Bounded(max_value),
        }
    }

    /// The largest value the samples whose sum is `sum` and sum of squares `sum_sq` can
    /// take: what [`interval_95`] takes as `upper`.
    pub fn upper(self, sum: f64, sum_sq: f64) -> f64 {
        match self {
            // Samples of 0 or ρ have Σv² = ρ Σv.
            SampleRange::Binary(max) if sum > 0.0 && sum_sq > 0.0 => (sum_sq / sum).min(max),
            SampleRange::Binary(max) | SampleRange::Bounded(max) | SampleRange::Signed(max) => max,
        }
    }

    /// The smallest value the samples whose mean is `mean` can take.
    pub fn lower(self, mean: f64) -> f64 {
        match self {
            SampleRange::Binary(_) | SampleRange::Bounded(_) => mean.min(0.0),
            SampleRange::Signed(max) => -max,
        }
    }
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

/// The one-sided 99 % upper bound of [`Film::rmse_bound`] on the realised RMSE of an image
/// of `pixels` pixels whose variances of the mean v sum to `sum` (Σv) and `sum_sq` (Σv²),
/// estimated with `dof` degrees of freedom; `None` when Σv is not finite.
pub fn rmse_bound(sum: f64, sum_sq: f64, pixels: u64, dof: u64) -> Option<f64> {
    let rmse = (sum / pixels as f64).sqrt();
    if !rmse.is_finite() {
        return None;
    }
    if sum_sq == 0.0 {
        return Some(rmse);
    }
    let p_eff = sum * sum / sum_sq;
    let d = dof.max(1) as f64;
    Some(rmse * (1.0 + 2.326 * ((1.0 + 1.0 / d) / (2.0 * p_eff)).sqrt()))
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
            exact: Vec::new(),
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
        (0..self.sum.len())
            .into_par_iter()
            .with_min_len(PAR_MIN_PIXELS)
            .map(|i| self.sum[i] / self.samples_of(i).max(1) as f64)
            .collect()
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
            .into_par_iter()
            .with_min_len(PAR_MIN_PIXELS)
            .map(|i| self.std_error_of(estimator, i))
            .collect()
    }

    /// Pixel `i`'s standard error of the mean by `estimator` ([`Film::std_error`]).
    fn std_error_of(&self, estimator: ErrorEstimator, i: usize) -> f64 {
        let r = self.replicate_sq.get(i).copied().unwrap_or(0.0);
        let e = match estimator {
            ErrorEstimator::Replicates { size, .. } => {
                ErrorEstimator::Replicates { size, count: self.replicates_of(i) }
            }
            e => e,
        };
        if self.is_exact(i) {
            return 0.0;
        }
        standard_error(e, self.samples_of(i), self.sum[i], self.sum_sq[i], r)
    }

    /// Whether pixel `i`'s value is exact (`exact`).
    pub fn is_exact(&self, i: usize) -> bool {
        self.exact.get(i).copied().unwrap_or(false)
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
        self.rmse_estimate()?;
        let v: Vec<f64> = self.std_error().iter().map(|e| e * e).collect();
        let (sum, sum_sq) = (v.iter().sum::<f64>(), v.iter().map(|x| x * x).sum::<f64>());
        let d = self.error_estimator().degrees_of_freedom(self.samples);
        rmse_bound(sum, sum_sq, v.len() as u64, d)
    }

    /// Per-pixel two-sided 95 % confidence intervals of the means ([`interval_95`]), for
    /// samples in `range`; `None` without a valid error estimate.
    pub fn intervals_95(&self, range: SampleRange) -> Option<Vec<(f64, f64)>> {
        let estimator = self.error_estimator();
        if estimator == ErrorEstimator::None {
            return None;
        }
        let (mean, se) = (self.mean(), self.std_error());
        Some(
            (0..mean.len())
                .into_par_iter()
                .with_min_len(PAR_MIN_PIXELS)
                .map(|i| {
                    let n = self.samples_of(i);
                    if self.is_exact(i) {
                        return (mean[i], mean[i]);
                    }
                    let dof = match estimator {
                        ErrorEstimator::Replicates { .. } => self.replicates_of(i).saturating_sub(1),
                        e => e.degrees_of_freedom(n),
                    };
                    let upper = range.upper(self.sum[i], self.sum_sq[i]);
                    interval_95_within(mean[i], se[i], dof, n, range.lower(mean[i]), upper)
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
    fn score_intervals_are_wilsons_for_proportions_and_the_t_interval_mid_range() {
        // 18 of 20 samples 1, with the binomial standard error and a normal quantile:
        // Wilson's interval, [0.6990, 0.9721] (Brown, Cai & DasGupta 2001, eq. 4).
        let p = 0.9f64;
        let (lo, hi) = interval_95(p, (p * (1.0 - p) / 20.0).sqrt(), u64::MAX, 20, 1.0);
        assert!((lo - 0.6990).abs() < 1e-4 && (hi - 0.9721).abs() < 1e-4, "[{lo}, {hi}]");
        // Samples of 0 or 0.5 (an albedo): the same interval, scaled.
        let (l2, h2) = interval_95(0.5 * p, 0.5 * (p * (1.0 - p) / 20.0).sqrt(), u64::MAX, 20, 0.5);
        assert!((l2 - 0.5 * lo).abs() < 1e-12 && (h2 - 0.5 * hi).abs() < 1e-12, "[{l2}, {h2}]");
        // Mid-range with a small variance: the t interval, to within 0.1 % of its width.
        let (mean, se) = (0.9, 0.001);
        let (lo, hi) = interval_95(mean, se, 15, 1000, 2.0);
        let h = t_quantile_975(15) * se;
        assert!((lo - (mean - h)).abs() < 1e-3 * h && (hi - (mean + h)).abs() < 1e-3 * h, "[{lo}, {hi}]");
        // Near an end it leans to the middle and stays inside the range.
        let (lo, hi) = interval_95(0.97, 0.02, 15, 64, 1.0);
        let h = t_quantile_975(15) * 0.02;
        assert!(hi <= 1.0 && lo < 0.97 - h && hi - 0.97 < 0.97 - lo, "[{lo}, {hi}]");
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

    /// Random f32 values of every magnitude from 2^(e − 60) to 2^e, both signs (xorshift,
    /// fixed seed), with the edges of the ranges the quanta are exact in.
    fn values(e: i32, n: usize) -> Vec<f32> {
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        let bound = pow2(e) as f32;
        let mut v: Vec<f32> = (0..n)
            .map(|_| {
                let r = next();
                let magnitude = (r >> 11) as f64 / (1u64 << 53) as f64 * pow2(e - (r % 61) as i32);
                let v = (magnitude as f32).min(bound);
                if r >> 63 == 1 { -v } else { v }
            })
            .collect();
        for k in [0, 1, 4, 5, 16, 30, 31, 32, 40, 54, 55, 56, 80, 120, 149] {
            let p = (pow2(e - k.min(e + 149)) as f32).max(f32::from_bits(1));
            v.extend([p, -p, f32::from_bits(p.to_bits() + 1).min(bound), f32::from_bits(p.to_bits() - 1).min(bound)]);
        }
        v.extend([0.0, -0.0, bound, -bound, f32::from_bits(1), f32::from_bits(0x7f_ffff)]);
        v
    }

    #[test]
    fn samples_are_quantised_exactly_or_within_half_a_quantum() {
        for e in [0, 1, 2, 7, 20, 127] {
            let (quantum, square_quantum) = (pow2(e - SAMPLE_FRACTION_BITS), pow2(2 * e - SAMPLE_FRACTION_BITS));
            for v in values(e, 20_000) {
                let (q, sq) = quantize_sample(v, e);
                let (x, x2) = (v as f64, v as f64 * v as f64);
                assert_eq!(sq & OUT_OF_RANGE_BIT, 0, "e {e}: {v:e} flagged");
                assert!(q.unsigned_abs() <= 1 << 54 && sq <= 1 << 54, "e {e}: {v:e} gives {q}, {sq}");
                // f64 holds every quantised value and square exactly (54 bits at most).
                let (back, back2) = (q as f64 * quantum, sq as f64 * square_quantum);
                if x.abs() >= pow2(e - 31) {
                    assert_eq!(back, x, "e {e}: {v:e} is a whole number of quanta");
                } else {
                    assert!((back - x).abs() <= quantum / 2.0, "e {e}: {v:e} → {back:e}");
                }
                if x.abs() >= pow2(e - 4) {
                    assert_eq!(back2, x2, "e {e}: the square of {v:e} is a whole number of quanta");
                } else {
                    assert!((back2 - x2).abs() <= square_quantum / 2.0, "e {e}: {v:e}² → {back2:e}");
                }
                assert!(q == 0 || (q > 0) == (v > 0.0), "e {e}: {v:e} changed sign");
            }
            // Past the bound, infinite or NaN: flagged, whatever the sign.
            let bound = pow2(e) as f32;
            for v in [f32::from_bits(bound.to_bits() + 1), 2.0 * bound, f32::INFINITY, f32::NAN] {
                for v in [v, -v] {
                    assert_eq!(quantize_sample(v, e), (0, OUT_OF_RANGE_BIT), "e {e}: {v:e}");
                }
            }
        }
        // The quantum of e = 1 is 2^-53: half of it rounds away from zero, three quarters
        // up, just under half down.
        assert_eq!(quantize_sample(2f32.powi(-54), 1).0, 1);
        assert_eq!(quantize_sample(-(2f32.powi(-54)), 1).0, -1);
        assert_eq!(quantize_sample(3.0 * 2f32.powi(-55), 1).0, 1);
        assert_eq!(quantize_sample(2f32.powi(-54) * 0.99, 1).0, 0);
    }

    /// A GPU film's words with stopped slots read as nothing are the same sums on 1, 2, 3
    /// and 8 threads as the words with those slots zeroed, read one slot after another on
    /// one thread, at sizes around the chunks the threads take.
    #[test]
    fn marked_words_read_the_same_on_any_number_of_threads() {
        let mut x = 0x853c_49e6_748f_ea9bu64;
        let mut next = move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x as u32
        };
        for count in [0, 1, PAR_MIN_PIXELS - 1, PAR_MIN_PIXELS, PAR_MIN_PIXELS + 1, 3 * PAR_MIN_PIXELS + 3] {
            let words: Vec<[u32; 4]> = (0..count)
                .map(|i| match i % 5 {
                    2 => [0, 0, 0, INACTIVE_SLOT_BITS],
                    _ => [next(), next(), next(), next() & 0x7fff_ffff],
                })
                .collect();
            let mut expected = BlockSums::new(count);
            for (i, w) in words.iter().enumerate() {
                if w[3] != INACTIVE_SLOT_BITS {
                    expected.sum[i] = (u64::from(w[0]) | u64::from(w[1]) << 32) as i64;
                    expected.sum_sq[i] = u64::from(w[2]) | u64::from(w[3]) << 32;
                }
            }
            assert!(count < 3 || expected.sum.iter().any(|&s| s != 0), "{count}");
            for threads in [1, 2, 3, 8] {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a thread pool");
                let got = pool.install(|| BlockSums::from_marked_words(&words));
                assert!(got == expected, "{count} slots on {threads} threads");
            }
        }
    }

    /// A block of the largest samples stays within 64 bits, and its sums shift into the
    /// exact sums to the exact total; the words round-trip; a flagged sample stays flagged
    /// and the block is refused naming its pixel.
    #[test]
    fn a_block_of_the_largest_samples_fits_and_adds_exactly() {
        for e in [0, 1, 5, 127] {
            let bound = pow2(e) as f32;
            let mut block = BlockSums::new(3);
            for k in 0..BLOCK_SAMPLES {
                block.add(0, bound, e);
                block.add(1, -bound, e);
                block.add(2, if k % 2 == 0 { 0.75 * bound } else { -0.25 * bound }, e);
            }
            assert_eq!(block.sum, [1 << 62, -(1 << 62), 1 << 60]);
            assert_eq!(block.sum_sq, [1 << 62, 1 << 62, 5 << 58]);
            assert_eq!(BlockSums::from_words(&block.to_words()), block);
            let mut exact = ExactSums::new(3, 1, pow2(e) * 0.75);
            exact.add_block(&block).unwrap();
            exact.add_block(&block).unwrap();
            let film = exact.to_film(512, 1);
            let b = bound as f64;
            assert_eq!(film.sum, [512.0 * b, -512.0 * b, 128.0 * b]);
            assert_eq!(film.sum_sq, [512.0 * b * b, 512.0 * b * b, 160.0 * b * b]);
        }
        let mut block = BlockSums::new(2);
        block.add(1, 0.5, 0);
        block.add(1, f32::NAN, 0);
        block.add(1, 0.5, 0);
        assert_eq!(block.sum[1], 1 << 54);
        assert_ne!(block.sum_sq[1] & OUT_OF_RANGE_BIT, 0);
        let e = ExactSums::new(2, 1, 1.0).add_block(&block).unwrap_err();
        assert!(e.0.starts_with("pixel (1, 0): a sample was not finite"), "{e}");
    }

    /// A replicate's integer sum is squared exactly and rounded once to the quantum of
    /// the replicates' squares.
    #[test]
    fn replicate_squares_come_from_the_integer_sums() {
        let mut exact = ExactSums::new(1, 2, 2.0);
        // Replicates of 16 samples of 1.5 and of 0.1f32 (not a whole number of quanta of its square).
        let (a, b) = (quantize_sample(1.5, 1).0 as i128 * 16, quantize_sample(0.1, 1).0 as i128 * 16);
        exact.add_replicates(&[a, b], 1).unwrap();
        let film = exact.to_film(16, 16);
        assert_eq!(film.replicate_sq[0], 24.0 * 24.0);
        let s = 16.0 * 0.1f32 as f64;
        assert!((film.replicate_sq[1] - s * s).abs() <= pow2(2 - 85), "{} against {}", film.replicate_sq[1], s * s);
    }

    /// Sums of several films' worth of pixels (more than one rayon task's), with values
    /// that round differently in every pixel, counted per pixel, some pixels stopped.
    fn varied_sums() -> ExactSums {
        let (w, h) = (301, 173);
        let mut exact = ExactSums::new(w, h, 1.0);
        let mut block = BlockSums::new((w * h) as usize);
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        for _ in 0..7 {
            for i in 0..block.len() {
                // xorshift: a sample in [0, 1) whose low bits differ in every pixel.
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                block.add(i, (x >> 40) as f32 / (1u64 << 24) as f32, 0);
            }
        }
        exact.add_block(&block).unwrap();
        exact.add_block(&block).unwrap();
        let groups: Vec<i128> = block.sum.iter().map(|&s| s as i128).collect();
        exact.add_replicates(&groups, 1).unwrap();
        exact.count_per_pixel(14);
        for i in (0..exact.sum.len()).step_by(97) {
            exact.stopped[i] = true;
            exact.pixel_replicates[i] = 1;
            exact.pixel_samples[i] = 7;
        }
        exact
    }

    #[test]
    fn the_parallel_film_conversion_is_the_serial_one_bit_for_bit() {
        let exact = varied_sums();
        assert!(exact.sum.len() > 2 * PAR_MIN_PIXELS, "the sums span several rayon tasks");
        let (film, serial) = (exact.to_film(14, 7), exact.to_film_serial(14, 7));
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<u64>>();
        assert_eq!(bits(&film.sum), bits(&serial.sum));
        assert_eq!(bits(&film.sum_sq), bits(&serial.sum_sq));
        assert_eq!(bits(&film.replicate_sq), bits(&serial.replicate_sq));
        assert!(serial.exact.iter().any(|&e| e) && serial.exact.iter().any(|&e| !e));
        assert_eq!(film, serial);
        // The per-pixel values made from the film, likewise.
        let n = film.sum.len();
        let mean: Vec<f64> = (0..n).map(|i| film.sum[i] / film.samples_of(i).max(1) as f64).collect();
        assert_eq!(bits(&film.mean()), bits(&mean));
        let estimator = film.error_estimator().or_samples();
        let se: Vec<f64> = (0..n).map(|i| film.std_error_of(estimator, i)).collect();
        assert!(se.iter().any(|&e| e > 0.0) && se.contains(&0.0));
        assert_eq!(bits(&film.std_error()), bits(&se));
        // Sums counted per image convert alike.
        let mut image = varied_sums();
        (image.pixel_samples, image.pixel_replicates, image.stopped) = (Vec::new(), Vec::new(), Vec::new());
        assert_eq!(image.to_film(14, 1), image.to_film_serial(14, 1));
    }

    #[test]
    fn a_block_added_in_parallel_is_added_pixel_by_pixel_and_names_the_first_bad_pixel() {
        let exact = varied_sums();
        let mut block = BlockSums::new(exact.sum.len());
        for i in 0..block.len() {
            block.add(i, (i % 1000) as f32 / 1000.0, 0);
            block.add(i, -((i % 7) as f32) / 8.0, 0);
        }
        let mut serial = exact.clone();
        for i in 0..block.len() {
            serial.sum[i] += (block.sum[i] as i128) << BLOCK_SHIFT;
            serial.sum_sq[i] += (block.sum_sq[i] as i128) << BLOCK_SHIFT;
        }
        let mut parallel = exact.clone();
        parallel.add_block(&block).unwrap();
        assert_eq!(parallel, serial);
        // Bad pixels in two rayon tasks: the error names the earlier one.
        let (w, late, early) = (exact.width as usize, 3 * PAR_MIN_PIXELS + 5, PAR_MIN_PIXELS + 11);
        block.add(late, f32::INFINITY, 0);
        block.add(early, f32::NAN, 0);
        let e = exact.clone().add_block(&block).unwrap_err();
        assert!(e.0.starts_with(&format!("pixel ({}, {}): a sample was not", early % w, early / w)), "{e}");
        let mut full = exact.clone();
        full.sum[late] = i128::MAX;
        let mut one = BlockSums::new(exact.sum.len());
        one.add(late, 1.0, 0);
        let e = full.add_block(&one).unwrap_err();
        assert_eq!(e.0, format!("pixel ({}, {}): a sum of samples is out of range", late % w, late / w));
    }
}

/// Samples per block, the unit of a device's sums: block `k` holds sample indices
/// `256k .. 256k + 256` (cut short by the ends of the rendered range). A device sums one
/// block at a time in 64-bit integers (`film::BlockSums`); each finished block is shifted
/// exactly into the wider `ExactSums`. Integer addition is exact and associative, so
/// the result does not depend on how the samples were grouped into passes, blocks, runs
/// or shards, nor on the device that added them.
pub const BLOCK_SAMPLES: u32 = 256;

/// log2 of the ratio of the bound on a sample's magnitude, 2^e ([`value_exponent`]), to
/// the quantum of a block's Σv: a sample is summed in units of 2^(e − 54), its square in
/// units of 2^(2e − 54). A sample of magnitude at most 2^e is then at most 2^54 quanta,
/// and so is its square, so [`BLOCK_SAMPLES`] of them stay within 2^62 in a 64-bit
/// integer. A sample of at least 2^(e − 31) is a whole number of quanta (its f32 value
/// exactly), and a square of a sample of at least 2^(e − 4); smaller ones are rounded, by
/// at most half a quantum: 2^(e − 55) of a sample, 2^(2e − 55) of a square, far below
/// the f32 resolution of any mean (`docs/design.md`, "Accumulation and checkpoints").
pub const SAMPLE_FRACTION_BITS: i32 = 54;

/// The bit of a slot's Σv² that marks a sample out of range (not finite, or past the
/// bound 2^e): no sum of squares of samples within range reaches it (they stay below
/// 2^62), and the host refuses a block that carries it.
pub const OUT_OF_RANGE_BIT: u64 = 1 << 63;

/// The bits the last word of a device film slot (the high word of Σv²) holds while its
/// pixel is inactive (an adaptive render has stopped sampling it): past any sum of
/// squares, and not what an out-of-range sample leaves ([`OUT_OF_RANGE_BIT`] with a sum
/// below 2^62). The GPU kernel skips such a slot; the slot reads back as empty.
pub const INACTIVE_SLOT_BITS: u32 = 0xffff_ffff;

/// The largest exponent e of the bound 2^e on a render's samples that sums are scaled for.
pub const MAX_VALUE_EXPONENT: i32 = 256;

/// The exponent e of the smallest power of two, 2^e, at least `max_value` (taken as at
/// least 1; a non-finite bound as twice the largest f32): the scale of a render's sums,
/// from the largest magnitude its samples can take.
pub fn value_exponent(max_value: f64) -> i32 {
    let v = if max_value.is_finite() { max_value.max(1.0) } else { 2.0 * f32::MAX as f64 };
    // At most 129 for any f32 value doubled.
    let mut e = 0;
    while e < MAX_VALUE_EXPONENT && pow2(e) < v {
        e += 1;
    }
    e
}

/// One sample's contribution to a block's sums: `v` in quanta of 2^(e − 54) and `v²` in
/// quanta of 2^(2e − 54) ([`SAMPLE_FRACTION_BITS`]), each rounded to the nearest quantum
/// (halves away from zero), or `(0, OUT_OF_RANGE_BIT)` when `v` is not finite or larger
/// than 2^e in magnitude. Computed from the bits of `v` in integer arithmetic alone, as
/// `quantize_sample` in `shaders/sums.wgsl` does, so that no compiler's contraction or
/// reordering of float operations can change it: the square is that of the significand,
/// exact in 48 bits, then shifted, not the float product.
pub fn quantize_sample(v: f32, e: i32) -> (i64, u64) {
    let bits = v.to_bits();
    let biased = (bits >> 23) & 0xff;
    // v = m × 2^(b − 150), with b the biased exponent (1 for subnormals).
    let (m, b) = if biased == 0 { (bits & 0x7f_ffff, 1) } else { ((bits & 0x7f_ffff) | 0x80_0000, biased as i32) };
    // v / 2^(e − 54) = m × 2^s.
    let s = b - 96 - e;
    if biased == 0xff || s > 31 || (s == 31 && m > 0x80_0000) {
        return (0, OUT_OF_RANGE_BIT);
    }
    let q = shift_rounded(m as u64, s);
    // v² / 2^(2e − 54) = m² × 2^(2s − 54).
    let sq = shift_rounded(m as u64 * m as u64, 2 * s - 54);
    (if bits >> 31 == 1 { -(q as i64) } else { q as i64 }, sq)
}

/// `x` × 2^`k`, rounded to the nearest integer (halves up) where `k` is negative; `x`
/// × 2^`k` must fit 64 bits.
fn shift_rounded(x: u64, k: i32) -> u64 {
    match k {
        0.. => x << k,
        -63..=-1 => (x + (1 << (-k - 1))) >> -k,
        _ => 0,
    }
}

/// Per-slot sums of the samples of one block, as a device keeps them: 64-bit integers in
/// the quanta of [`quantize_sample`] for the render's bound 2^e, the same on every device
/// for the same samples.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct BlockSums {
    /// Σv in quanta of 2^(e − 54).
    pub sum: Vec<i64>,
    /// Σv² in quanta of 2^(2e − 54); [`OUT_OF_RANGE_BIT`] set where a sample was out
    /// of range.
    pub sum_sq: Vec<u64>,
}

impl BlockSums {
    /// Zero sums of `slots` slots.
    pub fn new(slots: usize) -> BlockSums {
        BlockSums { sum: vec![0; slots], sum_sq: vec![0; slots] }
    }

    /// Slots.
    pub fn len(&self) -> usize {
        self.sum.len()
    }

    /// True when there are no slots.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Adds the sample `v` to slot `i`, for samples of magnitude at most 2^`e`.
    pub fn add(&mut self, i: usize, v: f32, e: i32) {
        add_sample(&mut self.sum[i], &mut self.sum_sq[i], v, e);
    }

    /// The sums as a GPU film holds them: per slot, the low and high words of Σv (two's
    /// complement), then of Σv².
    pub fn to_words(&self) -> Vec<[u32; 4]> {
        self.sum
            .par_iter()
            .with_min_len(PAR_MIN_PIXELS)
            .zip(&self.sum_sq)
            .map(|(&s, &q)| [s as u32, (s as u64 >> 32) as u32, q as u32, (q >> 32) as u32])
            .collect()
    }

    /// The sums of a GPU film's words ([`BlockSums::to_words`]).
    pub fn from_words(words: &[[u32; 4]]) -> BlockSums {
        BlockSums::from_words_as(words, |w| *w)
    }

    /// The sums of a GPU film's words in which a slot marked stopped (its last word
    /// [`INACTIVE_SLOT_BITS`]) holds nothing: as [`BlockSums::from_words`] of the words
    /// with those slots zeroed, without the copy.
    pub fn from_marked_words(words: &[[u32; 4]]) -> BlockSums {
        BlockSums::from_words_as(words, |w| if w[3] == INACTIVE_SLOT_BITS { [0; 4] } else { *w })
    }

    /// The sums of `words`, each slot's as `slot` reads its words, on rayon's threads (each
    /// slot on its own: the same bits on any number of threads).
    fn from_words_as(words: &[[u32; 4]], slot: impl Fn(&[u32; 4]) -> [u32; 4] + Sync) -> BlockSums {
        // Words `k` and `k + 1` of every slot as one u64, the two columns on threads of their own.
        let column = |k: usize| -> Vec<u64> {
            words
                .par_iter()
                .with_min_len(PAR_MIN_PIXELS)
                .map(|w| {
                    let w = slot(w);
                    w[k] as u64 | (w[k + 1] as u64) << 32
                })
                .collect()
        };
        let (sum, sum_sq) = rayon::join(|| column(0), || column(2));
        // The same size and alignment: collected in place, no second allocation.
        let sum = sum.into_iter().map(|x| x as i64).collect();
        BlockSums { sum, sum_sq }
    }

    /// Slot `i`'s Σv and Σv² as f64, in the units of the samples (2^`e` their bound).
    pub fn slot(&self, i: usize, e: i32) -> (f64, f64) {
        let f = SAMPLE_FRACTION_BITS;
        (self.sum[i] as f64 * pow2(e - f), (self.sum_sq[i] & !OUT_OF_RANGE_BIT) as f64 * pow2(2 * e - f))
    }
}

/// Adds the sample `v` (of magnitude at most 2^`e`) to a slot's sums `sum` and `sum_sq`,
/// in the quanta of [`quantize_sample`], wrapping as the GPU's 64-bit words do: the sum of
/// a block of samples within range does not reach their bounds.
pub fn add_sample(sum: &mut i64, sum_sq: &mut u64, v: f32, e: i32) {
    let (q, sq) = quantize_sample(v, e);
    *sum = sum.wrapping_add(q);
    *sum_sq = sum_sq.wrapping_add(sq) | (sq & OUT_OF_RANGE_BIT) | (*sum_sq & OUT_OF_RANGE_BIT);
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
/// log2 of the ratio of a block's quanta to those of [`ExactSums`] (2^39, Σv and Σv²
/// alike): a block's sums shift into the exact sums without rounding.
const BLOCK_SHIFT: i32 = MAGNITUDE_LOG2 - MAX_SAMPLES_LOG2 - SAMPLE_FRACTION_BITS;
const _: () = assert!(BLOCK_SHIFT > 0);

/// Pixels a rayon task converts or adds at least: enough that a small film stays on one
/// thread, few enough that a 1080p film spreads over every core.
const PAR_MIN_PIXELS: usize = 1 << 14;

/// 2^n as f64, exactly, for n in -1022..=1023.
fn pow2(n: i32) -> f64 {
    debug_assert!((-1022..=1023).contains(&n));
    f64::from_bits(((n + 1023) as u64) << 52)
}

/// Per-pixel sums of finished blocks in fixed point: Σv of pixel `i` is
/// `sum[i]` × 2^`sum_exponent`, Σv² is `sum_sq[i]` × 2^`sq_exponent`. The quanta are set
/// from the largest value a sample can take so that 2^32 samples fit; they are 2^-93 of
/// that value's bound 2^e, 2^39 times finer than a block's ([`BlockSums`]), so blocks
/// shift into them exactly. Integer addition is associative: blocks added in any order
/// or grouping give the same bits.
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
    /// after group), in the quanta of a block's Σv ([`BlockSums::sum`]): each is squared
    /// exactly and rounded once to the quantum of `replicate_sq` (halves up). An error
    /// names the first group whose square is out of range.
    pub fn add_replicates(&mut self, sums: &[i128], count: u64) -> Result<(), SumsError> {
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
        // The square's quantum is 2^(2 (sum_exponent + BLOCK_SHIFT)), replicate_sq's
        // 2^(sq_exponent + REPLICATE_SQ_SHIFT): 2^23 times coarser.
        let shift = self.sq_exponent + REPLICATE_SQ_SHIFT - 2 * (self.sum_exponent + BLOCK_SHIFT);
        debug_assert!(shift > 0);
        for (g, chunk) in sums.chunks_exact(count.max(1) as usize).enumerate() {
            for &s in chunk {
                let bad = || SumsError(format!("group {g}: a replicate's sum of {s} quanta is out of range"));
                // A replicate of at most 256 samples sums to under 2^62 quanta in magnitude.
                if s.unsigned_abs() >= 1 << 63 {
                    return Err(bad());
                }
                let q = (s * s + (1 << (shift - 1))) >> shift;
                self.replicate_sq[g] = self.replicate_sq[g].checked_add(q).ok_or_else(bad)?;
            }
        }
        self.replicates += count;
        Ok(())
    }

    /// The quanta's exponents for samples of magnitude at most `max_value`
    /// ([`value_exponent`] e): e + 32 − 125 and 2e + 32 − 125.
    pub fn exponents(max_value: f64) -> (i32, i32) {
        let e = value_exponent(max_value);
        (e + MAX_SAMPLES_LOG2 - MAGNITUDE_LOG2, 2 * e + MAX_SAMPLES_LOG2 - MAGNITUDE_LOG2)
    }

    /// The bound 2^e of the samples these sums are scaled for ([`value_exponent`]).
    pub fn value_exponent(&self) -> i32 {
        self.sum_exponent - MAX_SAMPLES_LOG2 + MAGNITUDE_LOG2
    }

    /// Adds a block's sums, shifted exactly from the block's quanta into these. An error
    /// names the first pixel whose block carries a sample out of range, or whose sum
    /// overflows.
    pub fn add_block(&mut self, block: &BlockSums) -> Result<(), SumsError> {
        if block.len() != self.sum.len() || block.sum_sq.len() != block.sum.len() {
            return Err(SumsError(format!("a block of {} pixels added to sums of {}", block.len(), self.sum.len())));
        }
        // Chunks of pixels on rayon's threads; of the chunks that fail, the first names its
        // first bad pixel, as a pass pixel after pixel would.
        let bad = self
            .sum
            .par_chunks_mut(PAR_MIN_PIXELS)
            .zip(self.sum_sq.par_chunks_mut(PAR_MIN_PIXELS))
            .enumerate()
            .map(|(c, (sums, sqs))| {
                let first = c * PAR_MIN_PIXELS;
                let (bs, bq) = (&block.sum[first..first + sums.len()], &block.sum_sq[first..first + sums.len()]);
                for (k, (((a, b), &s), &q)) in sums.iter_mut().zip(sqs.iter_mut()).zip(bs).zip(bq).enumerate() {
                    if q & OUT_OF_RANGE_BIT != 0 {
                        return Some((
                            first + k,
                            "a sample was not finite or larger than the scene's albedos and background allow",
                        ));
                    }
                    let (Some(s), Some(q)) =
                        (a.checked_add((s as i128) << BLOCK_SHIFT), b.checked_add((q as i128) << BLOCK_SHIFT))
                    else {
                        return Some((first + k, "a sum of samples is out of range"));
                    };
                    (*a, *b) = (s, q);
                }
                None
            })
            .find_first(|bad| bad.is_some())
            .flatten();
        match bad {
            Some((i, why)) => {
                let w = self.width.max(1) as usize;
                Err(SumsError(format!("pixel ({}, {}): {why}", i % w, i / w)))
            }
            None => Ok(()),
        }
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

    /// Slot `k`'s sum of the replicates' squares rounded once to f64, as in
    /// [`ExactSums::to_film`]'s film; 0 where there is none.
    pub fn replicate_sq_value(&self, k: usize) -> f64 {
        let qr = pow2(self.sq_exponent + REPLICATE_SQ_SHIFT);
        self.replicate_sq.get(k).map_or(0.0, |&s| s as f64 * qr)
    }

    /// The sums as a [`Film`] of `samples` samples per pixel in replicates of
    /// `replicate` samples (each sum rounded once to f64). Pixels are converted on
    /// rayon's threads: each is on its own, so the film is the same bit for bit.
    pub fn to_film(&self, samples: u64, replicate: u32) -> Film {
        let (qs, qq) = (pow2(self.sum_exponent), pow2(self.sq_exponent));
        let qr = pow2(self.sq_exponent + REPLICATE_SQ_SHIFT);
        let scaled = |v: &[i128], q: f64| -> Vec<f64> {
            v.par_iter().with_min_len(PAR_MIN_PIXELS).map(|&s| s as f64 * q).collect()
        };
        let (sum, sum_sq) = rayon::join(|| scaled(&self.sum, qs), || scaled(&self.sum_sq, qq));
        Film {
            width: self.width,
            height: self.height,
            samples,
            sum,
            sum_sq,
            replicate,
            replicates: self.replicate_count(),
            replicate_sq: scaled(&self.replicate_sq, qr),
            pixel_samples: self.pixel_samples.par_iter().with_min_len(PAR_MIN_PIXELS).map(|&n| n as u64).collect(),
            pixel_replicates: self
                .pixel_replicates
                .par_iter()
                .with_min_len(PAR_MIN_PIXELS)
                .map(|&n| n as u64)
                .collect(),
            exact: match self.pixel_replicates.par_iter().any(|&k| k < 2) {
                true => {
                    (0..self.sum.len()).into_par_iter().with_min_len(PAR_MIN_PIXELS).map(|i| self.is_exact(i)).collect()
                }
                false => Vec::new(),
            },
        }
    }

    /// [`ExactSums::to_film`] on one thread, pixel after pixel: the reference the parallel
    /// conversion is held to.
    #[cfg(test)]
    fn to_film_serial(&self, samples: u64, replicate: u32) -> Film {
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
            exact: match self.pixel_replicates.iter().any(|&k| k < 2) {
                true => (0..self.sum.len()).map(|i| self.is_exact(i)).collect(),
                false => Vec::new(),
            },
        }
    }

    /// Whether pixel `i` was stopped before its second replicate: only a background
    /// pixel is (every other waits for `MIN_TARGET_REPLICATES`), and its value is exact.
    fn is_exact(&self, i: usize) -> bool {
        self.stopped.get(i).copied().unwrap_or(false) && self.pixel_replicates.get(i).is_some_and(|&k| k < 2)
    }

    /// Complete replicates: the fewest of any pixel when counted per pixel, leaving out
    /// the exact ones (background pixels stopped after their first replicate), unless
    /// every pixel is.
    pub fn replicate_count(&self) -> u64 {
        let counted = self.pixel_replicates.iter().enumerate().filter(|&(i, _)| !self.is_exact(i));
        counted
            .map(|(_, &k)| k)
            .min()
            .or(self.pixel_replicates.iter().max().copied())
            .map_or(self.replicates, |k| k as u64)
    }
}

impl BlockSums {
    /// The block of float sums a device kept before sums were integers (checkpoint
    /// format versions 1 and 2: the GPU's compensated f32 pairs added in f64, the CPU
    /// reference's f64 sums), each rounded to the nearest quantum for samples of bound
    /// 2^`e`. An error names the first slot whose sum is not finite or out of range.
    pub fn from_floats(sums: impl Iterator<Item = (f64, f64)>, e: i32) -> Result<BlockSums, SumsError> {
        let f = SAMPLE_FRACTION_BITS;
        let mut block = BlockSums::default();
        for (i, (s, q)) in sums.enumerate() {
            let (qs, qq) = ((s * pow2(f - e)).round(), (q * pow2(f - 2 * e)).round());
            // A block within range is below 2^62 quanta: twice that is damage.
            if !(qs.abs() < pow2(63) && (0.0..pow2(63)).contains(&qq)) {
                return Err(SumsError(format!("slot {i}: a sum of samples ({s}, squares {q}) is out of range")));
            }
            block.sum.push(qs as i64);
            block.sum_sq.push(qq as u64);
        }
        Ok(block)
    }
}
