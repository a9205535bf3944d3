//! The benchmark's text table (stdout) and CSV files.

use super::{Results, Run};
use std::fmt::Write as _;

/// `v` with engineering-style precision: three significant digits.
fn sig(v: f64) -> String {
    if !v.is_finite() {
        return "-".into();
    }
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-3..1e5).contains(&a) {
        format!("{v:.2e}")
    } else if a >= 100.0 {
        format!("{v:.0}")
    } else if a >= 10.0 {
        format!("{v:.1}")
    } else if a >= 1.0 {
        format!("{v:.2}")
    } else {
        let decimals = (2 - a.log10().floor() as i32) as usize;
        format!("{v:.decimals$}")
    }
}

fn opt(v: Option<f64>) -> String {
    v.map_or_else(|| "-".into(), sig)
}

/// The human-readable summary printed on stdout.
pub fn table(r: &Results) -> String {
    let mut o = String::new();
    let a = &r.adapter;
    let m = &r.machine;
    let _ = writeln!(o, "aorender bench{}", if r.quick { " --quick" } else { "" });
    let _ = writeln!(o, "adapter: {} ({}, {}, {})", a.name, a.backend, a.device_type, a.driver);
    let _ = writeln!(o, "CPU reference: {}, {} threads ({})", m.cpu, m.threads, m.os);
    let _ = writeln!(
        o,
        "GPU time: {}; CPU time: wall clock. Rays are camera + AO rays. {:.0} s in all.",
        if r.gpu_time_source == "gpu-timestamps" { "timestamp queries" } else { "wall clock" },
        r.total_seconds
    );

    let _ = writeln!(
        o,
        "\nScenes (rays/s of cosine/independent at N spp; best = highest 1/(MSE·s) at N, unbiased samplers)"
    );
    let _ = writeln!(
        o,
        "{:<18} {:>9} {:>8} {:>5} {:>8} {:>8} {:>7} {:>6} {:>6} {:>9} {:<26}",
        "scene",
        "triangles",
        "image",
        "N",
        "GPU Mr/s",
        "CPU Mr/s",
        "GPU/CPU",
        "load s",
        "BVH s",
        "ref RMSE",
        "best (× cosine/indep.)"
    );
    for s in &r.scenes {
        let (g, c, ratio) = match &s.gpu_cpu {
            Some(gc) => (sig(gc.gpu_rays_per_second / 1e6), sig(gc.cpu_rays_per_second / 1e6), sig(gc.ratio)),
            None => {
                let g = s.runs.iter().find(|x| x.device == "gpu" && x.baseline);
                (g.map_or("-".into(), |g| sig(g.last().rays_per_second / 1e6)), "-".into(), "-".into())
            }
        };
        let best = s.best.as_ref().map_or("-".into(), |b| {
            format!("{}/{} ({})", b.hemisphere, b.sampler, b.over_default.map_or("-".into(), |x| format!("{x:.2}×")))
        });
        let _ = writeln!(
            o,
            "{:<18} {:>9} {:>8} {:>5} {:>8} {:>8} {:>7} {:>6} {:>6} {:>9} {:<26}",
            s.name,
            s.triangles,
            format!("{}x{}", s.width, s.height),
            s.max_spp,
            g,
            c,
            ratio,
            sig(s.load_seconds),
            sig(s.bvh_build_seconds),
            sig(s.reference.rmse_floor),
            best
        );
    }

    let _ = writeln!(o, "\nConvergence: slope of ln RMSE against ln spp; RMSE, relative MSE, time and efficiency at N");
    let _ = writeln!(
        o,
        "{:<18} {:<4} {:<16} {:<12} {:>7} {:>9} {:>9} {:>8} {:>8} {:>10}",
        "scene", "dev", "hemisphere", "sampler", "slope", "RMSE", "relMSE", "seconds", "Mray/s", "1/(MSE·s)"
    );
    for s in &r.scenes {
        for run in &s.runs {
            let _ = writeln!(o, "{:<18} {}", s.name, run_row(run));
        }
    }

    if r.scenes.iter().any(|s| s.runs.iter().any(|run| run.sky_sampling.is_some())) {
        let _ = writeln!(
            o,
            "\nOvercast sky: variance of a sample at N (independent: the film's spread; else MSE × N), samples per \
             second, their ratio (less is better)"
        );
        let _ = writeln!(
            o,
            "{:<18} {:<4} {:<16} {:<12} {:>8} {:>10} {:>8} {:>10}",
            "scene", "dev", "sky sampling", "sampler", "mean", "variance", "Msmp/s", "variance·s"
        );
        for s in &r.scenes {
            for run in s.runs.iter().filter(|run| run.sky_sampling.is_some()) {
                let c = run.last();
                let samples_per_second = run.variance_per_sample / run.variance_seconds;
                let _ = writeln!(
                    o,
                    "{:<18} {:<4} {:<16} {:<12} {:>8} {:>10} {:>8} {:>10}",
                    s.name,
                    run.device,
                    run.distribution(),
                    run.sampler,
                    sig(c.image_mean),
                    sig(run.variance_per_sample),
                    sig(samples_per_second / 1e6),
                    sig(run.variance_seconds)
                );
            }
        }
    }

    if !r.bvh_presets.is_empty() {
        let _ = writeln!(
            o,
            "\nBVH presets (CWBVH; cosine/independent; break-even: rays after which the build pays off against fastest)"
        );
        let _ = writeln!(
            o,
            "{:<18} {:<8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>14}",
            "scene", "preset", "build s", "nodes", "GPU Mr/s", "CPU Mr/s", "convert", "break-even Mr"
        );
        for p in &r.bvh_presets {
            let _ = writeln!(
                o,
                "{:<18} {:<8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>14}",
                p.scene,
                p.preset,
                sig(p.build_seconds),
                p.nodes,
                sig(p.gpu_rays_per_second / 1e6),
                opt(p.cpu_rays_per_second.map(|v| v / 1e6)),
                sig(p.convert_seconds),
                opt(p.gpu_break_even_rays.map(|v| v / 1e6))
            );
        }
    }

    for (series, what) in [("triangles", "primitives"), ("resolution", "pixels"), ("spp", "spp")] {
        let points: Vec<_> = r.scaling.iter().filter(|p| p.series == series).collect();
        if points.is_empty() {
            continue;
        }
        let _ = writeln!(o, "\nSeconds per million rays against {what}");
        let _ =
            writeln!(o, "{:<18} {:<4} {:>10} {:>9} {:>8} {:>10}", "scene", "dev", what, "image", "seconds", "s/M rays");
        for p in points {
            let _ = writeln!(
                o,
                "{:<18} {:<4} {:>10} {:>9} {:>8} {:>10}",
                p.scene,
                p.device,
                p.x,
                format!("{}x{}", p.width, p.height),
                sig(p.seconds),
                sig(p.seconds_per_mray)
            );
        }
    }
    for f in &r.failures {
        let _ = writeln!(o, "\nFAILED {}: {}", f.scene, f.error);
    }
    o
}

