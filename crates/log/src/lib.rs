//! Progress and log lines that never take a process down.
//!
//! # Layout
//! - [`logln!`]: `eprintln!` without its panic. `eprintln!` panics when stderr cannot be written
//!   (`2>/dev/full`, a log file on a full disk, a closed pipe), and a run must not die because
//!   its progress could not be shown. A failed write is counted ([`failed_writes`], for
//!   `/metrics`) and the process carries on; the line is lost, as it would be anyway.

use std::io::Write;
use std::sync::atomic::{AtomicU64, Ordering};

static FAILED: AtomicU64 = AtomicU64::new(0);

/// Writes one line to stderr; a failure is counted, never raised.
pub fn write_line(args: std::fmt::Arguments<'_>) {
    let mut e = std::io::stderr().lock();
    if e.write_fmt(args).and_then(|()| e.write_all(b"\n")).is_err() {
        FAILED.fetch_add(1, Ordering::Relaxed);
    }
}

/// Lines that could not be written to stderr since the process started.
pub fn failed_writes() -> u64 {
    FAILED.load(Ordering::Relaxed)
}

/// `eprintln!` that counts a failed write instead of panicking ([`write_line`]).
#[macro_export]
macro_rules! logln {
    () => {
        $crate::write_line(format_args!(""))
    };
    ($($arg:tt)*) => {
        $crate::write_line(format_args!($($arg)*))
    };
}
