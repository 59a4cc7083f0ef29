//! `coadapt search`'s fleet: the rollouts on N actors (threads, or `coadapt search-actor`
//! processes over shared memory or gRPC), and the actor command itself.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;
use coadapt_policy_search::{FleetRunner, PlanarEnv};

use crate::search::SearchConfig;
use coadapt_fleet::procs::Children;
use coadapt_fleet::{LearnerGuard, TransportKind};

/// `coadapt search-actor`: runs the rollouts a search hands out on this machine's robot.
#[derive(Debug, Args)]
pub struct SearchActorArgs {
    /// The search's config (its `config.toml`, or the file the search was started with).
    #[arg(long)]
    pub config: PathBuf,
    /// This actor's id, unique among the search's actors.
    #[arg(long)]
    pub id: u64,
    /// How to reach the search (over the config's [fleet]).
    #[command(flatten)]
    pub join: crate::actor_procs::JoinArgs,
    /// Override `robot`: step this dm_env_rpc robot (`dm-env-rpc://HOST:PORT`) instead of the
    /// built-in planar one.
    #[arg(long)]
    pub robot: Option<String>,
    /// TLS and the actor's token (over [security]).
    #[command(flatten)]
    pub security: crate::security::SecurityArgs,
}

/// The search's fleet: the runner over the learner's links, and what keeps them up.
pub(crate) struct Fleet {
    pub(crate) runner: FleetRunner,
    guard: LearnerGuard,
    threads: Vec<std::thread::JoinHandle<Result<u64, coadapt_policy_search::RolloutError>>>,
    children: Children,
}

impl Fleet {
    pub(crate) fn start(cfg: &SearchConfig, out: &Path) -> anyhow::Result<Self> {
        let env = PlanarEnv::new(cfg.planar());
        let spec = coadapt_core::Env::spec(&env).clone();
        let dims = coadapt_transport::messages::Dims { obs: spec.obs_dim(), act: spec.act_dim(), design: spec.design.dim() };
        let lease = std::time::Duration::from_secs_f64(cfg.rollout_lease_secs);
        let deadline = std::time::Duration::from_secs_f64(cfg.iteration_deadline_secs);
        let (links, guard, threads, children) = match cfg.fleet.transport {
            TransportKind::InProcess => {
                let (learner, actors, _optimizer) = coadapt_transport::in_process::fleet(cfg.actors);
                let threads = actors
                    .into_iter()
                    .enumerate()
                    .map(|(i, mut links)| {
                        let mut robot = robot(cfg, &cfg.security)?;
                        let steps = spec.max_episode_steps;
                        Ok(std::thread::spawn(move || {
                            let stop = std::sync::atomic::AtomicBool::new(false);
                            coadapt_policy_search::run_actor(&mut *robot, steps, i as u64, &mut links, &stop)
                        }))
                    })
                    .collect::<anyhow::Result<Vec<_>>>()?;
                (learner, LearnerGuard::None, threads, Children::new(Vec::new()))
            }
            _ => {
                let procs = coadapt_fleet::procs::ProcessFleet {
                    role: "search",
                    subcommand: "search-actor",
                    actors: cfg.actors,
                    start: cfg.start_actors,
                    out,
                    extra: &|_| vec![],
                };
                let (links, guard, children) = procs.start(&cfg.fleet, dims, spec.max_episode_steps, &cfg.security)?;
                (links, guard, Vec::new(), children)
            }
        };
        let mut runner = FleetRunner::new(links, spec.max_episode_steps, spec.act_dim(), spec.obs_dim(), PlanarEnv::step_cost);
        runner.set_lease(lease);
        runner.set_deadline(deadline);
        if !children.is_empty() {
            // Actors started here that have all ended will never bring the rollouts back: say
            // so instead of waiting for the deadline.
            runner.set_abort(children.all_ended_check("search actor", &out.join("logs")));
        }
        Ok(Self { runner, guard, threads, children })
    }

    /// Closes the assignment queue (the actors end by themselves) and waits for them.
    pub(crate) fn finish(self) {
        let Self { runner, guard, threads, children } = self;
        drop(runner);
        drop(guard);
        coadapt_fleet::procs::join_threads("search", threads);
        children.finish();
    }
}

/// `coadapt search-actor`.
pub fn actor(a: SearchActorArgs) -> anyhow::Result<()> {
    let text = std::fs::read_to_string(&a.config).with_context(|| format!("reading {}", a.config.display()))?;
    let mut cfg: SearchConfig = toml::from_str(&text).with_context(|| format!("parsing {}", a.config.display()))?;
    if cfg.task != "planar" {
        anyhow::bail!("task: {:?}; only \"planar\" so far", cfg.task);
    }
    a.join.apply(&mut cfg.fleet)?;
    if let Some(r) = &a.robot {
        cfg.robot = r.clone();
    }
    let security = crate::security::with_args(cfg.security.clone(), &a.security);
    let mut robot = robot(&cfg, &security)?;
    let mut links = cfg.fleet.actor_links(a.id, &security)?;
    let shutdown = crate::progress::shutdown_on_ctrl_c();
    let name = if cfg.robot.is_empty() { "the planar robot" } else { cfg.robot.as_str() };
    coadapt_log::logln!("search actor {}: {name} over {}", a.id, cfg.fleet.transport.name());
    let steps = coadapt_core::Env::spec(&PlanarEnv::new(cfg.planar())).max_episode_steps;
    let n = coadapt_policy_search::run_actor(&mut *robot, steps, a.id, &mut links, &shutdown)?;
    coadapt_log::logln!("search actor {}: done after {n} rollouts", a.id);
    Ok(())
}

/// The robot an actor steps: the built-in planar one, or `cfg.robot` over dm_env_rpc (which
/// must have the planar task's shape: 12 actions, a 3-value observation, no design).
fn robot(cfg: &SearchConfig, security: &coadapt_fleet::SecurityConfig) -> anyhow::Result<Box<dyn coadapt_core::Env>> {
    if cfg.robot.is_empty() {
        return Ok(Box::new(PlanarEnv::new(cfg.planar())));
    }
    if !coadapt_env_rpc::is_remote(&cfg.robot) {
        anyhow::bail!("robot = {:?}: empty (the built-in planar robot) or dm-env-rpc://HOST:PORT", cfg.robot);
    }
    let remote =
        coadapt_env_rpc::RemoteEnv::connect(&cfg.robot, cfg.remote.options(security)?).with_context(|| format!("robot = {}", cfg.robot))?;
    let env = ServerUnits::new(remote);
    let (want, got) = (PlanarEnv::new(cfg.planar()), coadapt_core::Env::spec(&env));
    let want = coadapt_core::Env::spec(&want);
    // (A remote robot need not say its episode length: the actor plays the task's steps.)
    if (got.act_dim(), got.obs_dim()) != (want.act_dim(), want.obs_dim()) {
        anyhow::bail!(
            "robot = {}: {} actions and {}-value observations; the planar task needs {} and {}",
            cfg.robot,
            got.act_dim(),
            got.obs_dim(),
            want.act_dim(),
            want.obs_dim()
        );
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
