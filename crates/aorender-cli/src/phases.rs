//! Where a command's time goes: the phases of a render, probe or bake from the process's
//! start to its statistics, as `--stats` lists them and the summary line says them.

use aorender::{PassTimes, RenderStats};
use std::sync::OnceLock;
use std::time::Instant;

/// When `main` began.
static START: OnceLock<Instant> = OnceLock::new();

/// Starts the process's clock (the first call; later ones keep it).
pub fn start_clock() {
    START.get_or_init(Instant::now);
}

/// Seconds since [`start_clock`] (since the first call of this, where it was never called).
pub fn process_seconds() -> f64 {
    START.get_or_init(Instant::now).elapsed().as_secs_f64()
}

/// The phases of a command, in seconds. On the CPU reference `adapter_seconds` is the
/// reference's opening, `upload_seconds` laying out the tracer's records, `readback_seconds`
/// taking the block's sums from the tracer's film, and `readback_bytes` and `round_trips`
/// 0. The device opens on a thread of its own while the scene loads and its BVH builds:
/// `adapter_seconds` is the opening's own time, `overlap_seconds` the part of it that ran
/// beside the main thread, so that the phases less `overlap_seconds` are the main
/// thread's timeline, and with `other_seconds` the whole process.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Phases {
    /// From the process's start to loading: starting the program, reading the command
    /// line, checking the outputs.
    pub start_seconds: f64,
    /// Reading and parsing the input (and, for a bake, placing its points).
    pub load_seconds: f64,
    /// Building the BVH, its conversion to the GPU's layout included.
    pub bvh_build_seconds: f64,
    /// The session's setup beside the BVH and the upload: the scene moved to its local
    /// frame and back, the build's host copies freed.
    pub scene_seconds: f64,
    /// Opening the device, on its own thread.
    pub adapter_seconds: f64,
    /// Of the phases, the seconds that ran beside the main thread (the device's opening
    /// while the scene loaded and its BVH was built): not on the process's critical path.
    pub overlap_seconds: f64,
    /// Uploading the geometry (GPU) or laying out the tracer's records (CPU).
    pub upload_seconds: f64,
    /// Making the films and pipelines of the requests (a bake's points uploaded).
    pub pipeline_seconds: f64,
    /// Of `pipeline_seconds`: compiling pipelines.
    pub compile_seconds: f64,
    /// The driver's pipeline cache on disk: `hit`, `miss`, `rejected`, `off`,
    /// `unsupported`; empty on the CPU.
    pub pipeline_cache: String,
    /// The requests beside their films, pipelines and passes: checks, the hashes that
    /// name their checkpoints, their accumulations.
    pub request_seconds: f64,
    /// The passes: submitting them and waiting for the rays.
    pub pass_seconds: f64,
    /// Reading films back from the device.
    pub readback_seconds: f64,
    /// Bytes read back from the device (films and pass counters).
    pub readback_bytes: u64,
    /// Times the host waited for the device (submissions waited on, buffer mappings).
    pub round_trips: u64,
    /// Folding blocks into the exact sums, checking error targets, making the values and
    /// their error estimates.
    pub host_stats_seconds: f64,
    /// Saving checkpoints.
    pub checkpoint_seconds: f64,
    /// Writing the outputs (not the statistics file, written last).
    pub write_seconds: f64,
    /// Freeing the session once traced: the device's buffers and the device, the scene.
    pub teardown_seconds: f64,
    /// The whole process from its start to the statistics.
    pub process_seconds: f64,
    /// The whole process less the main thread's phases (every phase above, less
    /// `overlap_seconds`): what no phase accounts for.
    pub other_seconds: f64,
    /// Times an error target was checked.
    pub checks: u32,
}

