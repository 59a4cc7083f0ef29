//! Progress and log lines that never take a process down.
//!
//! # Layout
//! - [`logln!`]: `eprintln!` without its panic, each line in one `write` (whole among the
//!   lines of the other processes sharing stderr). `eprintln!` panics when stderr cannot be
//!   written (`2>/dev/full`, a log file on a full disk, a closed pipe), and a run must not die
//!   because its progress could not be shown. A failed write is counted ([`failed_writes`], for
//!   `/metrics`) and the process carries on; the line is lost, as it would be anyway.
//! - [`print_stdout_line`]: a result line on stdout (JSON, an address); a reader that has gone
//!   away (`coadapt bench nn | head -1`) ends the process quietly instead of a panic.
//! - [`duration`]: `1h02m`, `3m07s`, `12s` for progress lines.

use std::io::Write;
use std::sync::atomic::{AtomicU64, Ordering};

static FAILED: AtomicU64 = AtomicU64::new(0);

/// Writes one line to stderr in one `write`; a failure is counted, never raised.
///
/// Stderr is unbuffered: `write_fmt` straight to it makes one `write` per formatted piece, and
/// a fleet's processes share one stderr, so their lines were cut into each other mid-line
/// (`grpc://127.fleet 0http://...`: the address a user or test reads off the line, garbled).
/// A line formatted first and written whole is not (a pipe keeps writes up to 4 KiB whole).
pub fn write_line(args: std::fmt::Arguments<'_>) {
    let mut line = std::fmt::format(args);
    line.push('\n');
    if std::io::stderr().lock().write_all(line.as_bytes()).is_err() {
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

/// `1h02m`, `3m07s`, `12s`.
pub fn duration(secs: f64) -> String {
    let s = secs.max(0.0).round() as u64;
    match (s / 3600, (s % 3600) / 60, s % 60) {
        (0, 0, s) => format!("{s}s"),
        (0, m, s) => format!("{m}m{s:02}s"),
        (h, m, _) => format!("{h}h{m:02}m"),
    }
}

/// Prints one line to stdout; when the reader has gone away (`coadapt bench nn | head -1`),
/// exits quietly instead of panicking as `println!` does.
pub fn print_stdout_line(line: &str) {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    if let Err(e) = writeln!(out, "{line}").and_then(|_| out.flush()) {
        if e.kind() == std::io::ErrorKind::BrokenPipe {
            std::process::exit(0);
        }
        crate::logln!("error: writing to stdout: {e}");
        std::process::exit(1);
    }
}
