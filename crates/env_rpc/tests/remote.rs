//! RemoteEnv against our own server: the Env conformance suite over the wire, the same episodes
//! as in process, and what happens when the server misbehaves or goes away.

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use coadapt_core::conformance::{check_env, trace};
use coadapt_core::{BoxSpace, Env, EnvError, EnvSpec, Step};
use coadapt_env_rpc::{BackgroundServer, EnvFactory, RemoteEnv, RemoteOptions};

fn robot(name: &'static str) -> EnvFactory {
    coadapt_env_rpc::plain(move || coadapt_robots::make(name).map_err(|e| e.to_string()))
}

fn quick() -> RemoteOptions {
    RemoteOptions {
        connect_timeout: Duration::from_millis(500),
        request_timeout: Duration::from_millis(500),
        reconnect_for: Duration::from_secs(3),
        max_backoff: Duration::from_millis(200),
        ..RemoteOptions::default()
    }
}

#[test]
fn every_robot_passes_the_env_conformance_suite_in_process_and_over_dm_env_rpc() {
    for name in coadapt_robots::ENV_NAMES {
        let mut local = coadapt_robots::make(name).unwrap();
        check_env(&mut *local, 50);
        let server = BackgroundServer::start("127.0.0.1:0", robot(name)).unwrap();
        let mut remote = RemoteEnv::connect(&server.url(), quick()).unwrap();
        check_env(&mut remote, 50);
    }
}

#[test]
fn a_served_robot_gives_the_same_episodes_as_in_process() {
    for name in ["pendulum", "half-cheetah", "daisy"] {
        let server = BackgroundServer::start("127.0.0.1:0", robot(name)).unwrap();
        let mut remote = RemoteEnv::connect(&server.url(), quick()).unwrap();
        let mut local = coadapt_robots::make(name).unwrap();
        let spec = local.spec().clone();
        assert_eq!(remote.spec().state_dim, spec.state_dim);
        assert_eq!(remote.spec().design, spec.design, "{name}: the design box comes from the remote spec");
        assert_eq!(remote.spec().default_design, spec.default_design, "{name}: the default design comes from the server");
        let mut design = spec.default_design.clone();
        design[0] = spec.design.high[0];
        let a = trace(&mut *local, 3, &design, 5, 2_000).unwrap();
        let b = trace(&mut remote, 3, &design, 5, 2_000).unwrap();
        assert_eq!(a, b, "{name}: bit-identical over the wire");
        assert!(a.truncated && !a.terminated, "{name}: a time limit ends the episode as a truncation ({:?})", (a.terminated, a.truncated));
    }
}

/// A client's `[world]` reaches a served robot as CreateWorld settings: the served half-cheetah
/// on a slippery floor steps exactly as the local one on that floor, unlike the one on its own
/// floor; a setting the robot does not take, or a value it cannot have, is refused at connect,
/// named. The world is made again the same way on every reconnection.
#[test]
fn a_clients_world_settings_build_the_served_robots_world() {
    let factory: EnvFactory = Arc::new(|settings: &coadapt_env_rpc::WorldSettings| {
        let world = coadapt_robots::World::from_settings(settings)?;
        coadapt_robots::make_in("half-cheetah", &world).map_err(|e| e.to_string())
    });
    let server = BackgroundServer::start("127.0.0.1:0", factory).unwrap();
    let slippery = coadapt_robots::World { friction: Some(0.05), ..coadapt_robots::World::default() };
    let with = |settings: Vec<(String, f32)>| RemoteOptions { world_settings: settings, ..quick() };
    let mut remote = RemoteEnv::connect(&server.url(), with(vec![("friction".into(), 0.05)])).unwrap();
    let mut local = coadapt_robots::make_in("half-cheetah", &slippery).unwrap();
    let mut own = coadapt_robots::make("half-cheetah").unwrap();
    let design = vec![1.0; 6];
    let a = trace(&mut *local, 3, &design, 2, 300).unwrap();
    let b = trace(&mut remote, 3, &design, 2, 300).unwrap();
    assert_eq!(a, b, "the served robot is in the client's world");
    assert_ne!(a, trace(&mut *own, 3, &design, 2, 300).unwrap(), "the friction changed the run");
    for (settings, words) in [
        (vec![("gravity".to_string(), 1.0)], "unknown world setting `gravity`"),
        (vec![("friction".to_string(), -1.0)], "world.friction: -1 is not a finite number >= 0"),
    ] {
        let e = RemoteEnv::connect(&server.url(), with(settings)).err().unwrap().to_string();
        assert!(e.contains(words) && e.contains("code 3"), "{e}");
    }
}

