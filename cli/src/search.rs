//! `coadapt search` and `coadapt search-actor`: their flags, turned into the policy-search
//! library's config ([`coadapt_policy_search::app`]), which runs them.

use std::path::PathBuf;

use clap::Args;
use coadapt_fleet::TransportKind;
pub use coadapt_policy_search::app::SearchConfig;
use coadapt_policy_search::app::{self, Overrides};

use crate::progress::shutdown_on_ctrl_c;

/// Policy search from few rollouts on the bimanual planar reaching benchmark.
#[derive(Debug, Args)]
pub struct SearchArgs {
    /// The TOML config (default: GrouPS with 4 groups, 10 runs of 100 iterations).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override `method`: groups, pepper, power or nac.
    #[arg(long)]
    pub method: Option<String>,
    /// Override `runs`.
    #[arg(long)]
    pub runs: Option<usize>,
    /// Override `iterations`.
    #[arg(long)]
    pub iterations: Option<usize>,
    /// Override `seed`.
    #[arg(long)]
    pub seed: Option<u64>,
    /// The run directory (default runs/search-<method>-seed<seed>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Override `actors`: run the rollouts on N actors (0: in this process).
    #[arg(long)]
    pub actors: Option<usize>,
    /// Override fleet.transport: in-process (threads), shm or grpc.
    #[arg(long, value_enum)]
    pub transport: Option<TransportKind>,
    /// TLS and tokens of a gRPC fleet (over [security]).
    #[command(flatten)]
    pub security: crate::security::SecurityArgs,
}

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

/// `coadapt search`.
pub fn run(a: SearchArgs) -> anyhow::Result<()> {
    let o = Overrides { method: a.method, runs: a.runs, iterations: a.iterations, seed: a.seed, actors: a.actors, transport: a.transport };
    let mut cfg = app::resolve(a.config.as_deref(), &o)?;
    cfg.security = crate::security::with_args(cfg.security.clone(), &a.security);
    let out = a.out.unwrap_or_else(|| cfg.default_out());
    let shutdown = shutdown_on_ctrl_c();
    let summary = app::run(&cfg, &out, &shutdown)?;
    coadapt_log::print_stdout_line(&summary.to_string());
    Ok(())
}

/// `coadapt search-actor`.
pub fn actor(a: SearchActorArgs) -> anyhow::Result<()> {
    let mut cfg = SearchConfig::load_for_actor(&a.config)?;
    a.join.apply(&mut cfg.fleet)?;
    if let Some(r) = a.robot {
        cfg.robot = r;
    }
    cfg.security = crate::security::with_args(cfg.security.clone(), &a.security);
    let shutdown = shutdown_on_ctrl_c();
    app::actor(&cfg, a.id, &shutdown)?;
    Ok(())
}
