//! Heap accounting: the program's global allocator counts the bytes it holds on its own
//! heap, for the `heap_peak_bytes` statistic.
//!
//! The count differs from the resident peak (`host_peak_bytes`) where it matters for a
//! renderer: the resident peak also holds the driver (on lavapipe the "device" buffers live
//! in host memory, allocated by Mesa with C's allocator), while the heap count holds only
//! what aorender itself allocated (the loaded scene, the BVH build's workspace, the bytes
//! prepared for upload), so it answers "how many copies of the geometry did the host hold
//! at once" on any adapter.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

static CURRENT: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);
static INSTALLED: AtomicBool = AtomicBool::new(false);

/// The system allocator, counting the bytes live at once and their high-water mark.
///
/// Two relaxed atomic operations per allocation: the counts are exact once the threads
/// that allocated have been joined, which is when they are read.
pub struct CountingAlloc;

impl CountingAlloc {
    fn grew(size: usize) {
        let now = CURRENT.fetch_add(size, Ordering::Relaxed) + size;
        PEAK.fetch_max(now, Ordering::Relaxed);
    }

    fn shrank(size: usize) {
        CURRENT.fetch_sub(size, Ordering::Relaxed);
    }
}

// SAFETY: every call is forwarded to `System` unchanged; only counters are updated.
unsafe impl GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        INSTALLED.store(true, Ordering::Relaxed);
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            Self::grew(layout.size());
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        INSTALLED.store(true, Ordering::Relaxed);
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            Self::grew(layout.size());
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) };
        Self::shrank(layout.size());
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        // The change in size only: a large block moves by remapping its pages, not by
        // holding two copies, and a small one's brief copy is noise.
        if !p.is_null() {
            if new_size > layout.size() {
                Self::grew(new_size - layout.size());
            } else {
                Self::shrank(layout.size() - new_size);
            }
        }
        p
    }
}

/// The most bytes live on aorender's heap at once so far; `None` when `CountingAlloc` is not
/// the global allocator.
pub fn heap_peak_bytes() -> Option<u64> {
    INSTALLED.load(Ordering::Relaxed).then(|| PEAK.load(Ordering::Relaxed) as u64)
}

/// With this environment variable set to a path, the binary writes its heap peak there (in
/// bytes, one line) when it exits, whether it succeeded or not: the tests bound the memory
/// of refused reads with it, which write no statistics.
pub const TEST_HEAP_PEAK_FILE_ENV: &str = "AORENDER_TEST_HEAP_PEAK_FILE";

/// Writes [`heap_peak_bytes`] to the file [`TEST_HEAP_PEAK_FILE_ENV`] names, if it is set.
pub fn write_test_heap_peak() {
    if let (Some(path), Some(peak)) = (std::env::var_os(TEST_HEAP_PEAK_FILE_ENV), heap_peak_bytes()) {
        let _ = std::fs::write(path, format!("{peak}\n"));
    }
}

/// The memory the system says is available to a new allocation (`MemAvailable` of
/// `/proc/meminfo`), in bytes; `None` where it cannot be read.
pub fn available_bytes() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// The bytes a command may take: the memory the system says is available
/// ([`available_bytes`]), or less when the environment variable `AORENDER_MEMORY_LIMIT`
/// says so (a number of bytes; empty is unset); unlimited where neither is known.
pub fn budget_bytes() -> anyhow::Result<u64> {
    let available = available_bytes().unwrap_or(u64::MAX);
    match std::env::var("AORENDER_MEMORY_LIMIT") {
        Ok(text) if text.trim().is_empty() => Ok(available),
        Ok(text) => match text.trim().parse::<u64>() {
            Ok(limit) => Ok(limit.min(available)),
            Err(_) => anyhow::bail!("AORENDER_MEMORY_LIMIT={text}: expected a number of bytes"),
        },
        Err(std::env::VarError::NotPresent) => Ok(available),
        Err(e) => anyhow::bail!("AORENDER_MEMORY_LIMIT: {e}"),
    }
}
