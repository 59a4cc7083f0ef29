//! `coadapt latent` and `coadapt latent-actor`: their flags, turned into the latent library's
//! config ([`coadapt_latent::app`]), which runs them.

use std::path::PathBuf;

use clap::Args;
use coadapt_latent::app::{self, LatentConfig, Overrides};

use crate::progress::shutdown_on_ctrl_c;

/// DDPG from pixels exploring by latent trajectory optimisation (thesis ch. 4).
#[derive(Debug, Args)]
pub struct LatentArgs {
    /// The TOML config (default: the pixel half-cheetah, Q critic, planning with H = 10).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override `agent.explore`: plan or ou.
    #[arg(long)]
    pub explore: Option<String>,
    /// Override `agent.critic`: q or v.
    #[arg(long)]
    pub critic: Option<String>,
    /// Override `agent.objective`: sum-q, reward-plus-q or last-q.
    #[arg(long)]
    pub objective: Option<String>,
    /// Override `agent.horizon`.
    #[arg(long)]
    pub horizon: Option<usize>,
    /// Override `agent.updates-per-episode` (1000 in Fig. 4.5, 3000 in Fig. 4.6).
    #[arg(long)]
    pub updates_per_episode: Option<usize>,
    /// Override `runs`.
    #[arg(long)]
    pub runs: Option<usize>,
    /// Override `episodes`.
    #[arg(long)]
    pub episodes: Option<usize>,
    /// Override `seed`.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Override `embedding.path`.
    #[arg(long)]
    pub embedding: Option<PathBuf>,
    /// Only load or build the embedding, then stop.
    #[arg(long)]
    pub embed_only: bool,
    /// The run directory (default runs/latent-<explore>-<critic>-h<H>-seed<seed>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Override `actors`: run the episodes on N actors that plan where the robot is (0: in
    /// this process).
    #[arg(long)]
    pub actors: Option<usize>,
    /// Override fleet.transport: in-process (threads), shm or grpc.
    #[arg(long, value_enum)]
    pub transport: Option<coadapt_fleet::TransportKind>,
    /// Go on with the stopped run in --out: its finished runs are kept, the first unfinished
    /// one starts again (a run is deterministic given its seed). The config must be the run's.
    #[arg(long)]
    pub resume: bool,
}

/// `coadapt latent-actor`: runs the episodes a `coadapt latent` learner hands out on this
/// machine's robot, planning every step here.
#[derive(Debug, Args)]
pub struct LatentActorArgs {
    /// The run's config (its `config.toml`, or the file the learner was started with).
    #[arg(long)]
    pub config: PathBuf,
    /// This actor's id, unique among the run's actors.
    #[arg(long)]
    pub id: u64,
    /// How to reach the learner (over the config's [fleet]).
    #[command(flatten)]
    pub join: crate::actor_procs::JoinArgs,
    /// Override `robot`: a built-in robot or `dm-env-rpc://HOST:PORT` (this host's camera
    /// robot).
    #[arg(long)]
    pub robot: Option<String>,
    /// Append each episode's planning latency here (CSV; created with its header if new).
    #[arg(long)]
    pub latency_csv: Option<PathBuf>,
    /// TLS and the actor's token (over [security]).
    #[command(flatten)]
    pub security: crate::security::SecurityArgs,
}

/// `coadapt latent`.
pub fn run(a: LatentArgs) -> anyhow::Result<()> {
    let o = Overrides {
        explore: a.explore,
        critic: a.critic,
        objective: a.objective,
        horizon: a.horizon,
        updates_per_episode: a.updates_per_episode,
        runs: a.runs,
        episodes: a.episodes,
        seed: a.seed,
        embedding: a.embedding,
        actors: a.actors,
        transport: a.transport,
    };
    let cfg = app::resolve(a.config.as_deref(), &o)?;
    let shutdown = shutdown_on_ctrl_c();
    if a.embed_only {
        app::embedding(&cfg, &shutdown)?;
        return Ok(());
    }
    let out = a.out.unwrap_or_else(|| cfg.default_out());
    let summary = app::run(&cfg, &out, a.resume, &shutdown)?;
    println!("{summary}");
    Ok(())
}

/// `coadapt latent-actor`.
pub fn actor(a: LatentActorArgs) -> anyhow::Result<()> {
    let mut cfg = LatentConfig::load(&a.config)?;
    a.join.apply(&mut cfg.fleet)?;
    if let Some(r) = a.robot {
        cfg.robot = r;
    }
    cfg.security = crate::security::with_args(cfg.security.clone(), &a.security);
    let shutdown = shutdown_on_ctrl_c();
    app::actor(&cfg, a.id, a.latency_csv.as_deref(), &shutdown)?;
    Ok(())
}
