//! The run loop's command-line side, one for `render` and `bake`: the progress bar, the
//! checkpoints saved while tracing, the message that points at the last checkpoint when
//! the adapter fails, and the exit statuses of a run a signal stopped (128 + the signal).

use crate::args::RunArgs;
use crate::{output, signals};
use anyhow::Result;
use aorender::{Accumulation, Control, ErrorTarget, Progress};
use std::path::Path;
use std::sync::atomic::AtomicBool;

/// How a traced run is driven from the command line.
pub struct RunControl<'a> {
    /// Set by the signal handler.
    pub stop: &'a AtomicBool,
    /// `--time-limit`, `--checkpoint-interval`.
    pub run: &'a RunArgs,
    /// Where checkpoints are saved (`--checkpoint`, or `--resume`'s file).
    pub checkpoint: Option<&'a Path>,
    /// The progress bar's total and unit (`spp`, `samples`).
    pub total: u32,
    /// The progress bar's unit.
    pub unit: &'static str,
    /// An error target, for renders.
    pub target: Option<ErrorTarget>,
    /// Adaptive sampling, for renders.
    pub adaptive: bool,
}

/// Runs `work` under a [`Control`] made from `rc` (progress bar, stop flag, time limit,
/// checkpoints), and, when the adapter fails with a checkpoint saved, says how to resume.
pub fn traced<T>(rc: RunControl, work: impl FnOnce(&mut Control) -> aorender::Result<T>) -> Result<T> {
    let bar = signals::PassProgress::new(rc.total, rc.unit);
    let mut on_progress = |p: &Progress| bar.update(p);
    let checkpoint = rc.checkpoint;
    let mut save_to = |acc: &Accumulation| -> aorender::Result<()> {
        match checkpoint {
            Some(path) => acc.write(path),
            None => Ok(()),
        }
    };
    let mut control = Control {
        stop: Some(rc.stop),
        time_limit: rc.run.time_limit,
        progress: Some(&mut on_progress),
        save: if checkpoint.is_some() { Some(&mut save_to) } else { None },
        save_interval: rc.run.checkpoint_interval,
        target: rc.target,
        adaptive: rc.adaptive,
        ..Control::default()
    };
    let out = work(&mut control).map_err(|e| {
        // The adapter failed (setting up or mid-run): the last checkpoint saved before it
        // is whole.
        let adapter_failed = matches!(e, aorender::Error::DeviceLost { .. } | aorender::Error::OutOfMemory { .. });
        match checkpoint {
            Some(path) if adapter_failed && path.exists() => anyhow::anyhow!(
                "{e}; the last checkpoint, {}, is intact: continue with --resume {}",
                path.display(),
                path.display()
            ),
            _ => e.into(),
        }
    })?;
    bar.finish();
    Ok(out)
}

/// Ends a run a signal stopped before any sample was traced (`what`: `rendered`,
/// `traced`): nothing was written.
pub fn exit_before_any_sample(what: &str) -> ! {
    let signal = signals::stop_signal();
    crate::say!(
        "aorender: interrupted by {} before any sample was {what}; nothing was written",
        signals::signal_name(signal)
    );
    std::process::exit(128 + signal);
}

/// Ends a run a signal stopped after its files were written: `aorender: interrupted by
/// SIGNAL after {done}`, with the checkpoint to resume from.
pub fn exit_interrupted(done: &str, checkpoint: Option<&Path>) -> Result<()> {
    let signal = signals::stop_signal();
    let mut message = format!("interrupted by {} after {done}", signals::signal_name(signal));
    if let Some(path) = checkpoint {
        message += &format!("; continue with --resume {}", path.display());
    }
    crate::say!("aorender: {message}");
    output::flush()?;
    std::process::exit(128 + signal);
}
