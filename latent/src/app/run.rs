//! `coadapt latent`: DDPG from pixels that explores by planning in a learned latent space
//! (thesis ch. 4, Alg. 3) on a robot seen through the camera, several runs, a run directory like
//! `coadapt run`'s: the resolved `config.toml`; `episodes.csv` (one row per run and episode: the
//! training episode's return with exploration, the deterministic actor's evaluation return
//! after it, the model's loss, planning latency); `run-<r>/agent.safetensors` after every
//! episode (actor, critic, model, reward model); `plots/returns.svg` (both returns, mean and
//! standard deviation over runs); a JSON summary on stdout.
//!
//! With `actors = N` the episodes run on actors that plan where their robot is
//! (`actors`); the learner only trains, between episodes.
//!
//! The embedding is loaded from `[embedding] path`, or built there first (state-based DDPG's
//! episodes, see `embed`): every method pointed at the same file explores in the same
//! latent space.

use std::io::Write;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use coadapt_core::{Env, Pixels, PixelsConfig};

use super::config::LatentConfig;
use super::embed::{FrameSource, load_or_build};
use crate::{CriticKind, Embedding, Explore, LatentAgent, Objective};
use coadapt_fleet::app::{AppError, Context};

/// The robot seen through the camera: a built-in robot drawn by [`Pixels`] (one frame per
/// observation; the agent stacks codes), or a served one whose observation is the frame.
pub(crate) fn camera_env(cfg: &LatentConfig) -> Result<FrameSource, AppError> {
    let image = 3 * cfg.camera.side * cfg.camera.side;
    if coadapt_env_rpc::is_remote(&cfg.robot) {
        let env = coadapt_fleet::make_env_with(&cfg.robot, &coadapt_robots::World::default(), &cfg.remote, &cfg.security)
            .with_context(|| format!("robot = {}", cfg.robot))?;
        let got = env.spec().state_dim;
        if got != image {
            return Err(AppError::Config(format!(
                "robot = {}: its observation has {got} values; camera.side = {} needs one RGB frame of {image}",
                cfg.robot, cfg.camera.side
            )));
        }
        return Ok(FrameSource::Served(env));
    }
    let robot = coadapt_robots::make(&cfg.robot)
        .map_err(|e| AppError::Config(format!("robot = {:?}: {e}; or dm-env-rpc://HOST:PORT", cfg.robot)))?;
    let px = PixelsConfig { width: cfg.camera.side, height: cfg.camera.side, frames: 1, action_repeat: cfg.camera.action_repeat };
    Ok(FrameSource::Drawn(Box::new(Pixels::new(robot, px).with_context(|| format!("robot = {}", cfg.robot))?)))
}

/// The method's name in messages and the default run directory (`plan-h10-q-rq`, `ou-v`).
pub(crate) fn label(cfg: &LatentConfig) -> String {
    let e = match cfg.agent.explore {
        Explore::Plan => format!("plan-h{}", cfg.agent.horizon),
        Explore::OrnsteinUhlenbeck => "ou".into(),
    };
    let c = match cfg.agent.critic {
        CriticKind::Q => "q",
        CriticKind::V => "v",
    };
    let o = match cfg.agent.objective {
        Objective::SumQ => "",
        Objective::RewardPlusQ => "-rq",
        Objective::LastQ => "-lastq",
    };
    format!("{e}-{c}{o}")
}

/// One episode's figures.
struct Episode {
    ret: f32,
    steps: usize,
    plan_ms: Vec<f64>,
    /// Steps with a positive reward (the reach robot's success).
    rewarded: usize,
}

