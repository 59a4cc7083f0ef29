//! Remote environments through the binary: DeepMind's compliance suites against `coadapt
//! env-serve`, learning Pendulum-v1 served by the Python gymnasium bridge, a tiny FEAR run on
//! the design-parameterised MuJoCo HalfCheetah, and servers that die, lie or go silent.
//!
//! The Python side (dm-env-rpc, gymnasium, MuJoCo and the bridge package) lives in a virtualenv
//! that `bridges/python/setup_venv.sh` creates once under the target directory and reuses.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

fn workspace_file(rel: &str) -> PathBuf {
    coadapt_test_support::workspace_file(rel)
}

fn tmpdir(name: &str) -> PathBuf {
    coadapt_test_support::scratch_dir("envrpc", name)
}

/// The bridge's virtualenv (created on first use, then reused: the script checks a stamp).
fn venv() -> &'static Path {
    coadapt_test_support::bridge_venv(env!("CARGO_TARGET_TMPDIR"))
}

/// A server process, killed when dropped.
struct Server {
    child: Child,
    url: String,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Starts `cmd` and reads the address it prints on its first stdout line (`dm-env-rpc://...`
/// from env-serve, `coadapt-gym-serve listening on HOST:PORT` from the bridge).
fn start(mut cmd: Command) -> Server {
    let mut child = cmd.stdout(Stdio::piped()).stderr(Stdio::inherit()).spawn().unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap()).read_line(&mut line).unwrap();
    let addr = line.trim().rsplit(' ').next().unwrap().trim_start_matches("dm-env-rpc://").to_string();
    assert!(addr.contains(':'), "no address in the server's first line: {line:?}");
    Server { child, url: format!("dm-env-rpc://{addr}") }
}

fn env_serve(robot: &str) -> Server {
    let mut c = Command::new(env!("CARGO_BIN_EXE_coadapt"));
    c.args(["env-serve", "--env", robot, "--listen", "127.0.0.1:0"]);
    start(c)
}

fn gym_serve(args: &[&str]) -> Server {
    let mut c = Command::new(venv().join("bin/coadapt-gym-serve"));
    c.args(args);
    // MuJoCo writes warnings to MUJOCO_LOG.TXT in the working directory.
    c.current_dir(std::env::temp_dir());
    start(c)
}

fn coadapt(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_coadapt")).args(args).output().unwrap()
}

#[test]
fn deepminds_compliance_suites_and_dm_env_adaptor_pass_against_env_serve() {
    for (robot, design_dim) in [("half-cheetah", "6"), ("pendulum", "2")] {
        let server = env_serve(robot);
        let o = Command::new(venv().join("bin/python"))
            .arg(workspace_file("cli/tests/python/env_serve_compliance.py"))
            .args([&server.url, design_dim])
            .output()
            .unwrap();
        let out = String::from_utf8_lossy(&o.stdout);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{robot}: compliance failed:\n{out}\n{err}");
        assert!(err.contains("Ran 41 tests") && err.contains("OK"), "{robot}: every suite ran: {err}");
        assert!(out.contains("DmEnvAdaptor: one episode of"), "{robot}: {out}");
    }
}

#[test]
fn sac_learns_gymnasium_pendulum_served_by_the_python_bridge() {
    let server = gym_serve(&["--env", "Pendulum-v1", "--port", "0"]);
    sac_reaches_minus_200_on_pendulum(&server.url, "pendulum");
}

/// SAC on gymnasium's Pendulum-v1 served at `url` reaches -200 within 20,000 steps, every
/// episode whole (Pendulum-v1 truncates at 200 steps).
fn sac_reaches_minus_200_on_pendulum(url: &str, name: &str) {
    let out = tmpdir(name);
    let o = coadapt(&[
        "train",
        "--env",
        url,
        "--steps",
        "20000",
        "--seed",
        "1",
        "--target-return",
        "-200",
        "--stop-at-target",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s: serde_json::Value = serde_json::from_str(String::from_utf8(o.stdout).unwrap().trim()).unwrap();
    eprintln!("Pendulum-v1 over dm_env_rpc ({name}): {s}");
    let reached = s["first_step_reaching_target"].as_u64().unwrap_or_else(|| panic!("never above -200: {s}"));
    assert!(reached <= 20_000 && s["mean_return_last_10"].as_f64().unwrap() > -200.0, "{s}");
    let csv = std::fs::read_to_string(out.join("episodes.csv")).unwrap();
    assert!(csv.lines().skip(1).all(|l| l.split(',').nth(3) == Some("200")), "{csv}");
}

#[test]
fn sac_and_latent_learn_from_a_dm_env_rpc_server_not_written_for_coadapt() {
    // gymnasium's Pendulum-v1 behind a server written from the protocol's text: no `design`,
    // its own uids, an action named `torque`, and every setting refused.
    let mut c = Command::new(venv().join("bin/python"));
    c.arg(workspace_file("cli/tests/python/plain_dm_env_server.py"));
    let server = start(c);
    sac_reaches_minus_200_on_pendulum(&server.url, "plain");
    // Co-adaptation needs a design: refused as a setting (exit 78), saying what to do instead.
    let dir = tmpdir("plain-run");
    let cfg = tiny_config(&dir, &server.url, "", "");
    let o = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["run", "--config", cfg.to_str().unwrap(), "--out"])
        .arg(dir.join("run"))
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(78), "{e}");
    assert!(e.contains("has no design parameters to optimise") && e.contains("coadapt train"), "{e}");
    // A run of one fixed design (no design to choose): its actor processes step the server.
    let fixed = dir.join("fixed.toml");
    std::fs::write(
        &fixed,
        format!(
            "env = \"{}\"\nseed = 1\nlandscape-grid = 0\n\n[schedule]\ndesigns = 1\ninitial-episodes = 3\ninitial-designs = [[]]\n\
             eval-every = 1\n\n[learner]\nindividual-updates = 20\npopulation-updates = 10\nwarmup-episodes = 1\n\n[learner.sac]\nhidden = [32, 32]\n",
            server.url
        ),
    )
    .unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["run", "--config", fixed.to_str().unwrap(), "--actors", "2", "--out"])
        .arg(dir.join("fixed"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let eps = std::fs::read_to_string(dir.join("fixed/episodes.csv")).unwrap();
    assert_eq!(eps.lines().count(), 1 + 3, "{eps}");
    let designs = std::fs::read_to_string(dir.join("fixed/designs.csv")).unwrap();
    assert!(designs.lines().nth(1).is_some_and(|l| l.starts_with("0,initial,,3,")), "{designs}");
    // The same server showing a 16-pixel camera frame instead of its state: `coadapt latent`
    // (pixels to a time-contrastive embedding, DDPG planning in it) learns from it as it is.
    let mut c = Command::new(venv().join("bin/python"));
    c.arg(workspace_file("cli/tests/python/plain_dm_env_server.py")).args(["--pixels", "16"]);
    let pixels = start(c);
    let tiny = std::fs::read_to_string(workspace_file("configs/latent/pendulum-tiny.toml")).unwrap();
    assert!(tiny.contains("robot = \"pendulum\""));
    let latent_cfg = dir.join("latent.toml");
    let tiny = tiny
        .replace("robot = \"pendulum\"", &format!("robot = \"{}\"", pixels.url))
        .replace("[embedding]\n", &format!("[embedding]\npath = {:?}\n", dir.join("embedding.safetensors").display().to_string()));
    std::fs::write(&latent_cfg, tiny).unwrap();
    let o = coadapt(&["latent", "--config", latent_cfg.to_str().unwrap(), "--out", dir.join("latent").to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s: serde_json::Value = serde_json::from_str(String::from_utf8(o.stdout).unwrap().trim()).unwrap();
    assert_eq!((s["runs"].as_u64(), s["episodes"].as_u64()), (Some(2), Some(3)), "{s}");
    assert!(s["final_eval_return_mean"].as_f64().is_some_and(f64::is_finite), "{s}");
}

/// The tiny protocol on a remote env: `configs/half-cheetah-tiny.toml` with `env` replaced.
fn tiny_config(dir: &Path, url: &str, top: &str, tables: &str) -> PathBuf {
    let text = std::fs::read_to_string(workspace_file("configs/half-cheetah-tiny.toml")).unwrap();
    let text = text.replace("env = \"half-cheetah\"", &format!("env = \"{url}\"\n{top}")) + tables;
    let p = dir.join("tiny-remote.toml");
    std::fs::write(&p, text).unwrap();
    p
}

fn run_tiny(config: &Path, out: &Path) -> (serde_json::Value, String) {
    let o = coadapt(&["run", "--config", config.to_str().unwrap(), "--out", out.to_str().unwrap(), "--transport", "in-process"]);
    let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "{stderr}");
    (serde_json::from_str(String::from_utf8(o.stdout).unwrap().trim()).unwrap(), stderr)
}

/// Steps of every episodes.csv row (cumulative `steps` column) and the number of training
/// episodes.
fn episode_lengths(run: &Path) -> Vec<u64> {
    let csv = std::fs::read_to_string(run.join("episodes.csv")).unwrap();
    let steps: Vec<u64> = csv.lines().skip(1).map(|l| l.split(',').nth(3).unwrap().parse().unwrap()).collect();
    steps.iter().scan(0, |prev, &s| Some(s - std::mem::replace(prev, s))).collect()
}

#[test]
fn a_tiny_fear_run_co_designs_the_mujoco_half_cheetah_through_the_bridge() {
    let server = gym_serve(&["--factory", "coadapt_bridge.mujoco_half_cheetah:make", "--port", "0"]);
    let dir = tmpdir("mujoco");
    let (s, stderr) = run_tiny(&tiny_config(&dir, &server.url, "", ""), &dir.join("run"));
    assert_eq!(s["designs"], 4, "{s}");
    assert!(stderr.contains("design 3/4 [exploit pso-q]"), "{stderr}");
    let lengths = episode_lengths(&dir.join("run"));
    assert_eq!(lengths.len(), 10, "3 + 3 + 2 + 2 training episodes");
    assert!(lengths.iter().all(|&l| l == 1000), "HalfCheetah-v5's time limit ends every episode: {lengths:?}");
    assert_eq!(s["replay_transitions"], 10_000, "{s}");
    let designs = std::fs::read_to_string(dir.join("run/designs.csv")).unwrap();
    assert!(designs.contains("exploit"), "{designs}");
}

#[test]
fn a_bridge_killed_mid_episode_costs_only_that_episode() {
    // A fixed port, so the restarted server is found at the same address.
    let port = {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        l.local_addr().unwrap().port().to_string()
    };
    let args = ["--factory", "coadapt_bridge.mujoco_half_cheetah:make", "--port", &port];
    let server = gym_serve(&args);
    let dir = tmpdir("killed");
    let config = tiny_config(&dir, &server.url, "chunk-len = 100", "\n[remote]\nreconnect-secs = 30.0\n");
    let out = dir.join("run");
    let run = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["run", "--config", config.to_str().unwrap(), "--out", out.to_str().unwrap(), "--transport", "in-process"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Kill the server in the middle of a training episode (some chunks already sent), then
    // bring it back on the same port. Each row of episodes.csv is a training episode and its
    // evaluation; the time between rows 1 and 2 gives that period, and a quarter of it after
    // row 2 lands inside the next training episode whatever the machine's speed.
    let rows = || std::fs::read_to_string(out.join("episodes.csv")).map_or(0, |t| t.lines().count().saturating_sub(1));
    let wait_rows = |n: usize| {
        let t = std::time::Instant::now();
        while rows() < n {
            assert!(t.elapsed() < Duration::from_secs(120), "no episode row {n}");
            std::thread::sleep(Duration::from_millis(5));
        }
        std::time::Instant::now()
    };
    let first = wait_rows(1);
    let second = wait_rows(2);
    std::thread::sleep((second - first) / 4);
    drop(server);
    std::thread::sleep(Duration::from_millis(1000));
    let _server = gym_serve(&args);
    let o = run.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    let s: serde_json::Value = serde_json::from_str(String::from_utf8(o.stdout.clone()).unwrap().trim()).unwrap();
    // Killed mid-episode, the actor drops that episode; if the kill still fell between
    // episodes (the stream broke at a reset), nothing was under way and nothing is lost.
    assert!(
        stderr.contains("dropped after") || stderr.contains("the stream broke during ResetWorld"),
        "the actor neither dropped the broken episode nor broke at a reset: {stderr}"
    );
    assert!(stderr.contains("reconnected"), "the actor reconnected: {stderr}");
    let lengths = episode_lengths(&out);
    assert_eq!(lengths.len(), 10, "{lengths:?}");
    assert!(lengths.iter().all(|&l| l == 1000), "only whole episodes in episodes.csv: {lengths:?}");
    assert_eq!(s["replay_transitions"], 10_000, "only whole episodes in the replay: {s}");
    assert_eq!(s["start_states"], 10, "{s}");
}

#[test]
fn the_bridges_own_python_tests_pass() {
    let o = Command::new(venv().join("bin/python"))
        .args(["-m", "pytest", "-q", "-p", "no:cacheprovider"])
        .current_dir(workspace_file("bridges/python"))
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{out}\n{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.contains(" passed"), "{out}");
}

/// A tiny co-adaptation on one of cli/tests/python/faulty_envs.py's robots.
fn run_faulty(factory: &str, name: &str, tables: &str) -> (std::process::Output, PathBuf) {
    let mut c = Command::new(venv().join("bin/coadapt-gym-serve"));
    c.args(["--factory", &format!("faulty_envs:{factory}"), "--port", "0"]).env("PYTHONPATH", workspace_file("cli/tests/python"));
    let server = start(c);
    let dir = tmpdir(name);
    let config = tiny_config(&dir, &server.url, "", tables);
    let out = dir.join("run");
    let o = coadapt(&["run", "--config", config.to_str().unwrap(), "--out", out.to_str().unwrap(), "--transport", "in-process"]);
    (o, out)
}

#[test]
fn a_nan_observation_costs_its_episode_which_runs_again_and_the_run_goes_on() {
    let (o, run) = run_faulty("nan_once", "nan", "");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    assert!(stderr.contains("tensor `observation`: element 0 is NaN"), "the error names the tensor: {stderr}");
    assert_eq!(stderr.matches("dropped after").count(), 1, "{stderr}");
    let s: serde_json::Value = serde_json::from_str(String::from_utf8(o.stdout).unwrap().trim()).unwrap();
    let lengths = episode_lengths(&run);
    assert_eq!(lengths.len(), 10);
    assert!(lengths.iter().all(|&l| l == 50), "{lengths:?}");
    assert_eq!(s["replay_transitions"], 500, "nothing of the NaN episode reached the replay: {s}");
}

#[test]
fn a_server_that_stalls_misses_the_deadline_and_the_episode_runs_again() {
    let (o, run) = run_faulty("stall_once", "stall", "\n[remote]\nrequest-timeout-secs = 1.0\n");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    assert!(stderr.contains("no answer to Step within 1s"), "{stderr}");
    assert!(stderr.contains("reconnected"), "{stderr}");
    let s: serde_json::Value = serde_json::from_str(String::from_utf8(o.stdout).unwrap().trim()).unwrap();
    assert!(episode_lengths(&run).iter().all(|&l| l == 50));
    assert_eq!(s["replay_transitions"], 500, "{s}");
}

#[test]
fn an_environment_that_always_breaks_its_spec_stops_the_run_with_a_clear_error() {
    let (o, run) = run_faulty("wrong_shape", "shape", "\n[remote]\nenv-retries = 2\n");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{stderr}");
    // The bridge checks its environment's observations against the spec it published and
    // refuses the step; the actor shows the server's message (RemoteEnv's own shape check on
    // what a server sends is tested in crates/wire/tests/tensor.rs).
    assert!(stderr.contains("the server refused Step") && stderr.contains("4 observation values, 3 expected"), "{stderr}");
    assert_eq!(stderr.matches("dropped after").count(), 2, "two retries, then the actor stops: {stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    let csv = std::fs::read_to_string(run.join("episodes.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1, "no episode was recorded: {csv}");
}

#[test]
fn env_serve_stops_on_sigterm_even_with_a_client_connected() {
    let mut server = env_serve("pendulum");
    let _client = coadapt_env_rpc::RemoteEnv::connect(&server.url, coadapt_env_rpc::RemoteOptions::default()).unwrap();
    let t = Instant::now();
    let status = Command::new("kill").args(["-TERM", &server.child.id().to_string()]).status().unwrap();
    assert!(status.success());
    loop {
        if let Some(s) = server.child.try_wait().unwrap() {
            assert!(s.success(), "a clean exit: {s:?}");
            break;
        }
        assert!(t.elapsed() < Duration::from_secs(10), "env-serve did not stop within 10 s of SIGTERM");
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(t.elapsed() >= Duration::from_secs(1), "the open stream got its grace period");
}

#[test]
fn a_bridge_across_machines_serves_tls_to_actor_tokens_only() {
    let dir = tmpdir("bridge-tls");
    let sec = dir.join("sec");
    assert!(coadapt(&["tls", "new", "--out", sec.join("tls").to_str().unwrap()]).status.success());
    for role in ["actor", "client"] {
        let out = sec.join(format!("{role}.token"));
        let o = coadapt(&[
            "token",
            "new",
            "--role",
            role,
            "--out",
            out.to_str().unwrap(),
            "--tokens-file",
            sec.join("tokens").to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let p = |n: &str| sec.join(n).display().to_string();
    // Without TLS a bridge refuses an address other than loopback.
    let o = Command::new(venv().join("bin/coadapt-gym-serve")).args(["--env", "Pendulum-v1", "--host", "0.0.0.0"]).output().unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("not a loopback address") && e.contains("--insecure"), "{e}");
    // Nor with TLS and no tokens: every caller could drive the robot.
    let o = Command::new(venv().join("bin/coadapt-gym-serve"))
        .args(["--env", "Pendulum-v1", "--host", "0.0.0.0", "--tls-cert", &p("tls/server.pem"), "--tls-key", &p("tls/server-key.pem")])
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("no role tokens (--tokens-file)") && !e.contains("no TLS"), "{e}");
    let server = gym_serve(&[
        "--factory",
        "coadapt_bridge.mujoco_half_cheetah:make",
        "--port",
        "0",
        "--tls-cert",
        &p("tls/server.pem"),
        "--tls-key",
        &p("tls/server-key.pem"),
        "--tokens-file",
        &p("tokens"),
    ]);
    let security = |token: &str| format!("\n[security]\ntls-ca = \"{}\"\ntoken-file = \"{}\"\n", p("tls/ca.pem"), p(token));
    // The actor's token over TLS: a whole tiny co-adaptation.
    let (s, _) = run_tiny(&tiny_config(&dir, &server.url, "", &security("actor.token")), &dir.join("run"));
    assert_eq!(s["designs"], 4, "{s}");
    // A client's token may not step the robot; plaintext is not served.
    let cfg = tiny_config(&dir, &server.url, "", &security("client.token"));
    let o =
        coadapt(&["run", "--config", cfg.to_str().unwrap(), "--out", dir.join("client").to_str().unwrap(), "--transport", "in-process"]);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("PermissionDenied") && e.contains("role client"), "{e}");
    let cfg = tiny_config(&dir, &server.url, "", "");
    let o = coadapt(&["run", "--config", cfg.to_str().unwrap(), "--out", dir.join("plain").to_str().unwrap(), "--transport", "in-process"]);
    assert!(!o.status.success(), "a plaintext actor stepped a TLS bridge");
    let token = std::fs::read_to_string(sec.join("client.token")).unwrap();
    assert!(!e.contains(token.trim()), "the token is in the error");
}
