//! `coadapt run` as a local fleet: the learner, the design optimiser and N actors as separate
//! processes of this binary (`coadapt learner|optimizer|actor`), supervised by the fleet library
//! ([`coadapt_fleet::supervise`]): a crashed actor or optimiser is started again (the learner
//! re-issues the episode it had), Ctrl-C or SIGTERM is passed on once to every process, and when
//! the learner is done the others are given a few seconds to leave before they are stopped.
//! Shared memory left by killed processes is cleaned up when the fleet starts and when it ends.

use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use crate::AppError;
use crate::error::{Context, bail};
use coadapt_fleet::supervise::{Plan, Role, supervise};
use coadapt_fleet::{TransportKind, clean_stale};

use crate::config::RunConfig;

/// The shared-memory fleet of this start. Every start gets its own name
/// (`coadapt-start-PID`): a run killed whole (SIGKILL of its process group, an OOM kill, a
/// reboot) leaves its channels behind with dead owners, and a resume that reopened them under
/// the old name failed ("ExceedsMaxSupportedSubscribers"); the name a previous start chose
/// comes back from the run's config.toml, so a generated name (this form, or `coadapt-PID` of
/// earlier versions) is replaced, never reused. A name the operator chose (to attach processes of
/// their own) is kept, but refused while another fleet's channels of that name exist.
pub fn shm_fleet_name(configured: &str, pid: u32) -> crate::Result<String> {
    let generated = |n: &str| {
        let digits = n.strip_prefix("coadapt-start-").or_else(|| n.strip_prefix("coadapt-"));
        digits.is_some_and(|d| !d.is_empty() && d.bytes().all(|b| b.is_ascii_digit()))
    };
    if configured.is_empty() || generated(configured) {
        return Ok(format!("coadapt-start-{pid}"));
    }
    match coadapt_shm::fleet_services(configured) {
        Ok(left) if !left.is_empty() => bail!(
            "fleet.name = {configured:?}: another fleet's shared-memory channels of that name exist ({}); stop that fleet, \
             or leave fleet.name empty so that each start gets a name of its own",
            left.join(", ")
        ),
        _ => Ok(configured.to_string()),
    }
}

/// Launches the fleet for `cfg` into `dir` (continuing the run there with `resume`) and
/// supervises it until the learner is done. A learner that crashes is started again with
/// `--resume` from its newest snapshot, the other processes with it (actors hold nothing; the
/// optimiser continues from its state file), within `fleet.max-restarts` per
/// `fleet.restart-window-secs`.
pub fn launch(cfg: &RunConfig, dir: &Path, shutdown: &AtomicBool, resume: bool) -> crate::Result<()> {
    let mut cfg = cfg.clone();
    match cfg.fleet.transport {
        TransportKind::Shm => {
            clean_stale();
            cfg.fleet.name = shm_fleet_name(&cfg.fleet.name, std::process::id())?;
        }
        TransportKind::Grpc => {
            // A free loopback port for this fleet.
            let port = std::net::TcpListener::bind("127.0.0.1:0").and_then(|l| l.local_addr()).context("finding a free port")?.port();
            cfg.fleet.listen = format!("127.0.0.1:{port}");
            cfg.fleet.connect = format!("http://127.0.0.1:{port}");
        }
        TransportKind::InProcess => bail!("fleet.transport: in-process runs without a fleet"),
    }
    let window = Duration::try_from_secs_f64(cfg.fleet.restart_window_secs)
        .ok()
        .filter(|d| !d.is_zero())
        .with_context(|| format!("fleet.restart-window-secs: {} is not a positive number of seconds", cfg.fleet.restart_window_secs))?;
    let logs = dir.join("logs");
    std::fs::create_dir_all(&logs).with_context(|| format!("creating {}", logs.display()))?;
    let config = dir.join("fleet.toml");
    std::fs::write(&config, toml::to_string(&cfg).map_err(AppError::library)?).with_context(|| format!("writing {}", config.display()))?;
    let config = config.display().to_string();
    let common = ["--config".to_string(), config.clone(), "--transport".into(), cfg.fleet.transport.name().into()];

    let mut learner_args = vec!["learner".to_string()];
    learner_args.extend(common.iter().cloned());
    learner_args.extend(["--out".into(), dir.display().to_string()]);
    // Resolved once: a rebuild during a long run replaces the file, and a restart should still
    // find a binary at this path.
    let exe = std::env::current_exe().context("finding the coadapt binary")?;
    let mut opt_args = vec!["optimizer".to_string()];
    opt_args.extend(common.iter().cloned());
    opt_args.extend(["--state-dir".into(), crate::resume::optimizer_state_dir(dir).display().to_string()]);
    let mut others = vec![Role { name: "optimizer".into(), args: opt_args, log: Some(logs.join("optimizer.log")) }];
    for i in 0..cfg.actors {
        let mut a = vec!["actor".to_string()];
        a.extend(common.iter().cloned());
        a.extend(["--id".into(), i.to_string()]);
        others.push(Role { name: format!("actor {i}"), args: a, log: Some(logs.join(format!("actor-{i}.log"))) });
    }
    let shm = cfg.fleet.transport == TransportKind::Shm;
    let plan = Plan {
        exe,
        learner: Role { name: "learner".into(), args: learner_args, log: None },
        resume_arg: "--resume".into(),
        others,
        max_restarts: cfg.fleet.max_restarts,
        window,
        name: if cfg.fleet.name.is_empty() { cfg.fleet.connect.clone() } else { cfg.fleet.name.clone() },
        logs: logs.clone(),
        resume_hint: format!("coadapt run --resume {}", dir.display()),
        before_restart: Box::new(move || {
            if shm {
                clean_stale();
            }
        }),
    };
    let result = supervise(&plan, shutdown, resume);
    if shm {
        clean_stale();
        match coadapt_shm::fleet_services(&cfg.fleet.name) {
            Ok(left) if !left.is_empty() => coadapt_log::logln!("warning: shared memory of the fleet left behind: {left:?}"),
            Ok(_) => {}
            Err(e) => coadapt_log::logln!("warning: listing the fleet's shared memory: {e}"),
        }
    }
    Ok(result?)
}
