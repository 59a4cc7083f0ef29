//! The co-adaptation as a fleet of processes: over shared memory (the default) and gRPC, with
//! actors killed mid-run; and the learner's flow control (leases, episodes in flight) over
//! the in-process transport.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use coadapt_coadaptation::config::{RunConfig, resolve_initial_designs};
use coadapt_coadaptation::roles;
use coadapt_fleet::TransportKind;
use coadapt_learner::flow::FlowMode;
use coadapt_transport::in_process;

fn tmpdir(name: &str) -> PathBuf {
    coadapt_test_support::scratch_dir("fleet", name)
}

fn tiny() -> RunConfig {
    let mut c: RunConfig = coadapt_test_support::read_config("configs/half-cheetah-tiny.toml");
    c.landscape_grid = 0;
    c
}

fn write_config(dir: &Path, c: &RunConfig) -> PathBuf {
    let p = dir.join("fleet.toml");
    std::fs::write(&p, toml::to_string(c).unwrap()).unwrap();
    p
}

fn rows(path: &Path) -> usize {
    std::fs::read_to_string(path).map_or(0, |t| t.lines().count().saturating_sub(1))
}

/// Child processes of `pid` as (pid, command line).
fn children(pid: u32) -> Vec<(u32, String)> {
    let mut out = Vec::new();
    for e in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(p) = e.file_name().to_string_lossy().parse::<u32>() else { continue };
        let Ok(stat) = std::fs::read_to_string(format!("/proc/{p}/stat")) else { continue };
        // Fields after the command name, which is in parentheses and may hold spaces.
        let Some(rest) = stat.rsplit_once(')').map(|(_, r)| r.to_string()) else { continue };
        let ppid: u32 = rest.split_whitespace().nth(1).and_then(|s| s.parse().ok()).unwrap_or(0);
        if ppid == pid {
            let cmd = std::fs::read(format!("/proc/{p}/cmdline")).unwrap_or_default();
            out.push((p, String::from_utf8_lossy(&cmd).replace('\0', " ")));
        }
    }
    out
}

fn summary(stdout: &[u8]) -> serde_json::Value {
    let text = String::from_utf8_lossy(stdout);
    serde_json::from_str(text.lines().last().unwrap_or_default()).unwrap_or_else(|e| panic!("summary line {text:?}: {e}"))
}

/// `coadapt run` of `c` in the background, once it has written `min_rows` episode rows:
/// the process, the run directory and the file its stderr goes to.
fn start_run(dir: &Path, c: &RunConfig, min_rows: usize) -> (std::process::Child, PathBuf, PathBuf) {
    let config = write_config(dir, c);
    let out = dir.join("run");
    let stderr_path = dir.join("stderr.txt");
    let child = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["run", "--config", config.to_str().unwrap(), "--out", out.to_str().unwrap()])
        .stdout(Stdio::piped())
        .stderr(std::fs::File::create(&stderr_path).unwrap())
        .spawn()
        .unwrap();
    let t = Instant::now();
    while rows(&out.join("episodes.csv")) < min_rows {
        assert!(t.elapsed() < Duration::from_secs(120), "no episodes after 120 s: {}", std::fs::read_to_string(&stderr_path).unwrap());
        std::thread::sleep(Duration::from_millis(20));
    }
    (child, out, stderr_path)
}

