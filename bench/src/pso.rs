//! `coadapt bench pso`: one full PSO over the design objective (700 particles x 250 iterations
//! x 32 start states, 3 x 256 networks) timed, with the GFLOP/s reached.

use std::time::Instant;

use coadapt_core::rng;
use coadapt_design_optimizer::{CriticObjective, DesignObjective, PsoConfig, QMode, pso};
use coadapt_learner::{Sac, SacConfig};
use coadapt_nn::Precision;
use rand::Rng;

use crate::figure::emit;
use coadapt_fleet::app::AppError;

#[derive(Debug, Clone)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct PsoOptions {
    /// Start states per design (32 is the reference; 256 the landscape plots').
    #[cfg_attr(feature = "clap", arg(long, value_delimiter = ',', default_values_t = vec![32usize]))]
    pub states: Vec<usize>,
    /// PSO iterations (250 is the reference).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 250))]
    pub iterations: usize,
    /// The design objective: q1 (the reference: one critic), or pessimistic (the twin critics'
    /// mean minus 2 standard deviations: two critic passes per row).
    #[cfg_attr(feature = "clap", arg(long, default_value = "q1", value_parser = ["q1", "pessimistic"]))]
    pub q: String,
    /// The objective's products: f32, or bf16 (`learner.sac.precision`: the networks' precision,
    /// which the objective inherits; the figure's config name ends in `-bf16`).
    #[cfg_attr(feature = "clap", arg(long, default_value = "f32"))]
    pub precision: Precision,
}

pub fn run(a: &PsoOptions) -> Result<(), AppError> {
    let (obs, act, design) = (23, 6, 6);
    let sac = Sac::new(obs, act, SacConfig { hidden: vec![256; 3], precision: a.precision, ..SacConfig::default() }, 3)?;
    let bounds = coadapt_core::BoxSpace::uniform(design, 0.8, 2.0);
    for &n_states in &a.states {
        let mut r = rng(5, 0);
        let start: Vec<f32> = (0..n_states * obs).map(|_| r.random_range(-1.0..1.0)).collect();
        let ((q1, _), (q2, _)) = (sac.critic_params(0), sac.critic_params(1));
        let (critics, mode) = if a.q == "pessimistic" { (vec![q1, q2], QMode::MeanMinusKStd(2.0)) } else { (vec![q1], QMode::First) };
        let f = DesignObjective::new(sac.policy(), sac.policy_params(), sac.critic(), &critics, &start, obs - design, design)
            .map_err(AppError::library)?;
        let mut objective = CriticObjective::new(&f, mode, rayon::current_num_threads());
        let cfg = PsoConfig { iterations: a.iterations, ..PsoConfig::default() };
        let t = Instant::now();
        let result = pso::maximise(&mut objective, &bounds, &cfg, 1).map_err(AppError::library)?;
        let secs = t.elapsed().as_secs_f64();
        let suffix = if a.q == "pessimistic" { "-pessimistic" } else { "" };
        let precision = if a.precision == Precision::Bf16 { "-bf16" } else { "" };
        let config = format!("{}x{}x{n_states}{suffix}{precision}", cfg.particles, cfg.iterations);
        emit("pso_over_q", &config, secs, "s");
        let rows = result.evaluations as f64 * n_states as f64;
        if suffix.is_empty() {
            // (flops_per_row counts one critic: no GFLOP/s figure for the two-critic objective)
            emit("pso_over_q", &config, rows * f.flops_per_row() as f64 / secs / 1e9, "GFLOP/s");
        }
    }
    Ok(())
}
