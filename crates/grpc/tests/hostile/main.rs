//! Hostile and broken peers: raw tonic clients (built from the generated types, not our client)
//! that take others' work, invent sessions, poison sequence numbers, flood the learner's queue,
//! keep episodes alive with empty chunks, or lie about episode lengths. Each test names the
//! attack it stops.
//!
//! # Layout
//! - `support.rs`: raw peers on connections of their own, frames, chunks, and how a refusal reads;
//! - `attacks.rs`: attacks 1-10 on sessions, senders, queues and episode lengths (and one crash);
//! - `honest.rs`: what our own clients do passes every check, and survives a restarted learner;
//! - `connections.rs`: attack 13, connections per peer and in all.

mod attacks;
mod connections;
mod honest;
mod support;