#[test]
fn a_shared_memory_fleet_survives_killed_actors() {
    let dir = tmpdir("shm-kill");
    let mut c = tiny();
    c.actors = 2;
    c.schedule.initial_episodes = 8;
    c.flow.mode = FlowMode::Async;
    c.flow.assignment_lease_secs = 2.0;
    // Both actors are busy in async mode with two in flight: killing both loses an episode.
    let (child, out, stderr_path) = start_run(&dir, &c, 3);
    let procs = children(child.id());
    let count = |role: &str| procs.iter().filter(|(_, c)| c.contains(&format!(" {role} "))).count();
    assert_eq!((count("learner"), count("optimizer"), count("actor")), (1, 1, 2), "separate processes: {procs:?}");
    let resolved: RunConfig = toml::from_str(&std::fs::read_to_string(out.join("config.toml")).unwrap()).unwrap();
    let live = coadapt_shm::fleet_services(&resolved.fleet.name).unwrap();
    assert!(live.len() >= 6, "the running fleet's channels are visible: {live:?}");
    for (pid, cmd) in procs.iter().filter(|(_, c)| c.contains(" actor ")) {
        let ok = Command::new("kill").args(["-KILL", &pid.to_string()]).status().unwrap().success();
        assert!(ok, "killing {cmd}");
    }
    let o = child.wait_with_output().unwrap();
    let stderr = std::fs::read_to_string(&stderr_path).unwrap();
    assert!(o.status.success(), "{stderr}");
    assert!(stderr.contains("ended with signal 9; starting it again"), "{stderr}");
    let s = summary(&o.stdout);
    assert_eq!(s["designs"], 4, "{s}");
    assert!(s["episodes_reissued"].as_u64().unwrap() >= 1, "the killed actors' episodes were issued again: {s}");
    assert_eq!(rows(&out.join("episodes.csv")), 2 * 8 + 2 * 2, "every episode of the run is in episodes.csv");
    let logs: Vec<_> = std::fs::read_dir(out.join("logs")).unwrap().flatten().map(|e| e.file_name()).collect();
    assert_eq!(logs.len(), 3, "{logs:?}");
    // Nothing of the fleet is left in shared memory, the killed actors' resources included.
    assert!(resolved.fleet.name.starts_with("coadapt-"));
    let left = coadapt_shm::fleet_services(&resolved.fleet.name).unwrap();
    assert!(left.is_empty(), "stale shared memory after the run: {left:?}");
}

/// `designs.csv`, and `episodes.csv` without its wall-clock and actor columns.
fn run_tables(out: &Path) -> (String, String) {
    let designs = std::fs::read_to_string(out.join("designs.csv")).unwrap();
    let episodes = std::fs::read_to_string(out.join("episodes.csv")).unwrap();
    let episodes = episodes.lines().map(|l| l.split(',').take(7).collect::<Vec<_>>().join(",")).collect::<Vec<_>>().join("\n");
    (designs, episodes)
}

#[test]
fn the_same_seed_gives_the_same_run_over_every_transport() {
    let dir = tmpdir("same");
    let mut c = tiny();
    c.actors = 2;
    // A landscape that takes the learner a while after the optimiser and actors have ended.
    c.landscape_grid = 400;
    let config = write_config(&dir, &c);
    let mut tables = Vec::new();
    for t in ["in-process", "shm", "grpc"] {
        let out = dir.join(t);
        let o = Command::new(env!("CARGO_BIN_EXE_coadapt"))
            .args(["run", "--config", config.to_str().unwrap(), "--out", out.to_str().unwrap(), "--transport", t])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{t}: {stderr}");
        assert!(!stderr.contains("starting it again"), "{t}: roles that end with the run are not restarted: {stderr}");
        let s = summary(&o.stdout);
        assert_eq!((s["designs"].as_u64(), s["transport"].as_str()), (Some(4), Some(t)), "{s}");
        assert_eq!(rows(&out.join("episodes.csv")), 10, "{t}");
        tables.push((t, run_tables(&out)));
    }
    for (t, tab) in &tables[1..] {
        assert_eq!(tab, &tables[0].1, "{t} ran a different co-adaptation than in-process");
    }
}

