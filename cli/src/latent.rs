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
use clap::Args;
use coadapt_core::{Env, Pixels, PixelsConfig};
use coadapt_latent::{AgentConfig, CriticKind, Explore, LatentAgent, Objective};
use serde::{Deserialize, Serialize};

use crate::latent_embed::{EmbeddingSettings, FrameSource, load_or_build};

/// The camera (the `[camera]` table).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct CameraSettings {
    /// Square images of this side (64 in the thesis).
    pub side: usize,
    /// Codes stacked in the latent state (3 in simulation).
    pub frames: usize,
    /// Robot steps per agent step, with the same action (2 in the thesis).
    pub action_repeat: usize,
}

impl Default for CameraSettings {
    fn default() -> Self {
        Self { side: 64, frames: 3, action_repeat: 2 }
    }
}

/// `coadapt latent`'s config (TOML, kebab-case; every key has a default).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct LatentConfig {
    /// A built-in robot that can be drawn (half-cheetah, walker, hopper, pendulum, ...), seen
    /// through our camera; or `dm-env-rpc://HOST:PORT`, a server whose observation is one
    /// `side x side` RGB frame, channel-major, in [0, 1] (e.g. DeepMind Control's cheetah:
    /// `coadapt-gym-serve --dmc cheetah-run`; it repeats actions itself, `camera.action-repeat`
    /// is not applied again).
    pub robot: String,
    pub camera: CameraSettings,
    /// Agent steps per episode (420 in the thesis's cheetah); fewer if the robot ends it.
    pub episode_steps: usize,
    /// Training episodes per run, each followed by an evaluation episode.
    pub episodes: usize,
    /// Independent runs (seeds seed, seed + 1, ...) sharing the embedding.
    pub runs: usize,
    pub seed: u64,
    /// Scripted demonstrations put in the replay before each run's first episode (and the model
    /// and DDPG trained on them once, `agent.updates-per-episode` steps): the thesis put 5
    /// successful ones in for the sparse insertion task. Only for `robot = "reach"`, whose
    /// demonstrator is built in.
    pub demonstrations: usize,
    /// Alg. 3: critic, exploration, horizon, objective, model, DDPG.
    pub agent: AgentConfig,
    /// The frozen embedding: where it is, how it is built when it is not there yet.
    pub embedding: EmbeddingSettings,
    /// Deadlines and retries of a dm_env_rpc robot.
    pub remote: crate::roles::RemoteEnvConfig,
    /// TLS and token of a dm_env_rpc robot's server (and of the fleet's gRPC).
    pub security: crate::security::SecurityConfig,
    /// Where the episodes run: 0 in this process; N > 0 on N actors over `fleet.transport`,
    /// each planning where its robot is (`coadapt latent-actor`): the learner publishes the
    /// networks before every episode, the latent transitions come back.
    pub actors: usize,
    /// With actors over shm or gRPC: start them here as `coadapt latent-actor` processes
    /// (true), or wait for actors started elsewhere, e.g. on the robots' hosts (false).
    pub start_actors: bool,
    /// An episode an actor has sent nothing of for this long goes to another actor (seconds).
    pub episode_lease_secs: f64,
    /// An episode not back after this long stops the run (seconds).
    pub episode_deadline_secs: f64,
    /// How the learner and its actors talk (`transport`, `name`, `listen`, `connect`, ...:
    /// as `coadapt run`'s `[fleet]`; in-process threads by default).
    pub fleet: crate::fleet::FleetConfig,
}

impl Default for LatentConfig {
    fn default() -> Self {
        Self {
            robot: "half-cheetah".into(),
            camera: CameraSettings::default(),
            episode_steps: 420,
            episodes: 30,
            runs: 5,
            seed: 1,
            demonstrations: 0,
            agent: AgentConfig::default(),
            embedding: EmbeddingSettings::default(),
            remote: crate::roles::RemoteEnvConfig::default(),
            security: crate::security::SecurityConfig::default(),
            actors: 0,
            start_actors: true,
            episode_lease_secs: 120.0,
            episode_deadline_secs: 3600.0,
            fleet: crate::fleet::FleetConfig {
                transport: crate::fleet::TransportKind::InProcess,
                listen: "127.0.0.1:0".into(),
                ..crate::fleet::FleetConfig::default()
            },
        }
    }
}

