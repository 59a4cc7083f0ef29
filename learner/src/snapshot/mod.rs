//! Snapshots of a whole run, written so that a crash at any instant leaves the previous ones
//! intact, and read so that a damaged one is detected before anything is restored from it.
//!
//! A snapshot is a directory `RUN_DIR/snapshots/snap-NNNNNNNN` (NNNNNNNN grows with every
//! snapshot of the run) holding `arrays.bin` (named `f32` arrays: networks, Adam moments, replay
//! buffers), `state.json` (their index with a CRC-32 each, and every other value by name:
//! counters, generators, the schedule's position, the rows written so far) and `MANIFEST.json`
//! (sizes and checksums of the two, the run id), written last. The directory is built under a
//! temporary name, every file fsynced, then renamed into place and the parent fsynced: a
//! snapshot directory either is complete or does not exist under its final name. The newest
//! `keep` are kept.
//!
//! # Layout
//! - this file: [`SnapshotConfig`], [`write`], [`load_latest`], the manifest;
//! - `state`: [`StateOut`] and [`StateIn`], the contents;
//! - [`bits`]: `f32` values in JSON by their bits (a decimal round trip could move one by an ulp).

pub mod bits;
mod state;

use std::collections::BTreeMap;
use std::fs::{self, File};
use std::io;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::ConfigError;

pub use state::{ArrayEntry, StateIn, StateIndex, StateOut};

/// When snapshots are taken and how many are kept.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct SnapshotConfig {
    /// Take a snapshot after every this many episodes (at the first moment after them when no
    /// episode is out with an actor), besides the one at the end of every design and on
    /// shutdown; 0: only at the end of designs and on shutdown.
    pub every_episodes: usize,
    /// Snapshots kept (the newest); at least 2, so that a damaged newest one has a
    /// predecessor to fall back to.
    pub keep: usize,
    /// The largest share of the run's time the periodic snapshots may take (0 < share <= 1): a
    /// periodic snapshot waits, beyond `every-episodes`, until the time since the last one is at
    /// least the last one's write time over this share. A snapshot holds the whole replay, so
    /// its cost grows with the run (the reference protocol's reach 1-2 GB, seconds each to
    /// write, against about 4 s per episode); the wait bounds it, at the price of more episodes
    /// to redo after a crash. The end of a design and a shutdown always snapshot (a shutdown
    /// with a training episode out snapshots where it was handed out, and one with an
    /// evaluation out waits up to 20 s for it first; a design search by simulation is
    /// given up and asked again on resume).
    /// 1: no bound (`every-episodes` alone decides).
    pub max_share: f64,
}

impl Default for SnapshotConfig {
    fn default() -> Self {
        Self { every_episodes: 10, keep: 3, max_share: 0.05 }
    }
}

impl SnapshotConfig {
    pub fn validate(&self) -> Result<(), ConfigError> {
        if self.keep < 2 {
            return Err(ConfigError::TooFewSnapshots(self.keep));
        }
        if !(self.max_share > 0.0 && self.max_share <= 1.0) {
            return Err(ConfigError::SnapshotShare(self.max_share));
        }
        Ok(())
    }

