//! One fleet under every experiment: the co-adaptation, latent planning (`coadapt latent`) and
//! policy search (`coadapt search`) hand out work to actors and collect it the same way, over
//! every transport (in process, shared memory, gRPC), and start and watch their processes the
//! same way.
//!
//! # Layout
//! - [`dispatch`]: the learner's side. [`Dispatcher`] sends jobs out as assignments, holds their
//!   experience until each episode is whole, and returns it exactly once; leases, reissue after a
//!   silent actor, restarts, keep-alive bounds and deadlines live here and nowhere else.
//! - [`actor`]: the actor's side. [`actor::run`] waits for work and the newest weights and
//!   streams each episode back in chunks; an experiment supplies only its [`Worker`] (what one
//!   episode is).
//! - [`conformance`]: what the fleet must do over every transport, as functions the tests call
//!   with in-process, shared-memory and gRPC links.
//! - [`transports`]: the `[fleet]` table ([`FleetConfig`]) and each role's links over the
//!   transport it names, and the run id a learner's start carries.
//! - [`security`]: the `[security]` table: TLS and role tokens, and the rule that off loopback
//!   a server needs both.
//! - [`env`]: the environment factory (a robot by name, or `dm-env-rpc://` for a remote one).
//! - [`procs`]: actor processes a learner starts itself; [`supervise`]: the local fleet's
//!   supervisor with its restart budgets and the exit codes that say a restart cannot help.
//! - [`error`]: [`SetupError`], what callers branch on when a fleet cannot be set up.
//! - [`app`]: [`AppError`](app::AppError), why an application (any experiment family, a
//!   benchmark) stopped, and whether a restart could mend it.
//!
//! The experiment's own checks (shapes, magnitudes, the episode's length) plug into the
//! dispatcher as a [`Check`]; everything else is the same for every family.

pub mod actor;
pub mod app;
pub mod conformance;
pub mod dispatch;
pub mod env;
pub mod error;
pub mod procs;
pub mod security;
pub mod supervise;
pub mod transports;

pub use actor::{ActorConfig, ActorLoopError, ActorSummary, Failure, Stream, Worker};
pub use dispatch::{AcceptAll, Check, DispatchConfig, DispatchError, DispatchStats, Dispatcher, Done, Job, Verdict};
pub use env::{RemoteEnvConfig, make_env, make_env_with};
pub use error::SetupError;
pub use security::{SecurityConfig, check_listen};
pub use transports::{FleetConfig, LearnerGuard, TransportKind, clean_stale, new_run_id, run_id};
