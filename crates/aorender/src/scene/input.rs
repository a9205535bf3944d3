//! Reading input files within limits: the read budget ([`ReadLimits`]) every reader of the
//! crate applies, the memory a read has taken against it ([`Meter`]), and the byte stream
//! of a file, plain or gzip-compressed (`.gz`, decompressed as it is read), that refuses to
//! deliver more than the budget allows ([`Input`]).
//!
//! A read may hold at most [`ReadLimits::memory`] bytes of what it loads (by default half
//! of the memory the system has available); a file may deliver at most four times that
//! after decompression, a text line at most [`ReadLimits::line_bytes`], and a text file's
//! blank lines and comments at most a sixteenth of the budget plus as many bytes as its
//! data lines. Sizes a header declares are checked against the budget before anything is
//! read, and never size an allocation beyond what the rest of the file could fill.

use crate::error::{Error, Result};
use flate2::read::MultiGzDecoder;
use std::fs::File;
use std::io::{self, BufRead, BufReader, Read};
use std::path::Path;

/// Largest ratio of decompressed to compressed size DEFLATE can reach: a 258-byte match
/// costs at least 2 bits, 258 × 8 / 2 = 1032 (zlib's technical notes give 1032:1).
const MAX_DEFLATE_RATIO: u64 = 1032;

/// Read buffer size.
const BUFFER_BYTES: usize = 1 << 16;

/// The environment variable that sets the read budget: a size in bytes, optionally with
/// `K`, `M`, `G` or `T` (powers of 1024), such as `512M` or `1.5G`.
pub const READ_BUDGET_VARIABLE: &str = "AORENDER_READ_BUDGET";

/// The read budget where the system's available memory cannot be read (no `/proc/meminfo`).
pub const FIXED_READ_BUDGET: u64 = 4 << 30;

/// Longest line of a text file (OBJ, ASCII PLY, probe points), by default: this, or
/// a 64th of the budget where that is more (a polygon of millions of
/// vertices is one line of an OBJ file).
pub const DEFAULT_LINE_BYTES: usize = 1 << 20;

/// A line may take this fraction (1 / N) of the budget by default, when that is more than
/// [`DEFAULT_LINE_BYTES`].
pub const LINE_BUDGET_FRACTION: u64 = 64;

/// A file may deliver this many bytes (after decompression) per byte of the budget: more
/// is data the loader discards (skipped elements, ignored properties), read for nothing.
const INPUT_BYTES_PER_BUDGET_BYTE: u64 = 4;

/// Blank lines and comments may take this fraction of the budget before they must stay
/// below the bytes of the lines that hold data.
const IDLE_FRACTION: u64 = 16;

/// Where a budget came from, for messages.
#[derive(Clone, Debug, PartialEq)]
enum Origin {
    /// Half of the bytes `MemAvailable` gave.
    Available(u64),
    /// [`FIXED_READ_BUDGET`]: the available memory is unknown.
    Fixed,
    /// [`READ_BUDGET_VARIABLE`], as it was written.
    Environment(String),
    /// [`ReadLimits::with_memory`].
    Caller,
}

/// How much a read of input files may take: memory for what it loads, bytes of input,
/// the longest line of a text file. Every reader of the crate (scene files, meshes, glTF
/// buffers, bake assets, checkpoints, probe points) applies them, and refuses a file that
/// needs more in one line naming the file and the limit.
#[derive(Clone, Debug, PartialEq)]
pub struct ReadLimits {
    memory: u64,
    /// The longest line, when set; else the default of [`DEFAULT_LINE_BYTES`].
    line_bytes: Option<usize>,
    origin: Origin,
    /// Bytes of the budget taken by earlier reads ([`ReadLimits::after`]).
    spent: u64,
}

impl ReadLimits {
    /// The budget [`READ_BUDGET_VARIABLE`] sets, else [`ReadLimits::available`]. A value
    /// that is not a positive size is an error naming the variable.
    pub fn from_env() -> Result<ReadLimits> {
        match std::env::var(READ_BUDGET_VARIABLE) {
            Ok(text) => {
                let memory = parse_size(&text).ok_or_else(|| {
                    Error::settings(format!(
                        "{READ_BUDGET_VARIABLE}={text:?} is not a positive size in bytes (such as 512M or 8G)"
                    ))
                })?;
                Ok(ReadLimits { memory, origin: Origin::Environment(text.trim().to_string()), ..Self::base() })
            }
            Err(std::env::VarError::NotPresent) => Ok(ReadLimits::available()),
            Err(std::env::VarError::NotUnicode(_)) => {
                Err(Error::settings(format!("{READ_BUDGET_VARIABLE} is not a positive size in bytes")))
            }
        }
    }

