//! What coadapt's tests share, written once (a dev-dependency only; never in a library).
//!
//! # Layout
//! - [`scratch`], [`scratch_dir`]: a per-process temporary directory, emptied first.
//! - [`workspace_file`], [`read_config`]: files of the workspace (configs, reference scripts)
//!   from any crate's tests; [`confirming_tiny_config`]: the tiny run that waits for prototypes.
//! - [`browser`]: Chromium and ChromeDriver for the browser test, installed on first use.
//! - [`bridge_venv`]: the Python bridge's virtualenv (dm-env-rpc, gymnasium, MuJoCo,
//!   TensorBoard's reader), made once per target directory.
//! - [`reference`]: the statistics our PyTorch reference scripts print of a tensor, and the
//!   comparison against them.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test support: a panic is the failure report

use std::path::{Path, PathBuf};

/// `$TMPDIR/coadapt-<prefix>-<pid>-<name>`, removed if it exists (not created). The first call
/// of a test process also removes the scratch directories of test processes that have ended
/// ([`sweep_ended`]).
pub fn scratch(prefix: &str, name: &str) -> PathBuf {
    static SWEPT: std::sync::Once = std::sync::Once::new();
    SWEPT.call_once(|| {
        sweep_ended(&std::env::temp_dir(), std::time::Duration::from_secs(3600));
    });
    let d = std::env::temp_dir().join(format!("coadapt-{prefix}-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// Removes the directories `coadapt-...` directly under `tmp` whose name holds a process id (a
/// number between dashes) of no running process and that nobody has touched for `idle`; returns
/// how many. Tests keep their scratch directories for a look after a failure, and without this
/// they piled up: 2,210 of them, 12 GB, filled the disk under a campaign (2026-11-26).
pub fn sweep_ended(tmp: &Path, idle: std::time::Duration) -> usize {
    let Ok(entries) = std::fs::read_dir(tmp) else { return 0 };
    let mut removed = 0;
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some(rest) = name.strip_prefix("coadapt-") else { continue };
        let pids: Vec<&str> = rest.split('-').filter(|t| t.len() >= 2 && t.bytes().all(|b| b.is_ascii_digit())).collect();
        if pids.is_empty() || pids.iter().any(|p| Path::new("/proc").join(p).exists()) {
            continue;
        }
        let old = e
            .metadata()
            .ok()
            .filter(|m| m.is_dir())
            .and_then(|m| m.modified().ok())
            .and_then(|t| t.elapsed().ok())
            .is_some_and(|age| age >= idle);
        if old && std::fs::remove_dir_all(e.path()).is_ok() {
            removed += 1;
        }
    }
    removed
}

/// [`scratch`], created empty.
pub fn scratch_dir(prefix: &str, name: &str) -> PathBuf {
    let d = scratch(prefix, name);
    std::fs::create_dir_all(&d).unwrap_or_else(|e| panic!("creating {}: {e}", d.display()));
    d
}

/// `rel` under the workspace root (`configs/half-cheetah-tiny.toml`).
/// The Python bridge's virtualenv under `target_tmpdir` (a test passes
/// `env!("CARGO_TARGET_TMPDIR")`), created on first use by `bridges/python/setup_venv.sh` and
/// reused after (the script checks a stamp, under a lock: test binaries may call it at once).
pub fn bridge_venv(target_tmpdir: &str) -> &'static Path {
    static VENV: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    VENV.get_or_init(|| {
        let dir = PathBuf::from(target_tmpdir).join("py-bridge-venv");
        let t = std::time::Instant::now();
        let status = std::process::Command::new("bash")
            .arg(workspace_file("bridges/python/setup_venv.sh"))
            .arg(&dir)
            .status()
            .unwrap_or_else(|e| panic!("running bridges/python/setup_venv.sh: {e}"));
        assert!(status.success(), "bridges/python/setup_venv.sh failed");
        if t.elapsed() > std::time::Duration::from_secs(2) {
            eprintln!("python bridge venv ready in {:?}", t.elapsed());
        }
        dir
    })
}

/// Chromium and ChromeDriver for a browser test, installed on first use by
/// `scripts/setup_browser.sh` (Debian's packages); `None`, said loudly on stderr, where they
/// are missing and cannot be installed (not root, no apt-get): the caller skips.
pub fn browser() -> Option<(PathBuf, PathBuf)> {
    static BROWSER: std::sync::OnceLock<Option<(PathBuf, PathBuf)>> = std::sync::OnceLock::new();
    BROWSER
        .get_or_init(|| {
            let status = std::process::Command::new("bash")
                .arg(workspace_file("scripts/setup_browser.sh"))
                .status()
                .unwrap_or_else(|e| panic!("running scripts/setup_browser.sh: {e}"));
            match status.code() {
                Some(0) => Some((PathBuf::from("chromium"), PathBuf::from("chromedriver"))),
                Some(3) => {
                    eprintln!(
                        "\n*** SKIPPED: the browser test needs Debian's chromium and chromium-driver, which cannot be installed here \
                         (scripts/setup_browser.sh: not root, or no apt-get) ***\n"
                    );
                    None
                }
                _ => panic!("scripts/setup_browser.sh failed: {status}"),
            }
        })
        .clone()
}

pub fn workspace_file(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..").join(rel)
}

/// The text of `configs/half-cheetah-tiny.toml` shrunk (2 episodes per initial design, 1 per
/// chosen one, no landscape) with every design's prototype to confirm (polled every 50 ms):
/// the run the prototype-step tests answer, from the command line and from the operator page.
pub fn confirming_tiny_config() -> String {
    let mut t = std::fs::read_to_string(workspace_file("configs/half-cheetah-tiny.toml")).unwrap();
    for (from, to) in [
        ("landscape-grid = 12\n", "landscape-grid = 0\n"),
        ("initial-episodes = 3\n", "initial-episodes = 2\n"),
        ("episodes-per-design = 2\n", "episodes-per-design = 1\n"),
        ("[schedule]\n", "[schedule]\nconfirm-designs = true\nconfirm-poll-secs = 0.05\n"),
    ] {
        assert!(t.contains(from), "configs/half-cheetah-tiny.toml has no {from:?}");
        t = t.replace(from, to);
    }
    t
}

/// The TOML file `rel` of the workspace as `T` (a run's config, a search's).
pub fn read_config<T: serde::de::DeserializeOwned>(rel: &str) -> T {
    let path = workspace_file(rel);
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("reading {}: {e}", path.display()));
    toml::from_str(&text).unwrap_or_else(|e| panic!("parsing {}: {e}", path.display()))
}

