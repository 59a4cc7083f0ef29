//! `coadapt latent`: DDPG from pixels that explores by planning in a learned latent space
//! (thesis ch. 4, Alg. 3) on a robot seen through the camera, several runs, a run directory like
//! `coadapt run`'s: the resolved `config.toml`; `episodes.csv` (one row per run and episode: the
//! training episode's return with exploration, the deterministic actor's evaluation return
//! after it, the model's loss, planning latency); `run-<r>/agent.safetensors` after every
//! episode (actor, critic, model, reward model); `plots/returns.svg` (both returns, mean and
//! standard deviation over runs); a JSON summary on stdout.
//!
//! With `actors = N` the episodes run on actors that plan where their robot is
//! ([`crate::latent_fleet`]); the learner only trains, between episodes.
//!
//! The embedding is loaded from `[embedding] path`, or built there first (state-based DDPG's
//! episodes, see `latent_embed`): every method pointed at the same file explores in the same
//! latent space.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use coadapt_core::{Env, Pixels, PixelsConfig};
use coadapt_latent::{CriticKind, Explore, LatentAgent, Objective};

use crate::latent_config::resolve;
pub use crate::latent_config::{CameraSettings, LatentArgs, LatentConfig};
use crate::latent_embed::{FrameSource, load_or_build};

/// The robot seen through the camera: a built-in robot drawn by [`Pixels`] (one frame per
/// observation; the agent stacks codes), or a served one whose observation is the frame.
pub(crate) fn camera_env(cfg: &LatentConfig) -> anyhow::Result<FrameSource> {
    let image = 3 * cfg.camera.side * cfg.camera.side;
    if coadapt_env_rpc::is_remote(&cfg.robot) {
        let env = coadapt_fleet::make_env_with(&cfg.robot, &cfg.remote, &cfg.security).with_context(|| format!("robot = {}", cfg.robot))?;
        let got = env.spec().state_dim;
        if got != image {
            anyhow::bail!(
                "robot = {}: its observation has {got} values; camera.side = {} needs one RGB frame of {image}",
                cfg.robot,
                cfg.camera.side
            );
        }
        return Ok(FrameSource::Served(env));
    }
    let robot = coadapt_robots::make(&cfg.robot).map_err(|e| anyhow::anyhow!("robot = {:?}: {e}; or dm-env-rpc://HOST:PORT", cfg.robot))?;
    let px = PixelsConfig { width: cfg.camera.side, height: cfg.camera.side, frames: 1, action_repeat: cfg.camera.action_repeat };
    Ok(FrameSource::Drawn(Box::new(Pixels::new(robot, px).with_context(|| format!("robot = {}", cfg.robot))?)))
}

