//! `coadapt bench groups`: one GrouPS update (`Groups::update` and the x1.5 resize, with the
//! best-k reward weights), timed alone: the planar benchmark's sizes and `planar-groups4.toml`'s
//! settings (30 rollouts, the best 15, 12 actions in 4 groups, 11 features over 25 steps, 6
//! latent dimensions, 20 inner iterations). The peer is the same update in NumPy
//! (bench/peers/groups_update.py).
//!
//! The learner is trained a few iterations on the planar task first (so the state is not the
//! prior's), then one iteration's 30 rollouts are sampled from it and evaluated, once, before
//! anything is timed. Every repetition starts from a copy of that same state, made outside the
//! timed region. `--dump FILE` writes the inputs and one update's outputs as JSON, for the peer's
//! `--check` (and its timing on the very same inputs).

use std::path::PathBuf;
use std::time::Instant;

use coadapt_policy_search::{EpisodicTask, Groups, GroupsConfig, PlanarReaching, Sample, TimeFeatures};
use serde_json::json;

use crate::figure::percentile;
use coadapt_fleet::app::AppError;

#[derive(Debug, Clone)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct GroupsOptions {
    /// Timed repetitions (each one update from the same state).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 200))]
    pub repetitions: usize,
    /// Untimed updates before the timed ones.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 20))]
    pub warmup: usize,
    /// Iterations on the planar task before the benchmarked state is taken.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 5))]
    pub train_iterations: usize,
    /// Seed of the learner (its W and its rollouts' draws).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 1))]
    pub seed: u64,
    /// Write the inputs (state, rollouts, features) and one update's outputs to this JSON file.
    #[cfg_attr(feature = "clap", arg(long))]
    pub dump: Option<PathBuf>,
}

/// The benchmark's figure name and config, shared with the peer's line.
pub const BENCH: &str = "groups_update";

/// `planar-groups4.toml`: the thesis's groups (joints 1-4 and 5-6 of each arm) and GrouPS's
/// default settings (the file sets no `[groups-settings]`).
fn setting() -> (GroupsConfig, Vec<Vec<usize>>) {
    (GroupsConfig::default(), vec![vec![0, 1, 2, 3], vec![4, 5], vec![6, 7, 8, 9], vec![10, 11]])
}

/// The benchmarked work: what `Groups::iterate` does once the rollouts are evaluated and sorted
/// (best first): the best-k weights, the variational update, the resize.
pub fn one_update(g: &mut Groups, best: &[Sample], phi: &TimeFeatures) {
    let total: f64 = best.iter().map(|s| s.ret.max(0.0)).sum();
    let weights: Vec<f64> = best.iter().map(|s| s.ret.max(0.0) / total).collect();
    g.update(best, &weights, phi);
    g.resize();
}

/// The learner after `train` iterations and one iteration's rollouts sampled from it, evaluated
/// on the planar task, best first.
pub fn inputs(train: usize, seed: u64) -> Result<(Groups, Vec<Sample>, TimeFeatures), AppError> {
    let task = PlanarReaching::default();
    let phi = TimeFeatures::thesis(task.steps());
    let (cfg, groups) = setting();
    let mut g = Groups::new(cfg, groups, task.action_dim(), phi.len(), seed).map_err(|e| AppError::Failed(format!("groups: {e}")))?;
    for _ in 0..train {
        g.iterate(&task, &phi)?;
    }
    let mut samples: Vec<Sample> = (0..g.cfg.rollouts).map(|_| g.sample(&phi)).collect();
    for s in samples.iter_mut() {
        let actions: Vec<f32> = s.actions.iter().map(|&v| v as f32).collect();
        (s.ret, s.cost) = task.evaluate(&actions);
    }
    samples.sort_by(|a, b| b.ret.total_cmp(&a.ret));
    let total: f64 = samples[..g.cfg.best].iter().map(|s| s.ret.max(0.0)).sum();
    if !(total > 0.0 && total.is_finite()) {
        return Err(AppError::Failed(format!("the best rollouts' returns sum to {total}")));
    }
    Ok((g, samples, phi))
}

/// A copy of the learner's state (every field the update reads or writes).
pub fn copy_of(g: &Groups) -> Groups {
    g.clone()
}