    /// Half of the memory available to the process
    /// ([`crate::host_memory::memory_available`]: `MemAvailable`, or the cgroup's limit), or
    /// [`FIXED_READ_BUDGET`] where that cannot be read: the other half is left to what the
    /// load leads to (the BVH build, the renderer).
    pub fn available() -> ReadLimits {
        match crate::host_memory::memory_available() {
            Some(bytes) => ReadLimits { memory: (bytes / 2).max(1), origin: Origin::Available(bytes), ..Self::base() },
            None => ReadLimits { memory: FIXED_READ_BUDGET, origin: Origin::Fixed, ..Self::base() },
        }
    }

    /// A budget of `memory` bytes (at least 1), with the default line length.
    pub fn with_memory(memory: u64) -> ReadLimits {
        ReadLimits { memory: memory.max(1), origin: Origin::Caller, ..Self::base() }
    }

    /// These limits with lines of text at most `bytes` long (at least 1).
    pub fn with_line_bytes(self, bytes: usize) -> ReadLimits {
        ReadLimits { line_bytes: Some(bytes.max(1)), ..self }
    }

    /// These limits less `bytes` already taken by other reads: what is left for the next
    /// one (the checkpoints of a merge, read one after the other and held together).
    pub fn after(&self, bytes: u64) -> ReadLimits {
        ReadLimits { spent: self.spent.saturating_add(bytes), ..self.clone() }
    }

    fn base() -> ReadLimits {
        ReadLimits { memory: FIXED_READ_BUDGET, line_bytes: None, origin: Origin::Caller, spent: 0 }
    }

    /// Bytes of memory a read may take.
    pub fn memory(&self) -> u64 {
        self.memory.saturating_sub(self.spent)
    }

    /// The longest line of a text file, in bytes.
    pub fn line_bytes(&self) -> usize {
        let share = usize::try_from(self.memory / LINE_BUDGET_FRACTION).unwrap_or(usize::MAX);
        self.line_bytes.unwrap_or(DEFAULT_LINE_BYTES.max(share))
    }

    /// The most bytes a file may deliver (after decompression): four times the budget.
    pub fn input_bytes(&self) -> u64 {
        self.memory.saturating_mul(INPUT_BYTES_PER_BUDGET_BYTE)
    }

    /// Bytes of blank lines and comments a text file may have beyond those of its data lines.
    pub(crate) fn idle_bytes(&self) -> u64 {
        self.memory / IDLE_FRACTION
    }

    /// "the read budget (half of the 19.2 GiB available); AORENDER_READ_BUDGET=SIZE sets it".
    fn budget_name(&self) -> String {
        let left = if self.spent > 0 { "what is left of " } else { "" };
        let (origin, hint) = match &self.origin {
            Origin::Available(bytes) => (format!("half of the {} available", size_text(*bytes)), true),
            Origin::Fixed => ("the fixed default where the available memory is unknown".to_string(), true),
            Origin::Environment(text) => (format!("{READ_BUDGET_VARIABLE}={text}"), false),
            Origin::Caller => ("as set by the caller".to_string(), false),
        };
        let hint = if hint { format!("; {READ_BUDGET_VARIABLE}=SIZE sets it") } else { String::new() };
        format!("{left}the read budget ({origin}){hint}")
    }

    /// `path: {what} needs more than {budget}, the read budget (…)`.
    pub(crate) fn exceeded(&self, path: &Path, what: &str) -> Error {
        Error::scene(path, self.exceeded_message(what))
    }

    /// The message of [`ReadLimits::exceeded`], without the file.
    pub(crate) fn exceeded_message(&self, what: &str) -> String {
        format!("{what} needs more than {}, {}", size_text(self.memory()), self.budget_name())
    }

    /// Why a file's data stopped being read: it delivered [`ReadLimits::input_bytes`].
    fn input_message(&self, gzip: bool) -> String {
        let decompressed = if gzip { " decompressed" } else { "" };
        format!(
            "the file holds more than {}{decompressed}, {INPUT_BYTES_PER_BUDGET_BYTE} times {}",
            size_text(self.input_bytes()),
            self.budget_name()
        )
    }

    /// Why a text file stopped being read at line `line`: too many blank or comment bytes.
    pub(crate) fn idle_message(&self, line: u64) -> String {
        format!(
            "more than {} of blank lines and comments by line {line}, more than its lines with data and 1/{IDLE_FRACTION} of {}",
            size_text(self.idle_bytes()),
            self.budget_name()
        )
    }
}

