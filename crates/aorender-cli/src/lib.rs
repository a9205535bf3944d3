//! The `aorender` command's modules: the command line (argument types and checks), one
//! module per command, the benchmark, standard output and the files each command writes,
//! signal handling and heap accounting. The binary (`src/main.rs`) parses the command
//! line and dispatches; the engine is the `aorender` library.

/// Writes a line to standard error as `eprintln!` does, but never panics: where standard
/// error is closed or full the line is lost and the command's exit status stands.
#[macro_export]
macro_rules! say {
    ($($arg:tt)*) => {{
        use ::std::io::Write as _;
        let _ = ::std::writeln!(::std::io::stderr(), $($arg)*);
    }};
}

pub mod args;
pub mod bench;
pub mod commands;
pub mod memory;
pub mod output;
pub mod phases;
pub mod run;
pub mod signals;
