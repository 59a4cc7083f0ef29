//! `coadapt learner`, `coadapt actor`, `coadapt optimizer`: one role per process, for a fleet
//! launched by `coadapt run`, by `deploy/` scripts, systemd or Kubernetes. Every role reads the
//! same run config; flags override its `[fleet]` table.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::bail;
use clap::Args;
use coadapt_transport::messages::Dims;

use crate::progress::shutdown_on_ctrl_c;
use crate::roles;
use crate::run::{RunArgs, RunConfig, check, finish, resolve, resolve_initial_designs};
use coadapt_fleet::TransportKind;

/// What every role takes.
#[derive(Debug, Args)]
pub struct RoleArgs {
    /// The run's TOML config (the same file for every process of a fleet; default: the
    /// embedded reference protocol).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override fleet.transport: shm (one machine) or grpc.
    #[arg(long, value_enum)]
    pub transport: Option<TransportKind>,
    /// Override fleet.name: the shared-memory fleet every process of the run joins.
    #[arg(long)]
    pub fleet: Option<String>,
    /// Override the seed.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Override [security]: TLS files, the learner's --tokens-file, this process's
    /// --token-file (one config for the whole fleet, a token per role; `COADAPT_TOKEN` in the
    /// environment wins), --insecure.
    #[command(flatten)]
    pub security: crate::security::SecurityArgs,
}

impl RoleArgs {
    fn load(&self) -> anyhow::Result<(RunConfig, String)> {
        let run = RunArgs {
            config: self.config.clone(),
            out: None,
            seed: self.seed,
            exploit: None,
            explore: None,
            designs: None,
            transport: self.transport,
            actors: None,
            flow: None,
            resume: None,
            serve: None,
            insecure: false,
        };
        let (mut cfg, name) = resolve(&run)?;
        if let Some(f) = &self.fleet {
            cfg.fleet.name = f.clone();
        }
        cfg.security = crate::security::with_args(cfg.security.clone(), &self.security);
        let spec = coadapt_fleet::make_env_with(&cfg.env, &cfg.remote, &cfg.security)?.spec().clone();
        resolve_initial_designs(&mut cfg, &spec);
        check(&cfg, &spec)?;
        Ok((cfg, name))
    }
}

/// The learner: owns the schedule and the run directory; for gRPC it serves the fleet.
#[derive(Debug, Args)]
pub struct LearnerArgs {
    #[command(flatten)]
    pub role: RoleArgs,
    /// Run directory (default: runs/<config name>-seed<seed>, -2, -3, ... if taken).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Override fleet.listen: the gRPC address to serve on (port 0: any free port).
    #[arg(long)]
    pub listen: Option<String>,
    /// Serve Prometheus metrics on this address (`GET /metrics`; overrides
    /// metrics.learner-listen).
    #[arg(long)]
    pub metrics: Option<String>,
    /// Override design-service.listen: serve DesignService and the Open Inference Protocol's
    /// `design-critic` during the run on ADDR (with the same TLS and tokens as the fleet).
    #[arg(long, value_name = "ADDR")]
    pub serve: Option<String>,
    /// Continue the run in --out from its newest sound snapshot (a damaged one is skipped,
    /// naming what is wrong); an --out without a run starts one. For restarts by systemd or
    /// Kubernetes: the same command line starts and resumes.
    #[arg(long)]
    pub resume: bool,
}

/// An actor: runs the episodes the learner hands out, with the newest weights.
#[derive(Debug, Args)]
pub struct ActorArgs {
    #[command(flatten)]
    pub role: RoleArgs,
    /// This actor's id, unique in the fleet (default: derived from the host and process id).
    #[arg(long)]
    pub id: Option<u64>,
    /// Override fleet.connect: the learner's gRPC address, e.g. http://10.0.0.1:50051.
    #[arg(long)]
    pub connect: Option<String>,
}

/// The design optimiser: answers the learner's design requests.
#[derive(Debug, Args)]
pub struct OptimizerArgs {
    #[command(flatten)]
    pub role: RoleArgs,
    /// Override fleet.connect: the learner's gRPC address.
    #[arg(long)]
    pub connect: Option<String>,
    /// Serve Prometheus metrics on this address (`GET /metrics`; overrides
    /// metrics.optimizer-listen).
    #[arg(long)]
    pub metrics: Option<String>,
    /// Keep the optimiser's state here (optimizer-state.jsonl, a line appended after every reply) and
    /// continue from it when it exists, so a restarted optimiser answers as the one that died.
    #[arg(long)]
    pub state_dir: Option<PathBuf>,
}