/// How a scene or mesh file is read: within which limits, and whether a glTF file's
/// URIs may name files outside its folder.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadOptions {
    /// The read budget.
    pub limits: ReadLimits,
    /// Follow glTF buffer and image URIs that lead outside the glTF file's folder
    /// (absolute paths, `..`, symbolic links). Off by default: a file found on the web
    /// could otherwise read any file the user can.
    pub allow_external_uris: bool,
}

impl LoadOptions {
    /// The limits of [`ReadLimits::from_env`], external URIs refused.
    pub fn from_env() -> Result<LoadOptions> {
        Ok(LoadOptions { limits: ReadLimits::from_env()?, allow_external_uris: false })
    }
}

/// A size in bytes: digits (a fraction allowed) and an optional `K`, `M`, `G` or `T`
/// (powers of 1024, with or without `B` or `iB` after it); `None` unless positive.
fn parse_size(text: &str) -> Option<u64> {
    let text = text.trim();
    let end = text.find(|c: char| !(c.is_ascii_digit() || c == '.')).unwrap_or(text.len());
    let (number, unit) = text.split_at(end);
    let unit = unit.trim().to_ascii_uppercase();
    let unit = unit.strip_suffix("IB").or_else(|| unit.strip_suffix('B')).unwrap_or(&unit);
    let scale: f64 = match unit {
        "" => 1.0,
        "K" => 1024.0,
        "M" => 1024f64.powi(2),
        "G" => 1024f64.powi(3),
        "T" => 1024f64.powi(4),
        _ => return None,
    };
    let value = number.parse::<f64>().ok()? * scale;
    (value >= 1.0 && value < u64::MAX as f64).then_some(value as u64)
}

/// `bytes` for messages: `512 bytes`, `64 KiB`, `9.6 GiB`.
pub(crate) fn size_text(bytes: u64) -> String {
    const UNITS: [&str; 5] = ["KiB", "MiB", "GiB", "TiB", "PiB"];
    if bytes < 1024 {
        return format!("{bytes} bytes");
    }
    let mut value = bytes as f64 / 1024.0;
    let mut unit = 0;
    while value >= 1024.0 && unit + 1 < UNITS.len() {
        value /= 1024.0;
        unit += 1;
    }
    let text = format!("{value:.1}");
    format!("{} {}", text.strip_suffix(".0").unwrap_or(&text), UNITS[unit])
}

/// The memory a read has taken, against its budget. Readers charge what they hold (or are
/// about to allocate) before they hold it; a charge past the budget is the error.
#[derive(Debug)]
pub(crate) struct Meter {
    limits: ReadLimits,
    used: u64,
    /// What the message calls the data: "the mesh", "the scene", "the checkpoint's sums".
    what: &'static str,
}

impl Meter {
    /// A meter of `limits`, for data that messages call `what`.
    pub(crate) fn new(limits: &ReadLimits, what: &'static str) -> Meter {
        Meter { limits: limits.clone(), used: 0, what }
    }

    /// A meter without a limit (for data the caller already holds, such as arrays).
    pub(crate) fn unlimited() -> Meter {
        Meter::new(&ReadLimits::with_memory(u64::MAX), "the data")
    }

    /// The limits it counts against.
    pub(crate) fn limits(&self) -> &ReadLimits {
        &self.limits
    }

    /// Bytes charged so far.
    pub(crate) fn used(&self) -> u64 {
        self.used
    }

    /// Bytes left before the budget is exceeded.
    pub(crate) fn left(&self) -> u64 {
        self.limits.memory().saturating_sub(self.used)
    }

    /// Takes `bytes` more, or fails naming `path` and the budget.
    pub(crate) fn charge(&mut self, path: &Path, bytes: u64) -> Result<()> {
        self.used = self.used.saturating_add(bytes);
        if self.used > self.limits.memory() {
            return Err(self.exceeded(path));
        }
        Ok(())
    }

    /// Sets the bytes held to `bytes` (a reader's running total), or fails naming `path`
    /// and the budget when that is past it.
    pub(crate) fn hold(&mut self, path: &Path, bytes: u64) -> Result<()> {
        self.used = bytes;
        if self.used > self.limits.memory() {
            return Err(self.exceeded(path));
        }
        Ok(())
    }

    /// Gives back `bytes` taken before.
    pub(crate) fn release(&mut self, bytes: u64) {
        self.used = self.used.saturating_sub(bytes);
    }

    /// Sets the bytes held to `bytes`: what is left after a step freed its working memory.
    pub(crate) fn set_used(&mut self, bytes: u64) {
        self.used = bytes;
    }

    /// The error of a charge past the budget.
    pub(crate) fn exceeded(&self, path: &Path) -> Error {
        self.limits.exceeded(path, self.what)
    }