/// DDPG from pixels exploring by latent trajectory optimisation (thesis ch. 4).
#[derive(Debug, Args)]
pub struct LatentArgs {
    /// The TOML config (default: the pixel half-cheetah, Q critic, planning with H = 10).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override `agent.explore`: plan or ou.
    #[arg(long)]
    pub explore: Option<String>,
    /// Override `agent.critic`: q or v.
    #[arg(long)]
    pub critic: Option<String>,
    /// Override `agent.objective`: sum-q, reward-plus-q or last-q.
    #[arg(long)]
    pub objective: Option<String>,
    /// Override `agent.horizon`.
    #[arg(long)]
    pub horizon: Option<usize>,
    /// Override `agent.updates-per-episode` (1000 in Fig. 4.5, 3000 in Fig. 4.6).
    #[arg(long)]
    pub updates_per_episode: Option<usize>,
    /// Override `runs`.
    #[arg(long)]
    pub runs: Option<usize>,
    /// Override `episodes`.
    #[arg(long)]
    pub episodes: Option<usize>,
    /// Override `seed`.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Override `embedding.path`.
    #[arg(long)]
    pub embedding: Option<PathBuf>,
    /// Only load or build the embedding, then stop.
    #[arg(long)]
    pub embed_only: bool,
    /// The run directory (default runs/latent-<explore>-<critic>-h<H>-seed<seed>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Override `actors`: run the episodes on N actors that plan where the robot is (0: in
    /// this process).
    #[arg(long)]
    pub actors: Option<usize>,
    /// Override fleet.transport: in-process (threads), shm or grpc.
    #[arg(long, value_enum)]
    pub transport: Option<crate::fleet::TransportKind>,
}

fn parse_enum<T: serde::de::DeserializeOwned>(key: &str, v: &str, choices: &str) -> anyhow::Result<T> {
    T::deserialize(serde::de::value::StrDeserializer::<serde::de::value::Error>::new(v))
        .map_err(|_| anyhow::anyhow!("{key} = {v:?}: one of {choices}"))
}

