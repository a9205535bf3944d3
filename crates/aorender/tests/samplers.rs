//! What each sampler costs and buys, measured at a point with partial occlusion whose AO
//! has a closed form: a floor point with a sphere of radius r at distance d, at angle β
//! from the normal, AO = 1 − cos β (r/d)².
//!
//! An orthographic view 10 µm wide makes every pixel an estimate at that point; pixels
//! are decorrelated, so the spread of the 64×64 pixel means is the spread of one N-sample
//! estimate. Variances are compared with F-tests and checked against theory with
//! chi-square tests, each at α = 0.001 with a Šidák correction over all the file's tests.

mod common;
use aorender::{Film, Hemisphere, Sampler, Scene};
use common::*;
use statrs::distribution::{ChiSquared, ContinuousCDF, FisherSnedecor};
use std::f64::consts::PI;

const RADIUS: f64 = 0.5;
const DISTANCE: f64 = 1.0;
const BETA_DEGREES: f64 = 30.0;
const SIDE: u32 = 64;
const COUNTS: [u32; 2] = [16, 256];
/// Family-wise significance level.
const ALPHA: f64 = 0.001;
/// Tests per device: for each count, 3 hemispheres × 2 sampler comparisons, 2 hemisphere
/// comparisons and 2 chi-square variance checks.
const TESTS_PER_DEVICE: usize = COUNTS.len() * (3 * 2 + 2 + 2);

fn expected_ao() -> f64 {
    1.0 - BETA_DEGREES.to_radians().cos() * (RADIUS / DISTANCE).powi(2)
}

/// Variance of one uniform-hemisphere sample 2 V cos θ: 4/(2π) ∫_open cos² θ dω − μ².
/// Over the cap of half-angle α about an axis at β from the normal,
/// ∫ cos² θ dω = cos² β · 2π(1 − cos³α)/3 + sin² β · (2π(1 − cos α) − 2π(1 − cos³α)/3)/2.
fn uniform_sample_variance() -> f64 {
    let ca = (1.0 - (RADIUS / DISTANCE).powi(2)).sqrt();
    let beta = BETA_DEGREES.to_radians();
    let along = 2.0 * PI * (1.0 - ca.powi(3)) / 3.0;
    let across = (2.0 * PI * (1.0 - ca) - along) / 2.0;
    let cap = beta.cos().powi(2) * along + beta.sin().powi(2) * across;
    let open = 2.0 * PI / 3.0 - cap;
    4.0 / (2.0 * PI) * open - expected_ao().powi(2)
}

/// Variance of one cosine sample V: Bernoulli with mean μ.
fn cosine_sample_variance() -> f64 {
    expected_ao() * (1.0 - expected_ao())
}

fn scene(dir: &std::path::Path) -> Scene {
    let beta = BETA_DEGREES.to_radians();
    let (cx, cy) = (DISTANCE * beta.sin(), DISTANCE * beta.cos());
    // The camera looks at the origin from the side away from the sphere.
    let text = format!(
        r#"
        [image]
        width = {SIDE}
        height = {SIDE}
        [camera]
        type = "orthographic"
        eye = [-2.0, 2.0, 0.0]
        look_at = [0.0, 0.0, 0.0]
        height = 1e-5
        [[object]]
        type = "plane"
        point = [0.0, 0.0, 0.0]
        normal = [0.0, 1.0, 0.0]
        [[object]]
        type = "sphere"
        center = [{cx}, {cy}, 0.0]
        radius = {RADIUS}
        "#
    );
    scene_from_toml(&text, dir)
}

/// Mean and unbiased variance of the pixel means.
fn pixel_statistics(film: &Film) -> (f64, f64) {
    let m = film.mean();
    let n = m.len() as f64;
    let mean = m.iter().sum::<f64>() / n;
    let var = m.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, var)
}

struct Measured {
    hemisphere: Hemisphere,
    sampler: Sampler,
    spp: u32,
    mean: f64,
    var: f64,
}

/// Renders every hemisphere × sampler at each count, each with its own seed so the
/// estimates compared by the F-tests are independent.
fn measure(options: &Config) -> Vec<Measured> {
    let dir = temp_dir();
    let mut scene = scene(dir.path());
    let session = session(&scene, options);
    let mut out = Vec::new();
    let mut seed = 100;
    for spp in COUNTS {
        for hemisphere in Hemisphere::ALL {
            for sampler in Sampler::ALL {
                seed += 1;
                scene.settings.spp = spp;
                scene.settings.sampling.hemisphere = hemisphere;
                scene.settings.sampling.sampler = sampler;
                scene.settings.sampling.seed = seed;
                let (mean, var) = pixel_statistics(&render_settings(&session, &scene.settings));
                out.push(Measured { hemisphere, sampler, spp, mean, var });
            }
        }
    }
    out
}

fn find(all: &[Measured], h: Hemisphere, s: Sampler, spp: u32) -> &Measured {
    all.iter().find(|m| m.hemisphere == h && m.sampler == s && m.spp == spp).expect("measured")
}

fn sidak_alpha(devices: usize) -> f64 {
    1.0 - (1.0 - ALPHA).powf(1.0 / (devices * TESTS_PER_DEVICE) as f64)
}

