//! SIGINT and SIGTERM during `aorender render` and `bake`: the first asks the render to stop after
//! its current pass (and the outputs for the samples done are written); a second removes
//! the temporary files of writes in progress (their targets are untouched) and exits at
//! once with status 128 + signal. Before the render's first pass has finished there is
//! nothing to write: a signal exits at once.

use anyhow::{Context, Result};
use std::io::IsTerminal;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicI32, Ordering};

/// The signal that asked the render to stop (0 for none).
static STOP_SIGNAL: AtomicI32 = AtomicI32::new(0);
/// Set when the render's first pass has finished: before that (loading the scene, building
/// the BVH, setting up the device, the first pass) a signal ends the process at once.
static FIRST_PASS_DONE: AtomicBool = AtomicBool::new(false);

/// The signal that asked the render to stop, 0 for none.
pub fn stop_signal() -> i32 {
    STOP_SIGNAL.load(Ordering::SeqCst)
}

/// Records that the render's first pass has finished: from now on a signal lets the
/// current pass finish.
pub fn first_pass_done() {
    FIRST_PASS_DONE.store(true, Ordering::SeqCst);
}

/// Name of a signal number.
pub fn signal_name(signal: i32) -> String {
    #[cfg(unix)]
    {
        use signal_hook::consts::{SIGINT, SIGTERM};
        match signal {
            SIGINT => return "SIGINT".into(),
            SIGTERM => return "SIGTERM".into(),
            _ => {}
        }
    }
    format!("signal {signal}")
}

/// Installs the handlers; `stop` is set by the first signal after the first pass.
#[cfg(unix)]
pub fn install(stop: Arc<AtomicBool>) -> Result<()> {
    use signal_hook::consts::{SIGINT, SIGTERM};
    let mut signals = signal_hook::iterator::Signals::new([SIGINT, SIGTERM]).context("cannot handle signals")?;
    std::thread::Builder::new()
        .name("signals".into())
        .spawn(move || {
            for signal in signals.forever() {
                if !FIRST_PASS_DONE.load(Ordering::SeqCst) {
                    aorender::output::remove_temporary_files();
                    crate::say!(
                        "aorender: interrupted by {} before the first pass finished (loading the scene, building the \
                         BVH or setting up the device); nothing was written",
                        signal_name(signal)
                    );
                    signal_hook::low_level::exit(128 + signal);
                }
                if STOP_SIGNAL.compare_exchange(0, signal, Ordering::SeqCst, Ordering::SeqCst).is_ok() {
                    stop.store(true, Ordering::SeqCst);
                    crate::say!("{}: finishing the current pass (a second signal stops at once)", signal_name(signal));
                } else {
                    aorender::output::remove_temporary_files();
                    crate::say!(
                        "aorender: stopped at once by a second {}; files being written were left as they were",
                        signal_name(signal)
                    );
                    signal_hook::low_level::exit(128 + signal);
                }
            }
        })
        .context("cannot start the signal thread")?;
    Ok(())
}

/// Installs the handlers (none on this platform).
#[cfg(not(unix))]
pub fn install(_stop: Arc<AtomicBool>) -> Result<()> {
    Ok(())
}

/// The progress bar of a render or bake on stderr, drawn only when stderr is a terminal;
/// its updates also mark the first pass done for the signal handlers.
pub struct PassProgress(Option<indicatif::ProgressBar>);

impl PassProgress {
    /// A bar of `total` samples, counted in `unit` (`spp`, `samples`).
    pub fn new(total: u32, unit: &str) -> PassProgress {
        PassProgress(std::io::stderr().is_terminal().then(|| {
            let bar = indicatif::ProgressBar::new(total as u64);
            let template = format!("{{bar:40}} {{pos}}/{{len}} {unit}  {{msg}}  eta {{eta}}");
            bar.set_style(indicatif::ProgressStyle::with_template(&template).expect("valid template"));
            bar
        }))
    }

    /// After a pass: the first one is done, and the bar shows the samples and the rays per
    /// second so far.
    pub fn update(&self, p: &aorender::Progress) {
        first_pass_done();
        if let Some(bar) = &self.0 {
            bar.set_length(p.samples_total as u64);
            bar.set_position(p.samples_done as u64);
            bar.set_message(format!("{:.1} M rays/s", p.rays as f64 / p.elapsed.max(1e-9) / 1e6));
        }
    }

    /// Removes the bar.
    pub fn finish(self) {
        if let Some(bar) = self.0 {
            bar.finish_and_clear();
        }
    }
}
