//! `coadapt bench env`: environment steps over dm_env_rpc on loopback against the same robot in
//! process, and any other server by URL (the Python bridge's gymnasium Pendulum-v1). The peer
//! is dm_env_rpc's own Python client stepping the same servers (bench/peers/env_client.py).
//!
//! Actions are drawn before the timed loop; every step is timed on its own for the latency
//! percentiles; episodes end where the server ends them and the reset is inside the time (a
//! real run pays it too).

use std::time::Instant;

use coadapt_core::{Env, rng};
use coadapt_env_rpc::{BackgroundServer, RemoteEnv, RemoteOptions};
use rand::Rng;
use serde_json::json;

use coadapt_fleet::app::AppError;

#[derive(Debug, Clone)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct EnvOptions {
    /// Seconds to time each figure for.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 5.0))]
    pub seconds: f64,
    /// Built-in robots to serve on loopback and time (comma-separated).
    #[cfg_attr(feature = "clap", arg(long, value_delimiter = ',', default_values_t = vec!["pendulum".to_string(), "half-cheetah".to_string()]))]
    pub env: Vec<String>,
    /// Also time these servers (dm-env-rpc://HOST:PORT, e.g. `coadapt-gym-serve --env
    /// Pendulum-v1`), comma-separated.
    #[cfg_attr(feature = "clap", arg(long, value_delimiter = ','))]
    pub url: Vec<String>,
}

struct Timing {
    steps: u64,
    seconds: f64,
    latencies_us: Vec<f64>,
}

/// Steps `env` for `seconds` with pre-drawn uniform actions, timing each step.
fn time_env(env: &mut dyn Env, seconds: f64) -> Result<Timing, AppError> {
    let spec = env.spec().clone();
    let mut r = rng(1, 0x454e_5642);
    let n_actions = 4096;
    let actions: Vec<f32> = (0..n_actions * spec.act_dim())
        .map(|i| {
            let d = i % spec.act_dim();
            r.random_range(spec.action.low[d]..=spec.action.high[d])
        })
        .collect();
    let design = spec.default_design.clone();
    let mut latencies_us = Vec::with_capacity(1 << 16);
    let start = Instant::now();
    let (mut steps, mut episode) = (0u64, 0u64);
    env.reset(episode, &design)?;
    while start.elapsed().as_secs_f64() < seconds {
        let a = &actions[(steps as usize % n_actions) * spec.act_dim()..][..spec.act_dim()];
        let t = Instant::now();
        let done = {
            let s = env.step(a)?;
            s.terminated || s.truncated
        };
        if done {
            episode += 1;
            env.reset(episode, &design)?;
        }
        latencies_us.push(t.elapsed().as_secs_f64() * 1e6);
        steps += 1;
    }
    Ok(Timing { steps, seconds: start.elapsed().as_secs_f64(), latencies_us })
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

fn emit(name: &str, transport: &str, t: &mut Timing) {
    t.latencies_us.sort_by(f64::total_cmp);
    let rate = t.steps as f64 / t.seconds;
    let config = json!({"env": name, "transport": transport, "steps": t.steps, "client": "coadapt (Rust)"});
    coadapt_log::print_stdout_line(
        &json!({"bench": "env_steps_per_second", "config": config, "value": rate, "unit": "steps/s"}).to_string(),
    );
    for (label, p) in [("median", 0.5), ("p99", 0.99)] {
        let v = percentile(&t.latencies_us, p);
        coadapt_log::print_stdout_line(
            &json!({"bench": format!("env_step_latency_{label}"), "config": config, "value": v, "unit": "us"}).to_string(),
        );
    }
}

pub fn run(a: &EnvOptions) -> Result<(), AppError> {
    for name in &a.env {
        let mut local = coadapt_robots::make(name)?;
        emit(name, "in-process", &mut time_env(&mut *local, a.seconds)?);
        let n = name.clone();
        let server =
            BackgroundServer::start("127.0.0.1:0", coadapt_env_rpc::plain(move || coadapt_robots::make(&n).map_err(|e| e.to_string())))
                .map_err(AppError::io(format!("serving {name} on loopback")))?;
        let mut remote = RemoteEnv::connect(&server.url(), RemoteOptions::default())?;
        emit(name, "dm_env_rpc loopback", &mut time_env(&mut remote, a.seconds)?);
    }
    for url in &a.url {
        let mut remote = RemoteEnv::connect(url, RemoteOptions::default())?;
        emit(url, "dm_env_rpc loopback", &mut time_env(&mut remote, a.seconds)?);
    }
    Ok(())
}
