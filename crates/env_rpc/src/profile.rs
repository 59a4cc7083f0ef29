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

    /// Reads a server's specs: the four observations and the action by name (any uids), fixed
    /// one-dimensional float shapes, a bounded action.
    pub fn from_specs(specs: &ActionObservationSpecs) -> Result<(Profile, Uids), ProfileError> {
        let find = |map: &std::collections::HashMap<u64, TensorSpec>, name: &'static str, what: &'static str| {
            map.iter().find(|(_, s)| s.name == name).map(|(&uid, s)| (uid, s.clone())).ok_or(ProfileError::Missing { what, name })
        };
        let (action_uid, action) = find(&specs.actions, "action", "action")?;
        let (obs_uid, obs) = find(&specs.observations, "observation", "observation")?;
        let (reward_uid, reward) = find(&specs.observations, "reward", "observation")?;
        let (discount_uid, discount) = find(&specs.observations, "discount", "observation")?;
        let (design_uid, design) = find(&specs.observations, "design", "observation")?;
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
        let d = vector(&design)?;
        let design = match d.bounds {
            Some((lo, hi)) => BoxSpace::new(lo, hi).map_err(|e| ProfileError::Box { name: "design", why: e.to_string() })?,
            None if d.dims[0] == 0 => BoxSpace::uniform(0, 0.0, 0.0),
            None => return Err(ProfileError::Unbounded("design")),
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
    pub design: u64,
}

/// A server's specs do not follow the coadapt profile.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ProfileError {
    #[error("the server's specs have no {what} named `{name}` (see the coadapt profile in proto/README.md)")]
    Missing { what: &'static str, name: &'static str },
    #[error(transparent)]
    Tensor(#[from] TensorError),
    #[error("spec `{name}` has shape {dims:?}, {want} expected")]
    Shape { name: String, dims: Vec<usize>, want: &'static str },
    #[error("spec `{0}` has no bounds; the profile needs its box")]
    Unbounded(&'static str),
    #[error("spec `{name}`: {why}")]
    Box { name: &'static str, why: String },
}