/// The learner and one real actor over the in-process transport, plus one actor that takes an
/// episode and never answers (a process that died holding it).
#[test]
fn a_silent_actors_episode_is_issued_again() {
    let mut c = tiny();
    c.schedule.designs = 2;
    c.flow.assignment_lease_secs = 0.5;
    let spec = coadapt_robots::make(&c.env).unwrap().spec().clone();
    resolve_initial_designs(&mut c, &spec);
    let (mut learner, mut actors, mut optimizer) = in_process::fleet(2);
    let shutdown = AtomicBool::new(false);
    let finished = AtomicBool::new(false);
    let dir = tmpdir("lease").join("run");
    let outcome = std::thread::scope(|s| {
        let mut dead = actors.pop().unwrap();
        let mut live = actors.pop().unwrap();
        let finished = &finished;
        let taken = s.spawn(move || {
            let a = dead.assignments.recv_timeout(Duration::from_secs(30)).unwrap().expect("an episode for the dead actor");
            // Hold the channels and say nothing until the run is over.
            while !finished.load(std::sync::atomic::Ordering::Relaxed) {
                std::thread::sleep(Duration::from_millis(20));
            }
            drop(dead);
            a.id
        });
        let (c, spec, shutdown) = (&c, &spec, &shutdown);
        std::thread::sleep(Duration::from_millis(50));
        s.spawn(move || roles::actor(c, spec, 1, &mut live, shutdown).unwrap());
        s.spawn(move || roles::optimizer(c, spec, &mut optimizer, shutdown, None).unwrap());
        let outcome = roles::learner(c, spec, &dir, &mut learner, shutdown, false).unwrap();
        drop(learner);
        finished.store(true, std::sync::atomic::Ordering::Relaxed);
        assert_eq!(taken.join().unwrap(), 1, "the silent actor took the first episode");
        outcome
    });
    assert!(!outcome.interrupted);
    assert_eq!(outcome.time.reissued, 1);
    assert_eq!(outcome.designs.iter().map(|d| d.episodes).sum::<usize>(), 6);
}

#[test]
fn async_flow_keeps_episodes_in_flight_and_reports_policy_lag() {
    let dir = tmpdir("async");
    let mut c = tiny();
    c.fleet.transport = TransportKind::InProcess;
    c.actors = 3;
    c.flow.mode = FlowMode::Async;
    let spec = coadapt_robots::make(&c.env).unwrap().spec().clone();
    resolve_initial_designs(&mut c, &spec);
    let o = coadapt_coadaptation::run::run_config(&c, &dir.join("run"), &AtomicBool::new(false), false).unwrap();
    assert!(!o.interrupted);
    assert_eq!(o.designs.iter().map(|d| d.episodes).sum::<usize>(), 10);
    assert!(o.time.max_policy_lag >= 1, "with three episodes in flight some act with older weights: {:?}", o.time);
    let csv = std::fs::read_to_string(dir.join("run/episodes.csv")).unwrap();
    let actors: std::collections::BTreeSet<&str> = csv.lines().skip(1).filter_map(|l| l.split(',').nth(8)).collect();
    assert!(actors.len() >= 2, "episodes spread over the actors: {actors:?}");
}

#[test]
fn ctrl_c_stops_the_whole_fleet_and_keeps_the_run() {
    let dir = tmpdir("sigint");
    let mut c = tiny();
    c.actors = 2;
    c.schedule.initial_episodes = 200;
    let (child, out, stderr_path) = start_run(&dir, &c, 2);
    let procs = children(child.id());
    assert_eq!(procs.len(), 4, "{procs:?}");
    assert!(Command::new("kill").args(["-INT", &child.id().to_string()]).status().unwrap().success());
    let o = child.wait_with_output().unwrap();
    let stderr = std::fs::read_to_string(&stderr_path).unwrap();
    assert!(o.status.success(), "{stderr}");
    let s = summary(&o.stdout);
    assert_eq!(s["interrupted"], true, "{s}");
    let done = rows(&out.join("episodes.csv"));
    assert!((2..400).contains(&done), "the rows written before Ctrl-C are kept: {done}");
    assert_eq!(rows(&out.join("designs.csv")), 1, "the interrupted design's row is written");
    for (pid, cmd) in &procs {
        assert!(!Path::new(&format!("/proc/{pid}")).exists(), "{cmd} still runs after coadapt run ended");
    }
    for log in ["actor-0.log", "actor-1.log", "optimizer.log"] {
        let text = std::fs::read_to_string(out.join("logs").join(log)).unwrap();
        assert!(!text.contains("error"), "{log} ends cleanly: {text}");
    }
    let resolved: RunConfig = toml::from_str(&std::fs::read_to_string(out.join("config.toml")).unwrap()).unwrap();
    assert!(coadapt_shm::fleet_services(&resolved.fleet.name).unwrap().is_empty());
}

