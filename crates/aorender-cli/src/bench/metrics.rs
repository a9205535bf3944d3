//! Error metrics of a render against a converged reference that has noise of its own,
//! and the convergence slope.

/// ε of the relative MSE, mean((x − ref)² / (ref² + ε)): it keeps pixels whose reference
/// is 0 (background, fully occluded) finite. AO values lie in [0, albedo], so with albedo
/// 1 a pixel of reference 0.1 is weighted half as much as one of reference 0.
pub const REL_MSE_EPSILON: f64 = 0.01;

/// A converged image: per-pixel means and the variance of each mean.
#[derive(Clone, Debug, PartialEq)]
pub struct Reference {
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Samples per pixel it was rendered with.
    pub samples: u64,
    /// Per-pixel means.
    pub mean: Vec<f64>,
    /// Per-pixel variance of the mean (squared standard error), from the sample variance
    /// of independent samples.
    pub variance: Vec<f64>,
}

impl Reference {
    /// The reference's own mean squared error, mean(SE²): the floor under which a
    /// render's error cannot be told from the reference's.
    pub fn mse_floor(&self) -> f64 {
        mean(&self.variance)
    }

    /// The floor weighted as [`ErrorMetrics::rel_mse`] weights a pixel.
    pub fn rel_mse_floor(&self) -> f64 {
        let w = self.mean.iter().zip(&self.variance).map(|(r, v)| v / (r * r + REL_MSE_EPSILON));
        w.sum::<f64>() / self.mean.len().max(1) as f64
    }
}

/// Errors of one image against a [`Reference`].
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ErrorMetrics {
    /// Mean squared error with the reference's own variance taken out:
    /// mean((x − ref)²) − mean(SE_ref²). Since the image and the reference are
    /// independent, E[(x − ref)²] = MSE(x) + Var(ref), so this is an unbiased estimate of
    /// the image's MSE against the true image. It can come out negative when the image's
    /// error is below the reference's floor.
    pub mse: f64,
    /// √max(mse, 0).
    pub rmse: f64,
    /// mean(((x − ref)² − SE_ref²) / (ref² + ε)) with ε = [`REL_MSE_EPSILON`].
    pub rel_mse: f64,
    /// mean((x − ref)²), before the reference's variance is taken out.
    pub raw_mse: f64,
    /// Standard error of `mse` from the spread of the per-pixel terms (pixels are
    /// independent): how precisely the error itself is measured.
    pub mse_std_error: f64,
}

impl ErrorMetrics {
    /// Compares `image` (per-pixel values) with `reference`.
    pub fn measure(image: &[f64], reference: &Reference) -> ErrorMetrics {
        assert_eq!(image.len(), reference.mean.len(), "image and reference sizes differ");
        let n = image.len().max(1) as f64;
        let (mut raw, mut mse, mut mse_sq, mut rel) = (0.0, 0.0, 0.0, 0.0);
        for ((x, r), v) in image.iter().zip(&reference.mean).zip(&reference.variance) {
            let d2 = (x - r) * (x - r);
            raw += d2;
            mse += d2 - v;
            mse_sq += (d2 - v) * (d2 - v);
            rel += (d2 - v) / (r * r + REL_MSE_EPSILON);
        }
        let mse = mse / n;
        let spread = (mse_sq / n - mse * mse).max(0.0) * n / (n - 1.0).max(1.0);
        ErrorMetrics {
            mse,
            rmse: mse.max(0.0).sqrt(),
            rel_mse: rel / n,
            raw_mse: raw / n,
            mse_std_error: (spread / n).sqrt(),
        }
    }
}

/// Efficiency 1 / (MSE × seconds): doubling it halves the time to a given error. `None`
/// when the MSE is not positive (the error is below the reference's floor) or no time
/// was measured.
pub fn efficiency(mse: f64, seconds: f64) -> Option<f64> {
    (mse > 0.0 && seconds > 0.0).then(|| 1.0 / (mse * seconds))
}

