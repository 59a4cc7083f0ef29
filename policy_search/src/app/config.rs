//! `coadapt search`'s config (the task, the method and its settings, the fleet) and the
//! command line's overrides over it, resolved and checked before anything runs.

use std::path::{Path, PathBuf};

use coadapt_fleet::{FleetConfig, TransportKind};
use serde::{Deserialize, Serialize};

use crate::{GroupsConfig, NacConfig, PlanarReaching, PowerConfig};
use coadapt_fleet::app::AppError;

/// `coadapt search`'s config (TOML, kebab-case; every key has a default).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct SearchConfig {
    /// The task: `planar` (the bimanual planar reaching benchmark, 12 actions x 25 steps).
    pub task: String,
    /// Degrees one unit of the planar task's actions turns a joint: 1 (degrees, the default:
    /// what makes the thesis's exploration variance sensible), 57.29578 (radians), or any scale
    /// between (a probe of the thesis's units).
    pub action_unit_degrees: f64,
    /// `groups` (GrouPS), `pepper` (PePPER: the factor model without priors or groups, resize
    /// sqrt(1.09)), `power` (PoWER) or `nac` (episodic Natural Actor-Critic).
    pub method: String,
    /// Independent runs (seeds seed, seed + 1, ...).
    pub runs: usize,
    /// Iterations per run.
    pub iterations: usize,
    pub seed: u64,
    /// GrouPS's groups of action indices (0-5 the left arm's joints, 6-11 the right's).
    /// Default: Eq. 2.32, joints 1-4 and 5-6 of each arm.
    pub groups: Vec<Vec<usize>>,
    /// GrouPS's settings.
    #[serde(rename = "groups-settings")]
    pub groups_settings: GroupsConfig,
    /// PoWER's settings.
    pub power: PowerConfig,
    /// eNAC's settings.
    pub nac: NacConfig,
    /// GrouPS with reuse of synergies (ch. 3): a `policy.safetensors` or `w-iter<N>.safetensors`
    /// of an earlier search whose W becomes the prior centre W-hat and the starting W (empty:
    /// none, chapter 2).
    pub w_hat: String,
    /// Also save each run's W after this iteration as `run-<r>/w-iter<N>.safetensors` (0: no).
    pub save_w_at: usize,
    /// `plots/synergy_poses.svg` shows the two strongest synergies of run 0 after this
    /// iteration (the thesis found the most useful ones at iterations 7-8).
    pub synergy_iteration: usize,
    /// Where the rollouts run: 0 in this process, one after the other; N > 0 on N actors over
    /// `fleet.transport` (each rollout's actions go out, its transitions and return come back).
    pub actors: usize,
    /// With actors over shm or gRPC: start them here as `coadapt search-actor` processes
    /// (true), or wait for actors started elsewhere, e.g. on robots' hosts (false).
    pub start_actors: bool,
    /// A rollout that sent nothing for this many seconds goes to another actor.
    pub rollout_lease_secs: f64,
    /// An iteration whose rollouts are not all back after this many seconds stops the search.
    pub iteration_deadline_secs: f64,
    /// How the search and its actors talk (`transport`, `name`, `listen`, `connect`, ...:
    /// the `[fleet]` table of a run config).
    pub fleet: FleetConfig,
    /// TLS and tokens of a gRPC fleet (the `[security]` table of a run config).
    pub security: coadapt_fleet::SecurityConfig,
    /// The robot the actors step: empty for the built-in planar robot, or
    /// `dm-env-rpc://HOST:PORT` for one served over dm_env_rpc (`coadapt env-serve --env
    /// planar`, or a real robot's server with the planar task's shape).
    pub robot: String,
    /// Deadlines and retries of a dm_env_rpc robot.
    pub remote: coadapt_fleet::RemoteEnvConfig,
}

impl SearchConfig {
    /// The planar benchmark in the config's units.
    pub fn planar(&self) -> PlanarReaching {
        let mut t = PlanarReaching::default();
        t.geometry.unit_degrees = self.action_unit_degrees;
        t
    }
}

impl Default for SearchConfig {
    fn default() -> Self {
        Self {
            task: "planar".into(),
            action_unit_degrees: 1.0,
            method: "groups".into(),
            runs: 10,
            iterations: 100,
            seed: 1,
            groups: vec![vec![0, 1, 2, 3], vec![4, 5], vec![6, 7, 8, 9], vec![10, 11]],
            groups_settings: GroupsConfig::default(),
            power: PowerConfig::default(),
            nac: NacConfig::default(),
            w_hat: String::new(),
            save_w_at: 0,
            synergy_iteration: 8,
            actors: 0,
            start_actors: true,
            rollout_lease_secs: 60.0,
            iteration_deadline_secs: 3600.0,
            fleet: FleetConfig { transport: TransportKind::InProcess, listen: "127.0.0.1:0".into(), ..FleetConfig::default() },
            security: coadapt_fleet::SecurityConfig::default(),
            robot: String::new(),
            remote: coadapt_fleet::RemoteEnvConfig::default(),
        }
    }
}

