//! `coadapt bench plan`: the planning latency of one control step (thesis Alg. 3, issue 15):
//! `Planner::plan` maximising f_Q (Eq. 4.11) over the H + 1 actions with 20 iterations of the
//! box-bounded L-BFGS, for horizons 1, 10 and 20. The thesis's sizes: codes of 20 over 3 stacked
//! frames (a 60-value latent state), 6 actions in [-1, 1], the dynamics `psi_bar` 66-400-400-20,
//! the critic 66-400-300-1. No peer: this is our own figure, to set against a control period.
//!
//! The networks' parameters are drawn once (`Mlp::init`: PyTorch's bounds for the hidden layers;
//! the critic's last layer +-3e-3 as DDPG's, the model's +-1/sqrt(400)). Every repetition has
//! its own start state (three random unit-length codes) and warm-start actions (uniform in the
//! box), all drawn before anything is timed; the planner and the L-BFGS buffers are made once
//! and reused across steps, as a controller would. Each repetition times one `plan` call.
//!
//! `plan` does not return the number of f_Q evaluations, so an untimed second pass runs the same
//! minimisation (`Lbfgsb::minimize` over `Planner::value_and_grad`, as `plan` does) on every
//! repetition's inputs to count them, and checks it ends at the value `plan` returned.

use std::time::Instant;

use coadapt_latent::{LatentDynamics, Lbfgsb, Planner};
use coadapt_nn::Mlp;
use rand::Rng;
use serde_json::json;

use crate::figure::percentile;
use coadapt_fleet::app::AppError;

#[derive(Debug, Clone)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct PlanOptions {
    /// Timed repetitions (control steps) per horizon.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 200))]
    pub repetitions: usize,
    /// Untimed steps before the timed ones.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 20))]
    pub warmup: usize,
    /// Horizons H (H + 1 actions are planned), comma-separated.
    #[cfg_attr(feature = "clap", arg(long, value_delimiter = ',', default_values_t = vec![1usize, 10, 20]))]
    pub horizon: Vec<usize>,
    /// L-BFGS iterations per step (Alg. 3: 20).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 20))]
    pub iterations: usize,
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 1))]
    pub seed: u64,
}

/// Codes per state, frames stacked, action dimensions, hidden widths of the model and critic.
pub const LATENT: usize = 20;
pub const FRAMES: usize = 3;
pub const ACT: usize = 6;
pub const MODEL_HIDDEN: [usize; 2] = [400, 400];
pub const CRITIC_HIDDEN: [usize; 2] = [400, 300];

/// The model and critic with their parameters.
pub fn networks(seed: u64) -> Result<(LatentDynamics, Vec<f32>, Mlp, Vec<f32>), AppError> {
    let model = LatentDynamics::new(LATENT, FRAMES, ACT, &MODEL_HIDDEN)?;
    let critic = Mlp::new(&[FRAMES * LATENT + ACT, CRITIC_HIDDEN[0], CRITIC_HIDDEN[1], 1])?;
    let mut r = coadapt_core::rng(seed, 10);
    let mut mp = model.net.zeros();
    model.net.init(&mut mp, 1.0 / (MODEL_HIDDEN[1] as f32).sqrt(), &mut r);
    let mut cp = critic.zeros();
    critic.init(&mut cp, 3e-3, &mut r);
    Ok((model, mp, critic, cp))
}

/// One step's inputs: a start state of `FRAMES` unit-length codes and warm-start actions.
pub fn step_inputs<R: Rng + ?Sized>(horizon: usize, r: &mut R) -> (Vec<f32>, Vec<f32>) {
    let mut z0: Vec<f32> = (0..FRAMES * LATENT).map(|_| r.random_range(-1.0..1.0f32)).collect();
    for code in z0.chunks_exact_mut(LATENT) {
        let norm = code.iter().map(|v| v * v).sum::<f32>().sqrt().max(1e-12);
        code.iter_mut().for_each(|v| *v /= norm);
    }
    let actions = (0..(horizon + 1) * ACT).map(|_| r.random_range(-1.0..=1.0f32)).collect();
    (z0, actions)
}

/// `plan`'s minimisation, written out to count its evaluations: returns (f_Q, iterations,
/// evaluations), `actions` holding the plan.
pub fn plan_counted(p: &mut Planner<'_>, z0: &[f32], actions: &mut [f32], iterations: usize, opt: &mut Lbfgsb) -> (f32, usize, usize) {
    let n = actions.len();
    let mut x: Vec<f64> = actions.iter().map(|&a| f64::from(a)).collect();
    let (lo, hi) = (vec![-1.0; n], vec![1.0; n]);
    let (mut x32, mut g32) = (Vec::with_capacity(n), vec![0.0f32; n]);
    let r = opt.minimize(&mut x, &lo, &hi, iterations, |x, g| {
        x32.clear();
        x32.extend(x.iter().map(|&v| v as f32));
        let f = p.value_and_grad(z0, &x32, &mut g32);
        g.iter_mut().zip(&g32).for_each(|(a, b)| *a = -f64::from(*b));
        -f64::from(f)
    });
    actions.iter_mut().zip(&x).for_each(|(a, v)| *a = *v as f32);
    (-r.value as f32, r.iterations, r.evaluations)
}

