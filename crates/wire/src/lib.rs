//! coadapt's wire schema: the prost types of `proto/coadapt/v1` and their conversions to the
//! domain messages of `coadapt-transport`.
//!
//! # Layout
//! - [`pb`]: the generated messages, clients and servers (package `coadapt.v1`).
//! - [`Wire`]: encode a domain message to bytes and decode bytes back, validating on the way
//!   in: lengths that fit the declared rows, finite floats, sizes within [`Limits`]. Shared
//!   memory and gRPC carry the same bytes, so there is one schema and one set of checks.
//! - [`WireError`]: names the offending field; it becomes `Status::invalid_argument` at a gRPC
//!   edge.
//!
//! - [`dm_env_rpc`], [`google`]: the generated code of DeepMind's dm_env_rpc v1 (package
//!   `dm_env_rpc.v1`) and of `google.rpc.Status`, which it carries errors in.
//! - [`tensor`]: dm_env_rpc tensors and specs to and from f32 vectors, validating shape, type,
//!   broadcast and finiteness, naming the tensor.
//!
//! Dimension checks against the receiver's robot (obs, action and design widths) happen after
//! decoding, with [`coadapt_transport::Validate`].

use bytes::{Buf, Bytes};
use coadapt_transport::messages::{Assignment, DesignKind, DesignReply, DesignRequest, EpisodeEnd, EpisodeMode, ExperienceChunk, Weights};
use prost::Message;

/// The generated code of package `coadapt.v1`.
#[allow(clippy::all, missing_debug_implementations)]
pub mod pb {
    tonic::include_proto!("coadapt.v1");
}

/// dm_env_rpc v1, DeepMind's protocol for environments (`proto/dm_env_rpc/v1`).
#[allow(clippy::all, missing_debug_implementations)]
pub mod dm_env_rpc {
    pub mod v1 {
        tonic::include_proto!("dm_env_rpc.v1");
    }
}

/// `google.rpc.Status`, the error inside a dm_env_rpc stream.
#[allow(clippy::all, missing_debug_implementations)]
pub mod google {
    pub mod rpc {
        tonic::include_proto!("google.rpc");
    }
}

/// TensorBoard's event-file schema, as much as coadapt writes (`proto/tensorboard/`).
#[allow(clippy::all, missing_debug_implementations)]
pub mod tensorboard {
    tonic::include_proto!("tensorboard");
}

/// The Open Inference Protocol (KServe v2), package `inference` (`proto/inference`).
#[allow(clippy::all, missing_debug_implementations)]
pub mod inference {
    tonic::include_proto!("inference");
}

pub mod tensor;

/// The encoded file descriptors of every coadapt service, for gRPC reflection.
pub const FILE_DESCRIPTOR_SET: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/coadapt_descriptor.bin"));

/// The encoded file descriptor of the Open Inference Protocol, for gRPC reflection.
pub const INFERENCE_DESCRIPTOR_SET: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/inference_descriptor.bin"));

/// A message that could not be accepted.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{field}: {why}")]
pub struct WireError {
    pub field: &'static str,
    pub why: String,
}

fn err(field: &'static str, why: impl Into<String>) -> WireError {
    WireError { field, why: why.into() }
}

impl From<WireError> for tonic::Status {
    fn from(e: WireError) -> Self {
        tonic::Status::invalid_argument(e.to_string())
    }
}

/// Size limits a receiver enforces before it allocates.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    /// Largest encoded message (bytes); weight messages are the large ones.
    pub max_message_bytes: usize,
}

impl Default for Limits {
    fn default() -> Self {
        // A 3 x 1024 policy and two critics on a 50-wide observation take about 26 MiB.
        Self { max_message_bytes: 64 << 20 }
    }
}

/// f32 values as little-endian bytes.
pub fn f32_bytes(v: &[f32]) -> Bytes {
    let mut out = Vec::with_capacity(v.len() * 4);
    for x in v {
        out.extend_from_slice(&x.to_le_bytes());
    }
    out.into()
}

/// Little-endian bytes as f32 values, refusing a ragged length or a non-finite value.
pub fn f32s(field: &'static str, b: &[u8]) -> Result<Vec<f32>, WireError> {
    if !b.len().is_multiple_of(4) {
        return Err(err(field, format!("{} bytes is not a whole number of f32 values", b.len())));
    }
    let mut out = Vec::with_capacity(b.len() / 4);
    for (i, c) in b.chunks_exact(4).enumerate() {
        let x = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
        if !x.is_finite() {
            return Err(err(field, format!("value {i} is {x}")));
        }
        out.push(x);
    }
    Ok(out)
}

