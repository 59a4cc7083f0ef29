//! `coadapt learner`, `coadapt actor`, `coadapt optimizer`: one role per process, for a fleet
//! launched by `coadapt run`, by `deploy/` scripts, systemd or Kubernetes. Every role reads the
//! same run config; flags override its `[fleet]` table.

use std::path::PathBuf;

use clap::Args;
use coadapt_coadaptation::config::{Overrides, resolve};
use coadapt_coadaptation::{RunConfig, processes};
use coadapt_fleet::TransportKind;

use crate::progress::shutdown_on_ctrl_c;

/// What every role takes.
#[derive(Debug, Args)]
pub struct RoleArgs {
    /// The run's TOML config (the same file for every process of a fleet; default: the
    /// embedded default, `configs/half-cheetah.toml`).
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
        let o = Overrides { seed: self.seed, transport: self.transport, ..Overrides::default() };
        let (mut cfg, name) = resolve(self.config.as_deref(), None, &o)?;
        if let Some(f) = &self.fleet {
            cfg.fleet.name = f.clone();
        }
        cfg.security = crate::security::with_args(cfg.security.clone(), &self.security);
        Ok((processes::prepare(cfg)?, name))
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
    let shutdown = shutdown_on_ctrl_c();
    Ok(processes::learner(&cfg, &name, args.out, args.resume, &shutdown)?)
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
    let shutdown = shutdown_on_ctrl_c();
    Ok(processes::actor(&cfg, id, &shutdown)?)
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
    let shutdown = shutdown_on_ctrl_c();
    Ok(processes::optimizer(&cfg, args.state_dir.as_deref(), &shutdown)?)
}
