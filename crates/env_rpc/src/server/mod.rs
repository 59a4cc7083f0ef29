//! A dm_env_rpc server for any coadapt [`Env`]: `coadapt env-serve`.
//!
//! Worlds are created by CreateWorld (settings `design` and `seed`, both optional, and the
//! world's own, e.g. `friction`, which the factory takes or refuses), one agent
//! joins each, and a world lives as long as the connection that created it (a client that goes
//! away without DestroyWorld leaks nothing). Every request gets one response in order; a bad
//! request gets an `error` (google.rpc.Status) and the stream goes on.
//!
//! # Layout
//! - here: the worlds, the sessions and the service ([`EnvService`]) that answers requests;
//! - `serve`: a listener served with TLS, tokens and limits ([`serve`], [`ServerHandle`]), and
//!   [`BackgroundServer`], one on its own runtime for tests and benchmarks.

use std::collections::HashMap;
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};

use coadapt_core::{Env, EnvSpec};
use coadapt_wire::dm_env_rpc::v1::environment_request::Payload as Req;
use coadapt_wire::dm_env_rpc::v1::environment_response::Payload as Resp;
use coadapt_wire::dm_env_rpc::v1::environment_server::Environment;
use coadapt_wire::dm_env_rpc::v1::{self as pb, EnvironmentRequest, EnvironmentResponse, EnvironmentStateType, Tensor};
use coadapt_wire::google::rpc::Status;
use coadapt_wire::tensor::{self, Accept};
use tokio_stream::{Stream, StreamExt};
use tonic::{Code, Request, Response, Streaming};

mod serve;
pub use serve::{BackgroundServer, ServerHandle, serve};

use crate::profile::{self, Profile};

/// The settings CreateWorld gave besides `design` and `seed`: the world's own (a number each,
/// e.g. `friction`), fixed for its life. Empty: the environment's own world.
pub type WorldSettings = [(String, f32)];

/// Builds one environment per world, in the world its settings describe; it refuses (with a
/// message naming it) a setting it does not take, and the client gets INVALID_ARGUMENT.
pub type EnvFactory = Arc<dyn Fn(&WorldSettings) -> Result<Box<dyn Env>, String> + Send + Sync>;

/// A factory of environments that take no world settings beyond `design` and `seed`.
pub fn plain(make: impl Fn() -> Result<Box<dyn Env>, String> + Send + Sync + 'static) -> EnvFactory {
    Arc::new(move |settings: &WorldSettings| match settings.first() {
        Some((name, _)) => Err(format!("unknown world setting `{name}` (the coadapt profile has `design` and `seed`)")),
        None => make(),
    })
}

/// A google.rpc.Status for an error response.
fn status(code: Code, message: impl Into<String>) -> Status {
    Status { code: code as i32, message: message.into(), details: vec![] }
}

type Failure = Status;

struct World {
    env: Box<dyn Env>,
    spec: EnvSpec,
    design: Vec<f32>,
    /// Seed of the next episode (set by a `seed` setting), else a counter from the last one.
    next_seed: u64,
    /// Changes at every ResetWorld: an agent whose episode began before sees INTERRUPTED.
    epoch: u64,
    joined: bool,
    /// The connection that created the world (worlds die with it).
    owner: u64,
}

#[derive(Default)]
struct Worlds {
    map: HashMap<String, Arc<Mutex<World>>>,
    next: u64,
}

/// What one connection holds.
struct Session {
    id: u64,
    joined: Option<(String, Arc<Mutex<World>>)>,
    /// The world epoch the running episode began in; `None` when not running.
    running: Option<u64>,
    obs: Vec<f32>,
    reward: f32,
    discount: f32,
    scratch: Vec<f32>,
}

/// What a server holds at most for its peers: each world is a live simulation (memory and a
/// physics state), each connection a task, so a peer that opens them in a loop must be stopped
/// before it takes the machine.
#[derive(Clone, Copy, Debug)]
pub struct ServerLimits {
    /// Worlds alive at once, from all connections; CreateWorld beyond it gets
    /// RESOURCE_EXHAUSTED and the worlds already made go on.
    pub max_worlds: usize,
    /// TCP connections from one remote host at once; more are closed as they are accepted.
    pub max_connections_per_peer: usize,
    /// TCP connections at once from all hosts.
    pub max_connections: usize,
}

impl Default for ServerLimits {
    fn default() -> Self {
        // A fleet's actors each hold one connection and one world; 64 actors on one robot
        // server is already far past what one simulator process steps usefully.
        Self { max_worlds: 64, max_connections_per_peer: 32, max_connections: 256 }
    }
}

/// What a server refused, for its logs and tests.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ServerRefusals {
    /// CreateWorld refused: `max_worlds` were alive.
    pub worlds: u64,
    /// Connections closed as accepted: their host held `max_connections_per_peer`.
    pub connections_per_peer: u64,
    /// Connections closed as accepted: `max_connections` were open.
    pub connections_total: u64,
}