/// `coadapt learner`, `coadapt optimizer` and `coadapt actor` started by hand over gRPC; the
/// learner is killed mid-run and a new one takes its port: the same actor and optimiser
/// processes reconnect and serve it to the end.
#[test]
fn grpc_actors_reconnect_to_a_learner_that_comes_back() {
    let dir = tmpdir("reconnect");
    let mut c = tiny();
    c.schedule.initial_episodes = 6;
    c.fleet.transport = TransportKind::Grpc;
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    c.fleet.listen = format!("127.0.0.1:{port}");
    c.fleet.connect = format!("http://127.0.0.1:{port}");
    let config = write_config(&dir, &c);
    let cfg = config.to_str().unwrap();
    let bin = env!("CARGO_BIN_EXE_coadapt");
    let log = |name: &str| std::fs::File::create(dir.join(name)).unwrap();
    let learner = |out: &str, logname: &str| {
        Command::new(bin)
            .args(["learner", "--config", cfg, "--out", dir.join(out).to_str().unwrap()])
            .stdout(Stdio::piped())
            .stderr(log(logname))
            .spawn()
            .unwrap()
    };
    let mut first = learner("first", "learner-1.log");
    let mut actor = Command::new(bin).args(["actor", "--config", cfg, "--id", "42"]).stderr(log("actor.log")).spawn().unwrap();
    let mut opt = Command::new(bin).args(["optimizer", "--config", cfg]).stderr(log("optimizer.log")).spawn().unwrap();
    let t = Instant::now();
    while rows(&dir.join("first/episodes.csv")) < 2 {
        assert!(t.elapsed() < Duration::from_secs(60), "{}", std::fs::read_to_string(dir.join("learner-1.log")).unwrap());
        std::thread::sleep(Duration::from_millis(20));
    }
    first.kill().unwrap();
    first.wait().unwrap();
    std::thread::sleep(Duration::from_millis(500));
    assert!(actor.try_wait().unwrap().is_none(), "the actor waits for the learner to come back");
    let second = learner("second", "learner-2.log");
    let o = second.wait_with_output().unwrap();
    assert!(o.status.success(), "{}", std::fs::read_to_string(dir.join("learner-2.log")).unwrap());
    assert_eq!(summary(&o.stdout)["designs"], 4);
    let csv = std::fs::read_to_string(dir.join("second/episodes.csv")).unwrap();
    assert_eq!(csv.lines().skip(1).filter(|l| l.split(',').nth(8) == Some("42")).count(), 16, "actor 42 ran every episode:\n{csv}");
    // The learner finished: actor and optimiser end on their own, successfully.
    for (name, p) in [("actor", &mut actor), ("optimizer", &mut opt)] {
        let t = Instant::now();
        let status = loop {
            if let Some(s) = p.try_wait().unwrap() {
                break s;
            }
            assert!(t.elapsed() < Duration::from_secs(30), "{name} did not end after the learner finished");
            std::thread::sleep(Duration::from_millis(50));
        };
        assert!(status.success(), "{name}: {}", std::fs::read_to_string(dir.join(format!("{name}.log"))).unwrap());
    }
}
