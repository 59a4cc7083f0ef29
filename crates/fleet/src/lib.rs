//! One fleet under every experiment: the co-adaptation, latent planning (`coadapt latent`) and
//! policy search (`coadapt search`) hand out work to actors and collect it the same way, over
//! every transport (in process, shared memory, gRPC).
//!
//! # Layout
//! - [`dispatch`]: the learner's side. [`Dispatcher`] sends jobs out as assignments, holds their
//!   experience until each episode is whole, and returns it exactly once; leases, reissue after a
//!   silent actor, restarts, keep-alive bounds and deadlines live here and nowhere else.
//! - [`actor`]: the actor's side. [`actor::run`] waits for work and the newest weights and
//!   streams each episode back in chunks; an experiment supplies only its [`Worker`] (what one
//!   episode is).
//!
//! - [`conformance`]: what the fleet must do over every transport, as functions the tests call
//!   with in-process, shared-memory and gRPC links.
//!
//! The experiment's own checks (shapes, magnitudes, the episode's length) plug into the
//! dispatcher as a [`Check`]; everything else is the same for every family.

pub mod actor;
pub mod conformance;
pub mod dispatch;

pub use actor::{ActorConfig, ActorLoopError, ActorSummary, Failure, Stream, Worker};
pub use dispatch::{AcceptAll, Check, DispatchConfig, DispatchError, DispatchStats, Dispatcher, Done, Job, Verdict};
