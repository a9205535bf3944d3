//! The host memory a request's film may take: what a render holds per film slot (pixel,
//! or probe lane) at its peak, and the budget that is checked against before any of it is
//! made, so that a 16384² image asked of a small machine is refused in one line instead of
//! growing until the system kills it.

use crate::error::{Error, Result};
use std::path::Path;

/// Environment variable that sets the film budget, in bytes, in place of the share of the
/// memory available ([`film_budget`]).
pub const FILM_BUDGET_ENV: &str = "AORENDER_FILM_BUDGET";

/// Host bytes a film slot takes at a render's peak: the exact block sums (two i128, 32
/// bytes), the device's block as it is taken and handed over (64-bit integer sums, 16
/// bytes, with the GPU's words or the CPU's copy beside them: 32 to 48), and the film and figures the render
/// ends with (32 to 48). Measured (aorender's heap peak, 2048² images): 128 bytes on the
/// CPU reference, 112 on the GPU; an eighth more here for the allocator's rounding and
/// the outputs' buffers. `tests/limits.rs` holds every device to it.
pub const SLOT_BYTES: u64 = 144;

/// More per slot when the samples are in replicates: the squares of the replicates' sums
/// (16 bytes exact, 8 in the film) and an adaptive render's per-pixel counts. Measured:
/// 56 more.
pub const REPLICATE_SLOT_BYTES: u64 = 64;

/// More per slot on a CPU adapter (lavapipe), whose device memory is host memory: the
/// film, its readback and the driver's staging. Measured: 56 more (the process's resident
/// peak).
pub const CPU_ADAPTER_SLOT_BYTES: u64 = 64;

/// Host bytes a film of `slots` slots takes at its peak, with samples in replicates or
/// not, on a GPU whose device memory is host memory (`cpu_adapter`) or elsewhere.
pub fn film_bytes(slots: u64, replicated: bool, cpu_adapter: bool) -> u64 {
    let mut per_slot = SLOT_BYTES;
    if replicated {
        per_slot += REPLICATE_SLOT_BYTES;
    }
    if cpu_adapter {
        per_slot += CPU_ADAPTER_SLOT_BYTES;
    }
    slots.saturating_mul(per_slot)
}

/// The most bytes a film may take, and where that figure comes from (for messages).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FilmBudget {
    /// Bytes; `u64::MAX` where the memory available is unknown.
    pub bytes: u64,
    /// How it was set, in words.
    pub basis: String,
}

/// The film budget: [`FILM_BUDGET_ENV`] when set, else three quarters of the memory
/// available now (Linux's `MemAvailable`, or what the process's cgroup leaves, whichever
/// is less: the rest is the system's, and the scene's and BVH's are already taken), else
/// none.
pub fn film_budget() -> Result<FilmBudget> {
    if let Ok(text) = std::env::var(FILM_BUDGET_ENV) {
        let bytes = text.trim().parse::<u64>().map_err(|_| {
            Error::settings(format!("{FILM_BUDGET_ENV} must be a number of bytes, not '{}'", text.trim()))
        })?;
        return Ok(FilmBudget { bytes, basis: format!("set by {FILM_BUDGET_ENV}") });
    }
    Ok(match memory_available() {
        Some(available) => FilmBudget {
            bytes: available / 4 * 3,
            basis: format!("three quarters of the {} bytes available; {FILM_BUDGET_ENV} sets it", available),
        },
        None => FilmBudget { bytes: u64::MAX, basis: "the memory available is unknown".into() },
    })
}

/// Bytes of memory available to this process: `MemAvailable` from `/proc/meminfo`, less
/// where the cgroup's limit leaves less; `None` where neither is known.
pub fn memory_available() -> Option<u64> {
    let meminfo = std::fs::read_to_string("/proc/meminfo").ok().and_then(|text| {
        let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
        let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
        Some(kb * 1024)
    });
    let number = |path: &str| -> Option<u64> { std::fs::read_to_string(path).ok()?.trim().parse().ok() };
    // cgroup v2, then v1; a limit of 2⁶⁰ or more (v1's "none") is no limit.
    let cgroup = [
        ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
        ("/sys/fs/cgroup/memory/memory.limit_in_bytes", "/sys/fs/cgroup/memory/memory.usage_in_bytes"),
    ]
    .into_iter()
    .find_map(|(limit, used)| {
        let limit = number(limit).filter(|&l| l < 1 << 60)?;
        Some(limit.saturating_sub(number(used).unwrap_or(0)))
    });
    match (meminfo, cgroup) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    }
}

/// Fails with [`Error::FilmBudget`] naming `scene` when `what`, a film of `needed` bytes,
/// is past `budget`.
pub fn check_film(scene: &Path, what: String, needed: u64, budget: &FilmBudget) -> Result<()> {
    if needed <= budget.bytes {
        return Ok(());
    }
    Err(Error::FilmBudget {
        path: scene.to_path_buf(),
        what,
        needed,
        budget: budget.bytes,
        basis: budget.basis.clone(),
    })
}
