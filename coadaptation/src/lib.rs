//! The co-adaptation (thesis ch. 5: FEAR and its baselines) as an application: what
//! `coadapt run` and its role commands do, behind functions a test drives as the binary does.
//!
//! # Layout
//! - [`config`]: [`RunConfig`] (the TOML file's layout), read with a command line's
//!   [`Overrides`] and checked against the robot.
//! - [`run`]: [`run::run`], the whole co-adaptation into a directory (a local fleet, or threads
//!   over the in-process transport: [`run::run_config`]), and the run directory's last touches
//!   (landscape, plots, summary).
//! - [`roles`]: the learner, actor and design-optimiser roles over any links; [`processes`]:
//!   one role per process over the config's `[fleet]` (`coadapt learner|actor|optimizer`).
//! - [`launch`]: the local fleet of `coadapt run` (processes of this binary under the fleet's
//!   supervisor).
//! - [`resume`]: a run directory's config against the one given, the snapshot and the
//!   optimiser's state found in it.
//! - [`design_live`]: the learner's DesignService during the run; [`metrics`]: Prometheus
//!   `/metrics` of the learner and the optimiser; [`health`]: the learner's progress for
//!   gRPC health; [`page`]: the operator page on the design service's listener (watch the run,
//!   answer its prototype step from a browser).
//! - [`serve`]: a run's design critic for the design service (a running learner's, or a
//!   finished run's for `coadapt serve`).
//! - [`action_space`]: `coadapt action-space`, the latent design-dependent action space (thesis
//!   6.2) learned from a run's experience, with Fig. 6.1 and 6.2.
//! - [`transfer`]: `[init-population]`, a run that starts with another run's population
//!   networks (thesis section 6.1), the source checked against this run.
//! - [`plot`]: the run directory's SVG plots (`coadapt plot`, and at the end of a run).
//! - `error`: the short forms of the fleet's [`AppError`] this crate writes (`bail!`, `bail_config!`).

pub mod action_space;
pub mod config;
pub mod design_live;
pub mod error;
pub mod health;
pub mod launch;
pub mod metrics;
pub mod page;
pub mod plot;
pub mod processes;
pub mod resume;
pub mod roles;
pub mod run;
pub mod serve;
pub mod transfer;

pub use coadapt_fleet::app::{AppError, Result};
pub use config::{DEFAULT_CONFIG, Overrides, RunConfig};