    /// The error of an allocation of `bytes` the system refused within the budget.
    pub(crate) fn refused(&self, path: &Path, bytes: u64) -> Error {
        Error::scene(
            path,
            format!(
                "out of memory: {} more for {} (holding {}) was refused, within {}",
                size_text(bytes),
                self.what,
                size_text(self.used),
                self.limits.budget_name()
            ),
        )
    }

    /// The message of [`Meter::exceeded`], without the file.
    pub(crate) fn exceeded_message(&self) -> String {
        self.limits.exceeded_message(self.what)
    }
}

/// Room for one more element in `v`, the growth charged to `meter` first. Growth doubles
/// the capacity (at least 4096 elements), within what is left of the budget.
#[inline]
pub(crate) fn make_room<T>(v: &mut Vec<T>, meter: &mut Meter, path: &Path) -> Result<()> {
    if v.len() < v.capacity() {
        return Ok(());
    }
    grow(v, meter, path)
}

#[cold]
fn grow<T>(v: &mut Vec<T>, meter: &mut Meter, path: &Path) -> Result<()> {
    let size = std::mem::size_of::<T>().max(1) as u64;
    let fits = usize::try_from(meter.left() / size).unwrap_or(usize::MAX);
    let add = v.capacity().max(4096).min(fits).max(1);
    meter.charge(path, add as u64 * size)?;
    v.try_reserve_exact(add).map_err(|_| meter.refused(path, add as u64 * size))
}

/// Bytes `v` holds (its capacity).
pub(crate) fn vec_bytes<T>(v: &Vec<T>) -> u64 {
    (v.capacity() * std::mem::size_of::<T>()) as u64
}

/// An empty vector with room for `n` values, its memory backed by huge pages where the
/// system allows ([`advise_huge_pages`]).
pub(crate) fn huge_vec<T>(n: usize) -> Vec<T> {
    let v = Vec::with_capacity(n);
    advise_huge_pages(&v);
    v
}

/// Asks the kernel to back the 2 MiB pages inside `v`'s capacity with huge pages (Linux's
/// transparent huge pages, where set to `madvise` or `always`): a mesh's columns of
/// hundreds of MB are then faulted in 2 MiB at a time instead of 4 KiB, which took about a
/// third of a binary PLY read's CPU time in page faults. Advice only: nothing else changes.
pub(crate) fn advise_huge_pages<T>(v: &Vec<T>) {
    #[cfg(target_os = "linux")]
    {
        const HUGE: usize = 2 << 20;
        let bytes = v.capacity().saturating_mul(std::mem::size_of::<T>());
        let start = v.as_ptr() as usize;
        let (first, end) = (start.next_multiple_of(HUGE), start.saturating_add(bytes) / HUGE * HUGE);
        if bytes >= 2 * HUGE && end > first {
            // SAFETY: `madvise` only marks the range (whole pages of memory `v` owns), it
            // neither reads nor changes its contents; a refusal (EINVAL where the kernel
            // has no huge pages) leaves the memory as it was.
            unsafe {
                libc::madvise(first as *mut libc::c_void, end - first, libc::MADV_HUGEPAGE);
            }
        }
    }
}

/// The UTF-8 byte-order mark some editors write at the start of a text file: skipped.
pub(crate) const UTF8_BOM: &[u8] = b"\xEF\xBB\xBF";

/// The message for text in UTF-16 (a text file that starts with a UTF-16 byte-order mark,
/// or a line with NUL bytes), which no reader here decodes.
pub(crate) const UTF16_MESSAGE: &str = "UTF-16 text is not supported: convert the file to UTF-8";

/// Whether `bytes`, the start of a text file, are UTF-16 (either byte order's mark).
pub(crate) fn starts_utf16(bytes: &[u8]) -> bool {
    bytes.starts_with(b"\xFF\xFE") || bytes.starts_with(b"\xFE\xFF")
}

/// True when `path` names a gzip-compressed file (`.gz`).
pub(crate) fn is_gzip(path: &Path) -> bool {
    path.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("gz"))
}

/// A file opened for reading, decompressed on the fly when it is gzipped. Counts the
/// bytes consumed, refuses to deliver more than the limits' input bytes, and keeps the
/// first error of the underlying stream (or of the limits) so that a parser's "unexpected
/// end" can be told apart from a corrupt or truncated gzip stream or an exceeded limit.
pub(crate) struct Input {
    inner: Box<dyn BufRead>,
    gzip: bool,
    consumed: u64,
    /// Upper bound on the bytes the whole stream can deliver: the file's length (0 for a
    /// pipe or a device, which can deliver anything up to `cap`), times the DEFLATE limit
    /// when gzipped.
    max_total: u64,
    /// True for a regular file, whose length bounds what it can deliver.
    regular: bool,
    /// The stream ends here for the reader (for headers of bounded length).
    limit: u64,
    /// The most bytes the stream may deliver: past it, reading is an error.
    cap: u64,
    limits: ReadLimits,
    /// Lines read by [`Input::read_line`], for messages.
    lines: u64,
    stream_error: Option<String>,
}

