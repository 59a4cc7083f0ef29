//! `coadapt search`: episodic policy search from few rollouts (thesis ch. 2-3) on the bimanual
//! planar reaching benchmark: GrouPS or PoWER, several runs, a run directory like `coadapt
//! run`'s: the resolved `config.toml`, `iterations.csv` (one row per run and iteration: the
//! summed end-effector distance of the mean policy, the best and mean return of the
//! rollouts), `rollouts.csv` (one row per rollout), each run's final M (and W, the synergies) in
//! `run-<r>/policy.safetensors`, and `plots/learning_curve.svg` (mean and standard deviation
//! over runs). With synergies (GrouPS, PePPER): run 0's W and M after every iteration in
//! `run-0/history.safetensors`, `plots/synergies.svg` (W over the iterations, thesis Fig. 3.9)
//! and `plots/synergy_poses.svg` (the arms moved along the two strongest synergies, Fig. 3.10).
//!
//! The rollouts run in this process by default; with `actors = N` they go to N actors over
//! `[fleet] transport` (in-process threads, or `coadapt search-actor` processes over shared
//! memory or gRPC, started here or, with `start-actors = false`, by you on the robots' hosts).

use std::io::Write;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};

use super::config::SearchConfig;
use crate::{EpisodicTask, Groups, GroupsConfig, LinearPolicy, Nac, Power, RolloutRunner, TimeFeatures};
use coadapt_fleet::app::{AppError, Context};

enum Learner {
    Groups(Box<Groups>),
    Power(Box<Power>),
    Nac(Box<Nac>),
}

impl Learner {
    fn mean(&self) -> &[f64] {
        match self {
            Learner::Groups(g) => &g.m,
            Learner::Power(p) => &p.policy.m,
            Learner::Nac(n) => &n.policy.m,
        }
    }

    /// One iteration; (return, cost) of each rollout.
    fn iterate(&mut self, task: &dyn RolloutRunner, phi: &TimeFeatures) -> Result<Vec<(f64, f64)>, crate::RolloutError> {
        Ok(match self {
            Learner::Groups(g) => g.iterate(task, phi)?.into_iter().map(|s| (s.ret, s.cost)).collect(),
            Learner::Power(p) => p.iterate(task, phi)?.into_iter().map(|r| (r.ret, r.cost)).collect(),
            Learner::Nac(n) => n.iterate(task, phi)?.into_iter().map(|r| (r.ret, r.cost)).collect(),
        })
    }
}

