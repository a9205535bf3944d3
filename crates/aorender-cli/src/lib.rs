//! The `aorender` command's modules: the command line (argument types and checks), one
//! module per command, the benchmark, standard output and the files each command writes,
//! signal handling and heap accounting. The binary (`src/main.rs`) parses the command
//! line and dispatches; the engine is the `aorender` library.

pub mod args;
pub mod bench;
pub mod commands;
pub mod memory;
pub mod output;
pub mod phases;
pub mod signals;
