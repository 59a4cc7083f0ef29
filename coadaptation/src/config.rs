//! [`RunConfig`]: everything a co-adaptation run needs (the TOML file's layout), read with a
//! command line's [`Overrides`] and checked against the robot.

use std::path::{Path, PathBuf};

use coadapt_core::EnvSpec;
use coadapt_design_optimizer::role::{ExploitMethod, ExploreMethod, OptimizerConfig, QModeConfig};
use coadapt_fleet::{FleetConfig, TransportKind};
use coadapt_learner::coadapt::ScheduleConfig;
use coadapt_learner::fear::FearLearnerConfig;
use coadapt_learner::flow::{FlowConfig, FlowMode};
use coadapt_robots::World;
use serde::{Deserialize, Serialize};

use crate::transfer::InitPopulation;

use crate::error::Context;

/// coadapt's default run, used when no `--config` is given: HalfCheetah on the reduced protocol
/// with the ensemble's design choice (`configs/half-cheetah.toml`; EXPERIMENTS 5.13 has the
/// rule it met). The serde defaults below stay the thesis's FEAR, so `*-reduced.toml` and
/// `*-reference.toml` (and every archived config) keep meaning the thesis's protocol.
pub const DEFAULT_CONFIG: &str = include_str!("../../configs/half-cheetah.toml");

/// The name of [`DEFAULT_CONFIG`]: run directories default to `runs/<name>-seed<seed>`.
pub const DEFAULT_CONFIG_NAME: &str = "half-cheetah";

/// Everything a co-adaptation run needs; the TOML file's layout.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct RunConfig {
    /// The robot (pendulum, half-cheetah, walker, hopper, daisy), or a remote one served over
    /// dm_env_rpc: `dm-env-rpc://HOST:PORT` (dimensions and boxes come from its specs).
    pub env: String,
    /// The world the robot steps in (`friction`, `actuator-scale`, `torso-mass-scale`), each the
    /// robot's own unless set; a remote robot receives them as CreateWorld settings.
    #[serde(skip_serializing_if = "World::is_default")]
    pub world: World,
    /// Start the population networks from another run's (transfer, thesis section 6.1):
    /// `from` = its run directory, `replay` = also its population replay.
    #[serde(skip_serializing_if = "InitPopulation::is_off")]
    pub init_population: InitPopulation,
    /// Seed of every random stream: the same seed and config give the same run.
    pub seed: u64,
    /// Actors running episodes (processes, or threads in-process; lock-step uses one at a time).
    pub actors: usize,
    /// Transitions per experience chunk an actor sends.
    pub chunk_len: usize,
    /// Threads running the simulation baselines' rollouts.
    pub sim_threads: usize,
    /// Points per side of the design-landscape grid drawn at the end (0: no landscape).
    pub landscape_grid: usize,
    /// Start states of Eq. 5.6 for the landscape (the thesis's figures use 256).
    pub landscape_start_states: usize,
    pub schedule: ScheduleConfig,
    /// Collection against training: lock-step (the reference) or episodes in flight.
    pub flow: FlowConfig,
    /// How the roles talk and find each other.
    pub fleet: FleetConfig,
    pub learner: FearLearnerConfig,
    pub optimizer: OptimizerConfig,
    /// Deadlines and retries of a remote environment.
    pub remote: coadapt_fleet::RemoteEnvConfig,
    /// Snapshots of the whole run for `--resume` (`every-episodes`, `keep`, `max-share`).
    pub snapshot: coadapt_learner::snapshot::SnapshotConfig,
    /// Prometheus `/metrics` of the learner and the optimiser (`learner-listen`,
    /// `optimizer-listen`; empty: off).
    pub metrics: crate::metrics::MetricsConfig,
    /// The learner's DesignService and `design-critic` model during the run (`listen`; empty:
    /// off) and their bounds.
    pub design_service: crate::design_live::DesignServiceConfig,
    /// TLS and tokens of every gRPC endpoint (`tls-cert`, `tls-key`, `tls-ca`, `tokens-file`,
    /// `token-file`, `insecure`, ...).
    pub security: coadapt_fleet::SecurityConfig,
}

impl RunConfig {
    /// The run's robot in its world (a built-in one, or one served over dm_env_rpc).
    pub fn make_env(&self) -> Result<Box<dyn coadapt_core::Env>, coadapt_fleet::SetupError> {
        coadapt_fleet::make_env_with(&self.env, &self.world, &self.remote, &self.security)
    }
}

