//! Actor processes a learner starts itself (`coadapt search`, `coadapt latent`): spawned with
//! the run's config and the fleet's coordinates, logged to `<run>/logs/actor-<i>.log`, waited
//! for at the end and killed if the learner fails first.

use std::path::Path;
use std::process::Child;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use crate::{FleetConfig, LearnerGuard, SecurityConfig, SetupError, TransportKind};

/// Actor processes started by a learner; killed if it drops them before they end.
#[derive(Debug)]
pub struct Children(pub Arc<Mutex<Vec<Child>>>);

impl Children {
    pub fn new(children: Vec<Child>) -> Self {
        Self(Arc::new(Mutex::new(children)))
    }

    pub fn lock(&self) -> MutexGuard<'_, Vec<Child>> {
        self.0.lock().unwrap_or_else(|e| e.into_inner())
    }

    pub fn is_empty(&self) -> bool {
        self.lock().is_empty()
    }

    /// `Some(why)` once every process has ended (a robot unreachable, a bad config): the
    /// learner should stop waiting for them.
    pub fn all_ended_check(&self, what: &str, logs: &Path) -> Box<dyn Fn() -> Option<String> + Send + Sync> {
        let kids = self.0.clone();
        let what = what.to_string();
        let logs = logs.display().to_string();
        Box::new(move || {
            let mut kids = kids.lock().unwrap_or_else(|e| e.into_inner());
            kids.iter_mut().all(|c| matches!(c.try_wait(), Ok(Some(_)))).then(|| format!("every {what} has ended; see {logs}/actor-*.log"))
        })
    }

    /// Waits for the processes to end by themselves (their assignment queue closed), then
    /// kills what is left. The grace outlasts an actor's own connect timeout (10 s on shared
    /// memory): an actor that started late on a loaded machine, after a short run was already
    /// over, is still looking for its learner and ends by itself, saying so, within it.
    pub fn finish(self) {
        let deadline = Instant::now() + Duration::from_secs(25);
        for c in self.lock().iter_mut() {
            while matches!(c.try_wait(), Ok(None)) && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(20));
            }
        }
        // Drop kills the rest.
    }
}

impl Drop for Children {
    fn drop(&mut self) {
        // A learner that failed: its actor processes must not outlive it.
        for c in self.lock().iter_mut() {
            if matches!(c.try_wait(), Ok(None)) {
                let _ = c.kill();
                let _ = c.wait();
            }
        }
    }
}

/// Joins a learner's actor threads (their assignment queue closed), reporting any that failed.
pub fn join_threads<E: std::fmt::Display>(role: &str, threads: Vec<std::thread::JoinHandle<Result<u64, E>>>) {
    for t in threads {
        match t.join() {
            Ok(Err(e)) => coadapt_log::logln!("{role}: an actor thread failed: {e}"),
            Err(_) => coadapt_log::logln!("{role}: an actor thread panicked"),
            Ok(Ok(_)) => {}
        }
    }
}

/// Starts `n` actors as `coadapt <subcommand> --config <config> --id <i> --transport ...
/// --fleet ... [--connect ...] <extra(i)>`, each logging to `<logs>/actor-<i>.log`.
pub fn spawn(
    subcommand: &str,
    config: &Path,
    n: usize,
    fleet: &FleetConfig,
    connect: &str,
    logs: &Path,
    extra: &dyn Fn(usize) -> Vec<std::ffi::OsString>,
) -> Result<Children, SetupError> {
    let exe = std::env::current_exe().map_err(SetupError::io("finding the coadapt binary to start actors"))?;
    std::fs::create_dir_all(logs).map_err(SetupError::io(format!("creating {}", logs.display())))?;
    let children = Children::new(Vec::new());
    for i in 0..n {
        let mut cmd = std::process::Command::new(&exe);
        cmd.arg(subcommand).arg("--config").arg(config).arg("--id").arg(i.to_string());
        cmd.arg("--transport").arg(fleet.transport.name()).arg("--fleet").arg(&fleet.name);
        if !connect.is_empty() {
            cmd.arg("--connect").arg(connect);
        }
        cmd.args(extra(i));
        let path = logs.join(format!("actor-{i}.log"));
        let what = || format!("creating {}", path.display());
        let log = std::fs::File::create(&path).map_err(SetupError::io(what()))?;
        cmd.stdin(std::process::Stdio::null()).stdout(log.try_clone().map_err(SetupError::io(what()))?).stderr(log);
        let child = cmd.spawn().map_err(SetupError::io(format!("starting {subcommand} {i}")))?;
        children.lock().push(child);
    }
    Ok(children)
}