/// The dm_env_rpc service over an environment factory.
#[derive(Clone)]
pub struct EnvService {
    factory: EnvFactory,
    worlds: Arc<Mutex<Worlds>>,
    sessions: Arc<AtomicU64>,
    max_worlds: usize,
    refused_worlds: Arc<AtomicU64>,
}

impl std::fmt::Debug for EnvService {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("EnvService").finish_non_exhaustive()
    }
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A panic while holding a world's lock leaves a world that can still be destroyed.
    m.lock().unwrap_or_else(|p| p.into_inner())
}

fn profile_of(spec: &EnvSpec) -> Profile {
    Profile { state_dim: spec.state_dim, action: spec.action.clone(), design: spec.design.clone() }
}

impl EnvService {
    pub fn new(factory: EnvFactory) -> Self {
        Self::with_max_worlds(factory, ServerLimits::default().max_worlds)
    }

    /// A service that refuses CreateWorld while `max_worlds` worlds are alive.
    pub fn with_max_worlds(factory: EnvFactory, max_worlds: usize) -> Self {
        Self { factory, worlds: Arc::default(), sessions: Arc::new(AtomicU64::new(0)), max_worlds, refused_worlds: Arc::default() }
    }

    /// CreateWorld calls refused because `max_worlds` were alive.
    pub fn refused_worlds(&self) -> u64 {
        self.refused_worlds.load(Ordering::Relaxed)
    }

    /// Worlds currently alive (for tests and logs).
    pub fn world_count(&self) -> usize {
        lock(&self.worlds).map.len()
    }

    /// The settings of `settings` that are not `design` or `seed`: the world's own, one
    /// number each (sorted by name, so a factory sees them in one order).
    fn world_settings(settings: &HashMap<String, Tensor>) -> Result<Vec<(String, f32)>, Failure> {
        let mut out = Vec::new();
        for (name, t) in settings {
            if name != profile::SETTING_DESIGN && name != profile::SETTING_SEED {
                let mut v = Vec::new();
                tensor::read_f32(name, t, &[], Accept::AnyFloat, &mut v)
                    .map_err(|e| status(Code::InvalidArgument, format!("world setting `{name}`: {e}")))?;
                out.push((name.clone(), v[0]));
            }
        }
        out.sort_by(|a, b| a.0.cmp(&b.0));
        Ok(out)
    }

    /// Applies world settings (`design`, `seed`) to `world`; the world's own settings were
    /// taken at CreateWorld (`create`), and at a reset they are refused.
    fn apply_settings(world: &mut World, settings: &HashMap<String, Tensor>, create: bool) -> Result<(), Failure> {
        let mut design = None;
        let mut seed = None;
        for (name, t) in settings {
            match name.as_str() {
                profile::SETTING_DESIGN => {
                    let mut d = Vec::new();
                    tensor::read_f32(name, t, &[world.spec.design_dim()], Accept::AnyFloat, &mut d)
                        .map_err(|e| status(Code::InvalidArgument, e.to_string()))?;
                    world.spec.design.check("design", &d).map_err(|e| status(Code::InvalidArgument, format!("setting `design`: {e}")))?;
                    design = Some(d);
                }
                profile::SETTING_SEED => {
                    seed = Some(tensor::read_u64(name, t).map_err(|e| status(Code::InvalidArgument, e.to_string()))?);
                }
                _ if create => {}
                other => {
                    return Err(status(
                        Code::InvalidArgument,
                        format!(
                            "world setting `{other}` at a reset: ResetWorld takes `design` and `seed` (a world's own settings are given to CreateWorld)"
                        ),
                    ));
                }
            }
        }
        if let Some(d) = design {
            world.design = d;
        }
        if let Some(s) = seed {
            world.next_seed = s;
        }
        Ok(())
    }

    fn create_world(&self, session: &Session, r: pb::CreateWorldRequest) -> Result<Resp, Failure> {
        // Checked before building the environment (the expensive part), and again under the
        // lock when inserting: two connections may race past the first check.
        let full = |n: usize| {
            self.refused_worlds.fetch_add(1, Ordering::Relaxed);
            status(
                Code::ResourceExhausted,
                format!("the server holds {n} worlds, its limit (max-worlds): destroy one or close a connection first"),
            )
        };
        let alive = self.world_count();
        if alive >= self.max_worlds {
            return Err(full(alive));
        }
        let own = Self::world_settings(&r.settings)?;
        // With settings of its own, a refusal is the request's (a name or value the robot does
        // not take); without, the server's.
        let code = if own.is_empty() { Code::Internal } else { Code::InvalidArgument };
        let env = (self.factory)(&own).map_err(|e| status(code, format!("building the environment: {e}")))?;
        let spec = env.spec().clone();
        let mut world = World { design: spec.default_design.clone(), env, spec, next_seed: 0, epoch: 0, joined: false, owner: session.id };
        Self::apply_settings(&mut world, &r.settings, true)?;
        let mut worlds = lock(&self.worlds);
        if worlds.map.len() >= self.max_worlds {
            return Err(full(worlds.map.len()));
        }
        worlds.next += 1;
        let name = format!("world-{}", worlds.next);
        worlds.map.insert(name.clone(), Arc::new(Mutex::new(world)));
        Ok(Resp::CreateWorld(pb::CreateWorldResponse { world_name: name }))
    }

