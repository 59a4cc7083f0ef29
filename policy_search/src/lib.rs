//! Episodic policy search from few rollouts (thesis ch. 2 and 3): policies linear in time
//! features, whose exploration is a perturbation of their parameters drawn once per rollout or
//! per step, updated by expectation-maximisation on reward-weighted rollouts.
//!
//! # Layout
//! - `features`: normalised Gaussian RBF features of time, [`TimeFeatures`] (the thesis's 11
//!   features of width 3 for 25 steps, 8 for 15).
//! - `planar`: the bimanual planar reaching benchmark of ch. 2.4.1 as an episodic task
//!   ([`PlanarReaching`], whose kinematics live in `coadapt_robots::bimanual`): two
//!   planar 6-joint arms on a shared base, 12 joint angles per step, 25 steps, reward Eq. 2.31
//!   and the summed end-effector distance the thesis plots. The text leaves the arms and the goal
//!   paths open; the choices are documented there and fixed.
//! - `policy`: [`LinearPolicy`], actions `a_t = M phi_t` (M is `actions x features`), and
//!   [`Rollout`], one rollout's parameters, actions and return.
//! - `power`: PoWER (Kober and Peters), the EM baseline with exploration in the full parameter
//!   space and a static variance, best-k selection as in the thesis.
//! - `groups`: GrouPS (Alg. 1; the synergy prior W-hat of Alg. 2; Gamma or log-linear alpha),
//!   the variational updates in the order M, W, z, alpha, tau; without priors, PePPER;
//!   `linalg`: the small dense algebra.
//!
//! - `alpha`: the log-linear model of alpha (ch. 3) fitted by `lbfgs`, a small L-BFGS.
//! - `nac`: the episodic Natural Actor-Critic (eNAC), the gradient baseline: per-step Gaussian
//!   exploration, the natural gradient from a linear fit of the returns, [`Nac`].
//!
//! - `fleet`: rollouts through a fleet of actors over the co-adaptation's transports:
//!   [`FleetRunner`] (the learner's side, a [`RolloutRunner`]), [`run_actor`], and
//!   [`PlanarEnv`] (from `coadapt_robots::bimanual`), the planar benchmark as a robot an actor
//!   steps.
//! - [`app`]: `coadapt search` and `coadapt search-actor` as a library: the config, the runs
//!   and their run directory, the rollouts on actors started here, the plots; [`app::run`] and
//!   [`app::actor`] take the binary's shutdown flag.

mod alpha;
pub mod app;
mod features;
mod fleet;
mod groups;
mod lbfgs;
mod linalg;
mod nac;
mod planar;
mod policy;
mod power;

pub use alpha::LogLinearAlpha;
pub use coadapt_robots::bimanual::PlanarEnv;
pub use features::TimeFeatures;
pub use fleet::{FleetRunner, run_actor};
pub use groups::{Groups, GroupsConfig, GroupsError, Sample};
pub use nac::{Nac, NacConfig, NacConfigError, natural_gradient};
pub use planar::{ArmGeometry, PlanarReaching};
pub use policy::{LinearPolicy, Rollout};
pub use power::{Power, PowerConfig};

/// What an episodic task gives back for one rollout's actions.
pub trait EpisodicTask {
    /// Steps per rollout.
    fn steps(&self) -> usize;
    /// Action dimensions per step.
    fn action_dim(&self) -> usize;
    /// The return of `actions` (`steps x action_dim`, row-major), non-negative (the EM
    /// updates weigh rollouts by it), and the task's cost metric (lower is better).
    fn evaluate(&self, actions: &[f32]) -> (f64, f64);
}

/// Why an iteration's rollouts could not be run (a fleet gone, a deadline passed).
#[derive(Debug, thiserror::Error)]
#[error("running rollouts: {0}")]
pub struct RolloutError(pub String);

/// A fleet that failed may come back: a restart may mend it.
impl coadapt_fleet::supervise::exit::ExitCode for RolloutError {}

/// What runs an iteration's rollouts: every rollout's actions (`steps x action_dim`) at once,
/// so a fleet of actors can run them side by side; gives back each one's (return, cost) in
/// order. Every [`EpisodicTask`] runs them one after the other in process.
pub trait RolloutRunner {
    fn run(&self, rollouts: &[Vec<f32>]) -> Result<Vec<(f64, f64)>, RolloutError>;
}

/// `task.run`, checked to give one result per rollout.
pub(crate) fn run_all(task: &dyn RolloutRunner, rollouts: &[Vec<f32>]) -> Result<Vec<(f64, f64)>, RolloutError> {
    let got = task.run(rollouts)?;
    if got.len() != rollouts.len() {
        return Err(RolloutError(format!("{} results for {} rollouts", got.len(), rollouts.len())));
    }
    Ok(got)
}

impl<T: EpisodicTask + ?Sized> RolloutRunner for T {
    fn run(&self, rollouts: &[Vec<f32>]) -> Result<Vec<(f64, f64)>, RolloutError> {
        Ok(rollouts.iter().map(|a| self.evaluate(a)).collect())
    }
}
