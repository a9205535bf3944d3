//! What valid error bars cost: the variance of stratified and Sobol renders cut into
//! independently randomised replicates, against the same samples as one replicate.
//!
//! The spread of replicate means is an unbiased estimate of the error whatever the point
//! set does inside a replicate; the spread of single samples is not (it overestimates the
//! error of stratified and Sobol points). But a replicate of b points keeps only the
//! variance reduction of b points: 16 replicates of 16 Sobol points are, for a
//! discontinuous integrand, noisier than one 256-point sequence. This example measures
//! how much, on a real scan: the mean square error against a converged reference, over
//! several seeds, for each sampler and replicate size, as a ratio to the independent
//! sampler's.
//!
//! ```text
//! cargo run --release -p aorender --example replicate_cost [-- SCENE [SPP [SIZE]]]
//! ```
//!
//! Defaults: `scenes/bunny.obj`, 256 samples per pixel, 128 × 128, max distance 0.05, the
//! cosine hemisphere, on the CPU reference (the GPU gives the same samples).

use aorender::Sampling;
use aorender::{BvhOptions, Control, Device, ImageRequest, Sampler, Scene, Session, Settings};

fn main() -> aorender::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let path = args.first().map_or("scenes/bunny.obj", |s| s.as_str());
    let spp: u32 = args.get(1).map_or(256, |s| s.parse().expect("samples per pixel"));
    let size: u32 = args.get(2).map_or(128, |s| s.parse().expect("image size"));
    let mut scene = Scene::load(std::path::Path::new(path))?;
    (scene.settings.width, scene.settings.height) = (size, size);
    scene.settings.sampling.max_distance.get_or_insert(0.05);
    let session = Session::new(&Device::cpu(), scene.clone(), &BvhOptions::default())?;
    let render = |settings: Settings| -> aorender::Result<aorender::Film> {
        let request = ImageRequest { camera: scene.camera, settings, samples: None };
        Ok(session.render(&request)?.complete(&mut Control::default())?.film)
    };
    let reference = render(Settings {
        spp: 64 * spp,
        sampling: Sampling { seed: 999, ..scene.settings.sampling },
        ..scene.settings.clone()
    })?;
    let (r, r_se) = (reference.mean(), reference.std_error());
    let reference_var: f64 = r_se.iter().map(|e| e * e).sum::<f64>() / r.len() as f64;
    let seeds = 8u32;
    println!("{path}, {size}x{size}, {spp} spp, {seeds} seeds; reference {} spp", 64 * spp);
    println!("| sampler | samples per replicate | replicates | MSE | MSE / independent | estimated / measured RMSE |");
    println!("|---|---|---|---|---|---|");
    let mut independent_mse = None;
    let configs: Vec<(Sampler, Option<u32>)> = vec![
        (Sampler::Independent, None),
        (Sampler::Stratified, Some(0)),
        (Sampler::Stratified, Some(64)),
        (Sampler::Stratified, Some(16)),
        (Sampler::Stratified, Some(4)),
        (Sampler::Sobol, Some(0)),
        (Sampler::Sobol, Some(64)),
        (Sampler::Sobol, Some(16)),
        (Sampler::Sobol, Some(4)),
    ];
    for (sampler, replicate) in configs {
        let (mut mse, mut estimated) = (0.0, 0.0);
        for seed in 0..seeds {
            let settings = Settings {
                spp,
                sampling: Sampling { sampler, replicate, seed, ..scene.settings.sampling },
                ..scene.settings.clone()
            };
            let film = render(settings)?;
            let m = film.mean();
            let e: f64 = m.iter().zip(&r).map(|(a, b)| (a - b) * (a - b)).sum::<f64>() / m.len() as f64;
            mse += (e - reference_var) / seeds as f64;
            estimated += film.rmse_estimate().map_or(f64::NAN, |e| e * e) / seeds as f64;
        }
        let base = *independent_mse.get_or_insert(mse);
        let b = sampler.replicate_samples(replicate);
        let replicates = spp.checked_div(b).unwrap_or(1);
        println!(
            "| {} | {} | {replicates} | {mse:.3e} | {:.3} | {:.3} |",
            sampler.name(),
            if b == 0 { "all (one replicate)".to_string() } else { b.to_string() },
            mse / base,
            (estimated / mse).sqrt()
        );
    }
    Ok(())
}