/// What the command line overrides (each `None`: the config's value stands).
#[derive(Clone, Debug, Default)]
pub struct Overrides {
    /// `method`: groups, pepper, power or nac.
    pub method: Option<String>,
    pub runs: Option<usize>,
    pub iterations: Option<usize>,
    pub seed: Option<u64>,
    pub actors: Option<usize>,
    /// `fleet.transport`.
    pub transport: Option<TransportKind>,
}

impl SearchConfig {
    /// The config in the TOML file at `path`.
    pub fn load(path: &Path) -> Result<Self, AppError> {
        let text = std::fs::read_to_string(path).map_err(AppError::io(format!("reading {}", path.display())))?;
        toml::from_str(&text).map_err(|e| AppError::Config(format!("parsing {}: {e}", path.display())))
    }

    /// The config of an actor process: the search's file, its task one an actor can step.
    pub fn load_for_actor(path: &Path) -> Result<Self, AppError> {
        let cfg = Self::load(path)?;
        if cfg.task != "planar" {
            return Err(AppError::Config(format!("task: {:?}; only \"planar\" so far", cfg.task)));
        }
        Ok(cfg)
    }

    /// The run directory when none is given: `runs/search-<method>-seed<seed>`.
    pub fn default_out(&self) -> PathBuf {
        PathBuf::from(format!("runs/search-{}-seed{}", self.method, self.seed))
    }
}

/// The config in `file` (the defaults without one) with `o` over it, checked.
pub fn resolve(file: Option<&Path>, o: &Overrides) -> Result<SearchConfig, AppError> {
    let mut cfg = match file {
        Some(p) => SearchConfig::load(p)?,
        None => SearchConfig::default(),
    };
    if let Some(m) = &o.method {
        cfg.method = m.clone();
    }
    if let Some(r) = o.runs {
        cfg.runs = r;
    }
    if let Some(i) = o.iterations {
        cfg.iterations = i;
    }
    if let Some(s) = o.seed {
        cfg.seed = s;
    }
    if let Some(n) = o.actors {
        cfg.actors = n;
    }
    if let Some(t) = o.transport {
        cfg.fleet.transport = t;
    }
    check(&cfg)?;
    Ok(cfg)
}

/// Refuses settings that cannot run, naming the key.
fn check(cfg: &SearchConfig) -> Result<(), AppError> {
    let bad = |m: String| Err(AppError::Config(m));
    for (key, v) in [("rollout-lease-secs", cfg.rollout_lease_secs), ("iteration-deadline-secs", cfg.iteration_deadline_secs)] {
        if !(v > 0.0 && v.is_finite()) {
            return bad(format!("{key} = {v}: a positive number of seconds"));
        }
    }
    if cfg.task != "planar" {
        return bad(format!("task: {:?}; only \"planar\" (the bimanual planar reaching benchmark) so far", cfg.task));
    }
    if !(cfg.action_unit_degrees > 0.0 && cfg.action_unit_degrees.is_finite()) {
        return bad(format!("action-unit-degrees = {}: a positive number of degrees", cfg.action_unit_degrees));
    }
    if !["groups", "pepper", "power", "nac"].contains(&cfg.method.as_str()) {
        return bad(format!("method: {:?}; groups, pepper, power or nac", cfg.method));
    }
    // Settings that would degrade silently (a sampler falling back to another variance, a
    // selection clipped to what exists) are refused, naming the key.
    let p = &cfg.power;
    if cfg.method == "power" {
        if !(p.variance > 0.0 && p.variance.is_finite()) {
            return bad(format!("power.variance = {}: must be positive", p.variance));
        }
        if p.best == 0 || p.best > p.rollouts {
            return bad(format!("power.best = {}: between 1 and power.rollouts ({})", p.best, p.rollouts));
        }
    }
    if cfg.method == "nac" {
        cfg.nac.check().map_err(|e| AppError::Config(e.to_string()))?;
    }
    if cfg.runs == 0 || cfg.iterations == 0 {
        return bad("runs and iterations: at least 1 each".into());
    }
    Ok(())
}