fn run_row(run: &Run) -> String {
    let c = run.last();
    format!(
        "{:<4} {:<16} {:<12} {:>7} {:>9} {:>9} {:>8} {:>8} {:>10}",
        run.device,
        run.distribution(),
        if run.unbiased { run.sampler.clone() } else { format!("{} (biased)", run.sampler) },
        run.slope.map_or("-".into(), |s| format!("{s:.3}")),
        sig(c.rmse),
        sig(c.rel_mse),
        sig(c.seconds),
        sig(c.rays_per_second / 1e6),
        opt(c.efficiency)
    )
}

/// A CSV field, quoted when it holds a comma, quote or line break.
fn field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) { format!("\"{}\"", s.replace('"', "\"\"")) } else { s.to_string() }
}

/// Every checkpoint of every run, one row each.
pub fn convergence_csv(r: &Results) -> String {
    let mut o = String::from(
        "scene,triangles,width,height,device,hemisphere,sampler,unbiased,time_source,spp,seconds,wall_seconds,\
         rays,rays_per_second,mse,mse_std_error,rmse,rel_mse,efficiency,reference_rmse_floor,slope,sky_sampling,\
         variance_per_sample,variance_seconds\n",
    );
    for s in &r.scenes {
        for run in &s.runs {
            for c in &run.checkpoints {
                let _ = writeln!(
                    o,
                    "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
                    field(&s.name),
                    s.triangles,
                    s.width,
                    s.height,
                    run.device,
                    run.hemisphere,
                    run.sampler,
                    run.unbiased,
                    run.time_source,
                    c.spp,
                    c.seconds,
                    c.wall_seconds,
                    c.rays,
                    c.rays_per_second,
                    c.mse,
                    c.mse_std_error,
                    c.rmse,
                    c.rel_mse,
                    c.efficiency.map_or(String::new(), |e| e.to_string()),
                    s.reference.rmse_floor,
                    run.slope.map_or(String::new(), |e| e.to_string()),
                    run.sky_sampling.as_deref().unwrap_or(""),
                    run.variance_per_sample,
                    run.variance_seconds,
                );
            }
        }
    }
    o
}

/// The BVH presets, one row each.
pub fn presets_csv(r: &Results) -> String {
    let mut o = String::from(
        "scene,triangles,preset,build_seconds,convert_seconds,nodes,gpu_rays_per_second,cpu_rays_per_second,gpu_break_even_rays\n",
    );
    for p in &r.bvh_presets {
        let _ = writeln!(
            o,
            "{},{},{},{},{},{},{},{},{}",
            field(&p.scene),
            p.triangles,
            p.preset,
            p.build_seconds,
            p.convert_seconds,
            p.nodes,
            p.gpu_rays_per_second,
            p.cpu_rays_per_second.map_or(String::new(), |v| v.to_string()),
            p.gpu_break_even_rays.map_or(String::new(), |v| v.to_string()),
        );
    }
    o
}

/// The scaling series, one row per point.
pub fn scaling_csv(r: &Results) -> String {
    let mut o = String::from("series,scene,device,x,width,height,spp,rays,seconds,seconds_per_mray\n");
    for p in &r.scaling {
        let _ = writeln!(
            o,
            "{},{},{},{},{},{},{},{},{},{}",
            p.series,
            field(&p.scene),
            p.device,
            p.x,
            p.width,
            p.height,
            p.spp,
            p.rays,
            p.seconds,
            p.seconds_per_mray
        );
    }
    o
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fields_with_commas_and_quotes_are_quoted() {
        assert_eq!(field("dragon"), "dragon");
        assert_eq!(field("a,b"), "\"a,b\"");
        assert_eq!(field("say \"hi\""), "\"say \"\"hi\"\"\"");
    }

    #[test]
    fn numbers_keep_three_significant_digits() {
        assert_eq!(sig(12345.0), "12345");
        assert_eq!(sig(1.23456), "1.23");
        assert_eq!(sig(0.012345), "0.0123");
        assert_eq!(sig(0.5), "0.500");
        assert_eq!(sig(1.5e-5), "1.50e-5");
        assert_eq!(sig(f64::NAN), "-");
    }
}