/// `coadapt search`: `cfg.runs` searches into the run directory `out`; stops between
/// iterations when `shutdown` is set. Gives back the JSON summary the command prints.
pub fn run(cfg: &SearchConfig, out: &Path, shutdown: &AtomicBool) -> Result<serde_json::Value, AppError> {
    if out.join("iterations.csv").exists() {
        return Err(AppError::Config(format!("{} already holds a search (iterations.csv); choose another --out", out.display())));
    }
    std::fs::create_dir_all(out.join("plots")).map_err(AppError::io(format!("creating {}", out.display())))?;
    let text = toml::to_string(cfg).map_err(|e| AppError::Config(e.to_string()))?;
    std::fs::write(out.join("config.toml"), text).map_err(AppError::io("writing config.toml"))?;
    let task = cfg.planar();
    let phi = TimeFeatures::thesis(task.steps());
    let d = task.action_dim();
    let fleet = if cfg.actors > 0 { Some(super::actors::Fleet::start(cfg, out)?) } else { None };
    let runner: &dyn RolloutRunner = match &fleet {
        Some(f) => &f.runner,
        None => &task,
    };
    let create =
        |name: &str| std::fs::File::create(out.join(name)).map(std::io::BufWriter::new).map_err(AppError::io(format!("creating {name}")));
    let (iters_err, rolls_err) = (|| AppError::io("writing iterations.csv"), || AppError::io("writing rollouts.csv"));
    let mut iters = create("iterations.csv")?;
    writeln!(iters, "run,iteration,rollouts,mean_policy_cost,best_return,mean_return,best_cost").map_err(iters_err())?;
    let mut rolls = create("rollouts.csv")?;
    writeln!(rolls, "run,iteration,rollout,return,cost").map_err(rolls_err())?;
    let w_hat = if cfg.w_hat.trim().is_empty() {
        None
    } else {
        let k = cfg.groups_settings.latent;
        Some(load_w(Path::new(cfg.w_hat.trim()), d, k).with_context(|| format!("w-hat = {}", cfg.w_hat))?)
    };
    let mut curves: Vec<Vec<f64>> = Vec::new();
    let mut actions = Vec::new();
    for r in 0..cfg.runs {
        let seed = cfg.seed + r as u64;
        let mut learner = match cfg.method.as_str() {
            "groups" => {
                let mut g = Groups::new(cfg.groups_settings.clone(), cfg.groups.clone(), d, phi.len(), seed)
                    .map_err(|e| AppError::Config(format!("groups: {e}")))?;
                if let Some(w) = &w_hat {
                    // Reuse: the earlier synergies are both the prior's centre and the start.
                    g.w_hat = w.clone();
                    g.w = w.clone();
                }
                Learner::Groups(Box::new(g))
            }
            "pepper" => {
                let all: Vec<usize> = (0..d).collect();
                let settings = GroupsConfig {
                    latent: cfg.groups_settings.latent,
                    inner: cfg.groups_settings.inner,
                    rollouts: cfg.groups_settings.rollouts,
                    best: cfg.groups_settings.best,
                    initial_variance: cfg.groups_settings.initial_variance,
                    ..GroupsConfig::pepper()
                };
                let g = Groups::new(settings, vec![all], d, phi.len(), seed).map_err(|e| AppError::Config(format!("pepper: {e}")))?;
                Learner::Groups(Box::new(g))
            }
            "nac" => Learner::Nac(Box::new(
                Nac::new(LinearPolicy::zeros(d, phi.len()), cfg.nac.clone(), seed).map_err(|e| AppError::Config(e.to_string()))?,
            )),
            _ => Learner::Power(Box::new(Power::new(LinearPolicy::zeros(d, phi.len()), cfg.power.clone(), seed))),
        };
        let mut curve = Vec::with_capacity(cfg.iterations + 1);
        let cost_of = |m: &[f64], actions: &mut Vec<f32>| {
            LinearPolicy::actions_of(m, d, &phi, actions);
            task.evaluate(actions).1
        };
        curve.push(cost_of(learner.mean(), &mut actions));
        // Run 0's synergies and mean after every iteration (from the start), for the plots.
        let mut history = super::plot::History::default();
        if r == 0 {
            history.record(&learner_w(&learner), learner.mean());
        }
        // TensorBoard: one event file per run (`run-R/`), so the runs compare as TensorBoard runs.
        let run_dir = out.join(format!("run-{r}"));
        std::fs::create_dir_all(&run_dir).map_err(AppError::io(format!("creating {}", run_dir.display())))?;
        let mut events = coadapt_tensorboard::EventWriter::create(&run_dir, "coadapt")
            .map_err(AppError::io(format!("writing to {}", run_dir.display())))?;
        events
            .scalars(0, &[("iteration/mean_policy_cost", curve[0])])
            .and_then(|()| events.flush())
            .map_err(AppError::io("writing the event file"))?;
        let mut total_rollouts = 0;
        for it in 1..=cfg.iterations {
            if shutdown.load(Ordering::Relaxed) {
                iters.flush().map_err(iters_err())?;
                rolls.flush().map_err(rolls_err())?;
                return Err(AppError::Interrupted(format!(
                    "interrupted before run {r} iteration {it}: {} keeps the iterations so far",
                    out.display()
                )));
            }
            let got = learner.iterate(runner, &phi).with_context(|| format!("run {r} iteration {it}"))?;
            total_rollouts += got.len();
            for (k, (ret, cost)) in got.iter().enumerate() {
                writeln!(rolls, "{r},{it},{k},{ret},{cost}").map_err(rolls_err())?;
            }
            let cost = cost_of(learner.mean(), &mut actions);
            curve.push(cost);
            if r == 0 {
                history.record(&learner_w(&learner), learner.mean());
            }
            let best = got.iter().map(|x| x.0).fold(f64::NEG_INFINITY, f64::max);
            let best_cost = got.iter().map(|x| x.1).fold(f64::INFINITY, f64::min);
            let mean = got.iter().map(|x| x.0).sum::<f64>() / got.len().max(1) as f64;
            writeln!(iters, "{r},{it},{total_rollouts},{cost},{best},{mean},{best_cost}").map_err(iters_err())?;
            let values = [
                ("iteration/mean_policy_cost", cost),
                ("iteration/best_return", best),
                ("iteration/mean_return", mean),
                ("iteration/best_cost", best_cost),
                ("iteration/rollouts", total_rollouts as f64),
            ];
            events.scalars(it as i64, &values).and_then(|()| events.flush()).map_err(AppError::io("writing the event file"))?;
            if it == cfg.save_w_at
                && let Learner::Groups(g) = &learner
            {
                let dir = out.join(format!("run-{r}"));
                std::fs::create_dir_all(&dir).map_err(AppError::io(format!("creating {}", dir.display())))?;
                save_tensors(&dir.join(format!("w-iter{it}.safetensors")), &[("W".to_string(), vec![d, g.cfg.latent], g.w.clone())])?;
            }
            // Progress every iteration: on a robot an iteration takes minutes.
            coadapt_log::logln!(
                "search: {} run {}/{} iteration {it}/{} ({total_rollouts} rollouts): mean policy's summed distance {cost:.2}, best rollout's return {best:.3}",
                cfg.method,
                r + 1,
                cfg.runs,
                cfg.iterations
            );
        }
        iters.flush().map_err(iters_err())?;
        rolls.flush().map_err(rolls_err())?;
        let dir = out.join(format!("run-{r}"));
        std::fs::create_dir_all(&dir).map_err(AppError::io(format!("creating {}", dir.display())))?;
        let mut tensors = vec![("M".to_string(), vec![d, phi.len()], learner.mean().to_vec())];
        if let Learner::Groups(g) = &learner {
            tensors.push(("W".to_string(), vec![d, g.cfg.latent], g.w.clone()));
        }
        save_tensors(&dir.join("policy.safetensors"), &tensors)?;
        if let (0, Learner::Groups(g)) = (r, &learner) {
            let (n, k) = (history.m.len(), g.cfg.latent);
            save_tensors(
                &dir.join("history.safetensors"),
                &[("W".to_string(), vec![n, d, k], history.w.concat()), ("M".to_string(), vec![n, d, phi.len()], history.m.concat())],
            )?;
            super::plot::synergies(&out.join("plots/synergies.svg"), &history, d, k)?;
            let at = cfg.synergy_iteration.min(cfg.iterations);
            super::plot::synergy_poses(&out.join("plots/synergy_poses.svg"), &history, at, d, k, &phi, &task)?;
        }
        curves.push(curve);
    }
    if let Some(f) = fleet {
        f.finish();
    }
    super::plot::draw(&out.join("plots/learning_curve.svg"), cfg, &curves)?;
    let last: Vec<f64> = curves.iter().map(|c| c[c.len() - 1]).collect();
    let mean = last.iter().sum::<f64>() / last.len() as f64;
    let sd = (last.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (last.len().max(2) - 1) as f64).sqrt();
    Ok(serde_json::json!({"method": cfg.method, "runs": cfg.runs, "iterations": cfg.iterations,
        "final_mean_policy_cost_mean": mean, "final_mean_policy_cost_sd": sd, "out": out.display().to_string()}))
}

