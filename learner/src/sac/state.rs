//! Saving and restoring a [`Sac`]: its networks as safetensors (`save`, `load`: what a
//! checkpoint and `--init-population` read) and everything that decides its future for a
//! snapshot (`save_state`, `load_state`).

use std::path::Path;

use coadapt_nn::{Mlp, NamedNetwork, NnError};
use serde::{Deserialize, Serialize};

use coadapt_core::Rng64;

use super::Sac;
use crate::snapshot::{SnapshotError, StateIn, StateOut};

/// The scalars of [`Sac::save_state`].
#[derive(Serialize, Deserialize)]
struct SacScalars {
    log_alpha: f32,
    adam_steps: [u32; 4],
    updates: u64,
    #[serde(with = "crate::snapshot::bits::rng")]
    rng: Rng64,
    /// Adam steps of each ensemble head (absent without heads, and in older snapshots).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    head_steps: Vec<u32>,
    /// The conservative term's log lambda under dual ascent (absent while the term is off, and
    /// in older snapshots).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    conservative_log_weight: Option<f32>,
}

impl Sac {
    /// Saves the policy, critics and targets as one safetensors file (`policy`, `q1`, `q2`,
    /// `q1_target`, `q2_target`, and `head1`... for ensemble heads).
    pub fn save(&self, path: &Path) -> Result<(), NnError> {
        let [c1, c2] = &self.critics;
        let names: Vec<String> = (1..=self.heads.len()).map(|i| format!("head{i}")).collect();
        let mut nets = vec![
            ("policy", &self.policy, self.phi.as_slice()),
            ("q1", &self.critic, c1.theta.as_slice()),
            ("q2", &self.critic, c2.theta.as_slice()),
            ("q1_target", &self.critic, c1.theta_bar.as_slice()),
            ("q2_target", &self.critic, c2.theta_bar.as_slice()),
        ];
        nets.extend(names.iter().zip(&self.heads).map(|(name, h)| (name.as_str(), &self.critic, h.theta.as_slice())));
        coadapt_nn::save_networks(path, &nets)
    }

    /// Loads networks saved by [`Sac::save`]; the shapes must match this agent's.
    pub fn load(&mut self, path: &Path) -> Result<(), NnError> {
        let nets = coadapt_nn::load_networks(path)?;
        let get = |name: &str, mlp: &Mlp| NamedNetwork::find(&nets, path, name, mlp.sizes()).map(|n| n.params.clone());
        let phi = get("policy", &self.policy)?;
        let q = [get("q1", &self.critic)?, get("q2", &self.critic)?];
        let q_bar = [get("q1_target", &self.critic)?, get("q2_target", &self.critic)?];
        self.set_params(&phi, [&q[0], &q[1]], [&q_bar[0], &q_bar[1]]);
        // Heads the file has; a file without them (a run without heads) leaves ours as they are.
        for (i, h) in self.heads.iter_mut().enumerate() {
            let name = format!("head{}", i + 1);
            if nets.iter().any(|n| n.name == name) {
                let theta = get(&name, &self.critic)?;
                h.theta.copy_from_slice(&theta);
            }
        }
        Ok(())
    }

    /// Writes everything that decides this agent's future (networks, targets, every Adam state,
    /// log alpha, the generator, the update count) under `prefix`.
    pub fn save_state(&self, prefix: &str, out: &mut StateOut) -> std::io::Result<()> {
        let (m, v) = self.phi_adam.moments();
        out.f32s(&format!("{prefix}.policy"), &self.phi)?;
        out.f32s(&format!("{prefix}.policy.adam.m"), m)?;
        out.f32s(&format!("{prefix}.policy.adam.v"), v)?;
        for (i, c) in self.critics.iter().enumerate() {
            let (m, v) = c.adam.moments();
            out.f32s(&format!("{prefix}.q{}", i + 1), &c.theta)?;
            out.f32s(&format!("{prefix}.q{}.target", i + 1), &c.theta_bar)?;
            out.f32s(&format!("{prefix}.q{}.adam.m", i + 1), m)?;
            out.f32s(&format!("{prefix}.q{}.adam.v", i + 1), v)?;
        }
        for (i, h) in self.heads.iter().enumerate() {
            let (m, v) = h.adam.moments();
            out.f32s(&format!("{prefix}.head{}", i + 1), &h.theta)?;
            out.f32s(&format!("{prefix}.head{}.adam.m", i + 1), m)?;
            out.f32s(&format!("{prefix}.head{}.adam.v", i + 1), v)?;
        }
        let (m, v) = self.alpha_adam.moments();
        out.f32s(&format!("{prefix}.log_alpha.adam.m"), m)?;
        out.f32s(&format!("{prefix}.log_alpha.adam.v"), v)?;
        out.put(
            prefix,
            &SacScalars {
                log_alpha: self.log_alpha,
                adam_steps: self.optimiser_steps(),
                updates: self.updates,
                rng: self.rng.clone(),
                head_steps: self.heads.iter().map(|h| h.adam.steps()).collect(),
                conservative_log_weight: self.conservative.as_ref().map(|c| c.log_weight),
            },
        )
    }