fn check_device(options: &Config, devices: usize) {
    let what = label(options);
    let all = measure(options);
    let n = (SIDE * SIDE) as f64;
    let alpha = sidak_alpha(devices);
    // Under equal variances the ratio of two sample variances is F(n − 1, n − 1).
    let f_low = FisherSnedecor::new(n - 1.0, n - 1.0).expect("F").inverse_cdf(alpha);
    let chi2 = ChiSquared::new(n - 1.0).expect("chi-square");
    let mu = expected_ao();

    eprintln!("{what}: AO expected {mu:.6}; significant ratio below {f_low:.4}");
    eprintln!("{what}: hemisphere    spp  var(indep)   strat/indep sobol/indep  grid error");
    for spp in COUNTS {
        for h in Hemisphere::ALL {
            let ind = find(&all, h, Sampler::Independent, spp);
            let strat = find(&all, h, Sampler::Stratified, spp);
            let sobol = find(&all, h, Sampler::Sobol, spp);
            let grid = find(&all, h, Sampler::Grid, spp);
            eprintln!(
                "{what}: {:<12} {spp:>4}  {:.3e}   {:>10.4}  {:>10.4}  {:+.2e}",
                h.name(),
                ind.var,
                strat.var / ind.var,
                sobol.var / ind.var,
                grid.mean - mu
            );
            for better in [strat, sobol] {
                let ratio = better.var / ind.var;
                assert!(
                    ratio < f_low,
                    "{what} {} {spp} spp: var({}) / var(independent) = {ratio:.4}, not significantly below 1 \
                     (F quantile {f_low:.4})",
                    h.name(),
                    better.sampler.name()
                );
            }
        }
        let uniform = find(&all, Hemisphere::Uniform, Sampler::Independent, spp);
        for h in [Hemisphere::Cosine, Hemisphere::CosinePolar] {
            let ratio = find(&all, h, Sampler::Independent, spp).var / uniform.var;
            eprintln!("{what}: {spp} spp: var({}) / var(uniform) = {ratio:.4}", h.name());
            assert!(ratio < f_low, "{what} {spp} spp: {} is not significantly below uniform: {ratio:.4}", h.name());
        }
        // Independent sampling must show exactly the textbook variance σ²/N.
        for (h, sigma2) in
            [(Hemisphere::Uniform, uniform_sample_variance()), (Hemisphere::Cosine, cosine_sample_variance())]
        {
            let m = find(&all, h, Sampler::Independent, spp);
            let stat = (n - 1.0) * m.var / (sigma2 / spp as f64);
            let p = 2.0 * chi2.cdf(stat).min(chi2.sf(stat));
            eprintln!(
                "{what}: {} {spp} spp: var {:.4e} vs σ²/N {:.4e} (p {p:.3})",
                h.name(),
                m.var,
                sigma2 / spp as f64
            );
            assert!(
                p > alpha,
                "{what} {} {spp} spp: variance {} is not σ²/N = {} (p {p:.2e})",
                h.name(),
                m.var,
                sigma2
            );
        }
    }
    for m in all.iter().filter(|m| m.sampler.is_unbiased()) {
        let se = (m.var / n).sqrt();
        assert!(se > 0.0, "{what}: zero spread, the test could not see a bias");
        assert!(
            (m.mean - mu).abs() <= 4.0 * se,
            "{what} {} {} {} spp: mean {} is not {mu} ± 4·{se:.2e}",
            m.hemisphere.name(),
            m.sampler.name(),
            m.spp,
            m.mean
        );
    }
}

#[test]
fn variance_and_bias_of_every_sampler() {
    let mut devices = vec![Config::cpu()];
    if gpu_available() {
        devices.push(Config::default());
    }
    for options in &devices {
        check_device(options, devices.len());
    }
}

#[test]
fn closed_form_variances_are_consistent() {
    // The uniform variance formula against a direct quadrature of 2 V cos θ over the hemisphere.
    let beta = BETA_DEGREES.to_radians();
    let axis = [beta.sin(), beta.cos(), 0.0];
    let cos_alpha = (1.0 - (RADIUS / DISTANCE).powi(2)).sqrt();
    let (nt, np) = (2000, 4000);
    let (mut m1, mut m2) = (0.0, 0.0);
    for i in 0..nt {
        let z = (i as f64 + 0.5) / nt as f64; // cos θ, uniform in dω = d(cos θ) dφ
        let r = (1.0 - z * z).sqrt();
        for j in 0..np {
            let phi = 2.0 * PI * (j as f64 + 0.5) / np as f64;
            let w = [r * phi.cos(), z, r * phi.sin()];
            let open = w[0] * axis[0] + w[1] * axis[1] + w[2] * axis[2] < cos_alpha;
            let f = if open { 2.0 * z } else { 0.0 };
            let weight = 1.0 / (nt * np) as f64;
            m1 += f * weight;
            m2 += f * f * weight;
        }
    }
    assert!((m1 - expected_ao()).abs() < 1e-3, "mean {m1} vs {}", expected_ao());
    assert!(
        (m2 - m1 * m1 - uniform_sample_variance()).abs() < 2e-3,
        "variance {} vs {}",
        m2 - m1 * m1,
        uniform_sample_variance()
    );
}
