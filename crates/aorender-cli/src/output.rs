//! What the commands write, at the command line's edge: data printed to standard output
//! (a closed pipe ends the program quietly, as a pipeline expects; another failure is one
//! line), and the files of a run (`render`, `bake`) entered in the library's
//! [`FilePlan`], which refuses an output onto an input or another output before any work.

use crate::args::RunArgs;
use anyhow::{Result, anyhow};
use aorender::output::{FilePlan, OutputRules};
use std::io::Write;
use std::path::{Path, PathBuf};

/// The exit status of a program whose standard output was closed: 128 + SIGPIPE, as a
/// shell reports one killed by the signal.
pub const BROKEN_PIPE_STATUS: i32 = 128 + 13;

/// Prints `text` to standard output and flushes it. A reader that closed the pipe (`|
/// head -1`) ends the program at once, quietly, with [`BROKEN_PIPE_STATUS`]; any other
/// failure (`> /dev/full`) is an error naming standard output.
pub fn print(text: &str) -> Result<()> {
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
        Ok(()) => Ok(()),
        Err(e) => Err(stdout_error(e)),
    }
}

/// Flushes standard output (before an exit that skips the runtime's own flush), as
/// [`print()`] treats a failure.
pub fn flush() -> Result<()> {
    std::io::stdout().lock().flush().map_err(stdout_error)
}

fn stdout_error(e: std::io::Error) -> anyhow::Error {
    if e.kind() == std::io::ErrorKind::BrokenPipe {
        std::process::exit(BROKEN_PIPE_STATUS);
    }
    anyhow!("standard output: {e}")
}

/// The checkpoint a run saves to: `--checkpoint`, else the file `--resume` continues.
pub fn checkpoint_path(run: &RunArgs) -> Option<PathBuf> {
    run.checkpoint.clone().or_else(|| run.resume.clone())
}

/// Enters the checkpoint `--resume` continues in `plan`, an input (before the outputs,
/// which are checked against the inputs entered before them).
pub fn plan_resume(plan: &mut FilePlan, run: &RunArgs) {
    if let Some(path) = &run.resume {
        plan.input(path, "the checkpoint --resume continues");
    }
}

/// Enters a run's own outputs in `plan`: `--stats`, and the checkpoint saved to, which
/// may be the one `--resume` read.
pub fn plan_run(plan: &mut FilePlan, run: &RunArgs) -> Result<()> {
    if let Some(path) = &run.stats {
        plan.output(path, "--stats")?;
    }
    if let Some(path) = checkpoint_path(run) {
        let role = if run.checkpoint.is_some() { "--checkpoint" } else { "the checkpoint --resume saves" };
        plan.output_with(&path, role, OutputRules { replacing: run.resume.as_deref(), ..OutputRules::default() })?;
    }
    Ok(())
}

/// Enters the scene's files (`None`: the built-in scene, which has none) in `plan`.
pub fn plan_scene(plan: &mut FilePlan, scene: Option<&Path>) {
    if let Some(path) = scene {
        plan.scene(path);
    }
}