impl Phases {
    /// The phases a render's statistics hold.
    pub fn of_render(st: &RenderStats) -> Phases {
        Phases {
            start_seconds: st.start_seconds,
            load_seconds: st.load_seconds,
            bvh_build_seconds: st.bvh_build_seconds,
            scene_seconds: st.scene_seconds,
            adapter_seconds: st.adapter_seconds,
            overlap_seconds: st.overlap_seconds,
            upload_seconds: st.upload_seconds,
            pipeline_seconds: st.pipeline_seconds,
            compile_seconds: st.compile_seconds,
            pipeline_cache: st.pipeline_cache.clone(),
            request_seconds: st.request_seconds,
            pass_seconds: st.pass_seconds,
            readback_seconds: st.readback_seconds,
            readback_bytes: st.readback_bytes,
            round_trips: st.round_trips,
            host_stats_seconds: st.host_stats_seconds,
            checkpoint_seconds: st.checkpoint_seconds,
            write_seconds: st.write_seconds,
            teardown_seconds: st.teardown_seconds,
            process_seconds: st.process_seconds.unwrap_or(0.0),
            other_seconds: st.other_seconds,
            checks: st.checks,
        }
    }

    /// Sets the whole process's seconds, now, and what no phase accounts for.
    pub fn close(&mut self) {
        self.process_seconds = process_seconds();
        self.other_seconds = (self.process_seconds - self.accounted_seconds()).max(0.0);
    }

    /// Adds a request's passes, read-back, statistics and checkpoints.
    pub fn add_times(&mut self, times: &PassTimes) {
        self.upload_seconds += times.upload_seconds;
        self.pass_seconds += times.wall_seconds;
        self.readback_seconds += times.readback_seconds;
        self.readback_bytes += times.readback_bytes;
        self.round_trips += times.round_trips;
        self.host_stats_seconds += times.host_stats_seconds;
        self.checkpoint_seconds += times.checkpoint_seconds;
        self.checks += times.checks;
    }

    /// Adds a request's phases from its statistics (a bake's blocks, each a request).
    pub fn add_render(&mut self, st: &RenderStats) {
        self.upload_seconds += st.upload_seconds;
        self.pipeline_seconds += st.pipeline_seconds;
        self.compile_seconds += st.compile_seconds;
        self.request_seconds += st.request_seconds;
        self.teardown_seconds += st.teardown_seconds;
        // The session's, once for all its requests.
        self.scene_seconds = st.scene_seconds;
        self.pipeline_cache.clone_from(&st.pipeline_cache);
        self.pass_seconds += st.pass_seconds;
        self.readback_seconds += st.readback_seconds;
        self.readback_bytes += st.readback_bytes;
        self.round_trips += st.round_trips;
        self.host_stats_seconds += st.host_stats_seconds;
        self.checkpoint_seconds += st.checkpoint_seconds;
        self.checks += st.checks;
    }

    /// Sets the device's opening from the session's setup: its own seconds, the
    /// statistics kernels compiled on its thread (pipeline seconds), and what of them
    /// ran beside the main thread (all but what it waited for).
    pub fn set_opening(&mut self, setup: &aorender::Setup) {
        self.adapter_seconds = setup.adapter_seconds;
        self.pipeline_seconds += setup.adapter_compile_seconds;
        self.compile_seconds += setup.adapter_compile_seconds;
        let beside = setup.adapter_seconds + setup.adapter_compile_seconds - setup.adapter_wait_seconds;
        self.overlap_seconds = beside.max(0.0);
    }

    /// The phases on the main thread's timeline, which account for the process: every
    /// phase, less what ran beside it.
    pub fn accounted_seconds(&self) -> f64 {
        self.phase_seconds() - self.overlap_seconds
    }

    /// Every phase's seconds added, those that overlapped included.
    pub fn phase_seconds(&self) -> f64 {
        self.start_seconds
            + self.load_seconds
            + self.bvh_build_seconds
            + self.scene_seconds
            + self.adapter_seconds
            + self.upload_seconds
            + self.pipeline_seconds
            + self.pass_seconds
            + self.readback_seconds
            + self.host_stats_seconds
            + self.checkpoint_seconds
            + self.write_seconds
            + self.request_seconds
            + self.teardown_seconds
    }

