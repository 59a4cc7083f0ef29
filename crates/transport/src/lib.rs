//! How coadapt's roles (actors, learner, design optimiser) talk to each other.
//!
//! # Layout
//! - [`messages`]: what travels: versioned network weights, episode assignments, experience
//!   chunks, design requests and replies. Plain domain types; each checks itself
//!   ([`messages::Validate`]) so a receiver can refuse malformed input before it is used.
//! - [`traits`]: the two channel shapes every transport provides. A *queue*
//!   ([`Sender`]/[`Receiver`]: ordered, nothing acknowledged is lost) carries experience,
//!   assignments and design requests; a *latest-value topic* ([`Publisher`]/[`Subscriber`]:
//!   readers see the newest version, never a backlog) carries weights.
//! - [`links`]: the bundle of channels each role holds ([`LearnerLinks`], [`ActorLinks`],
//!   [`OptimizerLinks`]), so a role's code never names a transport.
//! - [`in_process`]: threads in one process (tests, the in-process `coadapt run`).
//! - [`conformance`]: the behaviour every implementation must show, as functions generic over
//!   a channel factory; each implementation's tests call them.
//!
//! Waiting is always bounded: every receive takes a timeout, so a role can notice shutdown or a
//! vanished peer.

pub mod conformance;
pub mod in_process;
pub mod links;
pub mod messages;
pub mod traits;

pub use links::{ActorLinks, LearnerLinks, OptimizerLinks};
pub use messages::{
    Assignment, DesignKind, DesignReply, DesignRequest, EpisodeEnd, EpisodeMode, ExperienceChunk, MessageError, Validate, Weights,
};
pub use traits::{Publisher, Receiver, Sender, Subscriber, TransportError, newest_or_stop, next_or_stop};