/// The learner's W (empty for methods without synergies).
fn learner_w(l: &Learner) -> Vec<f64> {
    match l {
        Learner::Groups(g) => g.w.clone(),
        _ => Vec::new(),
    }
}

/// The tensor `W` (`d x k`, F64) of a file written by `coadapt search`.
fn load_w(path: &Path, d: usize, k: usize) -> Result<Vec<f64>, AppError> {
    let bad = |m: String| AppError::Config(format!("{}: {m}", path.display()));
    let bytes = std::fs::read(path).map_err(AppError::io(format!("reading {}", path.display())))?;
    let st = safetensors::SafeTensors::deserialize(&bytes).map_err(|e| bad(e.to_string()))?;
    let t = st.tensor("W").map_err(|e| bad(format!("no tensor W ({e})")))?;
    if t.dtype() != safetensors::Dtype::F64 || t.shape() != [d, k] {
        return Err(bad(format!("W is {:?} {:?}; expected F64 [{d}, {k}] (the same latent dimension)", t.dtype(), t.shape())));
    }
    let w: Vec<f64> = t.data().chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().unwrap_or([0; 8]))).collect();
    if let Some(i) = w.iter().position(|v| !v.is_finite()) {
        return Err(bad(format!("W[{}, {}] is not finite", i / k, i % k)));
    }
    Ok(w)
}

/// `(name, shape, values)` as F64 tensors in one safetensors file.
fn save_tensors(path: &Path, tensors: &[(String, Vec<usize>, Vec<f64>)]) -> Result<(), AppError> {
    let bytes: Vec<Vec<u8>> = tensors.iter().map(|(_, _, v)| v.iter().flat_map(|x| x.to_le_bytes()).collect()).collect();
    let views = tensors
        .iter()
        .zip(&bytes)
        .map(|((name, shape, _), b)| {
            safetensors::tensor::TensorView::new(safetensors::Dtype::F64, shape.clone(), b).map(|v| (name.clone(), v))
        })
        .collect::<Result<Vec<_>, _>>()
        .map_err(AppError::failed)?;
    let buf = safetensors::serialize(views, None).map_err(AppError::failed)?;
    std::fs::write(path, buf).map_err(AppError::io(format!("writing {}", path.display())))
}
