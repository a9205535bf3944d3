//! SIGINT and SIGTERM during `aorender render`: the first asks the render to stop after
//! its current pass (and the outputs for the samples done are written); a second removes
//! the temporary files of writes in progress (their targets are untouched) and exits at
//! once with status 128 + signal. Before the render's first pass has finished there is
//! nothing to write: a signal exits at once.

use anyhow::{Context, Result};
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
                    eprintln!(
                        "aorender: interrupted by {} before the first pass finished (loading the scene, building the \
                         BVH or setting up the device); nothing was written",
                        signal_name(signal)
                    );
                    signal_hook::low_level::exit(128 + signal);
                }
                if STOP_SIGNAL.compare_exchange(0, signal, Ordering::SeqCst, Ordering::SeqCst).is_ok() {
                    stop.store(true, Ordering::SeqCst);
                    eprintln!("{}: finishing the current pass (a second signal stops at once)", signal_name(signal));
                } else {
                    aorender::output::remove_temporary_files();
                    eprintln!(
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
