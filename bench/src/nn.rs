//! `coadapt bench nn`: SAC updates per second (three network sizes, batch 256), the design
//! objective's forward throughput (700 particles over 32, optionally 256, start states), and
//! what the population critics' ensemble (`learner.population-critics`) costs: FEAR's
//! population update and the pessimistic design objective with 2 critics against 5; and what
//! the conservative design critic (`[learner.conservative]`) costs a population update.

use coadapt_core::{Batch, rng};
use coadapt_design_optimizer::{DesignObjective, ObjectiveWorkspace, QMode};
use coadapt_learner::conservative::ConservativeConfig;
use coadapt_learner::{Sac, SacConfig};
use coadapt_nn::Precision;
use rand::Rng;

use crate::figure::{emit, rate};
use coadapt_fleet::app::AppError;

#[derive(Debug, Clone)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct NnOptions {
    /// Seconds to time each figure for.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 10.0))]
    pub seconds: f64,
    /// Rows per chunk in the forward benchmark.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 256))]
    pub chunk_rows: usize,
    /// Also time the 179,200-row (256 start states) forward pass.
    #[cfg_attr(feature = "clap", arg(long))]
    pub large: bool,
    /// Run only the figures whose bench name contains this (e.g. `sac`, `forward`).
    #[cfg_attr(feature = "clap", arg(long))]
    pub only: Option<String>,
    /// The products of the SAC updates and of the design objective's forward pass: f32, or bf16
    /// (`learner.sac.precision`; the figures' config names end in `-bf16`).
    #[cfg_attr(feature = "clap", arg(long, default_value = "f32"))]
    pub precision: Precision,
}

pub fn run(a: &NnOptions) -> Result<(), AppError> {
    let wanted = |bench: &str| a.only.as_deref().is_none_or(|o| bench.contains(o));
    if wanted("sac_update") {
        sac_updates(a)?;
    }
    if wanted("forward_actor_critic") {
        forward(a)?;
    }
    if wanted("ensemble_cost") {
        ensemble_cost(a)?;
    }
    if wanted("conservative_cost") {
        conservative_cost(a)?;
    }
    Ok(())
}

/// The ensemble's cost, both sides in one run on the same thread, interleaved (2 critics, then
/// 5, then 2 again, ... 5 rounds of `seconds / 5` each), so drift in the machine's speed hits
/// both alike: FEAR's population update (3 x 200 networks, HalfCheetah's 17 + 6 inputs, batch
/// 256) and one pass of the pessimistic design objective (700 particles x 32 start states) over
/// the twin against the twin and 3 heads. One line per side and figure: mean and sample sd of
/// the rounds' rates, n = 5.
fn ensemble_cost(a: &NnOptions) -> Result<(), AppError> {
    let (obs, act, design) = (23, 6, 6);
    let cfg = SacConfig { hidden: vec![200; 3], auto_alpha: true, ..SacConfig::default() };
    let mut agents = [Sac::with_heads(obs, act, cfg.clone(), 1, 0)?, Sac::with_heads(obs, act, cfg, 1, 3)?];
    let batch = random_batch(256, obs, act, 2);
    let mut r = rng(4, 0);
    let start: Vec<f32> = (0..32 * obs).map(|_| r.random_range(-1.0..1.0)).collect();
    let heads = &agents[1];
    let thetas: Vec<&[f32]> =
        [heads.critic_params(0).0, heads.critic_params(1).0].into_iter().chain((0..3).map(|i| heads.head_params(i))).collect();
    let objective = |n: usize| {
        DesignObjective::new(heads.policy(), heads.policy_params(), heads.critic(), &thetas[..n], &start, obs - design, design)
            .map_err(AppError::library)
    };
    let (twin, five) = (objective(2)?, objective(5)?);
    let designs: Vec<f32> = (0..700 * design).map(|_| r.random_range(0.8..2.0)).collect();
    let mut out = vec![0.0; 700];
    let mut ws = vec![ObjectiveWorkspace::default()];
    let rounds = 5;
    let each = a.seconds / rounds as f64;
    let (mut updates, mut passes) = ([Vec::new(), Vec::new()], [Vec::new(), Vec::new()]);
    for _ in 0..rounds {
        for (k, agent) in agents.iter_mut().enumerate() {
            updates[k].push(rate(each, || {
                agent.update(&batch);
            }));
        }
        for (k, f) in [&twin, &five].into_iter().enumerate() {
            passes[k].push(rate(each, || f.evaluate(&designs, QMode::MeanMinusKStd(2.0), a.chunk_rows, &mut out, &mut ws)));
        }
    }
    rounds_line("ensemble_cost", "population-update-2-critics", &updates[0], "updates/s");
    rounds_line("ensemble_cost", "population-update-5-critics", &updates[1], "updates/s");
    rounds_line("ensemble_cost", "pessimistic-objective-2-critics-22400rows", &passes[0], "passes/s");
    rounds_line("ensemble_cost", "pessimistic-objective-5-critics-22400rows", &passes[1], "passes/s");
    Ok(())
}

