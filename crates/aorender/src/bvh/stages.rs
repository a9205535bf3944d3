//! Seconds spent in each stage of a CWBVH build: the breakdown the `bvh_build` example
//! prints. Wall seconds summed over the threads that ran a stage, and CPU seconds: the
//! process's for the stages that run alone (on every thread), the running thread's for a
//! cell's stages (cells are built side by side). Counted only with the `testing` feature
//! on Linux; elsewhere [`timed`] is the call it wraps.

/// A stage of the CWBVH build (`build_cwbvh`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// Finding copies of primitives (`build::distinct`).
    Distinct,
    /// The cells' Morton keys, sorted, and the octree cut into cells.
    Cells,
    /// A cell's primitive boxes and leaves in Morton order.
    Leaves,
    /// A cell's PLOC merging passes, and its depth check.
    Ploc,
    /// A cell's reinsertion passes.
    Reinsertion,
    /// A cell's BVH2 collapsed into 8-wide nodes.
    Collapse,
    /// The cells joined under nodes made above them.
    Join,
}

impl Stage {
    /// Every stage, in build order.
    #[cfg(feature = "testing")]
    pub const ALL: [Stage; 7] =
        [Stage::Distinct, Stage::Cells, Stage::Leaves, Stage::Ploc, Stage::Reinsertion, Stage::Collapse, Stage::Join];

    /// Whether the stage is part of one cell's build, which runs beside other cells'.
    #[cfg(feature = "testing")]
    pub fn in_cell(self) -> bool {
        matches!(self, Stage::Leaves | Stage::Ploc | Stage::Reinsertion | Stage::Collapse)
    }

    /// The stage's name in the example's table.
    #[cfg(feature = "testing")]
    pub fn name(self) -> &'static str {
        match self {
            Stage::Distinct => "copies",
            Stage::Cells => "Morton keys, sort, octree cells",
            Stage::Leaves => "cells: boxes, Morton order",
            Stage::Ploc => "cells: PLOC passes",
            Stage::Reinsertion => "cells: reinsertion",
            Stage::Collapse => "cells: collapse to CWBVH",
            Stage::Join => "join of the cells",
        }
    }
}

/// Wall and CPU nanoseconds of each stage.
#[cfg(all(feature = "testing", target_os = "linux"))]
static NANOS: [[std::sync::atomic::AtomicU64; 2]; Stage::ALL.len()] =
    [const { [const { std::sync::atomic::AtomicU64::new(0) }; 2] }; Stage::ALL.len()];

/// CPU nanoseconds of the calling thread, or of the whole process.
#[cfg(all(feature = "testing", target_os = "linux"))]
fn cpu_nanos(thread: bool) -> u64 {
    let clock = if thread { libc::CLOCK_THREAD_CPUTIME_ID } else { libc::CLOCK_PROCESS_CPUTIME_ID };
    let mut t = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: clock_gettime writes the timespec it is given; both clocks exist on Linux.
    unsafe { libc::clock_gettime(clock, &mut t) };
    t.tv_sec as u64 * 1_000_000_000 + t.tv_nsec as u64
}

/// Runs `f`, adding its seconds to `stage`'s.
#[inline]
pub(crate) fn timed<T>(stage: Stage, f: impl FnOnce() -> T) -> T {
    #[cfg(all(feature = "testing", target_os = "linux"))]
    {
        use std::sync::atomic::Ordering;
        let (start, cpu) = (std::time::Instant::now(), cpu_nanos(stage.in_cell()));
        let out = f();
        let counters = &NANOS[stage as usize];
        counters[0].fetch_add(start.elapsed().as_nanos() as u64, Ordering::Relaxed);
        counters[1].fetch_add(cpu_nanos(stage.in_cell()) - cpu, Ordering::Relaxed);
        out
    }
    #[cfg(not(all(feature = "testing", target_os = "linux")))]
    {
        let _ = stage;
        f()
    }
}

/// Each stage's wall and CPU seconds since the last call, and zeroes them (zeroes where
/// nothing is counted).
#[cfg(feature = "testing")]
pub fn take() -> Vec<(Stage, f64, f64)> {
    #[cfg(target_os = "linux")]
    {
        let seconds = |c: &std::sync::atomic::AtomicU64| c.swap(0, std::sync::atomic::Ordering::Relaxed) as f64 * 1e-9;
        Stage::ALL.iter().map(|&s| (s, seconds(&NANOS[s as usize][0]), seconds(&NANOS[s as usize][1]))).collect()
    }
    #[cfg(not(target_os = "linux"))]
    Stage::ALL.iter().map(|&s| (s, 0.0, 0.0)).collect()
}