/// A toy robot that misbehaves on cue: `bad_at` steps into an episode its observation (or
/// reward) turns NaN, or its step stalls for `stall`.
struct Faulty {
    spec: EnvSpec,
    obs: Vec<f32>,
    t: usize,
    bad_at: usize,
    nan_reward: bool,
    stall: Duration,
}

impl Faulty {
    fn factory(bad_at: usize, nan_reward: bool, stall: Duration) -> EnvFactory {
        coadapt_env_rpc::plain(move || {
            let spec = EnvSpec {
                name: "faulty".into(),
                state_dim: 2,
                action: BoxSpace::uniform(1, -1.0, 1.0),
                design: BoxSpace::uniform(1, 0.5, 2.0),
                design_names: vec!["design[0]".into()],
                default_design: vec![1.0],
                max_episode_steps: 100,
            };
            Ok(Box::new(coadapt_core::TimeLimit::new(Faulty { obs: vec![0.0; 3], spec, t: 0, bad_at, nan_reward, stall })) as Box<dyn Env>)
        })
    }
}

impl Env for Faulty {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }
    fn reset(&mut self, _seed: u64, design: &[f32]) -> Result<&[f32], EnvError> {
        self.t = 0;
        self.obs = vec![0.0, 0.0, design[0]];
        Ok(&self.obs)
    }
    fn step(&mut self, action: &[f32]) -> Result<Step<'_>, EnvError> {
        self.t += 1;
        self.obs[0] += action[0];
        self.obs[1] = self.t as f32;
        let mut reward = 1.0;
        if self.t == self.bad_at {
            if self.nan_reward {
                reward = f32::NAN;
            } else {
                self.obs[0] = f32::NAN;
            }
            std::thread::sleep(self.stall);
        }
        Ok(Step { observation: &self.obs, reward, terminated: false, truncated: false })
    }
}

fn run_to(env: &mut RemoteEnv, steps: usize) -> Result<usize, EnvError> {
    env.reset(1, &[1.0])?;
    for t in 1..=steps {
        let s = env.step(&[0.5])?;
        if s.truncated || s.terminated {
            return Ok(t);
        }
    }
    Ok(steps)
}

#[test]
fn a_non_finite_observation_or_reward_ends_the_episode_naming_the_tensor() {
    for (nan_reward, tensor) in [(false, "observation"), (true, "reward")] {
        let server = BackgroundServer::start("127.0.0.1:0", Faulty::factory(5, nan_reward, Duration::ZERO)).unwrap();
        let mut env = RemoteEnv::connect(&server.url(), quick()).unwrap();
        let e = run_to(&mut env, 10).unwrap_err().to_string();
        assert!(e.contains(&format!("tensor `{tensor}`")) && e.contains("NaN"), "{e}");
        assert_eq!(env.stats().bad_observations, 1);
        assert!(matches!(env.step(&[0.0]), Err(EnvError::NotRunning)), "the episode is over");
        // The connection is fine: the next episode runs (and fails at the same step again).
        assert!(run_to(&mut env, 4).is_ok());
        assert_eq!(env.stats().reconnects, 0);
    }
}

