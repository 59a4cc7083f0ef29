//! One role per process (`coadapt learner`, `coadapt actor`, `coadapt optimizer`), for a fleet
//! launched by `coadapt run`, by `deploy/` scripts, systemd or Kubernetes: each opens its links
//! over the config's `[fleet]` and runs its role until done or `shutdown`.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use coadapt_transport::messages::Dims;

use crate::config::{RunConfig, check, default_out, resolve_initial_designs};
use crate::error::bail;
use crate::roles;

/// `cfg` with the initial designs the robot gives, checked: what every role runs with.
pub fn prepare(mut cfg: RunConfig) -> crate::Result<RunConfig> {
    let spec = cfg.make_env()?.spec().clone();
    resolve_initial_designs(&mut cfg, &spec);
    check(&cfg, &spec)?;
    Ok(cfg)
}

/// The learner: owns the schedule and the run directory `out` (default:
/// `runs/<name>-seed<seed>`); for gRPC it serves the fleet. With `resume`, continues the run in
/// `out` from its newest sound snapshot.
pub fn learner(cfg: &RunConfig, name: &str, out: Option<PathBuf>, resume: bool, shutdown: &AtomicBool) -> crate::Result<()> {
    let dir = match out {
        Some(d) => d,
        None if resume => bail!("--resume needs --out RUN_DIR"),
        None => default_out(name, cfg.seed),
    };
    let spec = cfg.make_env()?.spec().clone();
    let dims = Dims { obs: spec.obs_dim(), act: spec.act_dim(), design: spec.design_dim() };
    let (mut links, guard) = cfg.fleet.learner_links(Some(dims), Some(spec.max_episode_steps), &cfg.security)?;
    coadapt_log::logln!("learner: {} over {}, into {}", cfg.env, cfg.fleet.transport.name(), dir.display());
    let stop_health = Arc::new(AtomicBool::new(false));
    let health = match &guard {
        coadapt_fleet::LearnerGuard::Grpc(server) => {
            let stall = Duration::try_from_secs_f64(cfg.fleet.health_stall_secs).ok().filter(|d| !d.is_zero()).ok_or_else(|| {
                crate::AppError::Config(format!(
                    "fleet.health-stall-secs: {} is not a positive number of seconds",
                    cfg.fleet.health_stall_secs
                ))
            })?;
            Some(crate::health::watch(server.health(), stall, stop_health.clone())?)
        }
        coadapt_fleet::LearnerGuard::None => None,
    };
    let start = Instant::now();
    let result = roles::learner(cfg, &spec, &dir, &mut links, shutdown, resume);
    stop_health.store(true, Ordering::Relaxed);
    if let Some(h) = health {
        let _ = h.join();
    }
    // Closing the channels tells actors and optimiser the run is over.
    drop(links);
    let mut outcome = result?;
    crate::run::finish(cfg, &dir, &mut outcome, shutdown, start)?;
    drop(guard);
    Ok(())
}

/// Actor `id`: runs the episodes the learner hands out, with the newest weights.
pub fn actor(cfg: &RunConfig, id: u64, shutdown: &AtomicBool) -> crate::Result<()> {
    let spec = cfg.make_env()?.spec().clone();
    let mut links = cfg.fleet.actor_links(id, &cfg.security)?;
    coadapt_log::logln!("actor {id}: {} over {}", cfg.env, cfg.fleet.transport.name());
    roles::actor(cfg, &spec, id, &mut links, shutdown)
}

/// The design optimiser: answers the learner's design requests, keeping its state in
/// `state_dir` (and continuing from it) when given.
pub fn optimizer(cfg: &RunConfig, state_dir: Option<&Path>, shutdown: &AtomicBool) -> crate::Result<()> {
    let spec = cfg.make_env()?.spec().clone();
    let mut links = cfg.fleet.optimizer_links(&cfg.security)?;
    coadapt_log::logln!("optimizer: {} over {}, exploit {}", cfg.env, cfg.fleet.transport.name(), cfg.optimizer.exploit.name());
    roles::optimizer(cfg, &spec, &mut links, shutdown, state_dir)
}