pub(crate) fn resolve(a: &LatentArgs) -> anyhow::Result<LatentConfig> {
    let mut cfg: LatentConfig = match &a.config {
        Some(p) => {
            let text = std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            toml::from_str(&text).with_context(|| format!("parsing {}", p.display()))?
        }
        None => LatentConfig::default(),
    };
    if let Some(v) = &a.explore {
        cfg.agent.explore = parse_enum("explore", v, "plan, ou")?;
    }
    if let Some(v) = &a.critic {
        cfg.agent.critic = parse_enum("critic", v, "q, v")?;
    }
    if let Some(v) = &a.objective {
        cfg.agent.objective = parse_enum("objective", v, "sum-q, reward-plus-q, last-q")?;
    }
    if let Some(h) = a.horizon {
        cfg.agent.horizon = h;
    }
    if let Some(u) = a.updates_per_episode {
        cfg.agent.updates_per_episode = u;
    }
    if let Some(r) = a.runs {
        cfg.runs = r;
    }
    if let Some(e) = a.episodes {
        cfg.episodes = e;
    }
    if let Some(s) = a.seed {
        cfg.seed = s;
    }
    if let Some(p) = &a.embedding {
        cfg.embedding.path = p.display().to_string();
    }
    if let Some(n) = a.actors {
        cfg.actors = n;
    }
    if let Some(t) = a.transport {
        cfg.fleet.transport = t;
    }
    for (key, v) in [("episode-lease-secs", cfg.episode_lease_secs), ("episode-deadline-secs", cfg.episode_deadline_secs)] {
        if !(v.is_finite() && v > 0.0 && v < 1e9) {
            anyhow::bail!("{key} = {v}: a positive number of seconds");
        }
    }
    if cfg.embedding.path.trim().is_empty() {
        let name: String = cfg.robot.chars().map(|c| if c.is_ascii_alphanumeric() || c == '-' { c } else { '_' }).collect();
        cfg.embedding.path = format!("runs/latent/embedding-{name}-{}px.safetensors", cfg.camera.side);
    }
    let c = &cfg.camera;
    if !(8..=1024).contains(&c.side) || c.frames == 0 || c.action_repeat == 0 {
        anyhow::bail!("camera: side from 8 to 1024, frames and action-repeat at least 1 ({c:?})");
    }
    if cfg.embedding.shape.image != c.side || cfg.embedding.shape.in_channels != 3 {
        anyhow::bail!(
            "embedding.shape: image = {} and in-channels = {} must match the camera ({} pixels square, RGB: 3)",
            cfg.embedding.shape.image,
            cfg.embedding.shape.in_channels,
            c.side
        );
    }
    for (key, v) in
        [("runs", cfg.runs), ("episodes", cfg.episodes), ("episode-steps", cfg.episode_steps), ("agent.horizon", cfg.agent.horizon)]
    {
        if v == 0 {
            anyhow::bail!("{key} = 0: at least 1");
        }
    }
    if cfg.agent.plan_iterations == 0 && cfg.agent.explore == Explore::Plan {
        anyhow::bail!("agent.plan-iterations = 0: planning needs at least 1 L-BFGS iteration");
    }
    if cfg.agent.ddpg.batch_size == 0 || cfg.agent.replay_capacity < cfg.agent.ddpg.batch_size {
        anyhow::bail!(
            "agent.ddpg.batch-size = {}: at least 1 and within agent.replay-capacity ({})",
            cfg.agent.ddpg.batch_size,
            cfg.agent.replay_capacity
        );
    }
    if cfg.demonstrations > 0 && cfg.robot != "reach" {
        anyhow::bail!(
            "demonstrations = {}: only robot = \"reach\" has a scripted demonstrator (robot is {:?})",
            cfg.demonstrations,
            cfg.robot
        );
    }
    if cfg.embedding.episodes == 0 || cfg.embedding.steps == 0 || cfg.embedding.batch == 0 {
        anyhow::bail!("embedding: episodes, steps and batch at least 1 each");
    }
    Ok(cfg)
}