    fn find(&self, name: &str) -> Result<Arc<Mutex<World>>, Failure> {
        lock(&self.worlds).map.get(name).cloned().ok_or_else(|| status(Code::NotFound, format!("no world named `{name}`")))
    }

    fn join_world(&self, session: &mut Session, r: pb::JoinWorldRequest) -> Result<Resp, Failure> {
        if let Some((name, _)) = &session.joined {
            return Err(status(Code::FailedPrecondition, format!("already joined to world `{name}`: leave it first")));
        }
        let world = self.find(&r.world_name)?;
        if let Some(k) = r.settings.keys().next() {
            return Err(status(Code::InvalidArgument, format!("unknown join setting `{k}` (joining takes no settings)")));
        }
        let specs = {
            let mut w = lock(&world);
            if w.joined {
                return Err(status(Code::FailedPrecondition, format!("world `{}` already has its agent", r.world_name)));
            }
            w.joined = true;
            profile_of(&w.spec).specs()
        };
        session.joined = Some((r.world_name, world));
        session.running = None;
        Ok(Resp::JoinWorld(pb::JoinWorldResponse { specs: Some(specs) }))
    }

    fn leave(session: &mut Session) {
        if let Some((_, world)) = session.joined.take() {
            lock(&world).joined = false;
        }
        session.running = None;
    }

    fn reset(session: &mut Session, r: pb::ResetRequest) -> Result<Resp, Failure> {
        let Some((_, world)) = &session.joined else {
            return Err(status(Code::FailedPrecondition, "reset before joining a world"));
        };
        if let Some(k) = r.settings.keys().next() {
            return Err(status(Code::InvalidArgument, format!("unknown reset setting `{k}` (reset takes no settings)")));
        }
        let specs = profile_of(&lock(world).spec).specs();
        session.running = None;
        Ok(Resp::Reset(pb::ResetResponse { specs: Some(specs) }))
    }

    fn reset_world(&self, session: &mut Session, r: pb::ResetWorldRequest) -> Result<Resp, Failure> {
        let world = self.find(&r.world_name)?;
        {
            let mut w = lock(&world);
            Self::apply_settings(&mut w, &r.settings, false)?;
            w.epoch += 1;
        }
        // The issuer, if joined to it, starts the next episode at once (no INTERRUPTED step).
        if session.joined.as_ref().is_some_and(|(n, _)| *n == r.world_name) {
            session.running = None;
        }
        Ok(Resp::ResetWorld(pb::ResetWorldResponse {}))
    }

    fn destroy_world(&self, session: &Session, r: pb::DestroyWorldRequest) -> Result<Resp, Failure> {
        if session.joined.as_ref().is_some_and(|(n, _)| *n == r.world_name) {
            return Err(status(Code::FailedPrecondition, format!("leave world `{}` before destroying it", r.world_name)));
        }
        let mut worlds = lock(&self.worlds);
        let Some(w) = worlds.map.get(&r.world_name) else {
            return Err(status(Code::NotFound, format!("no world named `{}`", r.world_name)));
        };
        if lock(w).joined {
            return Err(status(Code::FailedPrecondition, format!("world `{}` has an agent joined", r.world_name)));
        }
        worlds.map.remove(&r.world_name);
        Ok(Resp::DestroyWorld(pb::DestroyWorldResponse {}))
    }