/// Comparing our tensors with PyTorch's (float64) through the statistics the reference scripts
/// print, so a test pastes three numbers per tensor instead of the tensor.
pub mod reference {
    /// `n` values `f(0), f(1), ...` as f32: the deterministic inputs of a reference script.
    pub fn fill(n: usize, f: impl Fn(usize) -> f64) -> Vec<f32> {
        (0..n).map(|i| f(i) as f32).collect()
    }

    /// Sum, sum of `v_i (i + 1)` and sum of squares: as the reference scripts print them (the
    /// weighted sum catches a permutation the plain sum would not).
    pub fn stats(v: &[f32]) -> [f64; 3] {
        let mut s = [0.0; 3];
        for (i, &x) in v.iter().enumerate() {
            let x = f64::from(x);
            s[0] += x;
            s[1] += x * (i + 1) as f64;
            s[2] += x * x;
        }
        s
    }

    /// Our statistics `got` within `rel` of PyTorch's `want` (relative to the statistic's scale,
    /// at least 1): f32 arithmetic against float64.
    pub fn close(name: &str, got: [f64; 3], want: [f64; 3], rel: f64) {
        for (k, (g, w)) in got.iter().zip(want).enumerate() {
            assert!((g - w).abs() <= rel * w.abs().max(1.0), "{name} statistic {k}: {g} vs PyTorch {w}");
        }
    }

    #[cfg(test)]
    mod tests {
        use super::*;

        #[test]
        fn the_statistics_see_order_and_the_comparison_can_fail() {
            assert_eq!(stats(&[1.0, 2.0]), [3.0, 5.0, 5.0]);
            assert_ne!(stats(&[2.0, 1.0]), stats(&[1.0, 2.0]), "a permutation changes the weighted sum");
            close("same", [3.0, 5.0, 5.0], [3.0, 5.0, 5.0], 1e-6);
            assert!(std::panic::catch_unwind(|| close("off", [3.1, 5.0, 5.0], [3.0, 5.0, 5.0], 1e-4)).is_err());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_ended_processes_idle_directories_are_swept() {
        let tmp = scratch_dir("sweep", "tmp");
        let me = std::process::id();
        // A pid no process has (above the kernel's pid_max).
        let dead = 4_194_400u64;
        for name in [format!("coadapt-cli-{dead}-run"), format!("coadapt-cli-{me}-run"), "coadapt-cli-run".into(), format!("other-{dead}")]
        {
            std::fs::create_dir_all(tmp.join(name)).unwrap();
        }
        // Touched just now: nothing is idle an hour.
        assert_eq!(sweep_ended(&tmp, std::time::Duration::from_secs(3600)), 0);
        assert_eq!(sweep_ended(&tmp, std::time::Duration::ZERO), 1);
        assert!(!tmp.join(format!("coadapt-cli-{dead}-run")).exists());
        for kept in [format!("coadapt-cli-{me}-run"), "coadapt-cli-run".into(), format!("other-{dead}")] {
            assert!(tmp.join(&kept).exists(), "{kept} was removed");
        }
    }
}
