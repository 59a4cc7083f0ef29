//! The environment factory: a robot by name (a built-in one, or `dm-env-rpc://HOST:PORT` for a
//! robot or simulator served elsewhere), for every experiment and tool.

use std::time::Duration;

use coadapt_core::Env;
use coadapt_env_rpc::{RemoteEnv, RemoteOptions};
use coadapt_robots::{MakeError, World};
use serde::{Deserialize, Serialize};

use crate::{SecurityConfig, SetupError};

/// Remote environments (`env = "dm-env-rpc://HOST:PORT"`): deadlines and retries.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct RemoteEnvConfig {
    /// Seconds to connect to the environment server and open the stream.
    pub connect_timeout_secs: f64,
    /// Seconds to wait for the answer to any request (one step of a real robot included).
    pub request_timeout_secs: f64,
    /// Seconds a reset keeps reconnecting (waits doubling from 0.1 s) before the episode fails.
    pub reconnect_secs: f64,
    /// The longest wait between reconnection attempts, in seconds.
    pub max_backoff_secs: f64,
    /// Episodes in a row an actor may lose to its environment (each dropped and run again)
    /// before the actor stops: in one process that stops the run; in a fleet the supervisor
    /// starts the actor again, up to `fleet.max-restarts`.
    pub env_retries: u32,
}

impl Default for RemoteEnvConfig {
    fn default() -> Self {
        let o = RemoteOptions::default();
        Self {
            connect_timeout_secs: o.connect_timeout.as_secs_f64(),
            request_timeout_secs: o.request_timeout.as_secs_f64(),
            reconnect_secs: o.reconnect_for.as_secs_f64(),
            max_backoff_secs: o.max_backoff.as_secs_f64(),
            env_retries: 5,
        }
    }
}

impl RemoteEnvConfig {
    /// The client's options (with `security`'s TLS and token), refusing durations that are
    /// not positive numbers of seconds.
    pub fn options(&self, security: &SecurityConfig) -> Result<RemoteOptions, SetupError> {
        let secs = |field: &str, v: f64| {
            if v.is_finite() && v > 0.0 && v < 1e9 {
                Ok(Duration::from_secs_f64(v))
            } else {
                Err(SetupError::Config(format!("remote.{field}: {v} is not a positive number of seconds")))
            }
        };
        Ok(RemoteOptions {
            connect_timeout: secs("connect-timeout-secs", self.connect_timeout_secs)?,
            request_timeout: secs("request-timeout-secs", self.request_timeout_secs)?,
            reconnect_for: secs("reconnect-secs", self.reconnect_secs)?,
            max_backoff: secs("max-backoff-secs", self.max_backoff_secs)?,
            auth: security.client_auth()?,
            ..RemoteOptions::default()
        })
    }
}

/// The environment `name` in `world`: a built-in robot, or `dm-env-rpc://HOST:PORT` for a
/// remote one (which receives the world's values that differ from its own as CreateWorld
/// settings, and refuses those it does not know).
pub fn make_env_with(name: &str, world: &World, remote: &RemoteEnvConfig, security: &SecurityConfig) -> Result<Box<dyn Env>, SetupError> {
    world.check().map_err(|e| SetupError::Config(e.to_string()))?;
    if coadapt_env_rpc::is_remote(name) {
        let mut options = remote.options(security)?;
        options.world_settings = world.settings().into_iter().map(|(k, v)| (k.to_string(), v)).collect();
        let env = RemoteEnv::connect(name, options).map_err(|e| SetupError::Env(e.to_string()))?;
        return Ok(Box::new(env));
    }
    coadapt_robots::make_in(name, world).map_err(|e| match e {
        MakeError::Unknown(e) => SetupError::Config(format!("{e}; or dm-env-rpc://HOST:PORT for a remote environment")),
        MakeError::World(e) => SetupError::Config(e.to_string()),
    })
}

/// [`make_env_with`] with the robot's own world and the default remote settings.
pub fn make_env(name: &str) -> Result<Box<dyn Env>, SetupError> {
    make_env_with(name, &World::default(), &RemoteEnvConfig::default(), &SecurityConfig::default())
}
