//! The coadapt profile of dm_env_rpc (proto/README.md): which tensors and settings carry the
//! action, the state, the reward, the discount and the design, and how a spec says so.

use coadapt_core::BoxSpace;
use coadapt_wire::dm_env_rpc::v1::{ActionObservationSpecs, TensorSpec};
use coadapt_wire::tensor::{self, TensorError};

/// Action `action`.
pub const ACTION: u64 = 1;
/// Observation `observation`: the robot's state (the client appends the design).
pub const OBSERVATION: u64 = 1;
/// Observation `reward`: the reward of the step that led here.
pub const REWARD: u64 = 2;
/// Observation `discount`: 0 at a true end only.
pub const DISCOUNT: u64 = 3;
/// Observation `design`: the body in use; its spec's bounds are the design box.
pub const DESIGN: u64 = 4;
/// Every observation uid, in the order a client requests them.
pub const ALL_OBSERVATIONS: [u64; 4] = [OBSERVATION, REWARD, DISCOUNT, DESIGN];

/// World settings (CreateWorld, ResetWorld).
pub const SETTING_DESIGN: &str = "design";
pub const SETTING_SEED: &str = "seed";

/// What a coadapt environment publishes: state width, action box and design box.
#[derive(Clone, Debug, PartialEq)]
pub struct Profile {
    pub state_dim: usize,
    pub action: BoxSpace,
    pub design: BoxSpace,
}

impl Profile {
    /// The specs a server sends on JoinWorld and Reset.
    pub fn specs(&self) -> ActionObservationSpecs {
        let (a_lo, a_hi) = (&self.action.low[..], &self.action.high[..]);
        let (d_lo, d_hi) = (&self.design.low[..], &self.design.high[..]);
        let design_bounds = if self.design.dim() > 0 { Some((d_lo, d_hi)) } else { None };
        ActionObservationSpecs {
            actions: [(ACTION, tensor::float_spec("action", &[self.action.dim()], Some((a_lo, a_hi))))].into(),
            observations: [
                (OBSERVATION, tensor::float_spec("observation", &[self.state_dim], None)),
                (REWARD, tensor::float_spec("reward", &[], None)),
                (DISCOUNT, tensor::float_spec("discount", &[], Some((&[0.0], &[1.0])))),
                (DESIGN, tensor::float_spec("design", &[self.design.dim()], design_bounds)),
            ]
            .into(),
        }
    }

    /// Reads a server's specs: the action, and the observations `observation`, `reward` and
    /// `discount` by name (any uids), fixed one-dimensional float shapes, a bounded action. The
    /// `design` observation is optional: a server without one (any dm_env_rpc server not
    /// written for coadapt) is a fixed-design environment of design dimension 0, reset with
    /// `Reset` and no settings ([`Uids::coadapt`] says which kind). A server with one action
    /// of another name than `action`, or one float observation of another name than
    /// `observation` beside `reward` and `discount`, is read by that one.
    pub fn from_specs(specs: &ActionObservationSpecs) -> Result<(Profile, Uids), ProfileError> {
        let names = |map: &std::collections::HashMap<u64, TensorSpec>| {
            let mut n: Vec<String> = map.values().map(|s| format!("`{}`", s.name)).collect();
            n.sort();
            if n.is_empty() { "none".to_string() } else { n.join(", ") }
        };
        let find = |map: &std::collections::HashMap<u64, TensorSpec>, name: &'static str, what: &'static str| {
            map.iter().find(|(_, s)| s.name == name).map(|(&uid, s)| (uid, s.clone())).ok_or_else(|| ProfileError::Missing {
                what,
                name,
                has: names(map),
            })
        };
        // By name, else the only candidate.
        let find_or_only = |map: &std::collections::HashMap<u64, TensorSpec>, name: &'static str, what: &'static str, others: &[&str]| {
            find(map, name, what).or_else(|e| {
                let mut rest = map.iter().filter(|(_, s)| !others.contains(&s.name.as_str()));
                match (rest.next(), rest.next()) {
                    (Some((&uid, s)), None) => Ok((uid, s.clone())),
                    _ => Err(e),
                }
            })
        };
        let (action_uid, action) = find_or_only(&specs.actions, "action", "action", &[])?;
        let (reward_uid, reward) = find(&specs.observations, "reward", "observation")?;
        let (discount_uid, discount) = find(&specs.observations, "discount", "observation")?;
        let design = find(&specs.observations, "design", "observation").ok();
        let (obs_uid, obs) = find_or_only(&specs.observations, "observation", "observation", &["reward", "discount", "design"])?;
        let vector = |s: &TensorSpec| -> Result<tensor::FloatSpec, ProfileError> {
            let f = tensor::read_float_spec(s)?;
            if f.dims.len() != 1 {
                return Err(ProfileError::Shape { name: s.name.clone(), dims: f.dims, want: "one dimension" });
            }
            Ok(f)
        };
        for s in [&reward, &discount] {
            let f = tensor::read_float_spec(s)?;
            if f.dims.iter().product::<usize>() != 1 {
                return Err(ProfileError::Shape { name: s.name.clone(), dims: f.dims, want: "a scalar" });
            }
        }
        let a = vector(&action)?;
        let Some((lo, hi)) = a.bounds else { return Err(ProfileError::Unbounded("action")) };
        if let Some(i) = lo.iter().zip(&hi).position(|(l, h)| l >= h) {
            return Err(ProfileError::Box { name: "action", why: format!("min[{i}] {} is not below max[{i}] {}", lo[i], hi[i]) });
        }
        let action = BoxSpace::new(lo, hi).map_err(|e| ProfileError::Box { name: "action", why: e.to_string() })?;
        let s = vector(&obs)?;
        let (design_uid, design) = match design {
            None => (None, BoxSpace::uniform(0, 0.0, 0.0)),
            Some((uid, d)) => {
                let d = vector(&d)?;
                let b = match d.bounds {
                    Some((lo, hi)) => BoxSpace::new(lo, hi).map_err(|e| ProfileError::Box { name: "design", why: e.to_string() })?,
                    None if d.dims[0] == 0 => BoxSpace::uniform(0, 0.0, 0.0),
                    None => return Err(ProfileError::Unbounded("design")),
                };
                (Some(uid), b)
            }
        };
        let uids = Uids { action: action_uid, observation: obs_uid, reward: reward_uid, discount: discount_uid, design: design_uid };
        Ok((Profile { state_dim: s.dims[0], action, design }, uids))
    }
}

/// The uids a server chose for the profile's tensors.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Uids {
    pub action: u64,
    pub observation: u64,
    pub reward: u64,
    pub discount: u64,
    /// `None`: a server without a `design` observation (not a coadapt environment).
    pub design: Option<u64>,
}

impl Uids {
    /// The server speaks the coadapt profile (it has a `design` observation and takes the
    /// `design` and `seed` settings on ResetWorld); else it is a plain dm_env_rpc server.
    pub fn coadapt(&self) -> bool {
        self.design.is_some()
    }
}

/// A server's specs do not follow the coadapt profile.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ProfileError {
    #[error("the server's specs have no {what} named `{name}` (its {what}s: {has}; see the coadapt profile in proto/README.md)")]
    Missing { what: &'static str, name: &'static str, has: String },
    #[error(transparent)]
    Tensor(#[from] TensorError),
    #[error("spec `{name}` has shape {dims:?}, {want} expected")]
    Shape { name: String, dims: Vec<usize>, want: &'static str },
    #[error("spec `{0}` has no bounds; the profile needs its box")]
    Unbounded(&'static str),
    #[error("spec `{name}`: {why}")]
    Box { name: &'static str, why: String },
}
