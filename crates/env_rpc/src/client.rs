//! [`RemoteEnv`]: a coadapt [`Env`] backed by any dm_env_rpc server that follows the coadapt
//! profile (proto/README.md).
//!
//! One connection, one world. Every request has a deadline; a broken stream or a missed
//! deadline drops the connection, fails the episode in progress (the actor drops it, so no half
//! episode reaches a replay buffer), and the next `reset` reconnects with capped backoff and
//! creates a new world. Actions arrive in `[-1, 1]` and map linearly onto the server's action
//! box (clipped). Observations, rewards and discounts are checked for shape and finiteness;
//! a bad one ends the episode with an error naming the tensor.

use std::collections::HashMap;
use std::time::{Duration, Instant};

use coadapt_core::{BoxSpace, Env, EnvError, EnvSpec, Step};
use coadapt_wire::dm_env_rpc::v1::environment_client::EnvironmentClient;
use coadapt_wire::dm_env_rpc::v1::environment_request::Payload as Req;
use coadapt_wire::dm_env_rpc::v1::environment_response::Payload as Resp;
use coadapt_wire::dm_env_rpc::v1::{self as pb, EnvironmentRequest, EnvironmentStateType, Tensor};
use coadapt_wire::tensor::{self, Accept};
use tokio::sync::mpsc;
use tonic::Streaming;

use crate::profile::{self, Profile, ProfileError, Uids};
use crate::{RemoteOptions, block};