fn finite(field: &'static str, v: Vec<f32>) -> Result<Vec<f32>, WireError> {
    match v.iter().position(|x| !x.is_finite()) {
        Some(i) => Err(err(field, format!("value {i} is {}", v[i]))),
        None => Ok(v),
    }
}

fn rows_of(field: &'static str, v: &[f32], rows: usize) -> Result<(), WireError> {
    if rows == 0 && v.is_empty() || rows > 0 && v.len().is_multiple_of(rows) {
        Ok(())
    } else {
        Err(err(field, format!("{} values do not make {rows} equal rows", v.len())))
    }
}

/// A domain message with a byte encoding that validates on decode.
pub trait Wire: Sized {
    type Pb: Message + Default;
    fn to_pb(&self) -> Self::Pb;
    fn from_pb(pb: Self::Pb) -> Result<Self, WireError>;

    fn encode(&self) -> Vec<u8> {
        self.to_pb().encode_to_vec()
    }

    /// Decodes and validates bytes from an untrusted peer.
    fn decode(bytes: impl Buf, limits: &Limits) -> Result<Self, WireError> {
        if bytes.remaining() > limits.max_message_bytes {
            return Err(err("message", format!("{} bytes exceeds the limit of {}", bytes.remaining(), limits.max_message_bytes)));
        }
        let pb = Self::Pb::decode(bytes).map_err(|e| err("message", format!("not a valid encoding: {e}")))?;
        Self::from_pb(pb)
    }
}

impl Wire for Weights {
    type Pb = pb::Weights;

    fn to_pb(&self) -> pb::Weights {
        pb::Weights {
            version: self.version,
            policy: f32_bytes(&self.policy),
            q1: f32_bytes(&self.q1),
            q2: f32_bytes(&self.q2),
            heads: self.heads.iter().map(|h| f32_bytes(h)).collect(),
        }
    }

    fn from_pb(pb: pb::Weights) -> Result<Self, WireError> {
        let w = Weights {
            version: pb.version,
            policy: f32s("policy", &pb.policy)?,
            q1: f32s("q1", &pb.q1)?,
            q2: f32s("q2", &pb.q2)?,
            heads: pb.heads.iter().map(|h| f32s("heads", h)).collect::<Result<_, _>>()?,
        };
        if w.policy.is_empty() {
            return Err(err("policy", "no values"));
        }
        if w.q1.len() != w.q2.len() {
            return Err(err("q2", format!("{} values but q1 has {}", w.q2.len(), w.q1.len())));
        }
        if let Some(i) = w.heads.iter().position(|h| h.len() != w.q1.len()) {
            return Err(err("heads", format!("head {} has {} values but q1 has {}", i + 1, w.heads[i].len(), w.q1.len())));
        }
        Ok(w)
    }
}

impl Wire for Assignment {
    type Pb = pb::Assignment;

    fn to_pb(&self) -> pb::Assignment {
        pb::Assignment {
            id: self.id,
            design_index: self.design_index,
            design: self.design.clone(),
            mode: match self.mode {
                EpisodeMode::Train => pb::EpisodeMode::Train,
                EpisodeMode::Eval => pb::EpisodeMode::Eval,
            } as i32,
            seed: self.seed,
            min_weights_version: self.min_weights_version,
        }
    }

    fn from_pb(pb: pb::Assignment) -> Result<Self, WireError> {
        let mode = match pb::EpisodeMode::try_from(pb.mode) {
            Ok(pb::EpisodeMode::Train) => EpisodeMode::Train,
            Ok(pb::EpisodeMode::Eval) => EpisodeMode::Eval,
            _ => return Err(err("mode", format!("{} is not train (1) or eval (2)", pb.mode))),
        };
        Ok(Assignment {
            id: pb.id,
            design_index: pb.design_index,
            design: finite("design", pb.design)?,
            mode,
            seed: pb.seed,
            min_weights_version: pb.min_weights_version,
        })
    }
}

impl Wire for ExperienceChunk {
    type Pb = pb::ExperienceChunk;