/// How many times each file was opened by an [`Input`]: tests check that a bake reads
/// each input once.
#[cfg(feature = "testing")]
static OPENED: std::sync::Mutex<Vec<(std::path::PathBuf, usize)>> = std::sync::Mutex::new(Vec::new());

#[cfg(feature = "testing")]
fn count_open(path: &Path) {
    let mut opened = OPENED.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    match opened.iter_mut().find(|(p, _)| p == path) {
        Some((_, n)) => *n += 1,
        None => opened.push((path.to_path_buf(), 1)),
    }
}

/// How many times the loaders have opened `path` in this process (every mesh reader
/// opens its file through one function, which counts).
#[cfg(feature = "testing")]
pub fn times_opened(path: &Path) -> usize {
    let opened = OPENED.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    opened.iter().find(|(p, _)| p == path).map_or(0, |(_, n)| *n)
}

impl Input {
    /// Opens `path` within `limits`; a `.gz` file is decompressed as it is read.
    pub(crate) fn open(path: &Path, limits: &ReadLimits) -> Result<Input> {
        Input::open_as(path, limits, is_gzip(path))
    }

    /// Opens `path` within `limits` as it is, never decompressed (a glTF buffer file).
    pub(crate) fn open_plain(path: &Path, limits: &ReadLimits) -> Result<Input> {
        Input::open_as(path, limits, false)
    }

    /// Opens `path` within `limits`, decompressing it when `gzip` is set.
    fn open_as(path: &Path, limits: &ReadLimits, gzip: bool) -> Result<Input> {
        let file = File::open(path).map_err(|e| Error::scene(path, e))?;
        #[cfg(feature = "testing")]
        count_open(path);
        let metadata = file.metadata().map_err(|e| Error::scene(path, e))?;
        let (len, regular) = (metadata.len(), metadata.is_file());
        let inner: Box<dyn BufRead> = if gzip {
            // A regular file is inflated on a thread beside the parser; a pipe or a device
            // in place, where a read that never returns would hold the thread for ever.
            let file = match regular {
                true => match crate::scene::inflate::Inflated::start(file) {
                    Ok(inflated) => return Ok(Input::new(Box::new(inflated), true, len, regular, limits)),
                    Err(file) => file,
                },
                false => file,
            };
            let decoder = MultiGzDecoder::new(BufReader::with_capacity(BUFFER_BYTES, file));
            Box::new(BufReader::with_capacity(BUFFER_BYTES, decoder))
        } else {
            Box::new(BufReader::with_capacity(BUFFER_BYTES, file))
        };
        Ok(Input::new(inner, gzip, len, regular, limits))
    }

    /// The stream `inner` of a file of `len` bytes (which bound what it delivers where it is
    /// `regular`, times the DEFLATE limit where it is gzipped).
    fn new(inner: Box<dyn BufRead>, gzip: bool, len: u64, regular: bool, limits: &ReadLimits) -> Input {
        let max_total = if gzip { len.saturating_mul(MAX_DEFLATE_RATIO) } else { len };
        Input {
            inner,
            gzip,
            consumed: 0,
            max_total,
            regular,
            limit: u64::MAX,
            cap: limits.input_bytes(),
            limits: limits.clone(),
            lines: 0,
            stream_error: None,
        }
    }

    /// Upper bound on the bytes still to come: exact for a plain regular file, the DEFLATE
    /// limit for a gzipped one, the input cap for a pipe or a device.
    pub(crate) fn remaining_bound(&self) -> u64 {
        let total = if self.regular { self.max_total.min(self.cap) } else { self.cap };
        total.saturating_sub(self.consumed)
    }

    /// Bytes the rest of the stream is known to be able to hold, to reserve memory by:
    /// [`Input::remaining_bound`] for a regular file, nothing for a pipe or a device, whose
    /// data must arrive before memory is taken for it.
    pub(crate) fn known_remaining(&self) -> u64 {
        if self.regular { self.remaining_bound() } else { 0 }
    }

    /// True for a plain (not gzipped) regular file no longer than the input cap: what is
    /// left of it is known before it is read, and all of it may be read.
    pub(crate) fn is_plain_file(&self) -> bool {
        !self.gzip && self.regular && self.max_total <= self.cap
    }

