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