/// One episode of `agent` on `env` from `seed`, each action from `choose` (which says whether
/// it planned), each step stored in the agent's replay if `store`.
fn play<E: Env + ?Sized>(
    agent: &mut LatentAgent,
    env: &mut E,
    seed: u64,
    steps: usize,
    store: bool,
    mut choose: impl FnMut(&mut LatentAgent, &E, &mut [f32]) -> bool,
) -> Result<Episode, AppError> {
    let px = agent.image_len();
    let design = env.spec().default_design.clone();
    let first = env.reset(seed, &design)?[..px].to_vec();
    let mut z = agent.reset(&first).to_vec();
    let mut a = vec![0.0; env.spec().act_dim()];
    let mut out = Episode { ret: 0.0, steps: 0, plan_ms: Vec::new(), rewarded: 0 };
    for _ in 0..steps {
        let t = Instant::now();
        if choose(agent, env, &mut a) {
            out.plan_ms.push(t.elapsed().as_secs_f64() * 1e3);
        }
        let s = env.step(&a)?;
        let (r, term, trunc) = (s.reward, s.terminated, s.truncated);
        let next = agent.observe(&s.observation[..px]).to_vec();
        if store {
            agent.store(&z, &a, r, &next, term)?;
        }
        out.ret += r;
        out.steps += 1;
        out.rewarded += usize::from(r > 0.0);
        z = next;
        if term || trunc {
            break;
        }
    }
    Ok(out)
}

/// One episode of `agent` on `env`: exploring and stored (training), or deterministic.
fn episode(agent: &mut LatentAgent, env: &mut dyn Env, seed: u64, steps: usize, train: bool) -> Result<Episode, AppError> {
    play(agent, env, seed, steps, train, |agent, _, a| agent.act(train, a).is_some())
}

/// `n` episodes of the reach robot's scripted demonstrator through the camera, stored in the
/// agent's replay; how many succeeded.
fn demonstrate(agent: &mut LatentAgent, source: &mut FrameSource, n: usize, seed: u64, steps: usize) -> Result<usize, AppError> {
    let FrameSource::Drawn(env) = source else { return Err(AppError::Config("demonstrations need the built-in reach robot".into())) };
    let mut ok = 0;
    for d in 0..n {
        let e = play(agent, env.as_mut(), seed * 1_000_003 + 500_000 + d as u64, steps, true, |_, env, a| {
            coadapt_robots::reach::demonstration_action(env.state(), a);
            false
        })?;
        ok += e.rewarded;
    }
    Ok(ok)
}

/// The embedding `cfg` names: loaded, or built there first (`coadapt latent --embed-only`).
pub fn embedding(cfg: &LatentConfig, shutdown: &AtomicBool) -> Result<(Embedding, Vec<f32>), AppError> {
    load_or_build(&cfg.embedding, || camera_env(cfg), cfg.episode_steps, shutdown)
}

