//! What every resume test uses: the protocol, the reference run, processes and kill points.

pub use std::path::{Path, PathBuf};
pub use std::process::{Child, Command, Stdio};
pub use std::time::{Duration, Instant};

pub use coadapt_coadaptation::RunConfig;

pub fn tmpdir(name: &str) -> PathBuf {
    coadapt_test_support::scratch_dir("resume", name)
}

/// The tiny protocol, 6 designs, a snapshot every 2 episodes, short deadlines, and a PSO big
/// enough (seconds) that a kill lands while the learner waits for a design.
pub fn config() -> RunConfig {
    let mut c: RunConfig = coadapt_test_support::read_config("configs/half-cheetah-tiny.toml");
    c.landscape_grid = 0;
    c.schedule.designs = 6;
    c.schedule.design_request_resend_secs = 1.5;
    c.snapshot.every_episodes = 2;
    // Every 2 episodes, however short they are (no bound on the snapshots' share of the time).
    c.snapshot.max_share = 1.0;
    c.flow.assignment_lease_secs = 2.0;
    c.optimizer.pso.particles = 20_000;
    c.optimizer.pso.iterations = 40;
    c
}

pub fn write_config(dir: &Path, c: &RunConfig) -> PathBuf {
    let p = dir.join("config-in.toml");
    std::fs::write(&p, toml::to_string(c).unwrap()).unwrap();
    p
}

pub fn rows(path: &Path) -> usize {
    std::fs::read_to_string(path).map_or(0, |t| t.lines().count().saturating_sub(1))
}

/// `designs.csv`, and `episodes.csv` without its wall-clock column (`seconds`).
pub fn tables(out: &Path) -> (String, String) {
    let designs = std::fs::read_to_string(out.join("designs.csv")).unwrap();
    let episodes = std::fs::read_to_string(out.join("episodes.csv")).unwrap();
    let episodes = episodes
        .lines()
        .map(|l| l.split(',').enumerate().filter(|(i, _)| *i != 7).map(|(_, f)| f).collect::<Vec<_>>().join(","))
        .collect::<Vec<_>>()
        .join("\n");
    (designs, episodes)
}

pub fn coadapt(args: &[&str], stderr: &Path) -> Child {
    Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(std::fs::File::create(stderr).unwrap())
        .spawn()
        .unwrap()
}

/// The uninterrupted run of `c` in process (the same rows as a fleet: tested in fleet.rs).
pub fn reference(dir: &Path, c: &RunConfig) -> (String, String) {
    let config = write_config(dir, c);
    let out = dir.join("reference");
    let o = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["run", "--config", config.to_str().unwrap(), "--out", out.to_str().unwrap(), "--transport", "in-process"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    tables(&out)
}

/// Child processes of `pid` whose command line holds ` role `.
pub fn role_pids(pid: u32, role: &str) -> Vec<u32> {
    let mut out = Vec::new();
    for e in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(p) = e.file_name().to_string_lossy().parse::<u32>() else { continue };
        let Ok(stat) = std::fs::read_to_string(format!("/proc/{p}/stat")) else { continue };
        let Some(rest) = stat.rsplit_once(')').map(|(_, r)| r.to_string()) else { continue };
        let ppid: u32 = rest.split_whitespace().nth(1).and_then(|s| s.parse().ok()).unwrap_or(0);
        let cmd = String::from_utf8_lossy(&std::fs::read(format!("/proc/{p}/cmdline")).unwrap_or_default()).replace('\0', " ");
        if ppid == pid && cmd.contains(&format!(" {role} ")) {
            out.push(p);
        }
    }
    out
}

pub fn kill9(pid: u32) {
    assert!(Command::new("kill").args(["-KILL", &pid.to_string()]).status().unwrap().success());
}

pub fn wait_until(what: &str, stderr: &Path, mut done: impl FnMut() -> bool) {
    let t = Instant::now();
    while !done() {
        assert!(t.elapsed() < Duration::from_secs(180), "waiting for {what}: {}", std::fs::read_to_string(stderr).unwrap_or_default());
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// A small generator for the kill points, seeded by the clock and printed, so a failure can be
/// replayed with COADAPT_KILL_SEED.
pub fn kill_seed() -> u64 {
    let seed = std::env::var("COADAPT_KILL_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap().as_nanos() as u64);
    eprintln!("kill points from COADAPT_KILL_SEED={seed}");
    seed
}

pub fn draw(state: &mut u64, n: usize) -> usize {
    *state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    ((*state >> 33) % n as u64) as usize
}