    /// Whether a periodic snapshot is due after `episodes` episodes since the last snapshot,
    /// taken `since` ago (`None`: none yet in this start) and `write_seconds` long.
    pub fn periodic_due(&self, episodes: usize, since: Option<std::time::Duration>, write_seconds: f64) -> bool {
        if self.every_episodes == 0 || episodes < self.every_episodes {
            return false;
        }
        match since {
            Some(t) if self.max_share < 1.0 => t.as_secs_f64() * self.max_share >= write_seconds,
            _ => true,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum SnapshotError {
    // Not a `source()`: the message is all of it (see `CoadaptError`).
    #[error("{0}")]
    Io(io::Error),
    /// The files are damaged: truncated, bit flips, missing.
    #[error("damaged: {0}")]
    Corrupt(String),
    /// The files are sound but do not fit this run (another robot, network sizes, version).
    #[error("does not fit this run: {0}")]
    Mismatch(String),
    #[error("no usable snapshot in {dir}{}", if .why.is_empty() { String::new() } else { format!(" ({})", .why.join("; ")) })]
    None { dir: PathBuf, why: Vec<String> },
}

/// A snapshot that cannot be written to a full disk cannot be written after a restart either.
impl coadapt_fleet::supervise::exit::ExitCode for SnapshotError {
    fn exit_code(&self) -> Option<u8> {
        match self {
            Self::Io(e) => e.exit_code(),
            _ => None,
        }
    }
}

impl From<io::Error> for SnapshotError {
    fn from(e: io::Error) -> Self {
        Self::Io(e)
    }
}

/// The snapshot format this build writes and reads.
pub const FORMAT: u32 = 1;

#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct FileEntry {
    pub bytes: u64,
    /// CRC-32 of the whole file (`arrays.bin` is checked array by array instead: `None`).
    pub crc32: Option<u32>,
}

/// `MANIFEST.json`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Manifest {
    pub format: u32,
    /// `little` (arrays are stored in the writer's byte order).
    pub endian: String,
    /// The learner start that wrote it.
    pub run_id: String,
    pub sequence: u64,
    /// What the snapshot marks, e.g. `design 3 end` or `design 4 episode 10`.
    pub label: String,
    pub files: BTreeMap<String, FileEntry>,
}

const ENDIAN: &str = if cfg!(target_endian = "little") { "little" } else { "big" };

fn sync_dir(dir: &Path) -> io::Result<()> {
    File::open(dir)?.sync_all()
}

fn write_synced(path: &Path, bytes: &[u8]) -> io::Result<()> {
    use io::Write;
    let mut f = File::create(path)?;
    f.write_all(bytes)?;
    f.sync_all()
}

/// The snapshot directories under `root`, oldest first, with their sequence numbers.
pub fn list(root: &Path) -> io::Result<Vec<(u64, PathBuf)>> {
    let mut out = Vec::new();
    let entries = match fs::read_dir(root) {
        Ok(e) => e,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(out),
        Err(e) => return Err(e),
    };
    for e in entries {
        let e = e?;
        let name = e.file_name();
        let Some(seq) = name.to_str().and_then(|n| n.strip_prefix("snap-")).and_then(|n| n.parse::<u64>().ok()) else { continue };
        out.push((seq, e.path()));
    }
    out.sort();
    Ok(out)
}

/// `e` with what was being done to `path` in front (its kind kept: a full disk stays
/// `StorageFull`, so callers can tell it from a fault a retry could mend).
pub fn named(e: io::Error, doing: &str, path: &Path) -> io::Error {
    io::Error::new(e.kind(), format!("{doing} {}: {e}", path.display()))
}

/// Writes snapshot `sequence` under `root` with what `fill` puts in it, then removes all but
/// the newest `keep`. Returns its directory. A failure (a full disk, say) names the file and
/// removes the partial snapshot: what is left is the snapshots before it, untouched.
pub fn write(
    root: &Path,
    sequence: u64,
    run_id: &str,
    label: &str,
    keep: usize,
    fill: impl FnOnce(&mut StateOut) -> io::Result<()>,
) -> io::Result<PathBuf> {
    let tmp = root.join(format!(".tmp-snap-{sequence:08}"));
    let built = build(root, &tmp, sequence, run_id, label, fill);
    if let Err(e) = built {
        let removed = match fs::remove_dir_all(&tmp) {
            Ok(()) => "the partial snapshot was removed".to_string(),
            Err(r) if r.kind() == io::ErrorKind::NotFound => "nothing of it was left".to_string(),
            Err(r) => format!("removing the partial snapshot {} failed too: {r}", tmp.display()),
        };
        return Err(io::Error::new(e.kind(), format!("snapshot {sequence} ({label}): {e}; {removed}, the snapshots before it are kept")));
    }
    let dir = root.join(format!("snap-{sequence:08}"));
    if dir.exists() {
        // A snapshot of this number from before a resume that went back past it.
        fs::remove_dir_all(&dir).map_err(|e| named(e, "removing the stale", &dir))?;
    }
    fs::rename(&tmp, &dir).map_err(|e| named(e, "renaming into place", &tmp))?;
    sync_dir(root).map_err(|e| named(e, "syncing", root))?;
    let all = list(root).map_err(|e| named(e, "listing", root))?;
    for (_, old) in all.iter().take(all.len().saturating_sub(keep)) {
        fs::remove_dir_all(old).map_err(|e| named(e, "removing the old snapshot", old))?;
    }
    Ok(dir)
}

/// The snapshot's files under `tmp`, each fsynced.
fn build(
    root: &Path,
    tmp: &Path,
    sequence: u64,
    run_id: &str,
    label: &str,
    fill: impl FnOnce(&mut StateOut) -> io::Result<()>,
) -> io::Result<()> {
    fs::create_dir_all(root).map_err(|e| named(e, "creating", root))?;
    if tmp.exists() {
        fs::remove_dir_all(tmp).map_err(|e| named(e, "removing the partial snapshot", tmp))?;
    }
    fs::create_dir(tmp).map_err(|e| named(e, "creating", tmp))?;
    let bin = tmp.join("arrays.bin");
    let mut out = StateOut::create(&bin).map_err(|e| named(e, "creating", &bin))?;
    fill(&mut out).map_err(|e| named(e, "writing", &bin))?;
    let index = out.finish().map_err(|e| named(e, "writing", &bin))?;
    let state = serde_json::to_vec(&index).map_err(io::Error::other)?;
    let state_path = tmp.join("state.json");
    write_synced(&state_path, &state).map_err(|e| named(e, "writing", &state_path))?;
    let bin_bytes = fs::metadata(&bin).map_err(|e| named(e, "reading the size of", &bin))?.len();
    let manifest = Manifest {
        format: FORMAT,
        endian: ENDIAN.into(),
        run_id: run_id.into(),
        sequence,
        label: label.into(),
        files: BTreeMap::from([
            ("arrays.bin".into(), FileEntry { bytes: bin_bytes, crc32: None }),
            ("state.json".into(), FileEntry { bytes: state.len() as u64, crc32: Some(crc32fast::hash(&state)) }),
        ]),
    };
    let manifest_path = tmp.join("MANIFEST.json");
    write_synced(&manifest_path, &serde_json::to_vec_pretty(&manifest).map_err(io::Error::other)?)
        .map_err(|e| named(e, "writing", &manifest_path))?;
    sync_dir(tmp).map_err(|e| named(e, "syncing", tmp))
}

/// Reads and checks the snapshot in `dir`.
pub fn load(dir: &Path) -> Result<(Manifest, StateIn), SnapshotError> {
    let corrupt = SnapshotError::Corrupt;
    let manifest = fs::read(dir.join("MANIFEST.json")).map_err(|e| corrupt(format!("MANIFEST.json: {e}")))?;
    let manifest: Manifest = serde_json::from_slice(&manifest).map_err(|e| corrupt(format!("MANIFEST.json: {e}")))?;
    if manifest.format != FORMAT {
        return Err(SnapshotError::Mismatch(format!("format {} (this build reads {FORMAT})", manifest.format)));
    }
    if manifest.endian != ENDIAN {
        return Err(SnapshotError::Mismatch(format!("written on a {}-endian machine", manifest.endian)));
    }
    let entry = |name: &str| manifest.files.get(name).ok_or_else(|| corrupt(format!("MANIFEST.json lists no {name}")));
    let (state_entry, bin_entry) = (entry("state.json")?, entry("arrays.bin")?);
    let state = fs::read(dir.join("state.json")).map_err(|e| corrupt(format!("state.json: {e}")))?;
    if state.len() as u64 != state_entry.bytes {
        return Err(corrupt(format!("state.json has {} bytes, the manifest says {}", state.len(), state_entry.bytes)));
    }
    if let Some(crc) = state_entry.crc32 {
        let got = crc32fast::hash(&state);
        if got != crc {
            return Err(corrupt(format!("state.json: checksum {got:08x}, expected {crc:08x}")));
        }
    }
    let index: StateIndex = serde_json::from_slice(&state).map_err(|e| corrupt(format!("state.json: {e}")))?;
    let bin = dir.join("arrays.bin");
    let got = fs::metadata(&bin).map_err(|e| corrupt(format!("arrays.bin: {e}")))?.len();
    if got != bin_entry.bytes {
        return Err(corrupt(format!("arrays.bin has {got} bytes, the manifest says {}", bin_entry.bytes)));
    }
    let contents = StateIn::read(&bin, index, got)?;
    Ok((manifest, contents))
}

/// The newest snapshot under `root` that reads and checks, and what was wrong with each newer
/// one (`snap-00000012: damaged: arrays.bin: ...`).
pub fn load_latest(root: &Path) -> Result<(PathBuf, Manifest, StateIn, Vec<String>), SnapshotError> {
    let mut why = Vec::new();
    for (_, dir) in list(root)?.into_iter().rev() {
        match load(&dir) {
            Ok((m, s)) => return Ok((dir, m, s, why)),
            Err(e) => why.push(format!("{}: {e}", dir.file_name().map_or_else(String::new, |n| n.to_string_lossy().into_owned()))),
        }
    }
    Err(SnapshotError::None { dir: root.to_path_buf(), why })
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;

    #[test]
    fn a_periodic_snapshot_waits_until_its_write_time_is_within_the_share() {
        let c = SnapshotConfig { every_episodes: 10, keep: 3, max_share: 0.05 };
        // Too few episodes: never, however long ago.
        assert!(!c.periodic_due(9, Some(Duration::from_secs(1_000)), 0.0));
        // The first of this start: as soon as the episodes are there.
        assert!(c.periodic_due(10, None, 0.0));
        // A 2 s write allows the next one 40 s after it, not before.
        assert!(!c.periodic_due(10, Some(Duration::from_secs(39)), 2.0));
        assert!(c.periodic_due(25, Some(Duration::from_secs(40)), 2.0));
        // Share 1: the episode count alone.
        let every = SnapshotConfig { max_share: 1.0, ..c.clone() };
        assert!(every.periodic_due(10, Some(Duration::from_millis(1)), 2.0));
        // every-episodes 0: only at designs' ends and on shutdown.
        let off = SnapshotConfig { every_episodes: 0, ..c };
        assert!(!off.periodic_due(1_000, Some(Duration::from_secs(1_000)), 0.0));
    }

    #[test]
    fn a_share_outside_zero_to_one_is_refused_by_name() {
        for bad in [0.0, -0.1, 1.5, f64::NAN] {
            let e = SnapshotConfig { max_share: bad, ..SnapshotConfig::default() }.validate().unwrap_err();
            assert!(e.to_string().starts_with("snapshot.max-share:"), "{e}");
        }
        assert!(SnapshotConfig { max_share: 1.0, ..SnapshotConfig::default() }.validate().is_ok());
    }
}