/// What a learner starting actor processes needs to say.
#[allow(missing_debug_implementations)] // holds a closure
pub struct ProcessFleet<'a> {
    /// `search`, `latent`: the learner's name in messages and in a default fleet name.
    pub role: &'static str,
    /// The actors' subcommand.
    pub subcommand: &'a str,
    pub actors: usize,
    /// Start them here (true) or wait for actors started elsewhere.
    pub start: bool,
    /// The run directory: its `config.toml` is the actors', its `logs/` their logs.
    pub out: &'a Path,
    pub extra: &'a dyn Fn(usize) -> Vec<std::ffi::OsString>,
}

impl ProcessFleet<'_> {
    /// The learner's links over `fleet` (shm or gRPC; a shm fleet without a name gets one),
    /// and the actors started here (none when `start` is false).
    pub fn start(
        &self,
        fleet: &FleetConfig,
        dims: coadapt_transport::messages::Dims,
        max_episode_steps: usize,
        security: &SecurityConfig,
    ) -> Result<(coadapt_transport::LearnerLinks, LearnerGuard, Children), SetupError> {
        let mut fleet = fleet.clone();
        if fleet.transport == TransportKind::Shm && fleet.name.is_empty() {
            fleet.name = format!("coadapt-{}-{}", self.role, std::process::id());
        }
        let (links, guard) = fleet.learner_links(Some(dims), Some(max_episode_steps), security)?;
        let connect = match &guard {
            LearnerGuard::Grpc(server) => format!("http://127.0.0.1:{}", server.local_addr().port()),
            LearnerGuard::None => String::new(),
        };
        let (role, config) = (self.role, self.out.join("config.toml"));
        let children = if self.start {
            let logs = self.out.join("logs");
            let kids = spawn(self.subcommand, &config, self.actors, &fleet, &connect, &logs, self.extra)?;
            coadapt_log::logln!("{role}: {} actors over {} (logs in {})", self.actors, fleet.transport.name(), logs.display());
            kids
        } else {
            coadapt_log::logln!(
                "{role}: waiting for {} actors over {} ({}): coadapt {} --config {} --id N",
                self.actors,
                fleet.transport.name(),
                if connect.is_empty() { &fleet.name } else { &connect },
                self.subcommand,
                config.display()
            );
            Children::new(Vec::new())
        };
        Ok((links, guard, children))
    }
}

/// A learner's actors started by the learner itself, over any transport: threads of this
/// process (in-process links), or processes ([`ProcessFleet`]) that end when the assignment
/// queue closes. What latent planning and policy search share; the co-adaptation's local
/// fleet is the supervisor's ([`crate::supervise`]).
#[derive(Debug)]
pub struct LocalActors<E> {
    guard: LearnerGuard,
    threads: Vec<std::thread::JoinHandle<Result<u64, E>>>,
    children: Children,
    /// Names the actors in messages (`latent`, `search`).
    role: &'static str,
    logs: std::path::PathBuf,
}

impl<E: std::fmt::Display> LocalActors<E> {
    /// The learner's links over `fleet` and its `procs.actors` actors: for `in-process`, one
    /// thread each made by `thread(i, links)`; otherwise `procs`' processes (or none, waiting for
    /// actors started elsewhere).
    #[allow(clippy::type_complexity)]
    pub fn start<X: From<SetupError>>(
        fleet: &FleetConfig,
        procs: &ProcessFleet<'_>,
        dims: coadapt_transport::messages::Dims,
        max_episode_steps: usize,
        security: &SecurityConfig,
        mut thread: impl FnMut(usize, coadapt_transport::ActorLinks) -> Result<std::thread::JoinHandle<Result<u64, E>>, X>,
    ) -> Result<(coadapt_transport::LearnerLinks, Self), X> {
        let role = procs.role;
        let logs = procs.out.join("logs");
        if fleet.transport == TransportKind::InProcess {
            let (learner, actors, _optimizer) = coadapt_transport::in_process::fleet(procs.actors);
            let threads = actors.into_iter().enumerate().map(|(i, links)| thread(i, links)).collect::<Result<Vec<_>, X>>()?;
            let me = Self { guard: LearnerGuard::None, threads, children: Children::new(Vec::new()), role, logs };
            return Ok((learner, me));
        }
        let (links, guard, children) = procs.start(fleet, dims, max_episode_steps, security)?;
        Ok((links, Self { guard, threads: Vec::new(), children, role, logs }))
    }

    /// For the dispatcher's `abort`: `Some(why)` once every actor process started here has
    /// ended (none started: never).
    pub fn all_ended_check(&self) -> Option<Box<dyn Fn() -> Option<String> + Send + Sync>> {
        (!self.children.is_empty()).then(|| self.children.all_ended_check(&format!("{} actor", self.role), &self.logs))
    }

    /// After the learner's links are dropped (the queue closed, the actors end by themselves):
    /// stops serving, and waits for the threads and processes.
    pub fn finish(self) {
        let Self { guard, threads, children, role, .. } = self;
        drop(guard);
        join_threads(role, threads);
        children.finish();
    }
}
