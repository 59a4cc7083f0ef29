//! `coadapt bench`: benchmarks that print one JSON line per figure:
//! `{"bench": ..., "config": ..., "value": ..., "unit": ...}`.

use std::time::Instant;

use clap::{Args, Subcommand};
use coadapt_core::{Batch, rng};
use coadapt_design_optimizer::{DesignObjective, ObjectiveWorkspace, QMode};
use coadapt_learner::{Sac, SacConfig};
use rand::Rng;
use serde_json::json;

#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Networks: SAC updates per second and the design-objective forward throughput.
    Nn(NnArgs),
    /// Design optimisation over Q: one full PSO (700 particles x 250 iterations x 32 start
    /// states, 3 x 256 networks) timed, with the GFLOP/s reached.
    Pso(PsoArgs),
    /// Simulation: env steps per second of each robot on one core, random actions, resets
    /// included.
    Sim(SimArgs),
    /// Transports between processes: weight broadcast latency to 1, 4 and 16 actor processes,
    /// experience throughput, over shared memory and gRPC.
    Transport(crate::bench_transport::TransportArgs),
    /// Snapshots: writing and reading a learner with 1 and 10 million transitions in its
    /// population buffer (seconds and MB/s; the disk under --dir).
    Snapshot(crate::bench_snapshot::SnapshotArgs),
    /// Environments over dm_env_rpc: steps/s and step latency (median, p99) of our robots
    /// served on loopback against the same in process, and of any server given by --url.
    Env(crate::bench_env::EnvArgs),
    /// Design queries: Score latency and designs/s for batches of 1, 100 and 10,000 over gRPC
    /// (and TLS) against the same in process; the learner's updates/s with and without a client
    /// scoring in a loop.
    Design(crate::bench_design::DesignBenchArgs),
    /// Policy search: one GrouPS update (30 rollouts, the best 15, 12 actions in 4 groups, 11
    /// features, 6 latent dimensions, 20 inner iterations), median and p10/p90 over
    /// repetitions from the same state.
    Groups(crate::bench_groups::GroupsBenchArgs),
    /// Convolutions: the image embedding's convolutions and transposed convolutions on 64x64
    /// RGB frames, per layer and as the encoder and decoder, forward and forward + backward,
    /// batch 32 and 1, one thread: median and p10/p90 ms, model GFLOP/s.
    Conv(crate::bench_conv::ConvBenchArgs),
    /// Planning latency: one control step of Alg. 3 (L-BFGS, 20 iterations, over f_Q through
    /// the latent dynamics and critic) for horizons 1, 10 and 20, median and p10/p90 ms.
    Plan(crate::bench_plan::PlanBenchArgs),
}

#[derive(Debug, Args)]
pub struct PsoArgs {
    /// Start states per design (32 is the reference; 256 the landscape plots').
    #[arg(long, value_delimiter = ',', default_values_t = vec![32usize])]
    pub states: Vec<usize>,
    /// PSO iterations (250 is the reference).
    #[arg(long, default_value_t = 250)]
    pub iterations: usize,
    /// The design objective: q1 (the reference: one critic), or pessimistic (the twin critics'
    /// mean minus 2 standard deviations: two critic passes per row).
    #[arg(long, default_value = "q1", value_parser = ["q1", "pessimistic"])]
    pub q: String,
}

#[derive(Debug, Args)]
pub struct SimArgs {
    /// Seconds to time each robot for.
    #[arg(long, default_value_t = 10.0)]
    pub seconds: f64,
    /// Robots to time (default: all), comma-separated.
    #[arg(long, value_delimiter = ',')]
    pub env: Option<Vec<String>>,
}

#[derive(Debug, Args)]
pub struct NnArgs {
    /// Seconds to time each figure for.
    #[arg(long, default_value_t = 10.0)]
    pub seconds: f64,
    /// Rows per chunk in the forward benchmark.
    #[arg(long, default_value_t = 256)]
    pub chunk_rows: usize,
    /// Also time the 179,200-row (256 start states) forward pass.
    #[arg(long)]
    pub large: bool,
    /// Run only the figures whose bench name contains this (e.g. `sac`, `forward`).
    #[arg(long)]
    pub only: Option<String>,
}

pub fn run(cmd: BenchCommand) -> anyhow::Result<()> {
    match cmd {
        BenchCommand::Nn(a) => nn(&a),
        BenchCommand::Sim(a) => sim(&a),
        BenchCommand::Pso(a) => pso(&a),
        BenchCommand::Snapshot(a) => crate::bench_snapshot::run(&a),
        BenchCommand::Transport(a) => crate::bench_transport::run(&a),
        BenchCommand::Env(a) => crate::bench_env::run(&a),
        BenchCommand::Design(a) => crate::bench_design::run(&a),
        BenchCommand::Groups(a) => crate::bench_groups::run(&a),
        BenchCommand::Conv(a) => crate::bench_conv::run(&a),
        BenchCommand::Plan(a) => crate::bench_plan::run(&a),
    }
}

