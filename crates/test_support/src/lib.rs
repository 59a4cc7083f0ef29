//! What coadapt's tests share, written once (a dev-dependency only; never in a library).
//!
//! # Layout
//! - [`scratch`], [`scratch_dir`]: a per-process temporary directory, emptied first.
//! - [`workspace_file`], [`read_config`]: files of the workspace (configs, reference scripts)
//!   from any crate's tests.
//! - [`reference`]: the statistics our PyTorch reference scripts print of a tensor, and the
//!   comparison against them.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test support: a panic is the failure report

use std::path::{Path, PathBuf};

/// `$TMPDIR/coadapt-<prefix>-<pid>-<name>`, removed if it exists (not created).
pub fn scratch(prefix: &str, name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("coadapt-{prefix}-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// [`scratch`], created empty.
pub fn scratch_dir(prefix: &str, name: &str) -> PathBuf {
    let d = scratch(prefix, name);
    std::fs::create_dir_all(&d).unwrap_or_else(|e| panic!("creating {}: {e}", d.display()));
    d
}

/// `rel` under the workspace root (`configs/half-cheetah-tiny.toml`).
pub fn workspace_file(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..").join(rel)
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
