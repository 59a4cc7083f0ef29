//! Actor processes a learner starts itself (`coadapt search`, `coadapt latent`): spawned with
//! the run's config and the fleet's coordinates, logged to `<run>/logs/actor-<i>.log`, waited
//! for at the end and killed if the learner fails first.

use std::path::Path;
use std::process::Child;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use anyhow::Context;

use crate::fleet::FleetConfig;

/// Actor processes started by a learner; killed if it drops them before they end.
pub(crate) struct Children(pub(crate) Arc<Mutex<Vec<Child>>>);

impl Children {
    pub(crate) fn new(children: Vec<Child>) -> Self {
        Self(Arc::new(Mutex::new(children)))
    }

    pub(crate) fn lock(&self) -> MutexGuard<'_, Vec<Child>> {
        self.0.lock().unwrap_or_else(|e| e.into_inner())
    }

    pub(crate) fn is_empty(&self) -> bool {
        self.lock().is_empty()
    }

    /// `Some(why)` once every process has ended (a robot unreachable, a bad config): the
    /// learner should stop waiting for them.
    pub(crate) fn all_ended_check(&self, what: &'static str, logs: &Path) -> Box<dyn Fn() -> Option<String> + Send + Sync> {
        let kids = self.0.clone();
        let logs = logs.display().to_string();
        Box::new(move || {
            let mut kids = kids.lock().unwrap_or_else(|e| e.into_inner());
            kids.iter_mut().all(|c| matches!(c.try_wait(), Ok(Some(_)))).then(|| format!("every {what} has ended; see {logs}/actor-*.log"))
        })
    }

    /// Waits up to ten seconds for the processes to end by themselves (their assignment queue
    /// closed), then kills what is left.
    pub(crate) fn finish(self) {
        let deadline = Instant::now() + Duration::from_secs(10);
        for c in self.lock().iter_mut() {
            while matches!(c.try_wait(), Ok(None)) && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(20));
            }
        }
        // Drop kills the rest.
    }
}

impl Drop for Children {
    fn drop(&mut self) {
        // A learner that failed: its actor processes must not outlive it.
        for c in self.lock().iter_mut() {
            if matches!(c.try_wait(), Ok(None)) {
                let _ = c.kill();
                let _ = c.wait();
            }
        }
    }
}

/// Starts `n` actors as `coadapt <subcommand> --config <config> --id <i> --transport ...
/// --fleet ... [--connect ...] <extra(i)>`, each logging to `<logs>/actor-<i>.log`.
pub(crate) fn spawn(
    subcommand: &str,
    config: &Path,
    n: usize,
    fleet: &FleetConfig,
    connect: &str,
    logs: &Path,
    extra: &dyn Fn(usize) -> Vec<std::ffi::OsString>,
) -> anyhow::Result<Children> {
    let exe = std::env::current_exe().context("finding the coadapt binary to start actors")?;
    std::fs::create_dir_all(logs).with_context(|| format!("creating {}", logs.display()))?;
    let children = Children::new(Vec::new());
    for i in 0..n {
        let mut cmd = std::process::Command::new(&exe);
        cmd.arg(subcommand).arg("--config").arg(config).arg("--id").arg(i.to_string());
        cmd.arg("--transport").arg(fleet.transport.name()).arg("--fleet").arg(&fleet.name);
        if !connect.is_empty() {
            cmd.arg("--connect").arg(connect);
        }
        cmd.args(extra(i));
        let log = std::fs::File::create(logs.join(format!("actor-{i}.log")))?;
        cmd.stdin(std::process::Stdio::null()).stdout(log.try_clone()?).stderr(log);
        let child = cmd.spawn().with_context(|| format!("starting {subcommand} {i}"))?;
        children.lock().push(child);
    }
    Ok(children)
}
