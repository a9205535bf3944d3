//! Test hook: the phases of preparing a scene (`load`, `bvh`), appended one per line to the
//! file named by [`TEST_PHASE_FILE_ENV`] as each begins, so that a test can signal a
//! process while it is in a given phase instead of guessing how long the phase before took.

/// The environment variable naming the file the phases are appended to.
pub const TEST_PHASE_FILE_ENV: &str = "AORENDER_TEST_PHASE_FILE";

/// Records that `phase` begins (nothing when the variable is unset).
pub fn enter(phase: &str) {
    use std::io::Write;
    if let Some(path) = std::env::var_os(TEST_PHASE_FILE_ENV) {
        let file = std::fs::OpenOptions::new().create(true).append(true).open(&path);
        // A hook for tests only: a file that cannot be written fails the test that set it.
        file.and_then(|mut f| writeln!(f, "{phase}")).expect("the test's phase file is writable");
    }
}