fn pso(a: &PsoArgs) -> anyhow::Result<()> {
    use coadapt_design_optimizer::{CriticObjective, PsoConfig, pso};
    let (obs, act, design) = (23, 6, 6);
    let sac = Sac::new(obs, act, SacConfig { hidden: vec![256; 3], ..SacConfig::default() }, 3)?;
    let bounds = coadapt_core::BoxSpace::uniform(design, 0.8, 2.0);
    for &n_states in &a.states {
        let mut r = rng(5, 0);
        let start: Vec<f32> = (0..n_states * obs).map(|_| r.random_range(-1.0..1.0)).collect();
        let ((q1, _), (q2, _)) = (sac.critic_params(0), sac.critic_params(1));
        let (critics, mode) = if a.q == "pessimistic" { (vec![q1, q2], QMode::MeanMinusKStd(2.0)) } else { (vec![q1], QMode::First) };
        let f = DesignObjective::new(sac.policy(), sac.policy_params(), sac.critic(), &critics, &start, obs - design, design)?;
        let mut objective = CriticObjective::new(&f, mode, rayon::current_num_threads());
        let cfg = PsoConfig { iterations: a.iterations, ..PsoConfig::default() };
        let t = Instant::now();
        let result = pso::maximise(&mut objective, &bounds, &cfg, 1)?;
        let secs = t.elapsed().as_secs_f64();
        let suffix = if a.q == "pessimistic" { "-pessimistic" } else { "" };
        let config = format!("{}x{}x{n_states}{suffix}", cfg.particles, cfg.iterations);
        emit("pso_over_q", &config, secs, "s");
        let rows = result.evaluations as f64 * n_states as f64;
        if suffix.is_empty() {
            // (flops_per_row counts one critic: no GFLOP/s figure for the two-critic objective)
            emit("pso_over_q", &config, rows * f.flops_per_row() as f64 / secs / 1e9, "GFLOP/s");
        }
    }
    Ok(())
}

fn sim(a: &SimArgs) -> anyhow::Result<()> {
    let names: Vec<String> = match &a.env {
        Some(n) => n.clone(),
        None => coadapt_robots::ENV_NAMES.iter().map(|s| s.to_string()).collect(),
    };
    for name in names {
        let rate = coadapt_robots::bench::env_steps_per_second(&name, a.seconds)?;
        emit("env_steps", &name, rate, "steps/s");
        if let Some(dt) = coadapt_robots::bench::control_dt(&name) {
            // Simulated time per wall second: a fair figure across control steps of
            // different lengths (MuJoCo HalfCheetah-v5's is 0.05 s, ours 0.0165 s).
            emit("sim_seconds", &name, rate * dt, "sim-s/s");
        }
    }
    Ok(())
}

pub(crate) fn emit(bench: &str, config: &str, value: f64, unit: &str) {
    let line = json!({"bench": bench, "config": config, "value": (value * 1000.0).round() / 1000.0, "unit": unit, "impl": "coadapt"});
    coadapt_log::print_stdout_line(&line.to_string());
}

/// Calls `f` repeatedly for about `seconds` after a short warm-up; returns calls per second.
pub(crate) fn rate(seconds: f64, mut f: impl FnMut()) -> f64 {
    for _ in 0..3 {
        f();
    }
    let start = Instant::now();
    let mut n = 0u64;
    while start.elapsed().as_secs_f64() < seconds {
        f();
        n += 1;
    }
    n as f64 / start.elapsed().as_secs_f64()
}

pub(crate) fn random_batch(rows: usize, obs: usize, act: usize, seed: u64) -> Batch {
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

fn nn(a: &NnArgs) -> anyhow::Result<()> {
    let wanted = |bench: &str| a.only.as_deref().is_none_or(|o| bench.contains(o));
    if wanted("sac_update") {
        sac_updates(a)?;
    }
    if wanted("forward_actor_critic") {
        forward(a)?;
    }
    Ok(())
}

fn sac_updates(a: &NnArgs) -> anyhow::Result<()> {
    for (config, hidden, obs) in [("3x256-obs17", vec![256; 3], 17), ("3x200-obs23", vec![200; 3], 23), ("2x256-obs17", vec![256; 2], 17)] {
        let act = 6;
        let cfg = SacConfig { hidden, auto_alpha: true, ..SacConfig::default() };
        let mut sac = Sac::new(obs, act, cfg, 1)?;
        let batch = random_batch(256, obs, act, 2);
        let r = rate(a.seconds, || {
            sac.update(&batch);
        });
        emit("sac_update", config, r, "updates/s");
    }
    Ok(())
}

fn forward(a: &NnArgs) -> anyhow::Result<()> {
    let states = if a.large { vec![32, 256] } else { vec![32] };
    for n_states in states {
        let (obs, act, design) = (23, 6, 6);
        let sac = Sac::new(obs, act, SacConfig { hidden: vec![256; 3], ..SacConfig::default() }, 3)?;
        let mut r = rng(4, 0);
        let start: Vec<f32> = (0..n_states * obs).map(|_| r.random_range(-1.0..1.0)).collect();
        let (q1, _) = sac.critic_params(0);
        let objective = DesignObjective::new(sac.policy(), sac.policy_params(), sac.critic(), &[q1], &start, obs - design, design)?;
        let particles = 700;
        let designs: Vec<f32> = (0..particles * design).map(|_| r.random_range(0.8..2.0)).collect();
        let mut out = vec![0.0; particles];
        let mut ws = vec![ObjectiveWorkspace::default(); rayon::current_num_threads()];
        let passes = rate(a.seconds, || objective.evaluate(&designs, QMode::First, a.chunk_rows, &mut out, &mut ws));
        let rows = particles * n_states;
        let config = format!("{rows}rows");
        emit("forward_actor_critic", &config, 1.0 / passes, "s/pass");
        emit("forward_actor_critic", &config, rows as f64 * passes, "rows/s");
        emit("forward_actor_critic", &config, (rows * objective.flops_per_row()) as f64 * passes / 1e9, "GFLOP/s");
    }
    Ok(())
}