    /// The phases in words, for the summary line: `load 0.41 s, BVH 0.20 s, …, beside
    /// loading 0.15 s, whole 1.50 s`.
    pub fn line(&self) -> String {
        let cache = match self.pipeline_cache.as_str() {
            "" => String::new(),
            state => format!(", cache {state}"),
        };
        let mut parts = vec![
            format!("start {:.2} s", self.start_seconds),
            format!("load {:.2} s", self.load_seconds),
            format!("BVH {:.2} s", self.bvh_build_seconds),
            format!("scene {:.2} s", self.scene_seconds),
            format!("adapter {:.2} s", self.adapter_seconds),
            format!("upload {:.2} s", self.upload_seconds),
            format!("pipeline {:.2} s (compiling {:.2} s{cache})", self.pipeline_seconds, self.compile_seconds),
            format!("request {:.2} s", self.request_seconds),
            format!("passes {:.2} s", self.pass_seconds),
            format!(
                "read-back {:.2} s ({}, {} round trips)",
                self.readback_seconds,
                bytes(self.readback_bytes),
                self.round_trips
            ),
            format!("statistics {:.2} s", self.host_stats_seconds),
        ];
        if self.checkpoint_seconds > 0.0 {
            parts.push(format!("checkpoints {:.2} s", self.checkpoint_seconds));
        }
        parts.push(format!("writing {:.2} s", self.write_seconds));
        parts.push(format!("teardown {:.2} s", self.teardown_seconds));
        parts.push(format!("other {:.2} s", self.other_seconds));
        // What ran on the device's thread while the main thread loaded and built the BVH.
        parts.push(format!("beside loading {:.2} s", self.overlap_seconds));
        parts.push(format!("whole {:.2} s", self.process_seconds));
        parts.join(", ")
    }
}

/// `n` bytes in the largest binary unit that keeps a number of at least 1.
fn bytes(n: u64) -> String {
    const UNITS: [&str; 4] = ["KiB", "MiB", "GiB", "TiB"];
    if n < 1024 {
        return format!("{n} B");
    }
    let mut value = n as f64 / 1024.0;
    let mut unit = 0;
    while value >= 1024.0 && unit + 1 < UNITS.len() {
        value /= 1024.0;
        unit += 1;
    }
    format!("{value:.1} {}", UNITS[unit])
}

/// `bytes` per item, for `items` of them (`None` for none or no peak).
pub fn per(bytes: u64, items: u64) -> Option<f64> {
    (items > 0 && bytes > 0).then(|| bytes as f64 / items as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn byte_counts_read_in_binary_units() {
        assert_eq!(bytes(0), "0 B");
        assert_eq!(bytes(1023), "1023 B");
        assert_eq!(bytes(1024), "1.0 KiB");
        assert_eq!(bytes(3 << 20), "3.0 MiB");
        assert_eq!(bytes(5 << 30), "5.0 GiB");
    }

    #[test]
    fn accounted_seconds_add_every_phase_but_the_whole() {
        let p = Phases {
            start_seconds: 1024.0,
            load_seconds: 1.0,
            bvh_build_seconds: 2.0,
            scene_seconds: 2048.0,
            adapter_seconds: 4.0,
            overlap_seconds: 3.0,
            upload_seconds: 8.0,
            pipeline_seconds: 16.0,
            compile_seconds: 10.0,
            pipeline_cache: "hit".into(),
            request_seconds: 4096.0,
            pass_seconds: 32.0,
            readback_seconds: 64.0,
            readback_bytes: 7,
            round_trips: 5,
            host_stats_seconds: 128.0,
            checkpoint_seconds: 256.0,
            write_seconds: 512.0,
            teardown_seconds: 8192.0,
            process_seconds: 50000.0,
            other_seconds: 0.0,
            checks: 3,
        };
        // Compiling is part of the pipeline's seconds, not a phase of its own; what ran
        // beside the main thread is not on its timeline.
        assert_eq!(p.phase_seconds(), 16383.0);
        assert_eq!(p.accounted_seconds(), 16380.0);
    }
}