    fn to_pb(&self) -> pb::ExperienceChunk {
        pb::ExperienceChunk {
            actor: self.actor,
            assignment: self.assignment,
            design_index: self.design_index,
            weights_version: self.weights_version,
            first: self.first,
            rows: self.rewards.len() as u32,
            obs: f32_bytes(&self.obs),
            actions: f32_bytes(&self.actions),
            rewards: f32_bytes(&self.rewards),
            next_obs: f32_bytes(&self.next_obs),
            terminated: self.terminated.iter().map(|&t| u8::from(t)).collect::<Vec<u8>>().into(),
            end: self.end.map(|e| pb::EpisodeEnd { episode_return: e.episode_return, length: e.length }),
        }
    }

    fn from_pb(pb: pb::ExperienceChunk) -> Result<Self, WireError> {
        let rows = pb.rows as usize;
        let rewards = f32s("rewards", &pb.rewards)?;
        if rewards.len() != rows {
            return Err(err("rewards", format!("{} values for {rows} rows", rewards.len())));
        }
        let obs = f32s("obs", &pb.obs)?;
        let actions = f32s("actions", &pb.actions)?;
        let next_obs = f32s("next_obs", &pb.next_obs)?;
        rows_of("obs", &obs, rows)?;
        rows_of("actions", &actions, rows)?;
        if next_obs.len() != obs.len() {
            return Err(err("next_obs", format!("{} values but obs has {}", next_obs.len(), obs.len())));
        }
        if pb.terminated.len() != rows {
            return Err(err("terminated", format!("{} flags for {rows} rows", pb.terminated.len())));
        }
        let terminated = pb
            .terminated
            .iter()
            .map(|&b| match b {
                0 => Ok(false),
                1 => Ok(true),
                other => Err(err("terminated", format!("flag {other} is not 0 or 1"))),
            })
            .collect::<Result<Vec<bool>, _>>()?;
        let end = match pb.end {
            Some(e) if !e.episode_return.is_finite() => return Err(err("end.episode_return", format!("{}", e.episode_return))),
            Some(e) => Some(EpisodeEnd { episode_return: e.episode_return, length: e.length }),
            None => None,
        };
        if pb.first && rows == 0 {
            return Err(err("first", "a first chunk needs the start state"));
        }
        Ok(ExperienceChunk {
            actor: pb.actor,
            assignment: pb.assignment,
            design_index: pb.design_index,
            weights_version: pb.weights_version,
            first: pb.first,
            obs,
            actions,
            rewards,
            next_obs,
            terminated,
            end,
        })
    }
}

impl Wire for DesignRequest {
    type Pb = pb::DesignRequest;

    fn to_pb(&self) -> pb::DesignRequest {
        pb::DesignRequest {
            index: self.index,
            kind: match self.kind {
                DesignKind::Exploit => pb::DesignKind::Exploit,
                DesignKind::Explore => pb::DesignKind::Explore,
            } as i32,
            weights_version: self.weights_version,
            start_states: f32_bytes(&self.start_states),
            chosen: self.chosen.clone(),
            rejected: self.rejected.clone(),
        }
    }

    fn from_pb(pb: pb::DesignRequest) -> Result<Self, WireError> {
        let kind = match pb::DesignKind::try_from(pb.kind) {
            Ok(pb::DesignKind::Exploit) => DesignKind::Exploit,
            Ok(pb::DesignKind::Explore) => DesignKind::Explore,
            _ => return Err(err("kind", format!("{} is not exploit (1) or explore (2)", pb.kind))),
        };
        Ok(DesignRequest {
            index: pb.index,
            kind,
            weights_version: pb.weights_version,
            start_states: f32s("start_states", &pb.start_states)?,
            chosen: finite("chosen", pb.chosen)?,
            rejected: finite("rejected", pb.rejected)?,
        })
    }
}

impl Wire for DesignReply {
    type Pb = pb::DesignReply;

    fn to_pb(&self) -> pb::DesignReply {
        pb::DesignReply {
            index: self.index,
            design: self.design.clone(),
            method: self.method.clone(),
            predicted_objective: self.predicted_objective,
            design_rollouts: self.design_rollouts,
        }
    }

    fn from_pb(pb: pb::DesignReply) -> Result<Self, WireError> {
        if pb.method.len() > 256 {
            return Err(err("method", format!("{} bytes; at most 256", pb.method.len())));
        }
        if let Some(p) = pb.predicted_objective
            && !p.is_finite()
        {
            return Err(err("predicted_objective", format!("{p}")));
        }
        Ok(DesignReply {
            index: pb.index,
            design: finite("design", pb.design)?,
            method: pb.method,
            predicted_objective: pb.predicted_objective,
            design_rollouts: pb.design_rollouts,
        })
    }
}