impl Default for RunConfig {
    fn default() -> Self {
        Self {
            env: "half-cheetah".into(),
            world: World::default(),
            init_population: InitPopulation::default(),
            seed: 1,
            actors: 1,
            chunk_len: 250,
            sim_threads: 2,
            landscape_grid: 40,
            landscape_start_states: 256,
            schedule: ScheduleConfig::default(),
            flow: FlowConfig::default(),
            fleet: FleetConfig::default(),
            learner: FearLearnerConfig::default(),
            optimizer: OptimizerConfig::default(),
            remote: coadapt_fleet::RemoteEnvConfig::default(),
            snapshot: coadapt_learner::snapshot::SnapshotConfig::default(),
            metrics: crate::metrics::MetricsConfig::default(),
            design_service: crate::design_live::DesignServiceConfig::default(),
            security: coadapt_fleet::SecurityConfig::default(),
        }
    }
}

fn parse_enum<T: serde::de::DeserializeOwned>(flag: &str, v: &str) -> crate::Result<T> {
    T::deserialize(serde::de::value::StrDeserializer::<serde::de::value::Error>::new(v))
        .map_err(|e| crate::AppError::Config(format!("--{flag} {v}: {e}")))
}

/// What a command line may change in a config (each `None`/`false`: as the config says).
#[derive(Clone, Debug, Default)]
pub struct Overrides {
    pub seed: Option<u64>,
    /// `optimizer.exploit`, by its config name.
    pub exploit: Option<String>,
    /// `optimizer.explore`, by its config name.
    pub explore: Option<String>,
    pub designs: Option<usize>,
    pub transport: Option<TransportKind>,
    pub actors: Option<usize>,
    /// `flow.mode`, by its config name.
    pub flow: Option<String>,
    /// `design-service.listen`.
    pub serve: Option<String>,
    /// `security.insecure`.
    pub insecure: bool,
    /// `init-population.from` (made absolute, so the record holds wherever it is read).
    pub init_population: Option<PathBuf>,
    /// `world.friction`.
    pub friction: Option<f32>,
    /// `world.actuator-scale`.
    pub actuator_scale: Option<f32>,
    /// `world.torso-mass-scale`.
    pub torso_mass_scale: Option<f32>,
    /// `learner.sac.precision`.
    pub precision: Option<coadapt_nn::Precision>,
}

/// Reads the config: `resume`'s config.toml when resuming without `config`, else `config`, else
/// the embedded default ([`DEFAULT_CONFIG`]); then the overrides. Returns it with its name (the file's
/// stem).
pub fn resolve(config: Option<&Path>, resume: Option<&Path>, o: &Overrides) -> crate::Result<(RunConfig, String)> {
    let resumed_config = match (resume, config) {
        (Some(dir), None) => Some(dir.join("config.toml")),
        _ => None,
    };
    let (text, name) = match resumed_config.as_deref().or(config) {
        Some(p) => (
            std::fs::read_to_string(p).with_context(|| format!("reading config {}", p.display()))?,
            p.file_stem().map_or("run".into(), |s| s.to_string_lossy().into_owned()),
        ),
        None => (DEFAULT_CONFIG.to_string(), DEFAULT_CONFIG_NAME.into()),
    };
    let mut cfg: RunConfig = toml::from_str(&text).map_err(|e| crate::AppError::Config(format!("parsing config {name}: {e}")))?;
    if let Some(s) = o.seed {
        cfg.seed = s;
    }
    if let Some(m) = &o.exploit {
        cfg.optimizer.exploit = parse_enum::<ExploitMethod>("exploit", m)?;
    }
    if let Some(m) = &o.explore {
        cfg.optimizer.explore = parse_enum::<ExploreMethod>("explore", m)?;
    }
    if let Some(d) = o.designs {
        cfg.schedule.designs = d;
    }
    if let Some(t) = o.transport {
        cfg.fleet.transport = t;
    }
    if let Some(n) = o.actors {
        cfg.actors = n;
    }
    if let Some(f) = &o.flow {
        cfg.flow.mode = parse_enum::<FlowMode>("flow", f)?;
    }
    if let Some(a) = &o.serve {
        cfg.design_service.listen = a.clone();
    }
    if o.insecure {
        cfg.security.insecure = true;
    }
    if let Some(dir) = &o.init_population {
        let full = std::fs::canonicalize(dir).map_err(|e| crate::AppError::Config(format!("--init-population {}: {e}", dir.display())))?;
        cfg.init_population.from = full.display().to_string();
    }
    if let Some(f) = o.friction {
        cfg.world.friction = Some(f);
    }
    if let Some(x) = o.actuator_scale {
        cfg.world.actuator_scale = x;
    }
    if let Some(x) = o.torso_mass_scale {
        cfg.world.torso_mass_scale = x;
    }
    if let Some(p) = o.precision {
        cfg.learner.sac.precision = p;
    }
    cfg.world.check().map_err(|e| crate::AppError::Config(e.to_string()))?;
    Ok((cfg, name))
}

