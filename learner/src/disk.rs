//! Free space where the run directory lives, against what the next snapshot needs: a full disk
//! stops a run at its next snapshot (the partial one is removed, the older ones kept, the
//! supervisor does not restart), so the operator is warned before that, in the progress line,
//! once in the log, and in `/metrics` (`coadapt_learner_disk_free_bytes`, `_disk_needed_bytes`,
//! `_disk_low`).

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed};
use std::time::{Duration, Instant};

/// Room kept besides the snapshot: the CSV rows and a design's checkpoints until then.
const MARGIN: u64 = 16 << 20;

/// How often free space is measured at most (a `statvfs` call).
const EVERY: Duration = Duration::from_millis(200);

pub use coadapt_fleet::supervise::exit::is_disk_full;

/// Bytes free to an unprivileged writer on the filesystem holding `path`.
pub fn free_bytes(path: &Path) -> std::io::Result<u64> {
    let s = nix::sys::statvfs::statvfs(path).map_err(std::io::Error::from)?;
    Ok((s.blocks_available() as u64).saturating_mul(s.fragment_size() as u64))
}

/// Bytes of the files directly in `dir` (a snapshot directory).
fn dir_bytes(dir: &Path) -> u64 {
    std::fs::read_dir(dir).map_or(0, |r| r.filter_map(|e| e.ok()?.metadata().ok()).map(|m| m.len()).sum())
}

/// What the next snapshot needs: the last one grown by a quarter (the replay grows), and
/// [`MARGIN`].
pub fn needed(last_snapshot_bytes: u64) -> u64 {
    last_snapshot_bytes.saturating_add(last_snapshot_bytes / 4).saturating_add(MARGIN)
}

/// The run directory's free space, as last measured (see the module documentation).
#[derive(Debug)]
pub struct DiskWatch {
    dir: PathBuf,
    last_snapshot: AtomicU64,
    free: AtomicU64,
    low: AtomicBool,
    warned: AtomicBool,
    measured: Mutex<Option<Instant>>,
}

impl DiskWatch {
    /// Watches the filesystem of run directory `dir`; the newest snapshot already under
    /// `snapshots` (a resumed run) gives the first estimate of what the next one needs.
    pub fn new(dir: &Path, snapshots: &Path) -> Self {
        let newest = crate::snapshot::list(snapshots).ok().and_then(|l| l.last().map(|(_, d)| dir_bytes(d))).unwrap_or(0);
        let w = Self {
            dir: dir.to_path_buf(),
            last_snapshot: AtomicU64::new(newest),
            free: AtomicU64::new(u64::MAX),
            low: AtomicBool::new(false),
            warned: AtomicBool::new(false),
            measured: Mutex::new(None),
        };
        w.measure(true);
        w
    }

    /// The size of the newest snapshot, as the learner reports it (0: none this start).
    pub fn snapshot_taken(&self, bytes: u64) {
        if bytes > 0 {
            self.last_snapshot.store(bytes, Relaxed);
        }
    }

    /// Measures again unless it was done within [`EVERY`] (`force`: now).
    fn measure(&self, force: bool) {
        let mut at = self.measured.lock().unwrap_or_else(|e| e.into_inner());
        if !force && at.is_some_and(|t| t.elapsed() < EVERY) {
            return;
        }
        *at = Some(Instant::now());
        // Unmeasurable (the directory is gone): no warning rather than a false one.
        let free = free_bytes(&self.dir).unwrap_or(u64::MAX);
        self.free.store(free, Relaxed);
        self.low.store(free < self.needed(), Relaxed);
    }

    pub fn needed(&self) -> u64 {
        needed(self.last_snapshot.load(Relaxed))
    }

    /// (free bytes, bytes the next snapshot needs, low), measured at most 200 ms ago.
    pub fn reading(&self) -> (u64, u64, bool) {
        self.measure(false);
        (self.free.load(Relaxed), self.needed(), self.low.load(Relaxed))
    }

    /// The progress line's note when space is low (empty otherwise); the first time it is
    /// low, a warning line is logged as well.
    pub fn note(&self) -> String {
        let (free, need, low) = self.reading();
        if !low {
            return String::new();
        }
        if !self.warned.swap(true, Relaxed) {
            coadapt_log::logln!(
                "warning: disk low: {} free under {}, the next snapshot needs about {}; free space, or the run stops at its \
                 next snapshot (nothing written before it is lost, and `coadapt run --resume` continues from the newest one)",
                mib(free),
                self.dir.display(),
                mib(need)
            );
        }
        format!("  [DISK LOW: {} free, next snapshot ~{}]", mib(free), mib(need))
    }
}

fn mib(b: u64) -> String {
    format!("{:.1} MiB", b as f64 / (1u64 << 20) as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn free_space_is_measured_and_compared_with_the_next_snapshot() {
        let dir = std::env::temp_dir();
        let free = free_bytes(&dir).unwrap();
        assert!(free > 0 && free < u64::MAX);
        let w = DiskWatch::new(&dir, &dir.join("no-snapshots-here"));
        assert!(!w.reading().2 || free < MARGIN, "an empty run dir needs only the margin");
        // A snapshot larger than the disk's free space: low from the next reading.
        w.snapshot_taken(free);
        w.measure(true);
        let (_, need, low) = w.reading();
        assert!(low && need > free, "{need} vs {free}");
        assert!(w.note().contains("DISK LOW"));
    }
}