/// `coadapt latent`: `cfg.runs` runs into the run directory `out` (with `resume`, the stopped
/// run there goes on after its finished runs); stops between episodes when `shutdown` is set.
/// Gives back the JSON summary the command prints.
pub fn run(cfg: &LatentConfig, out: &Path, resume: bool, shutdown: &AtomicBool) -> Result<serde_json::Value, AppError> {
    let (emb, enc) = embedding(cfg, shutdown)?;
    if emb.cfg.image != cfg.camera.side || emb.cfg.in_channels != 3 {
        return Err(AppError::Config(format!(
            "embedding {}: {:?} does not match the camera ({} pixels)",
            cfg.embedding.path, emb.cfg, cfg.camera.side
        )));
    }
    let done = if resume {
        super::resume::finished(out, cfg)?
    } else {
        if out.join("episodes.csv").exists() {
            return Err(AppError::Config(format!(
                "{} already holds a run (episodes.csv); choose another --out, or --resume it",
                out.display()
            )));
        }
        super::resume::Finished::default()
    };
    std::fs::create_dir_all(out.join("plots")).map_err(AppError::io(format!("creating {}", out.display())))?;
    let text = toml::to_string(cfg).map_err(|e| AppError::Config(e.to_string()))?;
    std::fs::write(out.join("config.toml"), text).map_err(AppError::io("writing config.toml"))?;
    // The finished runs' rows first (a resumed run), through a temporary file: a crash now
    // leaves the old file or the new one, never half of one.
    let tmp = out.join("episodes.csv.tmp");
    let mut head = super::resume::HEADER.to_string() + "\n";
    done.rows.iter().for_each(|r| head.extend([r.as_str(), "\n"]));
    std::fs::write(&tmp, head).map_err(AppError::io("writing episodes.csv"))?;
    std::fs::rename(&tmp, out.join("episodes.csv")).map_err(AppError::io("writing episodes.csv"))?;
    let mut csv = std::io::BufWriter::new(
        std::fs::OpenOptions::new().append(true).open(out.join("episodes.csv")).map_err(AppError::io("opening episodes.csv"))?,
    );
    if done.runs > 0 {
        coadapt_log::logln!("latent {}: resuming {} after its {} finished run(s)", label(cfg), out.display(), done.runs);
    }
    let t0 = Instant::now() - std::time::Duration::from_secs_f64(done.seconds.max(0.0));
    let mut train_curves: Vec<Vec<f64>> = done.train;
    let mut eval_curves: Vec<Vec<f64>> = done.eval;
    let mut all_plan_ms = Vec::new();
    let mut fleet = None;
    for r in done.runs..cfg.runs {
        let seed = cfg.seed + r as u64;
        let mut env = camera_env(cfg)?;
        let mut rng = coadapt_core::rng(seed, 11);
        let act = env.env().spec().act_dim();
        if cfg.actors > 0 && fleet.is_none() {
            fleet = Some(super::actors::Fleet::start(cfg, out, act)?);
        }
        let mut agent = LatentAgent::new(cfg.agent.clone(), emb.clone(), enc.clone(), cfg.camera.frames, act, seed, &mut rng)?;
        let dir = out.join(format!("run-{r}"));
        std::fs::create_dir_all(&dir).map_err(AppError::io(format!("creating {}", dir.display())))?;
        // TensorBoard: one event file per run (`run-R/`). A resume starts run R over, so an
        // event file it left is removed first: no step appears twice.
        for e in std::fs::read_dir(&dir).map_err(AppError::io(format!("reading {}", dir.display())))?.flatten() {
            if e.file_name().to_string_lossy().starts_with("events.out.tfevents.") {
                std::fs::remove_file(e.path()).map_err(AppError::io(format!("removing {}", e.path().display())))?;
            }
        }
        let mut events =
            coadapt_tensorboard::EventWriter::create(&dir, "coadapt").map_err(AppError::io(format!("writing to {}", dir.display())))?;
        if cfg.demonstrations > 0 {
            let ok = demonstrate(&mut agent, &mut env, cfg.demonstrations, seed, cfg.episode_steps)?;
            agent.train(&mut rng);
            coadapt_log::logln!(
                "latent {}: run {}: {} demonstrations in the replay ({ok} successful), model and DDPG trained on them",
                label(cfg),
                r + 1,
                cfg.demonstrations
            );
        }
        let (mut tc, mut ec) = (Vec::new(), Vec::new());
        for ep in 0..cfg.episodes {
            if shutdown.load(Ordering::Relaxed) {
                return Err(AppError::Interrupted(format!(
                    "interrupted before run {r} episode {ep}: {} keeps the episodes so far; --resume starts run {r} again",
                    out.display()
                )));
            }
            let base = seed * 1_000_003 + 2 * ep as u64;
            let index = u32::try_from(r * cfg.episodes + ep).unwrap_or(u32::MAX);
            let mut play = |agent: &mut LatentAgent, seed: u64, train: bool| -> Result<Episode, AppError> {
                match fleet.as_mut() {
                    None => episode(agent, env.env(), seed, cfg.episode_steps, train),
                    Some(f) => {
                        let e = f.runner.episode(agent, train, seed, index)?;
                        Ok(Episode { ret: e.episode_return, steps: e.steps, plan_ms: Vec::new(), rewarded: 0 })
                    }
                }
            };
            let tr = play(&mut agent, base, true).with_context(|| format!("run {r} training episode {ep}"))?;
            let loss = agent.train(&mut rng);
            let ev = play(&mut agent, base + 1, false).with_context(|| format!("run {r} evaluation episode {ep}"))?;
            // Through a fleet the latency is measured where the planning runs: the actors' CSVs.
            let (mean, p90) = if fleet.is_some() { (f64::NAN, f64::NAN) } else { latency(&tr.plan_ms) };
            all_plan_ms.extend_from_slice(&tr.plan_ms);
            writeln!(csv, "{r},{ep},{},{},{},{},{loss},{mean},{p90},{:.1}", tr.ret, ev.ret, tr.steps, ev.steps, t0.elapsed().as_secs_f64())
                .and_then(|()| csv.flush())
                .map_err(AppError::io("writing episodes.csv"))?;
            let values = [
                ("episode/return", f64::from(tr.ret)),
                ("episode/eval_return", f64::from(ev.ret)),
                ("episode/env_steps", tr.steps as f64),
                ("loss/model", f64::from(loss)),
                ("time/plan_ms_mean", mean),
                ("time/plan_ms_p90", p90),
            ];
            events.scalars(ep as i64, &values).and_then(|()| events.flush()).map_err(AppError::io("writing the event file"))?;
            agent.save(&dir.join("agent.safetensors")).with_context(|| "writing the checkpoint")?;
            let plan = if fleet.is_some() { "on the actors".to_string() } else { format!("{mean:.1} ms/step") };
            coadapt_log::logln!(
                "latent {}: run {}/{} episode {}/{}: train {:.1} eval {:.1} model loss {loss:.4} plan {plan} ({:.0} s)",
                label(cfg),
                r + 1,
                cfg.runs,
                ep + 1,
                cfg.episodes,
                tr.ret,
                ev.ret,
                t0.elapsed().as_secs_f64()
            );
            tc.push(f64::from(tr.ret));
            ec.push(f64::from(ev.ret));
        }
        train_curves.push(tc);
        eval_curves.push(ec);
    }
    let on_actors = fleet.is_some();
    if let Some(f) = fleet {
        f.finish();
    }
    super::plot::draw(&out.join("plots/returns.svg"), &label(cfg), &cfg.robot, &train_curves, &eval_curves)?;
    let mean_last = |c: &[Vec<f64>]| c.iter().filter_map(|v| v.last()).sum::<f64>() / c.len().max(1) as f64;
    let (pm, p90) = latency(&all_plan_ms);
    // A resumed run's earlier planned steps count in the mean (from their per-episode means);
    // the 90th percentile covers the runs since the resume.
    let n_new = all_plan_ms.len();
    let pm = if n_new + done.plan_ms.1 > 0 { (pm * n_new as f64 + done.plan_ms.0) / (n_new + done.plan_ms.1) as f64 } else { pm };
    // Through a fleet: the mean over the actors' planned steps (their CSVs, for the actors
    // started here); no percentile across episodes can be rebuilt from theirs.
    let (pm, p90) = if on_actors {
        (
            super::actors::actors_plan_ms(&out.join("actors")).map_or(serde_json::Value::Null, serde_json::Value::from),
            serde_json::Value::Null,
        )
    } else {
        (serde_json::Value::from(pm), serde_json::Value::from(p90))
    };
    Ok(serde_json::json!({
        "run_dir": out.display().to_string(),
        "method": label(cfg),
        "robot": cfg.robot,
        "runs": cfg.runs,
        "episodes": cfg.episodes,
        "final_train_return_mean": mean_last(&train_curves),
        "final_eval_return_mean": mean_last(&eval_curves),
        "plan_ms_mean": pm,
        "plan_ms_p90": p90,
        "resumed_after_runs": done.runs,
        "seconds": t0.elapsed().as_secs_f64(),
    }))
}

/// Mean and 90th percentile of latencies (0, 0 when none).
pub(crate) fn latency(ms: &[f64]) -> (f64, f64) {
    if ms.is_empty() {
        return (0.0, 0.0);
    }
    let mut v = ms.to_vec();
    v.sort_by(f64::total_cmp);
    (v.iter().sum::<f64>() / v.len() as f64, v[(v.len() * 9 / 10).min(v.len() - 1)])
}