    fn step(session: &mut Session, r: pb::StepRequest) -> Result<Resp, Failure> {
        let Some((_, world)) = &session.joined else {
            return Err(status(Code::FailedPrecondition, "step before joining a world"));
        };
        if let Some(uid) = r.requested_observations.iter().find(|u| !profile::ALL_OBSERVATIONS.contains(u)) {
            return Err(status(Code::InvalidArgument, format!("requested observation uid {uid} does not exist (uids 1-4)")));
        }
        let mut w = lock(world);
        let state = match session.running {
            Some(epoch) if epoch != w.epoch => {
                // Someone reset the world under this agent: tell it once, start afresh next.
                session.running = None;
                EnvironmentStateType::Interrupted
            }
            Some(_) => {
                if let Some(uid) = r.actions.keys().find(|&&u| u != profile::ACTION) {
                    return Err(status(Code::InvalidArgument, format!("action uid {uid} does not exist (uid 1 is `action`)")));
                }
                let t = r
                    .actions
                    .get(&profile::ACTION)
                    .ok_or_else(|| status(Code::InvalidArgument, "action `action` (uid 1) is required on every running step"))?;
                tensor::read_f32("action", t, &[w.spec.act_dim()], Accept::FloatOnly, &mut session.scratch)
                    .map_err(|e| status(Code::InvalidArgument, e.to_string()))?;
                w.spec.action.check("action", &session.scratch).map_err(|e| status(Code::InvalidArgument, e.to_string()))?;
                let state_dim = w.spec.state_dim;
                let step = w.env.step(&session.scratch).map_err(|e| status(Code::Internal, format!("environment step: {e}")))?;
                session.obs.clear();
                session.obs.extend_from_slice(&step.observation[..state_dim]);
                session.reward = step.reward;
                session.discount = if step.terminated { 0.0 } else { 1.0 };
                if step.terminated || step.truncated {
                    session.running = None;
                    EnvironmentStateType::Terminated
                } else {
                    EnvironmentStateType::Running
                }
            }
            None => {
                // The first step of an episode: actions are ignored.
                let w = &mut *w;
                let seed = w.next_seed;
                w.next_seed = w.next_seed.wrapping_add(1);
                let state_dim = w.spec.state_dim;
                let first = w.env.reset(seed, &w.design).map_err(|e| status(Code::Internal, format!("environment reset: {e}")))?;
                session.obs.clear();
                session.obs.extend_from_slice(&first[..state_dim]);
                session.reward = 0.0;
                session.discount = 1.0;
                session.running = Some(w.epoch);
                EnvironmentStateType::Running
            }
        };
        let mut observations = HashMap::new();
        for &uid in &r.requested_observations {
            let t = match uid {
                profile::OBSERVATION => tensor::floats(&session.obs, &[session.obs.len()]),
                profile::REWARD => tensor::scalar(session.reward),
                profile::DISCOUNT => tensor::scalar(session.discount),
                _ => tensor::floats(&w.design, &[w.design.len()]),
            };
            observations.insert(uid, t);
        }
        Ok(Resp::Step(pb::StepResponse { state: state as i32, observations }))
    }

    fn handle(&self, session: &mut Session, req: EnvironmentRequest) -> Resp {
        let result = match req.payload {
            Some(Req::CreateWorld(r)) => self.create_world(session, r),
            Some(Req::JoinWorld(r)) => self.join_world(session, r),
            Some(Req::Step(r)) => Self::step(session, r),
            Some(Req::Reset(r)) => Self::reset(session, r),
            Some(Req::ResetWorld(r)) => self.reset_world(session, r),
            Some(Req::LeaveWorld(_)) => {
                Self::leave(session);
                Ok(Resp::LeaveWorld(pb::LeaveWorldResponse {}))
            }
            Some(Req::DestroyWorld(r)) => self.destroy_world(session, r),
            Some(Req::Extension(a)) => Err(status(Code::Unimplemented, format!("no extensions are supported (got `{}`)", a.type_url))),
            None => Err(status(Code::InvalidArgument, "empty request")),
        };
        result.unwrap_or_else(Resp::Error)
    }

    /// The connection is gone: leave its world and destroy the worlds it created.
    fn end_session(&self, session: &mut Session) {
        Self::leave(session);
        lock(&self.worlds).map.retain(|_, w| lock(w).owner != session.id);
    }
}

type ResponseStream = Pin<Box<dyn Stream<Item = Result<EnvironmentResponse, tonic::Status>> + Send>>;

#[tonic::async_trait]
impl Environment for EnvService {
    type ProcessStream = ResponseStream;

    async fn process(&self, request: Request<Streaming<EnvironmentRequest>>) -> Result<Response<Self::ProcessStream>, tonic::Status> {
        let mut inbound = request.into_inner();
        let (tx, rx) = tokio::sync::mpsc::channel(16);
        let service = self.clone();
        let id = self.sessions.fetch_add(1, Ordering::Relaxed) + 1;
        tokio::spawn(async move {
            let mut session = Session { id, joined: None, running: None, obs: Vec::new(), reward: 0.0, discount: 1.0, scratch: Vec::new() };
            while let Some(msg) = inbound.next().await {
                let Ok(req) = msg else { break };
                // Environment steps are short (tens of microseconds for our robots): inline.
                let payload = service.handle(&mut session, req);
                if tx.send(Ok(EnvironmentResponse { payload: Some(payload) })).await.is_err() {
                    break;
                }
            }
            service.end_session(&mut session);
        });
        Ok(Response::new(Box::pin(tokio_stream::wrappers::ReceiverStream::new(rx))))
    }
}
