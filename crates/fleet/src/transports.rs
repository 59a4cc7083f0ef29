//! Which transport the roles talk over (`[fleet]`), and each role's links for it.

use std::net::SocketAddr;
use std::time::Duration;

use coadapt_transport::messages::Dims;
use coadapt_transport::{ActorLinks, LearnerLinks, OptimizerLinks};
use serde::{Deserialize, Serialize};

use crate::{SecurityConfig, SetupError, check_listen};

/// How the roles talk.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum TransportKind {
    /// Separate processes on one machine over iceoryx2 shared memory.
    #[default]
    Shm,
    /// Separate processes, on one machine or many, over gRPC.
    Grpc,
    /// Threads of one process (`coadapt run` only).
    InProcess,
}

impl TransportKind {
    pub fn name(self) -> &'static str {
        match self {
            Self::Shm => "shm",
            Self::Grpc => "grpc",
            Self::InProcess => "in-process",
        }
    }
}

/// The `[fleet]` table: how the processes of a run find each other.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct FleetConfig {
    /// `shm` (iceoryx2 shared memory, one machine; the default), `grpc` (across machines) or
    /// `in-process` (threads; `coadapt run` only).
    pub transport: TransportKind,
    /// The fleet's name; every process of one run uses the same one. Shared memory: the prefix
    /// of its channels (empty: `coadapt run` picks `coadapt-<its pid>`; the role commands need
    /// it set or `--fleet`). gRPC: checked at registration (empty: `coadapt`).
    pub name: String,
    /// gRPC: the address the learner listens on.
    pub listen: String,
    /// gRPC: the learner's address as actors and the optimiser reach it.
    pub connect: String,
    /// gRPC: the deadline of every call (seconds).
    pub rpc_timeout_secs: f64,
    /// gRPC: the learner's health goes NOT_SERVING after this many seconds without progress
    /// (no episode back, no design chosen; waits for an operator do not count), so that a
    /// probe restarts it. Longer than the slowest episode and design search.
    pub health_stall_secs: f64,
    /// `coadapt run`: restarts of one crashed process (the learner resumes from its newest
    /// snapshot, an actor or the optimiser starts again) allowed within `restart-window-secs`;
    /// one more and the supervisor gives up on it (on the learner: the run stops).
    pub max_restarts: usize,
    /// The window of `max-restarts` (seconds): a process that crashes now and then for days is
    /// restarted every time; one that crash-loops is not.
    pub restart_window_secs: f64,
    /// Shared memory: most actors at once (sizes the channels' port tables; every process of
    /// a fleet must agree, so it lives in the shared config).
    pub max_actors: usize,
    /// gRPC: TCP connections one remote address may hold open on the learner at once (each
    /// actor or optimiser process needs one); one more is closed as it is accepted and counted.
    pub max_connections_per_peer: usize,
    /// gRPC: TCP connections open on the learner at once, from all peers.
    pub max_connections: usize,
}

impl Default for FleetConfig {
    fn default() -> Self {
        Self {
            transport: TransportKind::Shm,
            name: String::new(),
            listen: "0.0.0.0:50051".into(),
            connect: "http://127.0.0.1:50051".into(),
            rpc_timeout_secs: 10.0,
            health_stall_secs: 1800.0,
            max_restarts: 10,
            restart_window_secs: 600.0,
            max_actors: 64,
            max_connections_per_peer: 128,
            max_connections: 1024,
        }
    }
}

/// What keeps a learner's transport alive (the gRPC server); drop it last.
pub enum LearnerGuard {
    None,
    Grpc(coadapt_grpc::LearnerServer),
}

impl std::fmt::Debug for LearnerGuard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::None => "LearnerGuard::None",
            Self::Grpc(_) => "LearnerGuard::Grpc",
        })
    }
}

impl FleetConfig {
    fn shm(&self) -> Result<coadapt_shm::ShmConfig, SetupError> {
        if self.name.is_empty() {
            return Err(SetupError::Config(
                "fleet.name: a shared-memory fleet needs a name shared by all its processes (or --fleet NAME)".into(),
            ));
        }
        Ok(coadapt_shm::ShmConfig { fleet: self.name.clone(), max_actors: self.max_actors, ..coadapt_shm::ShmConfig::default() })
    }

    fn grpc(&self, security: &SecurityConfig) -> Result<coadapt_grpc::GrpcConfig, SetupError> {
        let t = self.rpc_timeout_secs;
        let rpc_timeout = Duration::try_from_secs_f64(t)
            .ok()
            .filter(|d| !d.is_zero())
            .ok_or_else(|| SetupError::Config(format!("fleet.rpc-timeout-secs: {t} is not a positive number of seconds")))?;
        for (name, v) in [("max-connections-per-peer", self.max_connections_per_peer), ("max-connections", self.max_connections)] {
            if v == 0 {
                return Err(SetupError::Config(format!("fleet.{name}: 0 would refuse every connection; at least 1")));
            }
        }
        let mut cfg = coadapt_grpc::GrpcConfig {
            rpc_timeout,
            max_connections_per_peer: self.max_connections_per_peer,
            max_connections: self.max_connections,
            ..coadapt_grpc::GrpcConfig::default()
        };
        // Clients of another fleet are refused at registration.
        if !self.name.is_empty() {
            cfg.fleet = self.name.clone();
        }
        cfg.server_auth = security.server_auth()?;
        cfg.client_auth = security.client_auth()?;
        Ok(cfg)
    }

