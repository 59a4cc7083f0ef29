//! Resuming a run: the run directory's config against the one given, and the learner's
//! snapshot and the optimiser's state file found in it.

use std::path::{Path, PathBuf};

use crate::AppError;
use crate::error::{Context, bail};

use crate::config::RunConfig;

/// Keys a resumed run may change: how long the schedule runs, how many actors and how the
/// processes talk, the snapshot settings, deadlines and restart budgets. Everything else decides
/// what the run learns and must be as it was.
const MAY_CHANGE: &[&str] = &[
    "schedule.designs",
    "schedule.design-request-resend-secs",
    "schedule.design-request-timeout-secs",
    "schedule.episode-timeout-secs",
    "actors",
    "fleet",
    "snapshot",
    "remote",
    "sim-threads",
    "metrics",
    "design-service",
    "security",
];

fn may_change(path: &str) -> bool {
    MAY_CHANGE.iter().any(|k| path == *k || path.starts_with(&format!("{k}.")))
}

/// The first key where `a` and `b` differ (dotted, kebab-case), skipping keys that may change.
fn first_difference(prefix: &str, a: &toml::Value, b: &toml::Value) -> Option<String> {
    if may_change(prefix) {
        return None;
    }
    match (a, b) {
        (toml::Value::Table(ta), toml::Value::Table(tb)) => {
            let keys: std::collections::BTreeSet<&String> = ta.keys().chain(tb.keys()).collect();
            keys.into_iter().find_map(|k| {
                let path = if prefix.is_empty() { k.clone() } else { format!("{prefix}.{k}") };
                match (ta.get(k), tb.get(k)) {
                    (Some(x), Some(y)) => first_difference(&path, x, y),
                    _ if may_change(&path) => None,
                    _ => Some(path),
                }
            })
        }
        _ => (a != b).then(|| prefix.to_string()),
    }
}

/// Refuses `new` when it differs from the run's `stored` config in a key that decides what the
/// run learns, naming the key and both values.
pub fn check_compatible(stored: &RunConfig, new: &RunConfig) -> crate::Result<()> {
    let a = toml::Value::try_from(stored).map_err(AppError::library)?;
    let b = toml::Value::try_from(new).map_err(AppError::library)?;
    if let Some(key) = first_difference("", &a, &b) {
        let get = |v: &toml::Value| key.split('.').try_fold(v, |v, k| v.get(k)).map_or("(absent)".to_string(), |v| v.to_string());
        bail!(
            "the config differs from the run's in `{key}` ({} in the run, {} now); a resumed run may change only {}",
            get(&a),
            get(&b),
            MAY_CHANGE.join(", ")
        );
    }
    Ok(())
}

/// The config saved in run directory `dir`.
pub fn stored_config(dir: &Path) -> crate::Result<RunConfig> {
    let path = dir.join("config.toml");
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {} (is {} a run directory?)", path.display(), dir.display()))?;
    toml::from_str(&text).map_err(AppError::library).with_context(|| format!("parsing {}", path.display()))
}

/// Where a run keeps its learner snapshots.
pub fn snapshot_root(dir: &Path) -> PathBuf {
    dir.join("snapshots")
}

/// Where `coadapt run` keeps the optimiser's state.
pub fn optimizer_state_dir(dir: &Path) -> PathBuf {
    dir.join("optimizer")
}
