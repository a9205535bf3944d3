//! Turning wgpu's panics and device errors into [`Error`]s: a panic inside wgpu (its own,
//! or one of the callbacks it runs) is caught and reported as the failure it was, and the
//! errors the device reports through its callbacks are kept until the next check.

use crate::error::{Error, Result};
use std::cell::Cell;
use std::panic::AssertUnwindSafe;
use std::sync::{Mutex, MutexGuard};

thread_local! {
    /// Depth of [`catch_panic`] calls running on this thread.
    static CATCHING: Cell<u32> = const { Cell::new(0) };
}

/// True while the library runs wgpu code on this thread whose panics it turns into
/// errors: a program's panic hook can stay quiet about a panic that becomes an error.
pub fn catching_panics() -> bool {
    CATCHING.with(Cell::get) > 0
}

/// Runs `f`, turning a panic inside it (wgpu's own, or one of the callbacks it invokes,
/// such as buffer mapping and device-lost callbacks) into an error saying `what` failed.
pub fn catch_panic<T>(what: &str, f: impl FnOnce() -> T) -> Result<T> {
    CATCHING.with(|c| c.set(c.get() + 1));
    let result = std::panic::catch_unwind(AssertUnwindSafe(f));
    CATCHING.with(|c| c.set(c.get() - 1));
    result.map_err(|payload| {
        let text = payload
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "no message".into());
        Error::Gpu(format!("wgpu panicked {what}: {}", text.lines().next().unwrap_or("")))
    })
}

/// A device error recorded by the callbacks.
#[derive(Debug)]
pub(crate) enum Fault {
    /// The device was lost.
    Lost(String),
    /// An allocation or submission ran out of memory.
    OutOfMemory(String),
    /// Any other error (validation, internal).
    Other(String),
}

/// The faults the device's callbacks record, shared with them.
#[derive(Debug, Default)]
pub(crate) struct Faults(Mutex<Vec<Fault>>);

impl Faults {
    /// The list, whatever a panicking holder left in it.
    fn lock(&self) -> MutexGuard<'_, Vec<Fault>> {
        self.0.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Records a fault.
    pub(crate) fn push(&self, fault: Fault) {
        self.lock().push(fault);
    }

    /// The most serious fault since the last call, as the error of `adapter`: a lost
    /// device, then running out of memory, then the first other error. A lost device
    /// stays lost: every later call, on any thread that shares the device, reports it.
    pub(crate) fn take(&self, adapter: &str) -> Result<()> {
        let faults = {
            let mut held = self.lock();
            let faults = std::mem::take(&mut *held);
            held.extend(faults.iter().filter_map(|f| match f {
                Fault::Lost(m) => Some(Fault::Lost(m.clone())),
                _ => None,
            }));
            faults
        };
        let adapter = adapter.to_string();
        let lost = faults.iter().find_map(|f| if let Fault::Lost(m) = f { Some(m) } else { None });
        let oom = faults.iter().find_map(|f| if let Fault::OutOfMemory(m) = f { Some(m) } else { None });
        if let Some(message) = lost {
            return Err(Error::DeviceLost { adapter, message: message.clone() });
        }
        if let Some(message) = oom {
            return Err(Error::OutOfMemory { adapter, message: message.clone() });
        }
        match faults.first() {
            Some(Fault::Other(e)) => Err(Error::Gpu(format!("GPU error: {e}"))),
            _ => Ok(()),
        }
    }
}