    /// True for a gzipped file (regular or not): how much it delivers is known only once
    /// it has been read.
    pub(crate) fn is_gzip(&self) -> bool {
        self.gzip
    }

    /// False when the rest of the stream cannot hold `bytes`: a regular file too short (a
    /// pipe or a device may deliver anything).
    pub(crate) fn could_hold(&self, bytes: u64) -> bool {
        !self.regular || bytes <= self.remaining_bound()
    }

    /// Bytes consumed so far.
    pub(crate) fn consumed(&self) -> u64 {
        self.consumed
    }

    /// The limits it reads within.
    pub(crate) fn limits(&self) -> &ReadLimits {
        &self.limits
    }

    /// Makes the stream end, for the reader, `bytes` bytes after the start; `None` lifts
    /// the limit.
    pub(crate) fn set_limit(&mut self, bytes: Option<u64>) {
        self.limit = bytes.unwrap_or(u64::MAX);
    }

    /// True when the limit of [`Input::set_limit`] has been reached.
    pub(crate) fn at_limit(&self) -> bool {
        self.consumed >= self.limit
    }

    /// The first error of the file, the gzip stream or the limits, in one line, if there
    /// was one.
    pub(crate) fn stream_error(&self) -> Option<&str> {
        self.stream_error.as_deref()
    }

    /// Records `message` as the stream's error (unless one came first) and returns it as
    /// an I/O error, for a reader that stops the parser it feeds.
    pub(crate) fn fail(&mut self, message: String) -> io::Error {
        let e = io::Error::other(message.clone());
        if self.stream_error.is_none() {
            self.stream_error = Some(message);
        }
        e
    }

    /// Reads everything that is left, the bytes charged to `meter` as they come (for a
    /// plain file, its length before any is read).
    pub(crate) fn read_all(mut self, path: &Path, meter: &mut Meter) -> Result<Vec<u8>> {
        let mut bytes = Vec::new();
        self.read_into(path, &mut bytes, meter, 1, u64::MAX)?;
        Ok(bytes)
    }

    /// Appends to `bytes` at most `most` more bytes, or what is left, charging
    /// `bytes_per_byte` times their growth to `meter` before it happens (for a plain
    /// file, its whole length first).
    pub(crate) fn read_into(
        &mut self,
        path: &Path,
        bytes: &mut Vec<u8>,
        meter: &mut Meter,
        bytes_per_byte: u64,
        most: u64,
    ) -> Result<()> {
        if !self.gzip && self.regular {
            let len = self.remaining_bound().min(most);
            let room = (bytes.capacity() - bytes.len()) as u64;
            if len > room {
                meter.charge(path, (len - room).saturating_mul(bytes_per_byte))?;
                let add = usize::try_from(len).unwrap_or(usize::MAX);
                bytes.try_reserve_exact(add).map_err(|_| meter.refused(path, add as u64))?;
                advise_huge_pages(bytes);
            }
        }
        let mut left = most;
        while left > 0 {
            let available = match self.fill_buf() {
                Ok(b) => b.len(),
                Err(e) => return Err(Error::scene(path, self.stream_error.clone().unwrap_or_else(|| e.to_string()))),
            };
            if available == 0 {
                break;
            }
            let n = available.min(usize::try_from(left).unwrap_or(usize::MAX));
            if bytes.capacity() - bytes.len() < n {
                // Doubling, within what is left of the budget.
                let fits = usize::try_from(meter.left() / bytes_per_byte.max(1)).unwrap_or(usize::MAX);
                let want = bytes.capacity().saturating_mul(2).max(BUFFER_BYTES).min(bytes.len().saturating_add(fits));
                let want = want.max(bytes.len() + n);
                meter.charge(path, ((want - bytes.capacity()) as u64).saturating_mul(bytes_per_byte))?;
                let add = want - bytes.len();
                bytes.try_reserve_exact(add).map_err(|_| meter.refused(path, add as u64))?;
            }
            bytes.extend_from_slice(self.inner_buffer(n));
            self.consume(n);
            left -= n as u64;
        }
        Ok(())
    }

    /// The first `n` bytes of the buffer [`BufRead::fill_buf`] just returned.
    fn inner_buffer(&mut self, n: usize) -> &[u8] {
        match self.inner.fill_buf() {
            Ok(b) => &b[..n.min(b.len())],
            Err(_) => &[],
        }
    }

