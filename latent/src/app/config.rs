//! `coadapt latent`'s config (`[camera]`, the agent, the embedding, the fleet) and the
//! command line's overrides over it, resolved and checked before anything runs.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::embed::EmbeddingSettings;
use crate::{AgentConfig, Explore};
use coadapt_fleet::app::AppError;

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
    pub remote: coadapt_fleet::RemoteEnvConfig,
    /// TLS and token of a dm_env_rpc robot's server (and of the fleet's gRPC).
    pub security: coadapt_fleet::SecurityConfig,
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
    pub fleet: coadapt_fleet::FleetConfig,
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
            remote: coadapt_fleet::RemoteEnvConfig::default(),
            security: coadapt_fleet::SecurityConfig::default(),
            actors: 0,
            start_actors: true,
            episode_lease_secs: 120.0,
            episode_deadline_secs: 3600.0,
            fleet: coadapt_fleet::FleetConfig {
                transport: coadapt_fleet::TransportKind::InProcess,
                listen: "127.0.0.1:0".into(),
                ..coadapt_fleet::FleetConfig::default()
            },
        }
    }
}

/// What the command line overrides (each `None`: the config's value stands).
#[derive(Clone, Debug, Default)]
pub struct Overrides {
    /// `agent.explore`: plan or ou.
    pub explore: Option<String>,
    /// `agent.critic`: q or v.
    pub critic: Option<String>,
    /// `agent.objective`: sum-q, reward-plus-q or last-q.
    pub objective: Option<String>,
    pub horizon: Option<usize>,
    pub updates_per_episode: Option<usize>,
    pub runs: Option<usize>,
    pub episodes: Option<usize>,
    pub seed: Option<u64>,
    /// `embedding.path`.
    pub embedding: Option<PathBuf>,
    pub actors: Option<usize>,
    /// `fleet.transport`.
    pub transport: Option<coadapt_fleet::TransportKind>,
}

fn parse_enum<T: serde::de::DeserializeOwned>(key: &str, v: &str, choices: &str) -> Result<T, AppError> {
    T::deserialize(serde::de::value::StrDeserializer::<serde::de::value::Error>::new(v))
        .map_err(|_| AppError::Config(format!("{key} = {v:?}: one of {choices}")))
}

impl LatentConfig {
    /// The config in the TOML file at `path`.
    pub fn load(path: &Path) -> Result<Self, AppError> {
        let text = std::fs::read_to_string(path).map_err(AppError::io(format!("reading {}", path.display())))?;
        toml::from_str(&text).map_err(|e| AppError::Config(format!("parsing {}: {e}", path.display())))
    }

    /// The run directory when none is given: `runs/latent-<method>-seed<seed>`.
    pub fn default_out(&self) -> PathBuf {
        PathBuf::from(format!("runs/latent-{}-seed{}", super::run::label(self), self.seed))
    }
}

/// The config in `file` (the defaults without one) with `o` over it, checked.
pub fn resolve(file: Option<&Path>, o: &Overrides) -> Result<LatentConfig, AppError> {
    let mut cfg = match file {
        Some(p) => LatentConfig::load(p)?,
        None => LatentConfig::default(),
    };
    if let Some(v) = &o.explore {
        cfg.agent.explore = parse_enum("explore", v, "plan, ou")?;
    }
    if let Some(v) = &o.critic {
        cfg.agent.critic = parse_enum("critic", v, "q, v")?;
    }
    if let Some(v) = &o.objective {
        cfg.agent.objective = parse_enum("objective", v, "sum-q, reward-plus-q, last-q")?;
    }
    if let Some(h) = o.horizon {
        cfg.agent.horizon = h;
    }
    if let Some(u) = o.updates_per_episode {
        cfg.agent.updates_per_episode = u;
    }
    if let Some(r) = o.runs {
        cfg.runs = r;
    }
    if let Some(e) = o.episodes {
        cfg.episodes = e;
    }
    if let Some(s) = o.seed {
        cfg.seed = s;
    }
    if let Some(p) = &o.embedding {
        cfg.embedding.path = p.display().to_string();
    }
    if let Some(n) = o.actors {
        cfg.actors = n;
    }
    if let Some(t) = o.transport {
        cfg.fleet.transport = t;
    }
    check(&mut cfg)?;
    Ok(cfg)
}

/// Refuses settings that cannot run, naming the key; fills in the default embedding path.
fn check(cfg: &mut LatentConfig) -> Result<(), AppError> {
    let bad = |m: String| Err(AppError::Config(m));
    for (key, v) in [("episode-lease-secs", cfg.episode_lease_secs), ("episode-deadline-secs", cfg.episode_deadline_secs)] {
        if !(v.is_finite() && v > 0.0 && v < 1e9) {
            return bad(format!("{key} = {v}: a positive number of seconds"));
        }
    }
    if cfg.embedding.path.trim().is_empty() {
        let name: String = cfg.robot.chars().map(|c| if c.is_ascii_alphanumeric() || c == '-' { c } else { '_' }).collect();
        cfg.embedding.path = format!("runs/latent/embedding-{name}-{}px.safetensors", cfg.camera.side);
    }
    let c = &cfg.camera;
    if !(8..=1024).contains(&c.side) || c.frames == 0 || c.action_repeat == 0 {
        return bad(format!("camera: side from 8 to 1024, frames and action-repeat at least 1 ({c:?})"));
    }
    if cfg.embedding.shape.image != c.side || cfg.embedding.shape.in_channels != 3 {
        return bad(format!(
            "embedding.shape: image = {} and in-channels = {} must match the camera ({} pixels square, RGB: 3)",
            cfg.embedding.shape.image, cfg.embedding.shape.in_channels, c.side
        ));
    }
    for (key, v) in
        [("runs", cfg.runs), ("episodes", cfg.episodes), ("episode-steps", cfg.episode_steps), ("agent.horizon", cfg.agent.horizon)]
    {
        if v == 0 {
            return bad(format!("{key} = 0: at least 1"));
        }
    }
    if cfg.agent.plan_iterations == 0 && cfg.agent.explore == Explore::Plan {
        return bad("agent.plan-iterations = 0: planning needs at least 1 L-BFGS iteration".into());
    }
    if cfg.agent.ddpg.batch_size == 0 || cfg.agent.replay_capacity < cfg.agent.ddpg.batch_size {
        return bad(format!(
            "agent.ddpg.batch-size = {}: at least 1 and within agent.replay-capacity ({})",
            cfg.agent.ddpg.batch_size, cfg.agent.replay_capacity
        ));
    }
    if cfg.demonstrations > 0 && cfg.robot != "reach" {
        return bad(format!(
            "demonstrations = {}: only robot = \"reach\" has a scripted demonstrator (robot is {:?})",
            cfg.demonstrations, cfg.robot
        ));
    }
    if cfg.embedding.episodes == 0 || cfg.embedding.steps == 0 || cfg.embedding.batch == 0 {
        return bad("embedding: episodes, steps and batch at least 1 each".into());
    }
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
            let cfg = resolve(Some(&p), &Overrides::default()).unwrap_or_else(|e| panic!("{}: {e:#}", p.display()));
            assert!(!cfg.embedding.path.is_empty());
            n += 1;
        }
        assert!(n >= 2, "configs/latent holds {n} configs");
    }
}
