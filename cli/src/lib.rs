//! The `coadapt` command line: thin subcommands over the libraries.
//!
//! # Layout
//! - [`Cli`] and [`run`]: the clap command tree and its dispatch.
//! - [`run`]: `coadapt run`, a whole co-adaptation, its config and the run directory's last
//!   touches (landscape, plots, summary).
//! - [`roles`]: the learner, actor and design-optimiser roles over any links.
//! - [`role_cmd`]: `coadapt learner|actor|optimizer`, one role per process.
//! - [`fleet`]: the `[fleet]` config and each role's links over shared memory or gRPC.
//! - [`launch`]: the local fleet of `coadapt run`: starts, supervises and stops the processes.
//! - [`confirm`]: `coadapt confirm`, the operator's answer to a run waiting for a prototype or
//!   a reset.
//! - [`plot`]: `coadapt plot`, the run directory's SVG plots (also drawn at the end of a run).
//! - [`train`]: `coadapt train`, RL on one environment and one design.
//! - [`bench`]: `coadapt bench`, its subcommands and their dispatch into `coadapt_bench` (the
//!   benchmarks, each printing one JSON line per figure).
//! - [`render`]: `coadapt render`, an episode as an animated GIF.
//! - [`env_serve`]: `coadapt env-serve`, a built-in robot served over dm_env_rpc.
//! - [`serve`]: `coadapt serve`, a run's design critic (DesignService, Open Inference Protocol);
//!   [`design_client`]: `coadapt score`, `coadapt optimize` and `coadapt history`, its
//!   command-line clients.
//! - [`search`]: the flags of `coadapt search` (episodic policy search: GrouPS, PePPER, PoWER,
//!   NAC on the planar benchmark) and `coadapt search-actor`; the application is
//!   `coadapt_policy_search::app`.
//! - [`latent`]: the flags of `coadapt latent` (DDPG from pixels exploring by latent trajectory
//!   optimisation, thesis ch. 4) and `coadapt latent-actor`; the application is
//!   `coadapt_latent::app`.
//! - [`actor_procs`]: actor processes a learner starts itself (search, latent), and how an actor
//!   process joins its learner (`JoinArgs`).
//! - [`progress`]: progress lines and the shutdown flag set by Ctrl-C.

pub mod actor_procs;
pub mod bench;
pub mod confirm;
pub mod credentials;
pub mod design_client;
pub mod env_serve;
pub mod exit;
pub mod latent;
pub mod plot;
pub mod progress;
pub mod render;
pub mod role_cmd;
pub mod run;
pub mod search;
pub mod security;
pub mod serve;
pub mod train;

use clap::{Parser, Subcommand};

/// Co-design a robot's body and its controller with sample-efficient deep RL.
#[derive(Debug, Parser)]
#[command(name = "coadapt", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    Run(run::RunArgs),
    Learner(role_cmd::LearnerArgs),
    Actor(role_cmd::ActorArgs),
    Optimizer(role_cmd::OptimizerArgs),
    Confirm(confirm::ConfirmArgs),
    Plot(plot::PlotArgs),
    Train(train::TrainArgs),
    Render(render::RenderArgs),
    EnvServe(env_serve::EnvServeArgs),
    Serve(serve::ServeArgs),
    Score(design_client::ScoreArgs),
    /// Policy search from few rollouts (thesis ch. 2-3): GrouPS, PePPER, PoWER or NAC on the
    /// bimanual planar reaching benchmark, in process or on a fleet of actors.
    Search(search::SearchArgs),
    /// DDPG from pixels exploring by planning in a learned latent space (thesis ch. 4, Alg. 3):
    /// Q or V critic, trajectory optimisation (three objectives) or OU noise, several runs.
    Latent(latent::LatentArgs),
    /// Runs the episodes a `coadapt latent` hands out (shm or gRPC), planning every step on
    /// this machine's camera robot.
    LatentActor(latent::LatentActorArgs),
    /// Runs the rollouts a `coadapt search` hands out (shm or gRPC), on this machine's robot.
    SearchActor(search::SearchActorArgs),
    /// Role tokens for the fleet's endpoints (`coadapt token new --role actor --out FILE`).
    #[command(subcommand)]
    Token(credentials::TokenCommand),
    /// TLS certificates for the fleet's endpoints (`coadapt tls new --out DIR`).
    #[command(subcommand)]
    Tls(credentials::TlsCommand),
    Optimize(design_client::OptimizeArgs),
    History(design_client::HistoryArgs),
    /// Run benchmarks; each prints one JSON line per figure.
    #[command(subcommand)]
    Bench(bench::BenchCommand),
}

/// Runs a parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Run(args) => run::run(args),
        Command::Learner(args) => role_cmd::learner(args),
        Command::Actor(args) => role_cmd::actor(args),
        Command::Optimizer(args) => role_cmd::optimizer(args),
        Command::Confirm(args) => confirm::run(args),
        Command::Plot(args) => plot::run(args),
        Command::Train(args) => train::run(args),
        Command::Render(args) => render::run(args),
        Command::EnvServe(args) => env_serve::run(args),
        Command::Serve(args) => serve::run(args),
        Command::Score(args) => design_client::score(args),
        Command::Search(args) => search::run(args),
        Command::SearchActor(args) => search::actor(args),
        Command::Latent(args) => latent::run(args),
        Command::LatentActor(args) => latent::actor(args),
        Command::Token(cmd) => credentials::token(cmd),
        Command::Tls(cmd) => credentials::tls(cmd),
        Command::Optimize(args) => design_client::optimize(args),
        Command::History(args) => design_client::history(args),
        Command::Bench(cmd) => bench::run(cmd),
    }
}
