//! The `coadapt` command line: argument parsing and dispatch into the libraries, which own
//! every application (docs/ARCHITECTURE.md). Each module holds a subcommand's clap flags and
//! turns them into the library's options; the binary makes the shutdown flag (Ctrl-C, SIGTERM)
//! and maps a library's error to an exit code ([`exit`]).
//!
//! # Layout
//! - [`Cli`] and [`run`]: the clap command tree and its dispatch.
//! - [`run`]: `coadapt run` (`coadapt_coadaptation::run`); [`role_cmd`]:
//!   `coadapt learner|actor|optimizer`, one role per process (`coadapt_coadaptation::processes`).
//! - [`confirm`]: `coadapt confirm`, the operator's answer to a run waiting for a prototype or
//!   a reset (`coadapt_learner::prototype`).
//! - [`plot`]: `coadapt plot` (`coadapt_coadaptation::plot`).
//! - [`train`]: `coadapt train` (`coadapt_learner::train`); [`render`]: `coadapt render`
//!   (`coadapt_learner::render`).
//! - [`bench`]: `coadapt bench` and its subcommands (`coadapt_bench`).
//! - [`env_serve`]: `coadapt env-serve`, a built-in robot served over dm_env_rpc.
//! - [`serve`]: `coadapt serve`, a run's design critic (`coadapt_coadaptation::serve`,
//!   `coadapt_design_service`); [`design_client`]: `coadapt score`, `optimize` and `history`,
//!   its command-line clients.
//! - [`search`]: `coadapt search` and `search-actor` (`coadapt_policy_search::app`).
//! - [`latent`]: `coadapt latent` and `latent-actor` (`coadapt_latent::app`).
//! - [`actor_procs`]: how an actor process joins its learner's fleet (`JoinArgs`).
//! - [`security`]: the TLS and token flags of the commands without a run config;
//!   [`world_args`]: the `[world]` flags of `run`, `train` and `render`.
//! - [`credentials`]: `coadapt token new` and `coadapt tls new`.
//! - [`exit`]: exit codes from the libraries' errors; [`progress`]: the shutdown flag set by
//!   Ctrl-C and SIGTERM.

pub mod action_space;
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
pub mod world_args;

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
    ActionSpace(action_space::ActionSpaceArgs),
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
        Command::ActionSpace(args) => action_space::run(args),
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