    /// Restores what [`Self::save_state`] wrote; the shapes must be this agent's.
    pub fn load_state(&mut self, prefix: &str, inp: &mut StateIn) -> Result<(), SnapshotError> {
        let mismatch = |e: String| SnapshotError::Mismatch(format!("{prefix}: {e}"));
        let s: SacScalars = inp.get(prefix)?;
        let (np, nc) = (self.phi.len(), self.critics[0].theta.len());
        self.phi = inp.f32s(&format!("{prefix}.policy"), np)?;
        let (m, v) = (inp.f32s(&format!("{prefix}.policy.adam.m"), np)?, inp.f32s(&format!("{prefix}.policy.adam.v"), np)?);
        self.phi_adam.restore(&m, &v, s.adam_steps[0]).map_err(|e| mismatch(e.to_string()))?;
        for i in 0..2 {
            let theta = inp.f32s(&format!("{prefix}.q{}", i + 1), nc)?;
            let theta_bar = inp.f32s(&format!("{prefix}.q{}.target", i + 1), nc)?;
            let m = inp.f32s(&format!("{prefix}.q{}.adam.m", i + 1), nc)?;
            let v = inp.f32s(&format!("{prefix}.q{}.adam.v", i + 1), nc)?;
            let c = &mut self.critics[i];
            c.adam.restore(&m, &v, s.adam_steps[1 + i]).map_err(|e| mismatch(e.to_string()))?;
            (c.theta, c.theta_bar) = (theta, theta_bar);
        }
        if s.head_steps.len() != self.heads.len() {
            return Err(mismatch(format!(
                "the snapshot has {} ensemble heads beside the twin critics, this run's settings {} (learner.population-critics)",
                s.head_steps.len(),
                self.heads.len()
            )));
        }
        for (i, h) in self.heads.iter_mut().enumerate() {
            let theta = inp.f32s(&format!("{prefix}.head{}", i + 1), nc)?;
            let m = inp.f32s(&format!("{prefix}.head{}.adam.m", i + 1), nc)?;
            let v = inp.f32s(&format!("{prefix}.head{}.adam.v", i + 1), nc)?;
            h.adam.restore(&m, &v, s.head_steps[i]).map_err(|e| mismatch(e.to_string()))?;
            h.theta = theta;
        }
        let (m, v) = (inp.f32s(&format!("{prefix}.log_alpha.adam.m"), 1)?, inp.f32s(&format!("{prefix}.log_alpha.adam.v"), 1)?);
        self.alpha_adam.restore(&m, &v, s.adam_steps[3]).map_err(|e| mismatch(e.to_string()))?;
        if !s.log_alpha.is_finite() {
            return Err(mismatch(format!("log alpha {} is not finite", s.log_alpha)));
        }
        self.log_alpha = s.log_alpha;
        // The term's weight goes on where it was (a snapshot from before the term, or of a run
        // without it, leaves the weight this run's settings start from).
        if let (Some(c), Some(saved)) = (self.conservative.as_mut(), s.conservative_log_weight) {
            if !saved.is_finite() {
                return Err(mismatch(format!("the conservative term's log weight {saved} is not finite")));
            }
            c.log_weight = saved;
        }
        self.updates = s.updates;
        self.rng = s.rng;
        Ok(())
    }
}
