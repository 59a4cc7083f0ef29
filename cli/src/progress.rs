//! Progress lines and the process-wide shutdown flag.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// A flag that Ctrl-C (SIGINT) sets; long work polls it and stops cleanly.
pub fn shutdown_on_ctrl_c() -> Arc<AtomicBool> {
    let flag = Arc::new(AtomicBool::new(false));
    let f = flag.clone();
    // A second handler cannot be installed (e.g. in tests driving `run` twice): then Ctrl-C
    // keeps its default meaning, which is acceptable there.
    let _ = ctrlc::set_handler(move || {
        if f.swap(true, Ordering::SeqCst) {
            std::process::exit(130);
        }
        coadapt_log::logln!("\ninterrupted: stopping and keeping what is written (Ctrl-C again to abort)");
    });
    coadapt_fleet::supervise::stop_when_orphaned(&flag);
    flag
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
        coadapt_log::logln!("error: writing to stdout: {e}");
        std::process::exit(1);
    }
}