#[test]
fn a_server_that_stops_answering_misses_the_deadline_and_the_next_reset_reconnects() {
    let server = BackgroundServer::start("127.0.0.1:0", Faulty::factory(3, false, Duration::from_secs(2))).unwrap();
    let mut env = RemoteEnv::connect(&server.url(), quick()).unwrap();
    let t = Instant::now();
    let e = run_to(&mut env, 10).unwrap_err().to_string();
    assert!(e.contains("no answer to Step within"), "{e}");
    assert!(t.elapsed() < Duration::from_millis(1500), "the deadline, not the stall, ended the wait: {:?}", t.elapsed());
    assert_eq!(env.stats().lost, 1);
    // A fresh connection and world; the first two steps are fine again.
    env.reset(1, &[1.0]).unwrap();
    env.step(&[0.0]).unwrap();
    assert_eq!(env.stats().reconnects, 1);
}

#[test]
fn a_server_killed_mid_episode_fails_the_episode_and_a_restarted_one_is_reconnected() {
    let server = BackgroundServer::start("127.0.0.1:0", robot("pendulum")).unwrap();
    let addr = server.addr;
    let mut env = RemoteEnv::connect(&server.url(), quick()).unwrap();
    let design = env.spec().default_design.clone();
    env.reset(1, &design).unwrap();
    env.step(&[0.1]).unwrap();
    drop(server);
    let e = env.step(&[0.1]).unwrap_err().to_string();
    assert!(e.contains("stream broke") || e.contains("no answer"), "{e}");
    // Nothing listens: reset retries with backoff, then gives up with the last error.
    let t = Instant::now();
    let e = env.reset(1, &design).unwrap_err().to_string();
    assert!(e.contains("cannot connect") || e.contains("no connection"), "{e}");
    assert!(t.elapsed() >= Duration::from_secs(2), "it kept trying for reconnect_for ({:?})", t.elapsed());
    // The server comes back on the same port: the next reset reconnects and the episode runs.
    let _server = BackgroundServer::start(&addr.to_string(), robot("pendulum")).unwrap();
    env.reset(1, &design).unwrap();
    for _ in 0..10 {
        env.step(&[0.1]).unwrap();
    }
    assert_eq!(env.stats().reconnects, 1);
}

#[test]
fn connecting_to_nothing_or_to_a_silent_socket_fails_within_the_deadline() {
    let e = RemoteEnv::connect("dm-env-rpc://127.0.0.1:1", quick()).unwrap_err().to_string();
    assert!(e.contains("cannot connect") || e.contains("no connection"), "{e}");
    // A socket that accepts and never speaks HTTP/2.
    let silent = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let url = format!("dm-env-rpc://{}", silent.local_addr().unwrap());
    let t = Instant::now();
    let e = RemoteEnv::connect(&url, quick()).unwrap_err().to_string();
    assert!(t.elapsed() < Duration::from_secs(3), "{:?}", t.elapsed());
    assert!(e.contains(&url), "{e}");
    for bad in ["dm-env-rpc://nohost", "dm-env-rpc://h:99999", "http://h:1", "dm-env-rpc://h:1/x"] {
        let e = RemoteEnv::connect(bad, quick()).unwrap_err().to_string();
        assert!(e.contains(bad), "{bad}: {e}");
    }
}

#[test]
fn worlds_die_with_their_connection() {
    let calls = Arc::new(AtomicUsize::new(0));
    let c = calls.clone();
    let factory: EnvFactory = coadapt_env_rpc::plain(move || {
        c.fetch_add(1, Ordering::Relaxed);
        coadapt_robots::make("pendulum").map_err(|e| e.to_string())
    });
    let server = BackgroundServer::start("127.0.0.1:0", factory).unwrap();
    let mut envs = Vec::new();
    for _ in 0..3 {
        let mut env = RemoteEnv::connect(&server.url(), quick()).unwrap();
        env.reset(0, &[1.0, 1.0]).unwrap();
        envs.push(env);
    }
    assert_eq!(calls.load(Ordering::Relaxed), 3, "one world per connection");
    assert_eq!(server.world_count(), 3);
    drop(envs);
    let t = Instant::now();
    while server.world_count() > 0 && t.elapsed() < Duration::from_secs(5) {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(server.world_count(), 0, "every world is gone with its client");
}
