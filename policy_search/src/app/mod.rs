//! `coadapt search` as a library: the run directory of episodic policy search on the planar
//! benchmark (config, runs, `iterations.csv` and `rollouts.csv`, policies, rollouts on actors,
//! plots, summary) and the actor process. The binary parses the command line into a
//! [`SearchConfig`] ([`resolve`]) and calls [`run`] or [`actor`] with its shutdown flag.
//!
//! - `config`: [`SearchConfig`] (the task, the method and its settings, `[fleet]`,
//!   `[security]`), the command line's [`Overrides`] and the checks, [`resolve`].
//! - `run`: [`run`], the searches and their files, W-hat reuse, the summary.
//! - `actors`: the rollouts on actors (threads, or `coadapt search-actor` processes), and
//!   [`actor`], the actor process's loop on the planar robot or a served one.
//! - `plot`: the learning curve and the synergies (thesis Fig. 3.9, 3.10).
//!
//! Its errors are the fleet's [`AppError`](coadapt_fleet::app::AppError), as every application's.

mod actors;
mod config;
mod plot;
mod run;

pub use actors::actor;
pub use config::{Overrides, SearchConfig, resolve};
pub use run::run;