/// One JSON line for a figure timed in interleaved rounds: the mean and sample sd of the rounds'
/// rates `v`, n = the rounds.
fn rounds_line(bench: &str, config: &str, v: &[f64], unit: &str) {
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    let sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt();
    let l = serde_json::json!({"bench": bench, "config": config, "value": (mean * 1000.0).round() / 1000.0,
        "sd": (sd * 1000.0).round() / 1000.0, "n": v.len(), "unit": unit, "impl": "coadapt"});
    coadapt_log::print_stdout_line(&l.to_string());
}

/// What the conservative design critic (`[learner.conservative]`, COMs' term on one ensemble
/// head) costs, both sides in one run on the same thread, interleaved as [`ensemble_cost`]:
/// FEAR's population update (3 x 200 networks, HalfCheetah's 17 + 6 inputs, batch 256) alone
/// and with one head trained with the term at its default reach (5 steps of 0.1 box widths over
/// the box [0.8, 2]^6). One line per side: mean and sample sd of the rounds' rates, n = 5.
fn conservative_cost(a: &NnOptions) -> Result<(), AppError> {
    let (obs, act, design) = (23, 6, 6);
    let cfg = SacConfig { hidden: vec![200; 3], auto_alpha: true, precision: a.precision, ..SacConfig::default() };
    let mut agents = [Sac::new(obs, act, cfg.clone(), 1)?, Sac::with_heads(obs, act, cfg, 1, 1)?];
    let c = ConservativeConfig { weight: 1.0, ..ConservativeConfig::default() };
    agents[1].set_conservative(c.on_box(obs - design..obs, &[0.8; 6], &[2.0; 6]));
    let mut batch = random_batch(256, obs, act, 2);
    for row in batch.obs.chunks_exact_mut(obs).chain(batch.next_obs.chunks_exact_mut(obs)) {
        for v in &mut row[obs - design..] {
            *v = 1.4 + 0.6 * *v;
        }
    }
    let rounds = 5;
    let each = a.seconds / rounds as f64;
    let mut updates = [Vec::new(), Vec::new()];
    for _ in 0..rounds {
        for (k, agent) in agents.iter_mut().enumerate() {
            updates[k].push(rate(each, || {
                agent.update(&batch);
            }));
        }
    }
    let suffix = if a.precision == Precision::Bf16 { "-bf16" } else { "" };
    for (k, config) in ["population-update-fear", "population-update-conservative-head-5x0.1"].into_iter().enumerate() {
        rounds_line("conservative_cost", &format!("{config}{suffix}"), &updates[k], "updates/s");
    }
    Ok(())
}

/// A batch of `rows` transitions with every value uniform in [-1, 1).
pub fn random_batch(rows: usize, obs: usize, act: usize, seed: u64) -> Batch {
    let mut r = rng(seed, 9);
    let mut b = Batch::new(rows, obs, act);
    for v in b.obs.iter_mut().chain(b.next_obs.iter_mut()).chain(b.rew.iter_mut()) {
        *v = r.random_range(-1.0..1.0);
    }
    for v in b.act.iter_mut() {
        *v = r.random_range(-1.0..1.0);
    }
    b
}

fn sac_updates(a: &NnOptions) -> Result<(), AppError> {
    for (config, hidden, obs) in [("3x256-obs17", vec![256; 3], 17), ("3x200-obs23", vec![200; 3], 23), ("2x256-obs17", vec![256; 2], 17)] {
        let act = 6;
        let cfg = SacConfig { hidden, auto_alpha: true, precision: a.precision, ..SacConfig::default() };
        let mut sac = Sac::new(obs, act, cfg, 1)?;
        let batch = random_batch(256, obs, act, 2);
        let r = rate(a.seconds, || {
            sac.update(&batch);
        });
        let config = if a.precision == Precision::Bf16 { format!("{config}-bf16") } else { config.to_owned() };
        emit("sac_update", &config, r, "updates/s");
    }
    Ok(())
}

fn forward(a: &NnOptions) -> Result<(), AppError> {
    let states = if a.large { vec![32, 256] } else { vec![32] };
    for n_states in states {
        let (obs, act, design) = (23, 6, 6);
        let sac = Sac::new(obs, act, SacConfig { hidden: vec![256; 3], precision: a.precision, ..SacConfig::default() }, 3)?;
        let mut r = rng(4, 0);
        let start: Vec<f32> = (0..n_states * obs).map(|_| r.random_range(-1.0..1.0)).collect();
        let (q1, _) = sac.critic_params(0);
        let objective = DesignObjective::new(sac.policy(), sac.policy_params(), sac.critic(), &[q1], &start, obs - design, design)
            .map_err(AppError::library)?;
        let particles = 700;
        let designs: Vec<f32> = (0..particles * design).map(|_| r.random_range(0.8..2.0)).collect();
        let mut out = vec![0.0; particles];
        let mut ws = vec![ObjectiveWorkspace::default(); rayon::current_num_threads()];
        let passes = rate(a.seconds, || objective.evaluate(&designs, QMode::First, a.chunk_rows, &mut out, &mut ws));
        let rows = particles * n_states;
        let config = if a.precision == Precision::Bf16 { format!("{rows}rows-bf16") } else { format!("{rows}rows") };
        emit("forward_actor_critic", &config, 1.0 / passes, "s/pass");
        emit("forward_actor_critic", &config, rows as f64 * passes, "rows/s");
        emit("forward_actor_critic", &config, (rows * objective.flops_per_row()) as f64 * passes / 1e9, "GFLOP/s");
    }
    Ok(())
}
