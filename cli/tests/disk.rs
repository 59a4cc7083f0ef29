//! Issue 29 (4): a full disk, as it happens in the field. A run's directory lives on a small
//! tmpfs (mounted in a private mount namespace); once its first snapshot is written the test
//! fills the disk but for 256 KiB. The run must then warn (progress line and log), stop at the
//! next snapshot with an error that names the file and says the cause once, not be restarted by
//! its supervisor, leave no half-written snapshot or checkpoint directory, and keep the newest
//! sound snapshot: with the filler removed, `coadapt run --resume` finishes the run.
//!
//! Needs root or user namespaces (`unshare -m`, else `unshare -Urm`) to mount a tmpfs; where
//! neither works the script exits 77 and the test reports the skip on stderr.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::io::Write;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use coadapt_coadaptation::RunConfig;

const SCRIPT: &str = r#"
mnt=$1 host=$2 bin=$3 config=$4
mount -t tmpfs -o size=48m tmpfs "$mnt" || exit 77
: > "$host/mounted"
"$bin" run --config "$config" --out "$mnt/run" > "$host/run1.out" 2> "$host/run1.log"
echo $? > "$host/exit1"
ls -a "$mnt/run/snapshots" "$mnt/run/checkpoints" > "$host/listing" 2>&1
rm -f "$mnt/filler"
"$bin" run --resume "$mnt/run" > "$host/run2.out" 2> "$host/run2.log"
echo $? > "$host/exit2"
cp "$mnt/run/designs.csv" "$host/designs.csv"
"#;

fn tmpdir(name: &str) -> PathBuf {
    coadapt_test_support::scratch_dir("disk", name)
}

/// Starts the script in a private mount namespace (as root, else in a user namespace).
fn start(args: &[&str]) -> Option<std::process::Child> {
    for ns in [&["-m"][..], &["-Urm"][..]] {
        let ok = Command::new("unshare").args(ns).args(["true"]).status().is_ok_and(|s| s.success());
        if ok {
            let child = Command::new("unshare").args(ns).args(["sh", "-c", SCRIPT, "sh"]).args(args).stdin(Stdio::null()).spawn().unwrap();
            return Some(child);
        }
    }
    None
}

#[test]
fn a_full_disk_stops_the_run_cleanly_and_the_newest_snapshot_resumes() {
    let host = tmpdir("host");
    let mnt = host.join("mnt");
    std::fs::create_dir_all(&mnt).unwrap();
    let mut c: RunConfig = coadapt_test_support::read_config("configs/half-cheetah-tiny.toml");
    c.landscape_grid = 0;
    c.schedule.designs = 6;
    // Snapshots at the end of design 1 (episode 6) and at episode 10: the disk is filled after
    // the first, episodes 7-9 show the warning, the second fails.
    c.schedule.initial_episodes = 6;
    let config = host.join("c.toml");
    std::fs::write(&config, toml::to_string(&c).unwrap()).unwrap();
    let args = [mnt.to_str().unwrap(), host.to_str().unwrap(), env!("CARGO_BIN_EXE_coadapt"), config.to_str().unwrap()];
    let Some(mut child) = start(&args) else {
        eprintln!("SKIPPED: no mount namespace can be made here (unshare -m and -Urm both fail)");
        return;
    };
    // The namespace's view of the tmpfs, from outside it.
    let inside = PathBuf::from(format!("/proc/{}/root", child.id())).join(mnt.strip_prefix("/").unwrap());
    let t = Instant::now();
    let log = |name: &str| std::fs::read_to_string(host.join(name)).unwrap_or_default();
    loop {
        if let Ok(Some(s)) = child.try_wait() {
            if s.code() == Some(77) {
                eprintln!("SKIPPED: tmpfs cannot be mounted here");
                return;
            }
            panic!("the script ended before the first snapshot ({s}): {}", log("run1.log"));
        }
        let snaps = std::fs::read_dir(inside.join("run/snapshots")).map(|r| r.count()).unwrap_or(0);
        if host.join("mounted").exists() && snaps > 0 {
            break;
        }
        assert!(t.elapsed() < Duration::from_secs(300), "no snapshot: {}", log("run1.log"));
        std::thread::sleep(Duration::from_millis(20));
    }
    // Fill the disk, then give back 256 KiB: rows still fit, the next snapshot does not.
    let filler = inside.join("filler");
    let mut f = std::fs::File::create(&filler).unwrap();
    let chunk = vec![7u8; 1 << 20];
    let mut written = 0u64;
    loop {
        match f.write(&chunk) {
            Ok(0) => break,
            Ok(n) => written += n as u64,
            Err(e) => {
                assert_eq!(e.raw_os_error(), Some(28), "filling: {e}");
                break;
            }
        }
    }
    f.set_len(written.saturating_sub(256 << 10)).unwrap();
    drop(f);
    let t = Instant::now();
    let status = loop {
        if let Ok(Some(s)) = child.try_wait() {
            break s;
        }
        assert!(t.elapsed() < Duration::from_secs(600), "the script did not end: {}", log("run1.log"));
        std::thread::sleep(Duration::from_millis(100));
    };
    let (run1, run2, listing) = (log("run1.log"), log("run2.log"), log("listing"));
    assert!(status.success(), "{status}: {run1}\n{run2}");
    // Stopped with the full disk's exit code, not restarted, saying why.
    assert_eq!(log("exit1").trim(), "73", "{run1}");
    assert!(!run1.contains("starting the fleet again") && !run1.contains("starting it again"), "restarted:\n{run1}");
    assert!(run1.contains("is not started again") && run1.contains("the disk holding the run directory is full"), "{run1}");
    // The error names the file and what was being written, and the cause once.
    let errors: Vec<&str> = run1.lines().filter(|l| l.contains("No space left on device")).collect();
    assert!(!errors.is_empty(), "{run1}");
    for e in &errors {
        assert_eq!(e.matches("No space left on device").count(), 1, "the cause twice: {e}");
    }
    let named = errors.iter().any(|e| e.contains(mnt.join("run").to_str().unwrap()) && e.contains("writing"));
    assert!(named, "no error names the file:\n{}", errors.join("\n"));
    // Warned before it stopped.
    assert!(run1.contains("warning: disk low") && run1.contains("[DISK LOW"), "{run1}");
    // No partial snapshot or checkpoint left; the run resumes from the newest snapshot.
    assert!(listing.contains("snap-") && !listing.contains(".tmp-snap-") && !listing.contains(".tmp-design-"), "{listing}");
    assert_eq!(log("exit2").trim(), "0", "{run2}");
    let rows = log("designs.csv").lines().count();
    assert_eq!(rows, 1 + 6, "every design trained after the resume:\n{}", log("designs.csv"));
    let _ = std::fs::remove_dir_all(&host);
}
