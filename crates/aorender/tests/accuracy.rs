//! The closed-form suite at the extremes (`aorender::closed_form`): every case in every
//! variant — scale 1, 1e-4 and 1e6 and translation by 1e6, with the normal along each
//! ±axis — on the CPU reference and the adapter, with every unbiased sampler, within 4
//! standard errors of the exact value. The base orientation (+y) of each scale runs every
//! hemisphere with every sampler; the other five run each sampler with one hemisphere,
//! rotating, so that every pair meets every scale.

mod common;
use aorender::closed_form::{Case, Variant, agrees, cases, configurations};
use aorender::{Device, Hemisphere, Sampler, Session};
use common::{gpu_available, gpu_device};

const SAMPLES: u32 = 1 << 14;

/// Runs every case of the variants with `scale` and `offset` in every configuration on
/// every device; panics listing every estimate that disagrees.
fn check_variants(scale: f64, offset: f64) {
    let mut devices = vec![Device::cpu()];
    if gpu_available() {
        devices.push(gpu_device());
    }
    let variants: Vec<Variant> =
        Variant::all().into_iter().filter(|v| v.scale == scale && v.offset == offset).collect();
    assert_eq!(variants.len(), 6, "six orientations");
    let mut failures = Vec::new();
    let mut checks = 0;
    for (vi, v) in variants.iter().enumerate() {
        let all: Vec<Case> = cases(v);
        assert!(all.len() >= 15, "{}: only {} cases", v.name(), all.len());
        for (ci, case) in all.iter().enumerate() {
            let configs: Vec<_> =
                configurations().into_iter().enumerate().filter(|(k, _)| vi == 0 || (k / 3 + vi) % 3 == 0).collect();
            assert!(configs.len() >= 3);
            // The case prepared once on each device, then probed in every configuration.
            let sessions: Vec<Session> = devices
                .iter()
                .map(|d| case.session(d).unwrap_or_else(|e| panic!("{} {}: {e}", case.name, v.name())))
                .collect();
            for (k, config) in configs {
                for session in &sessions {
                    let device = session.device().kind();
                    let seed = (vi * 1000 + ci * 10 + k) as u32;
                    let values = case
                        .estimate(session, config, seed, SAMPLES)
                        .unwrap_or_else(|e| panic!("{} {}: {e}", case.name, v.name()));
                    for (p, (value, &expected)) in values.iter().zip(&case.expected).enumerate() {
                        checks += 1;
                        assert_eq!(value.samples, SAMPLES as u64);
                        if !agrees(value, expected) {
                            failures.push(format!(
                                "{} [{}] probe {p} {:?} {} {}: {:.6} ± {:.2e}, expected {expected:.6}",
                                case.name,
                                v.name(),
                                device,
                                config.0.name(),
                                config.1.name(),
                                value.mean,
                                value.std_error
                            ));
                        }
                    }
                }
            }
        }
    }
    eprintln!("{checks} estimates, {} outside 4 standard errors", failures.len());
    assert!(failures.is_empty(), "{} of {checks} estimates disagree:\n{}", failures.len(), failures.join("\n"));
}

#[test]
fn unit_scale_in_every_orientation() {
    check_variants(1.0, 0.0);
}

#[test]
fn scaled_by_1e_minus_4() {
    check_variants(1e-4, 0.0);
}

#[test]
fn scaled_by_1e6() {
    check_variants(1e6, 0.0);
}

#[test]
fn translated_by_1e6() {
    check_variants(1.0, 1e6);
}

/// The exact values themselves: the variants pose the same question (up to rounding) and
/// the closed forms give the textbook numbers in the base frame.
#[test]
fn expected_values_are_the_closed_forms() {
    let base = cases(&Variant::BASE);
    let find = |prefix: &str| base.iter().find(|c| c.name.starts_with(prefix)).expect(prefix);
    let cap = find("plane under sphere r 0.5 d 1 β 30°");
    // 1 − cos 30° · 0.25, from the f32 centre (0.5, 0.8660254, 0).
    assert!((cap.expected[0] - (1.0 - 3f64.sqrt() / 2.0 * 0.25)).abs() < 1e-7, "{}", cap.expected[0]);
    assert_eq!(find("ceiling h 1 R 2").expected, vec![0.25]);
    assert_eq!(find("ceiling h 3 R 3").expected, vec![1.0]);
    assert_eq!(find("ceiling h 1 R ∞").expected, vec![0.0]);
    assert_eq!(find("ceiling h 1 R 0").expected, vec![1.0]);
    for v in Variant::all() {
        let names: Vec<String> = cases(&v).into_iter().map(|c| c.name).collect();
        let base_names: Vec<String> = base.iter().map(|c| c.name.clone()).collect();
        assert_eq!(names, base_names, "{} has every case", v.name());
        for c in cases(&v) {
            for (p, e) in c.probes.iter().zip(&c.expected) {
                assert!((0.0..=1.0).contains(e), "{} [{}]: {e}", c.name, v.name());
                assert!(p.normal.abs().max_element() == 1.0 || c.name.contains("closed") || c.name.contains("ico"));
            }
        }
    }
}

/// Every configuration really differs (the suite is not running one sampler nine times).
#[test]
fn configurations_cover_every_hemisphere_and_unbiased_sampler() {
    let configs = configurations();
    assert_eq!(configs.len(), Hemisphere::ALL.len() * 3);
    for s in [Sampler::Independent, Sampler::Stratified, Sampler::Sobol] {
        assert!(configs.iter().any(|c| c.1 == s));
    }
    assert!(configs.iter().all(|c| c.1 != Sampler::Grid), "the grid sampler is biased");
}