    /// The learner's side; for gRPC this starts the server, which then refuses experience of
    /// other widths than `dims` at the edge.
    /// `max_episode_steps`: the robot's episode length, the most steps an episode's end may
    /// claim over gRPC (it bounds what the server holds per episode).
    pub fn learner_links(
        &self,
        dims: Option<Dims>,
        max_episode_steps: Option<usize>,
        security: &SecurityConfig,
    ) -> Result<(LearnerLinks, LearnerGuard), SetupError> {
        match self.transport {
            TransportKind::Shm => {
                let cfg = self.shm()?;
                clean_stale();
                let links = coadapt_shm::learner_links(&cfg)
                    .map_err(SetupError::transport(format!("opening shared-memory fleet {}", cfg.fleet)))?;
                Ok((links, LearnerGuard::None))
            }
            TransportKind::Grpc => {
                let addr: SocketAddr = self
                    .listen
                    .parse()
                    .map_err(|_| SetupError::Config(format!("fleet.listen: {:?} is not an address like 0.0.0.0:50051", self.listen)))?;
                check_listen("fleet.listen", addr, security)?;
                let mut grpc = self.grpc(security)?;
                // The id the learner's snapshots carry too; a client that sees it change drops
                // what it holds from the older start.
                grpc.run_id = Some(crate::run_id());
                if let Some(n) = max_episode_steps {
                    grpc.max_episode_steps = n as u64;
                }
                let (links, server) =
                    coadapt_grpc::serve_learner(addr, &grpc).map_err(SetupError::transport(format!("serving gRPC on {addr}")))?;
                let tls = match &grpc.server_auth.tls {
                    Some(t) if t.mutual() => "TLS, client certificates required",
                    Some(_) => "TLS",
                    None => "plaintext",
                };
                let tokens = grpc.server_auth.tokens.as_ref().map_or("no tokens".to_string(), |t| format!("{} accepted token(s)", t.len()));
                coadapt_log::logln!("learner: gRPC on {} ({tls}, {tokens})", server.local_addr());
                if let Some(d) = dims {
                    server.expect_dims(d);
                }
                Ok((links, LearnerGuard::Grpc(server)))
            }
            TransportKind::InProcess => Err(SetupError::Config("fleet.transport: in-process works only inside `coadapt run`".into())),
        }
    }

    pub fn actor_links(&self, id: u64, security: &SecurityConfig) -> Result<ActorLinks, SetupError> {
        match self.transport {
            TransportKind::Shm => {
                let cfg = self.shm()?;
                clean_stale();
                coadapt_shm::actor_links(&cfg, id).map_err(SetupError::transport(format!("joining shared-memory fleet {}", cfg.fleet)))
            }
            TransportKind::Grpc => coadapt_grpc::actor_links(&self.connect, id, &self.grpc(security)?)
                .map_err(SetupError::transport(format!("connecting to {}", self.connect))),
            TransportKind::InProcess => Err(SetupError::Config("fleet.transport: in-process works only inside `coadapt run`".into())),
        }
    }

    pub fn optimizer_links(&self, security: &SecurityConfig) -> Result<OptimizerLinks, SetupError> {
        match self.transport {
            TransportKind::Shm => {
                let cfg = self.shm()?;
                clean_stale();
                coadapt_shm::optimizer_links(&cfg).map_err(SetupError::transport(format!("joining shared-memory fleet {}", cfg.fleet)))
            }
            TransportKind::Grpc => coadapt_grpc::optimizer_links(&self.connect, &self.grpc(security)?)
                .map_err(SetupError::transport(format!("connecting to {}", self.connect))),
            TransportKind::InProcess => Err(SetupError::Config("fleet.transport: in-process works only inside `coadapt run`".into())),
        }
    }
}

/// Removes what killed processes left in shared memory; a failure is worth a warning only.
pub fn clean_stale() {
    match coadapt_shm::cleanup_stale() {
        Ok(0) => {}
        Ok(n) => coadapt_log::logln!("cleaned up shared memory of {n} dead process(es)"),
        Err(e) => coadapt_log::logln!("warning: cleaning up stale shared memory: {e}"),
    }
}

/// This process's learner start id (16 hex digits, never zero): the same for the snapshots it
/// writes and for the gRPC server it serves (whose clients drop what they hold from an older
/// start when it changes).
pub fn run_id() -> u64 {
    static ID: std::sync::OnceLock<u64> = std::sync::OnceLock::new();
    *ID.get_or_init(|| {
        let t = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos() as u64);
        let mut z = t ^ (u64::from(std::process::id()) << 40);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        (z ^ (z >> 31)).max(1)
    })
}

/// [`run_id`] as text.
pub fn new_run_id() -> String {
    format!("{:016x}", run_id())
}