/// The robot seen through the camera: a built-in robot drawn by [`Pixels`] (one frame per
/// observation; the agent stacks codes), or a served one whose observation is the frame.
pub(crate) fn camera_env(cfg: &LatentConfig) -> anyhow::Result<FrameSource> {
    let image = 3 * cfg.camera.side * cfg.camera.side;
    if coadapt_env_rpc::is_remote(&cfg.robot) {
        let env = crate::roles::make_env_with(&cfg.robot, &cfg.remote, &cfg.security).with_context(|| format!("robot = {}", cfg.robot))?;
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
}

/// One episode of `agent` on `env`: exploring and stored (training), or deterministic.
fn episode(agent: &mut LatentAgent, env: &mut dyn Env, seed: u64, steps: usize, train: bool) -> anyhow::Result<Episode> {
    let px = agent.image_len();
    let design = env.spec().default_design.clone();
    let first = env.reset(seed, &design)?[..px].to_vec();
    let mut z = agent.reset(&first).to_vec();
    let mut a = vec![0.0; env.spec().act_dim()];
    let mut out = Episode { ret: 0.0, steps: 0, plan_ms: Vec::new() };
    for _ in 0..steps {
        let t = Instant::now();
        if agent.act(train, &mut a).is_some() {
            out.plan_ms.push(t.elapsed().as_secs_f64() * 1e3);
        }
        let s = env.step(&a)?;
        let (r, term, trunc) = (s.reward, s.terminated, s.truncated);
        let next = agent.observe(&s.observation[..px]).to_vec();
        if train {
            agent.store(&z, &a, r, &next, term)?;
        }
        out.ret += r;
        out.steps += 1;
        z = next;
        if term || trunc {
            break;
        }
    }
    Ok(out)
}

/// `n` episodes of the reach robot's scripted demonstrator through the camera, stored in the
/// agent's replay; how many succeeded.
fn demonstrate(agent: &mut LatentAgent, source: &mut FrameSource, n: usize, seed: u64, steps: usize) -> anyhow::Result<usize> {
    let FrameSource::Drawn(env) = source else { anyhow::bail!("demonstrations need the built-in reach robot") };
    let px = agent.image_len();
    let design = env.spec().default_design.clone();
    let mut a = vec![0.0; env.spec().act_dim()];
    let mut ok = 0;
    for d in 0..n {
        let first = env.reset(seed * 1_000_003 + 500_000 + d as u64, &design)?[..px].to_vec();
        let mut z = agent.reset(&first).to_vec();
        for _ in 0..steps {
            coadapt_robots::reach::demonstration_action(env.state(), &mut a);
            let s = env.step(&a)?;
            let (r, term, trunc) = (s.reward, s.terminated, s.truncated);
            let next = agent.observe(&s.observation[..px]).to_vec();
            agent.store(&z, &a, r, &next, term)?;
            z = next;
            if r > 0.0 {
                ok += 1;
            }
            if term || trunc {
                break;
            }
        }
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
    if out.join("episodes.csv").exists() {
        anyhow::bail!("{} already holds a run (episodes.csv); choose another --out", out.display());
    }
    std::fs::create_dir_all(out.join("plots")).with_context(|| format!("creating {}", out.display()))?;
    std::fs::write(out.join("config.toml"), toml::to_string(&cfg)?).context("writing config.toml")?;
    let mut csv = std::io::BufWriter::new(std::fs::File::create(out.join("episodes.csv"))?);
    writeln!(csv, "run,episode,train_return,eval_return,train_steps,eval_steps,model_loss,plan_ms_mean,plan_ms_p90,seconds")?;
    let t0 = Instant::now();
    let mut train_curves: Vec<Vec<f64>> = Vec::new();
    let mut eval_curves: Vec<Vec<f64>> = Vec::new();
    let mut all_plan_ms = Vec::new();
    let mut fleet = None;
    for r in 0..cfg.runs {
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
            eprintln!(
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
                        Ok(Episode { ret: e.episode_return, steps: e.steps, plan_ms: Vec::new() })
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
            eprintln!(
                "latent {}: run {}/{} episode {}/{}: train {:.1} eval {:.1} model loss {loss:.4} plan {mean:.1} ms/step ({:.0} s)",
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
    if let Some(f) = fleet {
        f.finish();
    }
    draw(&out.join("plots/returns.svg"), &label(&cfg), &cfg.robot, &train_curves, &eval_curves)?;
    let mean_last = |c: &[Vec<f64>]| c.iter().filter_map(|v| v.last()).sum::<f64>() / c.len().max(1) as f64;
    let (pm, p90) = latency(&all_plan_ms);
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

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

    use super::*;

    /// Every shipped config resolves (known keys, consistent camera and embedding).
    #[test]
    fn the_shipped_latent_configs_resolve() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/latent");
        let mut n = 0;
        for e in std::fs::read_dir(&dir).unwrap() {
            let p = e.unwrap().path();
            let args = LatentArgs {
                config: Some(p.clone()),
                explore: None,
                critic: None,
                objective: None,
                horizon: None,
                updates_per_episode: None,
                runs: None,
                episodes: None,
                seed: None,
                embedding: None,
                embed_only: false,
                out: None,
                actors: None,
                transport: None,
            };
            let cfg = resolve(&args).unwrap_or_else(|e| panic!("{}: {e:#}", p.display()));
            assert!(!cfg.embedding.path.is_empty());
            n += 1;
        }
        assert!(n >= 2, "configs/latent holds {n} configs");
    }
}