fn label(cfg: &LatentConfig) -> String {
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
) -> anyhow::Result<Episode> {
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
fn episode(agent: &mut LatentAgent, env: &mut dyn Env, seed: u64, steps: usize, train: bool) -> anyhow::Result<Episode> {
    play(agent, env, seed, steps, train, |agent, _, a| agent.act(train, a).is_some())
}

/// `n` episodes of the reach robot's scripted demonstrator through the camera, stored in the
/// agent's replay; how many succeeded.
fn demonstrate(agent: &mut LatentAgent, source: &mut FrameSource, n: usize, seed: u64, steps: usize) -> anyhow::Result<usize> {
    let FrameSource::Drawn(env) = source else { anyhow::bail!("demonstrations need the built-in reach robot") };
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

pub fn run(a: LatentArgs) -> anyhow::Result<()> {
    let cfg = resolve(&a)?;
    let (emb, enc) = load_or_build(&cfg.embedding, || camera_env(&cfg), cfg.episode_steps)?;
    if a.embed_only {
        return Ok(());
    }
    if emb.cfg.image != cfg.camera.side || emb.cfg.in_channels != 3 {
        anyhow::bail!("embedding {}: {:?} does not match the camera ({} pixels)", cfg.embedding.path, emb.cfg, cfg.camera.side);
    }
    let out = a.out.clone().unwrap_or_else(|| PathBuf::from(format!("runs/latent-{}-seed{}", label(&cfg), cfg.seed)));
    let done = if a.resume {
        crate::latent_resume::finished(&out, &cfg)?
    } else {
        if out.join("episodes.csv").exists() {
            anyhow::bail!("{} already holds a run (episodes.csv); choose another --out, or --resume it", out.display());
        }
        crate::latent_resume::Finished::default()
    };
    std::fs::create_dir_all(out.join("plots")).with_context(|| format!("creating {}", out.display()))?;
    std::fs::write(out.join("config.toml"), toml::to_string(&cfg)?).context("writing config.toml")?;
    // The finished runs' rows first (a resumed run), through a temporary file: a crash now
    // leaves the old file or the new one, never half of one.
    let tmp = out.join("episodes.csv.tmp");
    let mut head = crate::latent_resume::HEADER.to_string() + "\n";
    done.rows.iter().for_each(|r| head.extend([r.as_str(), "\n"]));
    std::fs::write(&tmp, head).context("writing episodes.csv")?;
    std::fs::rename(&tmp, out.join("episodes.csv")).context("writing episodes.csv")?;
    let mut csv =
        std::io::BufWriter::new(std::fs::OpenOptions::new().append(true).open(out.join("episodes.csv")).context("opening episodes.csv")?);
    if done.runs > 0 {
        coadapt_log::logln!("latent {}: resuming {} after its {} finished run(s)", label(&cfg), out.display(), done.runs);
    }
    let t0 = Instant::now() - std::time::Duration::from_secs_f64(done.seconds.max(0.0));
    let mut train_curves: Vec<Vec<f64>> = done.train;
    let mut eval_curves: Vec<Vec<f64>> = done.eval;
    let mut all_plan_ms = Vec::new();
    let mut fleet = None;
    for r in done.runs..cfg.runs {
        let seed = cfg.seed + r as u64;
        let mut env = camera_env(&cfg)?;
        let mut rng = coadapt_core::rng(seed, 11);
        let act = env.env().spec().act_dim();
        if cfg.actors > 0 && fleet.is_none() {
            fleet = Some(crate::latent_fleet::Fleet::start(&cfg, &out, act)?);
        }
        let mut agent = LatentAgent::new(cfg.agent.clone(), emb.clone(), enc.clone(), cfg.camera.frames, act, seed, &mut rng)?;
        let dir = out.join(format!("run-{r}"));
        std::fs::create_dir_all(&dir)?;
        if cfg.demonstrations > 0 {
            let ok = demonstrate(&mut agent, &mut env, cfg.demonstrations, seed, cfg.episode_steps)?;
            agent.train(&mut rng);
            coadapt_log::logln!(
                "latent {}: run {}: {} demonstrations in the replay ({ok} successful), model and DDPG trained on them",
                label(&cfg),
                r + 1,
                cfg.demonstrations
            );
        }
        let (mut tc, mut ec) = (Vec::new(), Vec::new());
        for ep in 0..cfg.episodes {
            let base = seed * 1_000_003 + 2 * ep as u64;
            let index = u32::try_from(r * cfg.episodes + ep).unwrap_or(u32::MAX);
            let mut play = |agent: &mut LatentAgent, seed: u64, train: bool| -> anyhow::Result<Episode> {
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
            writeln!(
                csv,
                "{r},{ep},{},{},{},{},{loss},{mean},{p90},{:.1}",
                tr.ret,
                ev.ret,
                tr.steps,
                ev.steps,
                t0.elapsed().as_secs_f64()
            )?;
            csv.flush()?;
            agent.save(&dir.join("agent.safetensors")).context("writing the checkpoint")?;
            let plan = if fleet.is_some() { "on the actors".to_string() } else { format!("{mean:.1} ms/step") };
            coadapt_log::logln!(
                "latent {}: run {}/{} episode {}/{}: train {:.1} eval {:.1} model loss {loss:.4} plan {plan} ({:.0} s)",
                label(&cfg),
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
    draw(&out.join("plots/returns.svg"), &label(&cfg), &cfg.robot, &train_curves, &eval_curves)?;
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
            crate::latent_fleet::actors_plan_ms(&out.join("actors")).map_or(serde_json::Value::Null, serde_json::Value::from),
            serde_json::Value::Null,
        )
    } else {
        (serde_json::Value::from(pm), serde_json::Value::from(p90))
    };
    let summary = serde_json::json!({
        "run_dir": out.display().to_string(),
        "method": label(&cfg),
        "robot": cfg.robot,
        "runs": cfg.runs,
        "episodes": cfg.episodes,
        "final_train_return_mean": mean_last(&train_curves),
        "final_eval_return_mean": mean_last(&eval_curves),
        "plan_ms_mean": pm,
        "plan_ms_p90": p90,
        "resumed_after_runs": done.runs,
        "seconds": t0.elapsed().as_secs_f64(),
    });
    println!("{summary}");
    Ok(())
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

/// Mean and standard deviation per episode over runs.
fn stats(curves: &[Vec<f64>]) -> Vec<(f64, f64)> {
    let n = curves.iter().map(Vec::len).min().unwrap_or(0);
    (0..n)
        .map(|i| {
            let v: Vec<f64> = curves.iter().map(|c| c[i]).collect();
            let m = v.iter().sum::<f64>() / v.len() as f64;
            (m, (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt())
        })
        .collect()
}

/// `plots/returns.svg`: training (exploring) and evaluation (deterministic) returns per episode,
/// mean and mean +- one standard deviation over runs.
fn draw(path: &Path, method: &str, robot: &str, train: &[Vec<f64>], eval: &[Vec<f64>]) -> anyhow::Result<()> {
    use plotters::prelude::*;
    let (ts, es) = (stats(train), stats(eval));
    let n = ts.len().max(es.len()).max(2);
    let all = ts.iter().chain(&es).flat_map(|(m, s)| [m - s, m + s]);
    let (lo, hi) = all.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
    let (lo, hi) = if lo.is_finite() && hi > lo { (lo - 0.05 * (hi - lo), hi + 0.05 * (hi - lo)) } else { (-1.0, 1.0) };
    let root = SVGBackend::new(path, (800, 500)).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(format!("{method} on the pixel {robot}, {} runs (mean, +- 1 sd)", train.len()), ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0f64..(n - 1) as f64, lo..hi)?;
    chart.configure_mesh().x_desc("episode").y_desc("episode return").draw()?;
    for (st, colour, name) in [(&ts, BLUE, "training (exploring)"), (&es, RED, "evaluation (deterministic actor)")] {
        chart
            .draw_series(LineSeries::new(st.iter().enumerate().map(|(i, (m, _))| (i as f64, *m)), colour.stroke_width(2)))?
            .label(name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2)));
        for sign in [1.0, -1.0] {
            chart.draw_series(LineSeries::new(st.iter().enumerate().map(|(i, (m, s))| (i as f64, m + sign * s)), colour.mix(0.35)))?;
        }
    }
    chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw()?;
    root.present()?;
    Ok(())
}