/// Least-squares slope of ln y against ln x over the points with positive x and y; `None`
/// with fewer than two such points or all x equal. For RMSE against samples per pixel,
/// independent sampling gives −1/2.
pub fn log_log_slope(points: &[(f64, f64)]) -> Option<f64> {
    let logs: Vec<(f64, f64)> =
        points.iter().filter(|(x, y)| *x > 0.0 && *y > 0.0).map(|(x, y)| (x.ln(), y.ln())).collect();
    if logs.len() < 2 {
        return None;
    }
    let n = logs.len() as f64;
    let (mx, my) = (logs.iter().map(|p| p.0).sum::<f64>() / n, logs.iter().map(|p| p.1).sum::<f64>() / n);
    let sxx: f64 = logs.iter().map(|p| (p.0 - mx) * (p.0 - mx)).sum();
    let sxy: f64 = logs.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    (sxx > 0.0).then(|| sxy / sxx)
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A deterministic normal deviate stream (Box–Muller over a 64-bit LCG).
    struct Gauss(u64);

    impl Gauss {
        fn uniform(&mut self) -> f64 {
            self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((self.0 >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        }

        fn next(&mut self) -> f64 {
            let (u1, u2) = (self.uniform(), self.uniform());
            (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
        }
    }

    /// An image `truth + N(0, σ_x²)` against a reference `truth + N(0, σ_r²)` whose
    /// variance is known: the metric recovers σ_x² (not σ_x² + σ_r²) within the standard
    /// error of a mean of n squared normals, 4·σ²·√(2/n) (and the raw MSE keeps both).
    #[test]
    fn mse_takes_the_reference_noise_out() {
        let n = 200_000;
        let (sx, sr) = (0.05, 0.02);
        let mut g = Gauss(7);
        let truth: Vec<f64> = (0..n).map(|i| 0.2 + 0.6 * (i % 97) as f64 / 97.0).collect();
        let reference = Reference {
            width: n as u32,
            height: 1,
            samples: 1,
            mean: truth.iter().map(|t| t + sr * g.next()).collect(),
            variance: vec![sr * sr; n],
        };
        let image: Vec<f64> = truth.iter().map(|t| t + sx * g.next()).collect();
        let m = ErrorMetrics::measure(&image, &reference);
        let tol = |var: f64| 4.0 * var * (2.0 / n as f64).sqrt();
        let total = sx * sx + sr * sr;
        assert!((m.mse - sx * sx).abs() < tol(total), "mse {} vs {}", m.mse, sx * sx);
        assert!((m.raw_mse - total).abs() < tol(total), "raw {} vs {total}", m.raw_mse);
        assert_eq!(m.rmse, m.mse.sqrt());
        // Each term is a squared normal of variance σ_x² + σ_r², whose spread is √2·(σ_x² + σ_r²);
        // a sample deviation of a variable with kurtosis 15 (χ²₁) has relative error ½√(14/n).
        let se = 2f64.sqrt() * total / (n as f64).sqrt();
        let tol = 4.0 * 0.5 * (14.0 / n as f64).sqrt();
        assert!((m.mse_std_error / se - 1.0).abs() < tol, "standard error {} vs {se}", m.mse_std_error);
        assert!((reference.mse_floor() - sr * sr).abs() < 1e-15);
    }

    /// The relative MSE divides each pixel's squared error by ref² + ε: with the same
    /// absolute noise everywhere, it is the noise variance times the mean of 1/(ref² + ε).
    #[test]
    fn relative_mse_weights_pixels_by_the_reference() {
        let n = 100_000;
        let s = 0.03;
        let mut g = Gauss(11);
        let levels = [0.0, 0.1, 0.5, 1.0];
        let mean: Vec<f64> = (0..n).map(|i| levels[i % 4]).collect();
        let reference = Reference { width: n as u32, height: 1, samples: 1, mean, variance: vec![0.0; n] };
        let image: Vec<f64> = reference.mean.iter().map(|r| r + s * g.next()).collect();
        let m = ErrorMetrics::measure(&image, &reference);
        let weight = levels.iter().map(|r| 1.0 / (r * r + REL_MSE_EPSILON)).sum::<f64>() / 4.0;
        let expected = s * s * weight;
        // Per pixel the weighted squared error has standard deviation √2·σ²·w ≤ √2·σ²·100.
        let tol = 4.0 * (2.0f64).sqrt() * s * s / REL_MSE_EPSILON / (n as f64).sqrt();
        assert!((m.rel_mse - expected).abs() < tol, "rel {} vs {expected} ± {tol}", m.rel_mse);
        assert_eq!(reference.rel_mse_floor(), 0.0);
    }

    /// An exact image has zero raw error and minus the floor as its MSE.
    #[test]
    fn an_image_equal_to_the_reference_sits_below_the_floor() {
        let reference =
            Reference { width: 2, height: 1, samples: 4, mean: vec![0.25, 0.75], variance: vec![1e-4, 3e-4] };
        let m = ErrorMetrics::measure(&reference.mean.clone(), &reference);
        assert_eq!(m.raw_mse, 0.0);
        assert!((m.mse + 2e-4).abs() < 1e-18);
        assert_eq!(m.rmse, 0.0);
        assert_eq!(efficiency(m.mse, 1.0), None);
        assert_eq!(efficiency(0.01, 2.0), Some(50.0));
    }

    /// The slope of an exact power law is its exponent; the fit ignores non-positive
    /// points and needs two distinct x.
    #[test]
    fn slope_of_a_power_law() {
        let pts: Vec<(f64, f64)> = (0..8).map(|k| (2f64.powi(k), 0.3 * 2f64.powi(k).powf(-0.5))).collect();
        assert!((log_log_slope(&pts).unwrap() + 0.5).abs() < 1e-12);
        let mut with_zero = pts.clone();
        with_zero.push((256.0, 0.0));
        assert!((log_log_slope(&with_zero).unwrap() + 0.5).abs() < 1e-12);
        assert_eq!(log_log_slope(&pts[..1]), None);
        assert_eq!(log_log_slope(&[(4.0, 1.0), (4.0, 2.0)]), None);
    }

    /// Means of n uniform samples per pixel, fresh samples for every n from 1 to 4096:
    /// the fitted slope of their RMSE is −1/2 within 4 standard errors of the fit. Each
    /// ln RMSE has a standard deviation of at most 1/√(2·pixels) (half that of the mean of
    /// squared errors, whose per-pixel relative deviation is at most √2, its normal limit).
    #[test]
    fn slope_of_monte_carlo_means_is_minus_one_half() {
        let pixels = 2000usize;
        let mut g = Gauss(3);
        let reference = Reference {
            width: pixels as u32,
            height: 1,
            samples: 1,
            mean: vec![0.5; pixels],
            variance: vec![0.0; pixels],
        };
        let ks: Vec<i32> = (0..=12).collect();
        let points: Vec<(f64, f64)> = ks
            .iter()
            .map(|&k| {
                let n = 1u32 << k;
                let image: Vec<f64> =
                    (0..pixels).map(|_| (0..n).map(|_| g.uniform()).sum::<f64>() / n as f64).collect();
                (n as f64, ErrorMetrics::measure(&image, &reference).rmse)
            })
            .collect();
        let slope = log_log_slope(&points).unwrap();
        let mean_x = ks.iter().map(|&k| k as f64).sum::<f64>() / ks.len() as f64 * std::f64::consts::LN_2;
        let sxx: f64 = ks.iter().map(|&k| (k as f64 * std::f64::consts::LN_2 - mean_x).powi(2)).sum();
        let tol = 4.0 / (2.0 * pixels as f64).sqrt() / sxx.sqrt();
        assert!((slope + 0.5).abs() < tol, "slope {slope}, tolerance {tol}");
    }
}
