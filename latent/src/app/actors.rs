//! `coadapt latent`'s actors: the episodes on N actors (threads, or `coadapt latent-actor`
//! processes over shared memory or gRPC) that plan where the robot is, and the actor process.
//!
//! Each actor holds a [`LatentActor`] and its own camera robot; the learner publishes the
//! packed networks (encoder included: an actor needs only the run's config) before every
//! episode and stores the latent transitions that come back. An actor writes each episode's
//! planning latency to its CSV (`<run>/actors/actor-<id>.csv` for the actors started here):
//! per-step latency is a property of the robot's host, not of the learner's.

use std::io::Write;
use std::path::Path;
use std::sync::atomic::AtomicBool;

use coadapt_fleet::procs::{LocalActors, ProcessFleet};

use super::config::LatentConfig;
use super::run::{camera_env, latency};
use crate::{ActorEpisode, Embedding, EpisodeRunner, FleetError, LatentActor};
use coadapt_fleet::app::{AppError, Context};

/// The learner's fleet: the episode runner over its links, and what keeps them up.
pub(crate) struct Fleet {
    pub(crate) runner: EpisodeRunner,
    actors: LocalActors<FleetError>,
}

/// One actor: its networks, sized from the config alone.
fn latent_actor(cfg: &LatentConfig, act: usize, id: u64) -> Result<LatentActor, AppError> {
    let emb = Embedding::new(cfg.embedding.shape).with_context(|| "embedding.shape")?.with_precision(cfg.embedding.precision);
    LatentActor::new(cfg.agent.clone(), emb, cfg.camera.frames, act, cfg.seed.wrapping_mul(1_000_003).wrapping_add(id))
        .with_context(|| "building the actor's networks")
}

/// Writes each episode's figures to `path` (CSV, appended).
fn latency_log(path: Option<&Path>, id: u64) -> Result<impl FnMut(&ActorEpisode) + Send + use<>, AppError> {
    let mut file = match path {
        Some(p) => {
            if let Some(dir) = p.parent().filter(|d| !d.as_os_str().is_empty()) {
                std::fs::create_dir_all(dir).map_err(AppError::io(format!("creating {}", dir.display())))?;
            }
            let new = !p.exists();
            let mut f =
                std::fs::OpenOptions::new().create(true).append(true).open(p).map_err(AppError::io(format!("opening {}", p.display())))?;
            if new {
                writeln!(f, "assignment,train,steps,return,plan_ms_mean,plan_ms_p90,seconds")
                    .map_err(AppError::io(format!("writing {}", p.display())))?;
            }
            Some(f)
        }
        None => None,
    };
    Ok(move |e: &ActorEpisode| {
        let (mean, p90) = latency(&e.plan_ms);
        coadapt_log::logln!(
            "latent actor {id}: {} episode (assignment {}): {} steps, return {:.1}, plan {mean:.1} ms/step (p90 {p90:.1}), {:.1} s",
            if e.train { "training" } else { "evaluation" },
            e.assignment,
            e.steps,
            e.episode_return,
            e.seconds
        );
        if let Some(f) = file.as_mut() {
            let row = writeln!(f, "{},{},{},{},{mean},{p90},{:.3}", e.assignment, e.train, e.steps, e.episode_return, e.seconds);
            if let Err(err) = row.and_then(|()| f.flush()) {
                coadapt_log::logln!("latent actor {id}: writing the latency CSV: {err}");
            }
        }
    })
}

/// The mean planning latency per planned step over the actors' CSVs in `dir` (each training
/// episode's mean weighted by its steps); `None` without any.
pub(crate) fn actors_plan_ms(dir: &Path) -> Option<f64> {
    let (mut sum, mut n) = (0.0, 0.0);
    for e in std::fs::read_dir(dir).ok()?.flatten() {
        let Ok(text) = std::fs::read_to_string(e.path()) else { continue };
        for row in text.lines().skip(1) {
            let v: Vec<&str> = row.split(',').collect();
            let (Some(steps), Some(ms)) = (v.get(2).and_then(|s| s.parse::<f64>().ok()), v.get(4).and_then(|s| s.parse::<f64>().ok()))
            else {
                continue;
            };
            if v.get(1) == Some(&"true") && ms.is_finite() && ms > 0.0 {
                sum += ms * steps;
                n += steps;
            }
        }
    }
    (n > 0.0).then(|| sum / n)
}

impl Fleet {
    /// The learner's side over `cfg.fleet`, with `cfg.actors` actors started here (threads,
    /// or processes unless `start-actors = false`); `out` is the run directory (its
    /// `config.toml` is what started actors read).
    pub(crate) fn start(cfg: &LatentConfig, out: &Path, act: usize) -> Result<Self, AppError> {
        let state = cfg.camera.frames * cfg.embedding.shape.latent;
        let dims = coadapt_transport::messages::Dims { obs: state, act, design: 0 };
        let lease = std::time::Duration::from_secs_f64(cfg.episode_lease_secs);
        let deadline = std::time::Duration::from_secs_f64(cfg.episode_deadline_secs);
        let csv = |i: usize| out.join("actors").join(format!("actor-{i}.csv"));
        let extra = |i: usize| vec!["--latency-csv".into(), csv(i).into_os_string()];
        let procs =
            ProcessFleet { role: "latent", subcommand: "latent-actor", actors: cfg.actors, start: cfg.start_actors, out, extra: &extra };
        let (links, actors) = LocalActors::start(&cfg.fleet, &procs, dims, cfg.episode_steps, &cfg.security, |i, mut links| {
            let mut source = camera_env(cfg)?;
            let mut actor = latent_actor(cfg, act, i as u64)?;
            let mut log = latency_log(Some(&csv(i)), i as u64)?;
            let steps = cfg.episode_steps;
            Ok::<_, AppError>(std::thread::spawn(move || {
                let stop = std::sync::atomic::AtomicBool::new(false);
                crate::run_actor(&mut actor, source.env(), steps, i as u64, &mut links, &stop, &mut log)
            }))
        })?;
        let mut runner = EpisodeRunner::new(links, state, act, cfg.episode_steps);
        runner.set_lease(lease);
        runner.set_deadline(deadline);
        // Actors started here that have all ended will never bring an episode back.
        if let Some(check) = actors.all_ended_check() {
            runner.set_abort(check);
        }
        Ok(Self { runner, actors })
    }

    /// Closes the assignment queue (the actors end by themselves) and waits for them.
    pub(crate) fn finish(self) {
        let Self { runner, actors } = self;
        drop(runner);
        actors.finish();
    }
}

/// `coadapt latent-actor`: runs the episodes a learner hands out over `cfg.fleet` (shm or
/// gRPC) on `cfg.robot`, planning here, until the learner closes the queue or `shutdown` is
/// set; each episode's planning latency is appended to `latency_csv`. Returns how many
/// episodes it ran.
pub fn actor(cfg: &LatentConfig, id: u64, latency_csv: Option<&Path>, shutdown: &AtomicBool) -> Result<u64, AppError> {
    let mut source = camera_env(cfg)?;
    let act = source.env().spec().act_dim();
    let mut actor = latent_actor(cfg, act, id)?;
    let mut links = cfg.fleet.actor_links(id, &cfg.security)?;
    let mut log = latency_log(latency_csv, id)?;
    coadapt_log::logln!("latent actor {id}: {} through the camera over {}", cfg.robot, cfg.fleet.transport.name());
    let n = crate::run_actor(&mut actor, source.env(), cfg.episode_steps, id, &mut links, shutdown, &mut log)?;
    coadapt_log::logln!("latent actor {id}: done after {n} episodes");
    Ok(n)
}
