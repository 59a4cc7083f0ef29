//! The learner's health for probes: it is making progress (episodes come back, designs are
//! chosen) or it is waiting for an operator on purpose; otherwise, after
//! `fleet.health-stall-secs` without either, its gRPC health goes NOT_SERVING so that
//! Kubernetes or systemd's watchdog can restart it (it resumes from its newest snapshot).

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use coadapt_learner::coadapt::RunEvent;

/// Milliseconds since the Unix epoch of the learner's last progress.
static LAST_PROGRESS_MS: AtomicU64 = AtomicU64::new(0);
/// The learner waits for an operator (a prototype or a reset): not a stall.
static WAITING: AtomicBool = AtomicBool::new(false);

fn now_ms() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_millis() as u64)
}

/// Marks progress now (the learner's start counts as progress).
pub fn progress() {
    LAST_PROGRESS_MS.store(now_ms(), Relaxed);
}

/// Notes what an event of the learner says about its progress.
pub fn observe(e: &RunEvent<'_>) {
    match e {
        RunEvent::AwaitingPrototype { .. } | RunEvent::AwaitingReset { .. } => WAITING.store(true, Relaxed),
        RunEvent::PrototypeDecided { .. } | RunEvent::ResetConfirmed { .. } => {
            WAITING.store(false, Relaxed);
            progress();
        }
        _ => progress(),
    }
}

/// The stall limit [`watch`] applies, in ms (0: not watched), for `/healthz`.
static WATCHED_STALL_MS: AtomicU64 = AtomicU64::new(0);

/// What `/healthz` answers: `Some(true)` serving, `Some(false)` stalled, `None` not watched.
pub fn watched_health() -> Option<bool> {
    let ms = WATCHED_STALL_MS.load(Relaxed);
    (ms > 0).then(|| healthy(Duration::from_millis(ms)))
}

/// Whether the learner is healthy: progress within `stall`, or waiting for an operator.
pub fn healthy(stall: Duration) -> bool {
    WAITING.load(Relaxed) || now_ms().saturating_sub(LAST_PROGRESS_MS.load(Relaxed)) <= stall.as_millis() as u64
}

/// Every second until `stop` is set, sets the server's health from [`healthy`] (on a change,
/// with one line to stderr).
pub fn watch(
    switch: coadapt_grpc::HealthSwitch,
    stall: Duration,
    stop: std::sync::Arc<AtomicBool>,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    progress();
    WATCHED_STALL_MS.store((stall.as_millis() as u64).max(1), Relaxed);
    std::thread::Builder::new().name("health".into()).spawn(move || {
        let mut serving = true;
        while !stop.load(Relaxed) {
            let now = healthy(stall);
            if now != serving {
                if now {
                    coadapt_log::logln!("learner: making progress again: health SERVING");
                } else {
                    coadapt_log::logln!(
                        "learner: no progress for {stall:?} (fleet.health-stall-secs): health NOT_SERVING, for probes to restart it"
                    );
                }
                switch.set_serving(now);
                serving = now;
            }
            std::thread::sleep(Duration::from_millis(250));
        }
    })
}