    /// Reads one line, through its `\n` (none at the end of the file), appending it to
    /// `line`; 0 at the end. A line longer than the limits' line length is an error.
    pub(crate) fn read_line(&mut self, line: &mut Vec<u8>) -> io::Result<usize> {
        let start = line.len();
        loop {
            let (used, done) = {
                let available = self.fill_buf()?;
                match memchr::memchr(b'\n', available) {
                    Some(i) => (i + 1, true),
                    None => (available.len(), available.is_empty()),
                }
            };
            if line.len() - start + used > self.limits.line_bytes() {
                let message = format!(
                    "line {} is longer than {}, the longest line a text file may have",
                    self.lines + 1,
                    size_text(self.limits.line_bytes() as u64)
                );
                return Err(self.fail(message));
            }
            line.extend_from_slice(self.inner_buffer(used));
            self.consume(used);
            if done {
                if line.len() > start {
                    self.lines += 1;
                }
                return Ok(line.len() - start);
            }
        }
    }

    /// Skips a UTF-8 byte-order mark at the start of a text file; refuses one of UTF-16
    /// ([`UTF16_MESSAGE`]), which the stream then reports as its error.
    pub(crate) fn skip_text_mark(&mut self) -> io::Result<()> {
        if self.consumed > 0 {
            return Ok(());
        }
        let start = self.fill_buf()?;
        if start.starts_with(UTF8_BOM) {
            self.consume(UTF8_BOM.len());
        } else if starts_utf16(start) {
            return Err(self.fail(UTF16_MESSAGE.to_string()));
        }
        Ok(())
    }

    /// Lines read by [`Input::read_line`] so far.
    pub(crate) fn line_number(&self) -> u64 {
        self.lines
    }

    /// Counts `n` more lines (lines a reader skipped itself).
    pub(crate) fn count_lines(&mut self, n: u64) {
        self.lines += n;
    }

    fn record(&mut self, e: io::Error) -> io::Error {
        if self.stream_error.is_none() {
            self.stream_error = Some(if self.gzip {
                format!("invalid or truncated gzip data: {e}")
            } else {
                format!("cannot read the file: {e}")
            });
        }
        e
    }
}

impl Read for Input {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let end = self.limit.min(self.cap);
        let allowed = usize::try_from(end.saturating_sub(self.consumed)).unwrap_or(usize::MAX);
        if allowed == 0 {
            // The end for the reader, or the cap: an error when more data follows it.
            return self.fill_buf().map(|_| 0);
        }
        let want = buf.len().min(allowed);
        match self.inner.read(&mut buf[..want]) {
            Ok(n) => {
                self.consumed += n as u64;
                Ok(n)
            }
            Err(e) => Err(self.record(e)),
        }
    }
}

impl BufRead for Input {
    fn fill_buf(&mut self) -> io::Result<&[u8]> {
        let end = self.limit.min(self.cap);
        let allowed = usize::try_from(end.saturating_sub(self.consumed)).unwrap_or(usize::MAX);
        // Two steps so that an error can be recorded without holding the buffer's borrow.
        let len = match self.inner.fill_buf() {
            Ok(buf) => buf.len(),
            Err(e) => return Err(self.record(e)),
        };
        if allowed == 0 && len > 0 && self.consumed >= self.cap && self.limit > self.cap {
            let message = self.limits.input_message(self.gzip);
            return Err(self.fail(message));
        }
        let buf = self.inner.fill_buf()?;
        Ok(&buf[..buf.len().min(allowed)])
    }

    fn consume(&mut self, amount: usize) {
        self.inner.consume(amount);
        self.consumed += amount as u64;
    }
}

/// Reads the whole text file `path` (never decompressed) within `limits`, which must hold
/// `bytes_per_byte` bytes of memory per byte of it: the text and its parsed form. `what`
/// names the two in messages ("the scene", "the probe file"). A file that cannot be
/// opened is "cannot read: …".
pub fn read_text(path: &Path, limits: &ReadLimits, bytes_per_byte: u64, what: &'static str) -> Result<String> {
    let mut meter = Meter::new(limits, what);
    let mut input =
        Input::open_as(path, limits, false).map_err(|e| Error::scene(path, format!("cannot read: {}", e.message())))?;
    let mut bytes = Vec::new();
    input.read_into(path, &mut bytes, &mut meter, bytes_per_byte, u64::MAX)?;
    String::from_utf8(bytes).map_err(|_| Error::scene(path, "stream did not contain valid UTF-8"))
}

