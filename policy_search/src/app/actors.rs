//! `coadapt search`'s actors: the rollouts on N actors (threads, or `coadapt search-actor`
//! processes over shared memory or gRPC), and the actor process itself.

use std::path::Path;
use std::sync::atomic::AtomicBool;

use coadapt_fleet::procs::{LocalActors, ProcessFleet};

use super::config::SearchConfig;
use crate::{FleetRunner, PlanarEnv};
use coadapt_fleet::app::{AppError, Context};

/// The search's fleet: the runner over the learner's links, and what keeps them up.
pub(crate) struct Fleet {
    pub(crate) runner: FleetRunner,
    actors: LocalActors<crate::RolloutError>,
}

impl Fleet {
    pub(crate) fn start(cfg: &SearchConfig, out: &Path) -> Result<Self, AppError> {
        let env = PlanarEnv::new(cfg.planar());
        let spec = coadapt_core::Env::spec(&env).clone();
        let dims = coadapt_transport::messages::Dims { obs: spec.obs_dim(), act: spec.act_dim(), design: spec.design.dim() };
        let lease = std::time::Duration::from_secs_f64(cfg.rollout_lease_secs);
        let deadline = std::time::Duration::from_secs_f64(cfg.iteration_deadline_secs);
        let procs = ProcessFleet {
            role: "search",
            subcommand: "search-actor",
            actors: cfg.actors,
            start: cfg.start_actors,
            out,
            extra: &|_| vec![],
        };
        let steps = spec.max_episode_steps;
        let (links, actors) = LocalActors::start(&cfg.fleet, &procs, dims, steps, &cfg.security, |i, mut links| {
            let mut robot = robot(cfg, &cfg.security)?;
            Ok::<_, AppError>(std::thread::spawn(move || {
                let stop = std::sync::atomic::AtomicBool::new(false);
                crate::run_actor(&mut *robot, steps, i as u64, &mut links, &stop)
            }))
        })?;
        let mut runner = FleetRunner::new(links, spec.max_episode_steps, spec.act_dim(), spec.obs_dim(), PlanarEnv::step_cost);
        runner.set_lease(lease);
        runner.set_deadline(deadline);
        // Actors started here that have all ended will never bring the rollouts back: say so
        // instead of waiting for the deadline.
        if let Some(check) = actors.all_ended_check() {
            runner.set_abort(check);
        }
        Ok(Self { runner, actors })
    }

    /// Closes the assignment queue (the actors end by themselves) and waits for them.
    pub(crate) fn finish(self) {
        let Self { runner, actors } = self;
        drop(runner);
        actors.finish();
    }
}

/// `coadapt search-actor`: runs the rollouts a search hands out over `cfg.fleet` (shm or
/// gRPC) on `cfg.robot` (the built-in planar robot when empty), with `cfg.security`, until the
/// search closes the queue or `shutdown` is set. Returns how many rollouts it ran.
pub fn actor(cfg: &SearchConfig, id: u64, shutdown: &AtomicBool) -> Result<u64, AppError> {
    let mut robot = robot(cfg, &cfg.security)?;
    let mut links = cfg.fleet.actor_links(id, &cfg.security)?;
    let name = if cfg.robot.is_empty() { "the planar robot" } else { cfg.robot.as_str() };
    coadapt_log::logln!("search actor {id}: {name} over {}", cfg.fleet.transport.name());
    let steps = coadapt_core::Env::spec(&PlanarEnv::new(cfg.planar())).max_episode_steps;
    let n = crate::run_actor(&mut *robot, steps, id, &mut links, shutdown)?;
    coadapt_log::logln!("search actor {id}: done after {n} rollouts");
    Ok(n)
}

/// The robot an actor steps: the built-in planar one, or `cfg.robot` over dm_env_rpc (which
/// must have the planar task's shape: 12 actions, a 3-value observation, no design).
fn robot(cfg: &SearchConfig, security: &coadapt_fleet::SecurityConfig) -> Result<Box<dyn coadapt_core::Env>, AppError> {
    if cfg.robot.is_empty() {
        return Ok(Box::new(PlanarEnv::new(cfg.planar())));
    }
    if !coadapt_env_rpc::is_remote(&cfg.robot) {
        return Err(AppError::Config(format!("robot = {:?}: empty (the built-in planar robot) or dm-env-rpc://HOST:PORT", cfg.robot)));
    }
    let remote =
        coadapt_env_rpc::RemoteEnv::connect(&cfg.robot, cfg.remote.options(security)?).with_context(|| format!("robot = {}", cfg.robot))?;
    let env = ServerUnits::new(remote);
    let (want, got) = (PlanarEnv::new(cfg.planar()), coadapt_core::Env::spec(&env));
    let want = coadapt_core::Env::spec(&want);
    // (A remote robot need not say its episode length: the actor plays the task's steps.)
    if (got.act_dim(), got.obs_dim()) != (want.act_dim(), want.obs_dim()) {
        return Err(AppError::Config(format!(
            "robot = {}: {} actions and {}-value observations; the planar task needs {} and {}",
            cfg.robot,
            got.act_dim(),
            got.obs_dim(),
            want.act_dim(),
            want.obs_dim()
        )));
    }
    Ok(Box::new(env))
}

/// A dm_env_rpc robot stepped in its server's own action units: the search's actions are joint
/// angles, which this maps into the `[-1, 1]` a `RemoteEnv` takes (and the server maps back).
struct ServerUnits {
    inner: coadapt_env_rpc::RemoteEnv,
    spec: coadapt_core::EnvSpec,
    scaled: Vec<f32>,
}

impl ServerUnits {
    fn new(inner: coadapt_env_rpc::RemoteEnv) -> Self {
        let mut spec = coadapt_core::Env::spec(&inner).clone();
        spec.action = inner.server_action().clone();
        Self { inner, spec, scaled: Vec::new() }
    }
}

impl coadapt_core::Env for ServerUnits {
    fn spec(&self) -> &coadapt_core::EnvSpec {
        &self.spec
    }

    fn reset(&mut self, seed: u64, design: &[f32]) -> Result<&[f32], coadapt_core::EnvError> {
        self.inner.reset(seed, design)
    }

    fn step(&mut self, action: &[f32]) -> Result<coadapt_core::Step<'_>, coadapt_core::EnvError> {
        let b = &self.spec.action;
        self.scaled.clear();
        self.scaled.extend(action.iter().zip(b.low.iter().zip(&b.high)).map(|(a, (lo, hi))| 2.0 * (a - lo) / (hi - lo) - 1.0));
        self.inner.step(&self.scaled)
    }
}