fn round(v: f64) -> f64 {
    (v * 1e4).round() / 1e4
}

pub fn config_name(horizon: usize, iterations: usize) -> String {
    format!(
        "H{horizon}-lbfgs{iterations}-z{}-a{ACT}-model{}x{}-critic{}x{}",
        FRAMES * LATENT,
        MODEL_HIDDEN[0],
        MODEL_HIDDEN[1],
        CRITIC_HIDDEN[0],
        CRITIC_HIDDEN[1]
    )
}

pub fn run(a: &PlanOptions) -> Result<(), AppError> {
    if a.repetitions == 0 {
        return Err(AppError::Config("--repetitions must be at least 1".into()));
    }
    let (model, mp, critic, cp) = networks(a.seed)?;
    let mut opt = Lbfgsb::default();
    for &h in &a.horizon {
        let mut r = coadapt_core::rng(a.seed, 20 + h as u64);
        let inputs: Vec<_> = (0..a.warmup + a.repetitions).map(|_| step_inputs(h, &mut r)).collect();
        let mut planner = Planner::new(&model, &mp, &critic, &cp, h);
        let mut actions = vec![0.0f32; (h + 1) * ACT];
        let mut values = Vec::with_capacity(a.repetitions);
        let mut ms = Vec::with_capacity(a.repetitions);
        for (i, (z0, warm)) in inputs.iter().enumerate() {
            actions.copy_from_slice(warm);
            let t = Instant::now();
            let v = planner.plan(z0, &mut actions, -1.0, 1.0, a.iterations, &mut opt);
            let elapsed = t.elapsed().as_secs_f64() * 1e3;
            std::hint::black_box(&actions);
            if i >= a.warmup {
                ms.push(elapsed);
                values.push(v);
            }
        }
        // One evaluation of f_Q and its action gradient, timed alone.
        let mut grad = vec![0.0f32; actions.len()];
        let mut eval_us: Vec<f64> = inputs
            .iter()
            .map(|(z0, warm)| {
                let t = Instant::now();
                std::hint::black_box(planner.value_and_grad(z0, warm, &mut grad));
                t.elapsed().as_secs_f64() * 1e6
            })
            .skip(a.warmup)
            .collect();
        // Untimed: the evaluations of every timed step, and the check that they are plan's.
        let (mut evals, mut iters) = (Vec::new(), Vec::new());
        for ((z0, warm), v) in inputs[a.warmup..].iter().zip(&values) {
            actions.copy_from_slice(warm);
            let (f, it, ev) = plan_counted(&mut planner, z0, &mut actions, a.iterations, &mut opt);
            if f.to_bits() != v.to_bits() {
                return Err(AppError::Failed(format!("the counting pass ended at f_Q {f}, plan at {v}")));
            }
            evals.push(ev as f64);
            iters.push(it as f64);
        }
        ms.sort_by(f64::total_cmp);
        eval_us.sort_by(f64::total_cmp);
        evals.sort_by(f64::total_cmp);
        iters.sort_by(f64::total_cmp);
        let line = json!({
            "bench": "plan_step",
            "config": config_name(h, a.iterations),
            "value": round(percentile(&ms, 0.5)),
            "unit": "ms",
            "impl": "coadapt",
            "p10": round(percentile(&ms, 0.1)),
            "p90": round(percentile(&ms, 0.9)),
            "max": round(ms[ms.len() - 1]),
            "repetitions": ms.len(),
            "horizon": h,
            "actions": (h + 1) * ACT,
            "iterations_median": percentile(&iters, 0.5),
            "evaluations_median": percentile(&evals, 0.5),
            "evaluations_min": evals[0],
            "evaluations_max": evals[evals.len() - 1],
            "objective_grad_us_median": round(percentile(&eval_us, 0.5)),
            "threads": 1,
        });
        coadapt_log::print_stdout_line(&line.to_string());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_counting_pass_is_plan() {
        let (model, mp, critic, cp) = networks(3).unwrap_or_else(|e| panic!("{e}"));
        let mut opt = Lbfgsb::default();
        let mut p = Planner::new(&model, &mp, &critic, &cp, 5);
        let (z0, warm) = step_inputs(5, &mut coadapt_core::rng(4, 0));
        assert!(z0.chunks_exact(LATENT).all(|c| (c.iter().map(|v| v * v).sum::<f32>() - 1.0).abs() < 1e-5));
        let mut grad = vec![0.0; warm.len()];
        let before = p.value_and_grad(&z0, &warm, &mut grad);
        let (mut a1, mut a2) = (warm.clone(), warm.clone());
        let v1 = p.plan(&z0, &mut a1, -1.0, 1.0, 20, &mut opt);
        let (v2, it, ev) = plan_counted(&mut p, &z0, &mut a2, 20, &mut opt);
        assert_eq!((v1.to_bits(), &a1), (v2.to_bits(), &a2));
        assert!(v1 > before, "{before} -> {v1}");
        assert!(it >= 1 && ev > it, "{it} iterations, {ev} evaluations");
    }
}