/// Why a remote environment failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RemoteError {
    /// The name is not a `dm-env-rpc://HOST:PORT` address (a setting to fix, not a fault).
    #[error("{url}: {error}")]
    Address { url: String, error: crate::AddressError },
    #[error("{url}: {what}")]
    Connect { url: String, what: String },
    #[error("{url}: no answer to {request} within {timeout:?}")]
    Deadline { url: String, request: &'static str, timeout: Duration },
    #[error("{url}: the stream broke during {request}: {what}")]
    Broken { url: String, request: &'static str, what: String },
    #[error("{url}: the server refused {request}: {message} (code {code})")]
    Server { url: String, request: &'static str, code: i32, message: String },
    #[error("{1}: {0}")]
    Profile(ProfileError, String),
    #[error("{url}: unexpected reply to {request}: {what}")]
    Protocol { url: String, request: &'static str, what: String },
    #[error("{0}: bad reply: {1}")]
    Bad(String, String),
    #[error("{url}: the server's specs changed on reconnection ({what})")]
    SpecChanged { url: String, what: String },
}

impl RemoteError {
    /// The connection is unusable (reconnect before the next episode).
    fn breaks_connection(&self) -> bool {
        matches!(self, RemoteError::Deadline { .. } | RemoteError::Broken { .. } | RemoteError::Connect { .. })
    }
}

impl From<RemoteError> for EnvError {
    fn from(e: RemoteError) -> Self {
        EnvError::Backend(e.to_string())
    }
}

/// Counters of what went wrong, for logs and tests.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RemoteStats {
    /// Connections made after the first.
    pub reconnects: u64,
    /// Episodes ended by a non-finite or misshapen observation, reward or discount.
    pub bad_observations: u64,
    /// Requests the server answered with an error.
    pub server_errors: u64,
    /// Requests without an answer in time, or on a broken stream.
    pub lost: u64,
}

struct Conn {
    tx: mpsc::Sender<EnvironmentRequest>,
    rx: Streaming<pb::EnvironmentResponse>,
    world: String,
}

/// Sends `req` on `conn` and waits for its response (or an error) within `timeout`.
async fn call(conn: &mut Conn, url: &str, request: &'static str, req: Req, timeout: Duration) -> Result<Resp, RemoteError> {
    let sent = tokio::time::timeout(timeout, conn.tx.send(EnvironmentRequest { payload: Some(req) }))
        .await
        .map_err(|_| RemoteError::Deadline { url: url.to_string(), request, timeout })?;
    sent.map_err(|_| RemoteError::Broken { url: url.to_string(), request, what: "the request stream is closed".into() })?;
    receive(conn, url, request, timeout).await
}

/// Waits for the response to a request already sent.
async fn receive(conn: &mut Conn, url: &str, request: &'static str, timeout: Duration) -> Result<Resp, RemoteError> {
    let broken = |what: String| RemoteError::Broken { url: url.to_string(), request, what };
    let resp = match tokio::time::timeout(timeout, conn.rx.message()).await {
        Err(_) => return Err(RemoteError::Deadline { url: url.to_string(), request, timeout }),
        Ok(Ok(Some(r))) => r,
        Ok(Ok(None)) => return Err(broken("the server closed the stream".into())),
        Ok(Err(s)) => return Err(broken(format!("{} ({:?})", s.message(), s.code()))),
    };
    match resp.payload {
        Some(Resp::Error(s)) => Err(RemoteError::Server { url: url.to_string(), request, code: s.code, message: s.message }),
        Some(p) => Ok(p),
        None => Err(RemoteError::Protocol { url: url.to_string(), request, what: "an empty response".into() }),
    }
}

/// Connects, creates a world (with `opts.world_settings`), joins it, and reads the default
/// design.
async fn open(url: String, endpoint: String, opts: RemoteOptions) -> Result<(Conn, Profile, Uids, Vec<f32>), RemoteError> {
    let connect_err = |what: String| RemoteError::Connect { url: url.clone(), what };
    let channel = opts
        .auth
        .endpoint(&endpoint)
        .map_err(|e| connect_err(format!("bad address {endpoint}: {e}")))?
        .connect_timeout(opts.connect_timeout)
        .tcp_nodelay(true)
        .http2_keep_alive_interval(opts.keep_alive)
        .keep_alive_timeout(opts.request_timeout)
        .keep_alive_while_idle(true);
    let channel = tokio::time::timeout(opts.connect_timeout, channel.connect())
        .await
        .map_err(|_| connect_err(format!("no connection within {:?}", opts.connect_timeout)))?
        .map_err(|e| connect_err(format!("cannot connect: {e}")))?;
    let mut client = EnvironmentClient::with_interceptor(channel, opts.auth.bearer());
    let (tx, requests) = mpsc::channel(4);
    // The first request goes in before the call: some servers (grpcio's) send their response
    // headers only with their first message, so waiting for the call to open first would wait
    // for ever.
    let settings = opts.world_settings.iter().map(|(name, v)| (name.clone(), tensor::scalar(*v))).collect();
    tx.send(EnvironmentRequest { payload: Some(Req::CreateWorld(pb::CreateWorldRequest { settings })) })
        .await
        .map_err(|_| connect_err("the request stream closed at once".into()))?;
    let stream = tokio::time::timeout(opts.connect_timeout, client.process(tokio_stream::wrappers::ReceiverStream::new(requests)))
        .await
        .map_err(|_| connect_err(format!("the stream did not open within {:?}", opts.connect_timeout)))?
        .map_err(|s| connect_err(format!("the server refused the stream: {} ({:?})", s.message(), s.code())))?;
    let mut conn = Conn { tx, rx: stream.into_inner(), world: String::new() };
    let t = opts.request_timeout;
    let unexpected = |request: &'static str| RemoteError::Protocol { url: url.clone(), request, what: "a response of another kind".into() };
    let Resp::CreateWorld(c) = receive(&mut conn, &url, "CreateWorld", t).await? else {
        return Err(unexpected("CreateWorld"));
    };
    conn.world = c.world_name.clone();
    let join = pb::JoinWorldRequest { world_name: c.world_name, settings: HashMap::new() };
    let Resp::JoinWorld(j) = call(&mut conn, &url, "JoinWorld", Req::JoinWorld(join), t).await? else {
        return Err(unexpected("JoinWorld"));
    };
    let specs = j.specs.ok_or_else(|| RemoteError::Protocol { url: url.clone(), request: "JoinWorld", what: "no specs".into() })?;
    let (profile, uids) = Profile::from_specs(&specs).map_err(|e| RemoteError::Profile(e, url.clone()))?;
    // A server of no design (not a coadapt environment) has no default design to read.
    let Some(design_uid) = uids.design else { return Ok((conn, profile, uids, Vec::new())) };
    let step = pb::StepRequest { actions: HashMap::new(), requested_observations: vec![design_uid] };
    let Resp::Step(s) = call(&mut conn, &url, "Step", Req::Step(step), t).await? else {
        return Err(unexpected("Step"));
    };
    let mut design = Vec::new();
    let t = s.observations.get(&design_uid).ok_or_else(|| RemoteError::Bad(url.clone(), "first step: no `design` observation".into()))?;
    tensor::read_f32("design", t, &[profile.design.dim()], Accept::AnyFloat, &mut design)
        .map_err(|e| RemoteError::Bad(url.clone(), e.to_string()))?;
    Ok((conn, profile, uids, design))
}

/// An environment served over dm_env_rpc.
pub struct RemoteEnv {
    url: String,
    endpoint: String,
    opts: RemoteOptions,
    conn: Option<Conn>,
    spec: EnvSpec,
    /// The server's action box (the spec's is `[-1, 1]`).
    server_action: BoxSpace,
    uids: Uids,
    design: Vec<f32>,
    obs: Vec<f32>,
    scratch: Vec<f32>,
    running: bool,
    stats: RemoteStats,
}

impl std::fmt::Debug for RemoteEnv {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RemoteEnv").field("url", &self.url).field("stats", &self.stats).finish_non_exhaustive()
    }
}

impl RemoteEnv {
    /// Connects to `url` (`dm-env-rpc://HOST:PORT`) and reads the environment's specs.
    pub fn connect(url: &str, opts: RemoteOptions) -> Result<Self, RemoteError> {
        let endpoint = crate::endpoint(url).map_err(|error| RemoteError::Address { url: url.to_string(), error })?;
        let (conn, profile, uids, default_design) = block(open(url.to_string(), endpoint.clone(), opts.clone()))
            .map_err(|what| RemoteError::Connect { url: url.to_string(), what })??;
        let spec = EnvSpec {
            name: url.to_string(),
            state_dim: profile.state_dim,
            action: BoxSpace::uniform(profile.action.dim(), -1.0, 1.0),
            design: profile.design.clone(),
            design_names: (0..profile.design.dim()).map(|i| format!("design[{i}]")).collect(),
            default_design,
            // The server ends episodes (TERMINATED with discount 1 at its time limit).
            max_episode_steps: usize::MAX,
        };
        Ok(Self {
            url: url.to_string(),
            endpoint,
            opts,
            conn: Some(conn),
            obs: vec![0.0; spec.obs_dim()],
            scratch: Vec::new(),
            design: spec.default_design.clone(),
            server_action: profile.action,
            spec,
            uids,
            running: false,
            stats: RemoteStats::default(),
        })
    }

    /// The server's own action box: the spec's `[-1, 1]` maps linearly onto it.
    pub fn server_action(&self) -> &BoxSpace {
        &self.server_action
    }

    pub fn stats(&self) -> RemoteStats {
        self.stats
    }

    /// Runs one request on the connection, dropping the connection when it breaks.
    fn request(&mut self, request: &'static str, req: Req) -> Result<Resp, RemoteError> {
        let Some(mut conn) = self.conn.take() else {
            return Err(RemoteError::Broken { url: self.url.clone(), request, what: "not connected".into() });
        };
        let (url, timeout) = (self.url.clone(), self.opts.request_timeout);
        let (conn, result) = block(async move {
            let r = call(&mut conn, &url, request, req, timeout).await;
            (conn, r)
        })
        .map_err(|what| RemoteError::Broken { url: self.url.clone(), request, what })?;
        match &result {
            Err(e) if e.breaks_connection() => self.stats.lost += 1,
            Err(RemoteError::Server { .. }) => {
                self.stats.server_errors += 1;
                self.conn = Some(conn);
            }
            _ => self.conn = Some(conn),
        }
        result
    }

    /// Makes sure a connection with a joined world exists, reconnecting with capped backoff
    /// for up to `opts.reconnect_for`.
    fn ensure_connected(&mut self) -> Result<(), RemoteError> {
        if self.conn.is_some() {
            return Ok(());
        }
        let start = Instant::now();
        let mut wait = Duration::from_millis(100);
        loop {
            let attempt = block(open(self.url.clone(), self.endpoint.clone(), self.opts.clone()))
                .map_err(|what| RemoteError::Connect { url: self.url.clone(), what })
                .and_then(|r| r);
            match attempt {
                Ok((conn, profile, uids, _)) => {
                    if profile.state_dim != self.spec.state_dim
                        || profile.action != self.server_action
                        || profile.design != self.spec.design
                    {
                        return Err(RemoteError::SpecChanged {
                            url: self.url.clone(),
                            what: format!(
                                "state {} -> {}, action box {:?} -> {:?}, design box {:?} -> {:?}",
                                self.spec.state_dim,
                                profile.state_dim,
                                self.server_action,
                                profile.action,
                                self.spec.design,
                                profile.design
                            ),
                        });
                    }
                    self.uids = uids;
                    self.conn = Some(conn);
                    self.stats.reconnects += 1;
                    coadapt_log::logln!("{}: reconnected (world {})", self.url, self.conn.as_ref().map_or("", |c| c.world.as_str()));
                    return Ok(());
                }
                Err(e) if start.elapsed() + wait > self.opts.reconnect_for => return Err(e),
                Err(e) => {
                    coadapt_log::logln!("{}: reconnecting in {wait:?}: {e}", self.url);
                    std::thread::sleep(wait);
                    wait = (wait * 2).min(self.opts.max_backoff);
                }
            }
        }
    }

    /// Reads the step's observations into `self.obs` (state, then the design), the reward and
    /// the discount.
    fn read_step(&mut self, s: &pb::StepResponse) -> Result<(f32, f32), RemoteError> {
        let url = &self.url;
        let get = |uid: u64, name: &str| -> Result<&Tensor, RemoteError> {
            s.observations.get(&uid).ok_or_else(|| RemoteError::Bad(url.clone(), format!("observation `{name}` is missing from the step")))
        };
        let bad = |e: tensor::TensorError| RemoteError::Bad(url.clone(), e.to_string());
        let sd = self.spec.state_dim;
        tensor::read_f32("observation", get(self.uids.observation, "observation")?, &[sd], Accept::AnyFloat, &mut self.scratch)
            .map_err(bad)?;
        self.obs[..sd].copy_from_slice(&self.scratch);
        self.obs[sd..].copy_from_slice(&self.design);
        tensor::read_f32("reward", get(self.uids.reward, "reward")?, &[], Accept::AnyFloat, &mut self.scratch).map_err(bad)?;
        let reward = self.scratch[0];
        tensor::read_f32("discount", get(self.uids.discount, "discount")?, &[], Accept::AnyFloat, &mut self.scratch).map_err(bad)?;
        let discount = self.scratch[0];
        if !(0.0..=1.0).contains(&discount) {
            return Err(RemoteError::Bad(url.clone(), format!("tensor `discount`: {discount} is outside [0, 1]")));
        }
        Ok((reward, discount))
    }

    fn reset_inner(&mut self, seed: u64, design: &[f32]) -> Result<(), RemoteError> {
        if self.uids.coadapt() {
            let world = self.conn.as_ref().map(|c| c.world.clone()).unwrap_or_default();
            let settings = HashMap::from([
                (profile::SETTING_DESIGN.to_string(), tensor::floats(design, &[design.len()])),
                (profile::SETTING_SEED.to_string(), tensor::scalar_u64(seed)),
            ]);
            let Resp::ResetWorld(_) = self.request("ResetWorld", Req::ResetWorld(pb::ResetWorldRequest { world_name: world, settings }))?
            else {
                return Err(RemoteError::Protocol {
                    url: self.url.clone(),
                    request: "ResetWorld",
                    what: "a response of another kind".into(),
                });
            };
        } else {
            // A plain dm_env_rpc server: the agent's next sequence, with no settings (it knows
            // no design and no seed: its episodes' randomness is its own, as a real robot's).
            let Resp::Reset(r) = self.request("Reset", Req::Reset(pb::ResetRequest { settings: HashMap::new() }))? else {
                return Err(RemoteError::Protocol { url: self.url.clone(), request: "Reset", what: "a response of another kind".into() });
            };
            // The specs may change on a Reset (the protocol allows it); ours may not.
            if let Some(specs) = r.specs {
                let (profile, uids) = Profile::from_specs(&specs).map_err(|e| RemoteError::Profile(e, self.url.clone()))?;
                if profile.state_dim != self.spec.state_dim || profile.action != self.server_action || profile.design.dim() != 0 {
                    return Err(RemoteError::SpecChanged {
                        url: self.url.clone(),
                        what: format!(
                            "on Reset: state {} -> {}, action box {:?} -> {:?}",
                            self.spec.state_dim, profile.state_dim, self.server_action, profile.action
                        ),
                    });
                }
                self.uids = uids;
            }
        }
        let step = pb::StepRequest { actions: HashMap::new(), requested_observations: self.requested() };
        let Resp::Step(s) = self.request("Step", Req::Step(step))? else {
            return Err(RemoteError::Protocol { url: self.url.clone(), request: "Step", what: "a response of another kind".into() });
        };
        if s.state != EnvironmentStateType::Running as i32 {
            return Err(RemoteError::Protocol { url: self.url.clone(), request: "Step", what: format!("first step in state {}", s.state) });
        }
        self.read_step(&s)?;
        Ok(())
    }

    fn requested(&self) -> Vec<u64> {
        vec![self.uids.observation, self.uids.reward, self.uids.discount]
    }
}

impl Env for RemoteEnv {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn reset(&mut self, seed: u64, design: &[f32]) -> Result<&[f32], EnvError> {
        self.running = false;
        self.spec.design.check("design", design).map_err(EnvError::Design)?;
        self.design.clear();
        self.design.extend_from_slice(design);
        // A stream that broke during the reset itself gets one more connection.
        for attempt in 0..2 {
            self.ensure_connected()?;
            match self.reset_inner(seed, design) {
                Ok(()) => break,
                Err(e) if e.breaks_connection() && attempt == 0 => {
                    coadapt_log::logln!("{}: {e}; reconnecting", self.url);
                }
                Err(e) => {
                    if matches!(e, RemoteError::Bad(..)) {
                        self.stats.bad_observations += 1;
                    }
                    return Err(e.into());
                }
            }
        }
        self.running = true;
        Ok(&self.obs)
    }

    fn step(&mut self, action: &[f32]) -> Result<Step<'_>, EnvError> {
        if !self.running {
            return Err(EnvError::NotRunning);
        }
        self.spec.action.check_finite("action", action).map_err(EnvError::Action)?;
        // [-1, 1] onto the server's box, clipped.
        self.scratch.clear();
        for ((&a, &lo), &hi) in action.iter().zip(&self.server_action.low).zip(&self.server_action.high) {
            self.scratch.push((lo + (a.clamp(-1.0, 1.0) + 1.0) * 0.5 * (hi - lo)).clamp(lo, hi));
        }
        let actions = HashMap::from([(self.uids.action, tensor::floats(&self.scratch, &[self.scratch.len()]))]);
        let step = pb::StepRequest { actions, requested_observations: self.requested() };
        self.running = false;
        let s = match self.request("Step", Req::Step(step))? {
            Resp::Step(s) => s,
            _ => {
                return Err(
                    RemoteError::Protocol { url: self.url.clone(), request: "Step", what: "a response of another kind".into() }.into()
                );
            }
        };
        let (reward, discount) = self.read_step(&s).inspect_err(|_| self.stats.bad_observations += 1)?;
        let state = EnvironmentStateType::try_from(s.state).unwrap_or(EnvironmentStateType::InvalidEnvironmentState);
        let (terminated, truncated) = match state {
            EnvironmentStateType::Running => (false, false),
            EnvironmentStateType::Terminated => (discount == 0.0, discount != 0.0),
            // The world was reset under us: the episode is cut, not ended.
            EnvironmentStateType::Interrupted => (false, true),
            EnvironmentStateType::InvalidEnvironmentState => {
                return Err(RemoteError::Protocol { url: self.url.clone(), request: "Step", what: format!("state {}", s.state) }.into());
            }
        };
        self.running = state == EnvironmentStateType::Running;
        Ok(Step { observation: &self.obs, reward, terminated, truncated })
    }
}

impl Drop for RemoteEnv {
    fn drop(&mut self) {
        // Leave and destroy the world (best effort, short deadline): servers reclaim it anyway
        // when the connection closes.
        if let Some(mut conn) = self.conn.take() {
            let url = self.url.clone();
            let t = Duration::from_millis(500);
            let _ = block(async move {
                let _ = call(&mut conn, &url, "LeaveWorld", Req::LeaveWorld(pb::LeaveWorldRequest {}), t).await;
                let world = conn.world.clone();
                let _ = call(&mut conn, &url, "DestroyWorld", Req::DestroyWorld(pb::DestroyWorldRequest { world_name: world }), t).await;
            });
        }
    }
}