pub fn run(a: &GroupsOptions) -> Result<(), AppError> {
    if a.repetitions == 0 {
        return Err(AppError::Config("--repetitions must be at least 1".into()));
    }
    let (state, samples, phi) = inputs(a.train_iterations, a.seed)?;
    let best = &samples[..state.cfg.best];
    if let Some(path) = &a.dump {
        let mut g = copy_of(&state);
        one_update(&mut g, best, &phi);
        std::fs::write(path, dump(&state, &samples, &phi, &g).to_string()).map_err(AppError::io(format!("writing {}", path.display())))?;
        coadapt_log::logln!("bench groups: inputs and outputs written to {}", path.display());
    }
    for _ in 0..a.warmup {
        let mut g = copy_of(&state);
        one_update(&mut g, best, &phi);
        std::hint::black_box(&g);
    }
    let mut ms = Vec::with_capacity(a.repetitions);
    for _ in 0..a.repetitions {
        let mut g = copy_of(&state);
        let t = Instant::now();
        one_update(&mut g, best, &phi);
        ms.push(t.elapsed().as_secs_f64() * 1e3);
        std::hint::black_box(&g);
    }
    ms.sort_by(f64::total_cmp);
    let line = json!({
        "bench": BENCH,
        "config": config_name(&state, &phi),
        "value": round(percentile(&ms, 0.5)),
        "unit": "ms",
        "impl": "coadapt",
        "p10": round(percentile(&ms, 0.1)),
        "p90": round(percentile(&ms, 0.9)),
        "repetitions": a.repetitions,
        "dtype": "f64",
    });
    coadapt_log::print_stdout_line(&line.to_string());
    Ok(())
}

/// `r30-b15-d12-p11-t25-k6-i20-g4`: rollouts, best, actions, features, steps, latent dimensions,
/// inner iterations, groups.
pub fn config_name(g: &Groups, phi: &TimeFeatures) -> String {
    let c = &g.cfg;
    format!("r{}-b{}-d{}-p{}-t{}-k{}-i{}-g{}", c.rollouts, c.best, g.d, g.p, phi.steps(), c.latent, c.inner, g.groups.len())
}

fn round(ms: f64) -> f64 {
    (ms * 1e4).round() / 1e4
}

/// The inputs and outputs of one update, for bench/peers/groups_update.py --check.
pub fn dump(before: &Groups, samples: &[Sample], phi: &TimeFeatures, after: &Groups) -> serde_json::Value {
    let phi_rows: Vec<f64> = (0..phi.steps()).flat_map(|t| phi.at(t).to_vec()).collect();
    let rollouts: Vec<_> = samples.iter().map(|s| json!({"actions": s.actions, "z": s.z, "ret": s.ret})).collect();
    json!({
        "config": before.cfg,
        "config_name": config_name(before, phi),
        "groups": before.groups,
        "d": before.d,
        "p": before.p,
        "steps": phi.steps(),
        "phi": phi_rows,
        "rollouts": rollouts,
        "before": {"m": before.m, "w": before.w, "w_hat": before.w_hat, "alpha": before.alpha, "tau": before.tau, "sigma_m": before.sigma_m, "sigma_w": before.sigma_w},
        "after": {"m": after.m, "w": after.w, "alpha": after.alpha, "tau": after.tau, "sigma_m": after.sigma_m, "sigma_w": after.sigma_w},
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_dump_holds_the_inputs_and_one_update_from_them() {
        let (state, samples, phi) = inputs(1, 3).unwrap_or_else(|e| panic!("{e}"));
        let best = &samples[..state.cfg.best];
        let mut g = copy_of(&state);
        one_update(&mut g, best, &phi);
        let v = dump(&state, &samples, &phi, &g);
        let floats =
            |v: &serde_json::Value| -> Vec<f64> { v.as_array().map(|a| a.iter().filter_map(|x| x.as_f64()).collect()).unwrap_or_default() };
        // f64 round-trips through the JSON exactly.
        assert_eq!(floats(&v["before"]["m"]), state.m);
        assert_eq!(floats(&v["after"]["w"]), g.w);
        assert_eq!(v["rollouts"].as_array().map(Vec::len), Some(30));
        assert_eq!(floats(&v["rollouts"][0]["actions"]), samples[0].actions);
        // The copy is the state: a second update from another copy gives the same outputs.
        let mut h = copy_of(&state);
        one_update(&mut h, best, &phi);
        assert_eq!((&h.m, &h.w, &h.alpha, &h.tau), (&g.m, &g.w, &g.alpha, &g.tau));
        assert_ne!(g.m, state.m, "the update changed nothing");
    }
}