/// A message from a parsing crate in one line of at most about 200 characters: line
/// breaks and control characters become spaces, runs of white space one space.
pub(crate) fn one_line(message: &str) -> String {
    const MAX_CHARS: usize = 200;
    let cleaned: String = message.chars().map(|c| if c.is_control() { ' ' } else { c }).collect();
    let mut words = cleaned.split_whitespace();
    let mut out = String::new();
    for word in words.by_ref() {
        if out.chars().count() + word.chars().count() > MAX_CHARS {
            out.push_str(" …");
            break;
        }
        if !out.is_empty() {
            out.push(' ');
        }
        out.push_str(word);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_line_collapses_breaks_and_truncates() {
        assert_eq!(
            one_line("Couldn't parse.\n\tString: 'x'\r\n\tError: bad"),
            "Couldn't parse. String: 'x' Error: bad"
        );
        let long = "word ".repeat(100);
        let short = one_line(&long);
        assert!(short.ends_with('…') && short.chars().count() <= 202, "{short}");
    }

    #[test]
    fn sizes_parse_in_powers_of_1024_and_print_back() {
        for (text, bytes) in [
            ("4096", 4096),
            ("64M", 64 << 20),
            ("64MiB", 64 << 20),
            (" 1.5g ", 3 << 29),
            ("2 GB", 2 << 30),
            ("1T", 1 << 40),
        ] {
            assert_eq!(parse_size(text), Some(bytes), "{text}");
        }
        for text in ["", "0", "0.1", "-1", "12Q", "M", "1e9", "1.2.3"] {
            assert_eq!(parse_size(text), None, "{text}");
        }
        for (bytes, text) in [(1000, "1000 bytes"), (64 << 20, "64 MiB"), (3 << 29, "1.5 GiB"), (1536, "1.5 KiB")] {
            assert_eq!(size_text(bytes), text);
        }
    }

    #[test]
    fn messages_name_the_budget_and_where_it_came_from() {
        let available = ReadLimits { memory: 10 << 30, origin: Origin::Available(20 << 30), ..ReadLimits::base() };
        assert_eq!(
            available.exceeded_message("the mesh"),
            "the mesh needs more than 10 GiB, the read budget (half of the 20 GiB available); \
             AORENDER_READ_BUDGET=SIZE sets it"
        );
        let set = ReadLimits { memory: 64 << 20, origin: Origin::Environment("64M".into()), ..ReadLimits::base() };
        assert_eq!(
            set.after(16 << 20).exceeded_message("the checkpoint"),
            "the checkpoint needs more than 48 MiB, what is left of the read budget (AORENDER_READ_BUDGET=64M)"
        );
        assert_eq!(set.input_bytes(), 256 << 20);
        assert_eq!(set.idle_bytes(), 4 << 20);
    }

    #[test]
    fn a_meter_refuses_the_charge_past_its_budget_and_growth_stays_within_it() {
        let path = Path::new("m.obj");
        let mut meter = Meter::new(&ReadLimits::with_memory(1000), "the mesh");
        meter.charge(path, 600).unwrap();
        meter.release(100);
        meter.charge(path, 500).unwrap();
        let e = meter.charge(path, 1).unwrap_err().to_string();
        assert_eq!(e, "m.obj: the mesh needs more than 1000 bytes, the read budget (as set by the caller)");
        // Growth doubles within what is left, and fails when nothing is.
        let mut meter = Meter::new(&ReadLimits::with_memory(4 * 5000), "the mesh");
        let mut v: Vec<u32> = Vec::new();
        let mut pushed = 0;
        while make_room(&mut v, &mut meter, path).is_ok() {
            v.push(0);
            pushed += 1;
        }
        assert_eq!(pushed, 5000);
        assert_eq!(meter.used(), 4 * 5000 + 4);
        assert!(vec_bytes(&v) <= 4 * 5000);
    }

    #[test]
    fn a_stream_stops_at_the_input_cap_and_a_line_at_the_line_length() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("f.obj");
        std::fs::write(&path, [b"v 1 2 3\n".repeat(4).as_slice(), &[b'x'; 100]].concat()).unwrap();
        // A budget of 16 bytes lets the file deliver 64.
        let mut input = Input::open(&path, &ReadLimits::with_memory(16)).unwrap();
        let mut all = Vec::new();
        assert!(input.read_to_end(&mut all).is_err());
        assert_eq!(all.len(), 64);
        let message = input.stream_error().unwrap();
        assert!(message.starts_with("the file holds more than 64 bytes, 4 times the read budget"), "{message}");
        // Lines of at most 50 bytes: the fifth is longer.
        let limits = ReadLimits::with_memory(1 << 20).with_line_bytes(50);
        let mut input = Input::open(&path, &limits).unwrap();
        let mut line = Vec::new();
        for _ in 0..4 {
            line.clear();
            assert_eq!(input.read_line(&mut line).unwrap(), 8);
        }
        assert!(input.read_line(&mut line).is_err());
        assert_eq!(input.stream_error(), Some("line 5 is longer than 50 bytes, the longest line a text file may have"));
    }
}