/// `coadapt learner`.
pub fn learner(args: LearnerArgs) -> anyhow::Result<()> {
    let (mut cfg, name) = args.role.load()?;
    if let Some(l) = args.listen {
        cfg.fleet.listen = l;
    }
    if let Some(m) = args.metrics {
        cfg.metrics.learner_listen = m;
    }
    if let Some(a) = args.serve {
        cfg.design_service.listen = a;
    }
    let dir = match args.out {
        Some(d) => d,
        None if args.resume => bail!("--resume needs --out RUN_DIR"),
        None => crate::run::default_out(&name, cfg.seed),
    };
    let spec = coadapt_fleet::make_env_with(&cfg.env, &cfg.remote, &cfg.security)?.spec().clone();
    let shutdown = shutdown_on_ctrl_c();
    let dims = Dims { obs: spec.obs_dim(), act: spec.act_dim(), design: spec.design_dim() };
    let (mut links, guard) = cfg.fleet.learner_links(Some(dims), Some(spec.max_episode_steps), &cfg.security)?;
    coadapt_log::logln!("learner: {} over {}, into {}", cfg.env, cfg.fleet.transport.name(), dir.display());
    let stop_health = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let health = match &guard {
        coadapt_fleet::LearnerGuard::Grpc(server) => {
            let stall = Duration::try_from_secs_f64(cfg.fleet.health_stall_secs).ok().filter(|d| !d.is_zero()).ok_or_else(|| {
                anyhow::anyhow!("fleet.health-stall-secs: {} is not a positive number of seconds", cfg.fleet.health_stall_secs)
            })?;
            Some(crate::health::watch(server.health(), stall, stop_health.clone())?)
        }
        coadapt_fleet::LearnerGuard::None => None,
    };
    let start = Instant::now();
    let result = roles::learner(&cfg, &spec, &dir, &mut links, &shutdown, args.resume);
    stop_health.store(true, std::sync::atomic::Ordering::Relaxed);
    if let Some(h) = health {
        let _ = h.join();
    }
    // Closing the channels tells actors and optimiser the run is over.
    drop(links);
    let mut outcome = result?;
    finish(&cfg, &dir, &mut outcome, &shutdown, start)?;
    drop(guard);
    Ok(())
}

/// A default actor id: the same process never gets two, two hosts rarely collide.
fn default_id() -> u64 {
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default();
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in host.trim().bytes() {
        h = (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
    }
    (h << 20) ^ u64::from(std::process::id())
}

/// `coadapt actor`.
pub fn actor(args: ActorArgs) -> anyhow::Result<()> {
    let (mut cfg, _) = args.role.load()?;
    if let Some(c) = args.connect {
        cfg.fleet.connect = c;
    }
    let id = args.id.unwrap_or_else(default_id);
    let spec = coadapt_fleet::make_env_with(&cfg.env, &cfg.remote, &cfg.security)?.spec().clone();
    let shutdown = shutdown_on_ctrl_c();
    let mut links = cfg.fleet.actor_links(id, &cfg.security)?;
    coadapt_log::logln!("actor {id}: {} over {}", cfg.env, cfg.fleet.transport.name());
    roles::actor(&cfg, &spec, id, &mut links, &shutdown)
}

/// `coadapt optimizer`.
pub fn optimizer(args: OptimizerArgs) -> anyhow::Result<()> {
    let (mut cfg, _) = args.role.load()?;
    if let Some(m) = args.metrics {
        cfg.metrics.optimizer_listen = m;
    }
    if let Some(c) = args.connect {
        cfg.fleet.connect = c;
    }
    let spec = coadapt_fleet::make_env_with(&cfg.env, &cfg.remote, &cfg.security)?.spec().clone();
    let shutdown = shutdown_on_ctrl_c();
    let mut links = cfg.fleet.optimizer_links(&cfg.security)?;
    coadapt_log::logln!("optimizer: {} over {}, exploit {}", cfg.env, cfg.fleet.transport.name(), cfg.optimizer.exploit.name());
    roles::optimizer(&cfg, &spec, &mut links, &shutdown, args.state_dir.as_deref())
}