/// Fills in what the config leaves to the robot: the initial designs.
pub fn resolve_initial_designs(cfg: &mut RunConfig, spec: &EnvSpec) {
    if !cfg.schedule.initial_designs.is_empty() {
        return;
    }
    cfg.schedule.initial_designs = coadapt_robots::reference_initial_designs(&cfg.env).unwrap_or_else(|| {
        let mut rng = coadapt_core::rng(cfg.seed, 0x494e_4954);
        let mut v = vec![spec.default_design.clone()];
        for _ in 0..4 {
            let mut d = vec![0.0; spec.design_dim()];
            spec.design.sample(&mut rng, &mut d);
            v.push(d);
        }
        v
    });
}

/// Checks what the config asks of the robot `spec` and of the fleet.
pub fn check(cfg: &RunConfig, spec: &EnvSpec) -> crate::Result<()> {
    if cfg.schedule.designs == 0 {
        crate::error::bail_config!("schedule.designs: must be at least 1");
    }
    if cfg.actors == 0 {
        crate::error::bail_config!("actors: must be at least 1");
    }
    if cfg.schedule.designs > cfg.schedule.initial_designs.len() && spec.design_dim() == 0 {
        crate::error::bail_config!(
            "env {}: has no design parameters to optimise (a dm_env_rpc server without a `design` observation is a fixed-design environment: train on it with coadapt train, or give schedule.designs no more designs than schedule.initial-designs)",
            cfg.env
        );
    }
    for (i, d) in cfg.schedule.initial_designs.iter().enumerate() {
        spec.design.check("design", d).map_err(|e| crate::AppError::Config(format!("schedule.initial-designs[{i}]: {e}")))?;
    }
    if cfg.optimizer.q == QModeConfig::Heads && cfg.learner.population_critics < 3 {
        crate::error::bail_config!(
            "optimizer.q: \"heads\" scores designs with the critics beyond the twin and learner.population-critics = {} leaves none; \
             set learner.population-critics = 3 or more (with [learner.conservative] weight above 0 they are conservative design critics)",
            cfg.learner.population_critics
        );
    }
    cfg.flow.lease()?;
    cfg.schedule.poll_interval()?;
    cfg.remote.options(&cfg.security)?;
    if cfg.fleet.transport == TransportKind::Shm && cfg.actors > cfg.fleet.max_actors {
        crate::error::bail_config!(
            "actors: {} is more than fleet.max-actors ({}); raise fleet.max-actors",
            cfg.actors,
            cfg.fleet.max_actors
        );
    }
    Ok(())
}

/// `runs/<name>-seed<seed>`, or with `-2`, `-3`, ... appended when that already holds a run, so
/// running the same command again never overwrites or refuses.
pub fn default_out(name: &str, seed: u64) -> PathBuf {
    let base = PathBuf::from("runs").join(format!("{name}-seed{seed}"));
    let mut dir = base.clone();
    let mut i = 2;
    while dir.join("designs.csv").exists() {
        dir = PathBuf::from(format!("{}-{i}", base.display()));
        i += 1;
    }
    dir
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(name: &str) -> RunConfig {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs").join(name);
        let text = std::fs::read_to_string(&path).unwrap();
        toml::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
    }

    /// The product configs are the thesis's reduced protocol plus the ensemble's keys and
    /// nothing else, and the thesis's files (which every FEAR line of the campaign queues and
    /// every transfer source names) still resolve to FEAR: two critics scored by Q1.
    #[test]
    fn the_default_is_the_reduced_protocol_with_the_ensemble_and_the_thesis_files_stay_fear() {
        for robot in ["half-cheetah", "walker", "hopper", "daisy"] {
            let fear = read(&format!("{robot}-reduced.toml"));
            assert_eq!((fear.learner.population_critics, fear.optimizer.q), (2, QModeConfig::Q1), "{robot}-reduced.toml");
            let reference = read(&format!("{robot}-reference.toml"));
            assert_eq!((reference.learner.population_critics, reference.optimizer.q), (2, QModeConfig::Q1), "{robot}-reference.toml");

            let mut expected = fear;
            expected.learner.population_critics = 5;
            expected.optimizer.q = QModeConfig::Pessimistic;
            expected.optimizer.pessimism = 2.0;
            assert_eq!(read(&format!("{robot}.toml")), expected, "{robot}.toml is not {robot}-reduced.toml plus the ensemble");
        }
        let (embedded, name) = resolve(None, None, &Overrides::default()).unwrap();
        assert_eq!((embedded, name.as_str()), (read("half-cheetah.toml"), "half-cheetah"));
    }
}
