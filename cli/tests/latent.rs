//! `coadapt latent` through the binary: the embedding built once and reused, the run directory,
//! the checkpoint's networks per critic and objective, and refusals named.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::process::Command;

fn coadapt(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_coadapt")).args(args).output().unwrap()
}

const TINY: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/latent/pendulum-tiny.toml");

fn rows(csv: &str) -> Vec<Vec<f64>> {
    csv.lines().skip(1).map(|l| l.split(',').map(|v| v.parse().unwrap()).collect()).collect()
}

#[test]
fn a_latent_run_builds_the_embedding_once_and_writes_its_run_directory() {
    let dir = std::env::temp_dir().join(format!("coadapt-latent-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let emb = dir.join("emb.safetensors");
    let (emb_s, out) = (emb.to_str().unwrap(), dir.join("plan"));
    let o = coadapt(&["latent", "--config", TINY, "--embedding", emb_s, "--out", out.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("building it") && emb.exists() && dir.join("emb.csv").exists(), "{err}");
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(summary["method"], "plan-h3-q");
    assert!(summary["plan_ms_mean"].as_f64().unwrap() > 0.0, "{summary}");
    let csv = std::fs::read_to_string(out.join("episodes.csv")).unwrap();
    assert!(csv.starts_with("run,episode,train_return,eval_return,train_steps,eval_steps,model_loss,plan_ms_mean"), "{csv}");
    let r = rows(&csv);
    assert_eq!(r.len(), 6, "2 runs x 3 episodes: {csv}");
    for row in &r {
        assert!(row.iter().all(|v| v.is_finite()), "{row:?}");
        assert_eq!((row[4], row[5]), (30.0, 30.0), "30 steps each: {row:?}");
        assert!(row[7] > 0.0, "a training episode that planned reports its latency: {row:?}");
    }
    // The same seeds give the same first episode; another run's differ.
    assert_ne!(r[0][2], r[3][2], "runs 0 and 1 share their seed");
    for f in ["config.toml", "run-0/agent.safetensors", "run-1/agent.safetensors", "plots/returns.svg"] {
        assert!(out.join(f).exists(), "{f} missing");
    }
    let names = |p: &std::path::Path| {
        let mut v: Vec<String> = coadapt_nn::load_networks(p).unwrap().into_iter().map(|n| n.name).collect();
        v.sort();
        v
    };
    assert_eq!(names(&out.join("run-0/agent.safetensors")), ["actor", "critic", "model"]);
    let svg = std::fs::read_to_string(out.join("plots/returns.svg")).unwrap();
    assert!(svg.contains("training (exploring)") && svg.contains("evaluation (deterministic actor)"));
    // The resolved config is a config: it runs again as it is (here: refused, the directory is
    // taken), and the embedding is loaded, not rebuilt, by the next method.
    let o = coadapt(&["latent", "--config", out.join("config.toml").to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("already holds a run"), "{}", String::from_utf8_lossy(&o.stderr));
    let out_v = dir.join("v-rq");
    let o = coadapt(&[
        "latent",
        "--config",
        TINY,
        "--embedding",
        emb_s,
        "--critic",
        "v",
        "--objective",
        "reward-plus-q",
        "--runs",
        "1",
        "--out",
        out_v.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("embedding: loaded") && !err.contains("building it"), "{err}");
    assert_eq!(names(&out_v.join("run-0/agent.safetensors")), ["actor", "model", "reward", "value"]);
    let out_ou = dir.join("ou");
    let o =
        coadapt(&["latent", "--config", TINY, "--embedding", emb_s, "--explore", "ou", "--runs", "1", "--out", out_ou.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(summary["method"], "ou-q");
    assert!(rows(&std::fs::read_to_string(out_ou.join("episodes.csv")).unwrap()).iter().all(|r| r[7] == 0.0), "OU never plans");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn bad_latent_settings_are_refused_naming_the_key() {
    let dir = std::env::temp_dir().join(format!("coadapt-latent-bad-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cases: [(&[&str], &str); 5] = [
        (&["--explore", "noise"], "explore = \"noise\""),
        (&["--objective", "sum"], "objective = \"sum\""),
        (&["--horizon", "0"], "agent.horizon = 0"),
        (&["--runs", "0"], "runs = 0"),
        (&["--embedding", TINY], "not a coadapt embedding"),
    ];
    for (extra, want) in cases {
        let mut args = vec!["latent", "--config", TINY, "--out", dir.to_str().unwrap()];
        args.extend_from_slice(extra);
        let o = coadapt(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains(want), "{extra:?}: wanted {want:?} in {err}");
    }
    // An unknown key and a camera/embedding mismatch in a file.
    let bad = dir.join("bad.toml");
    std::fs::write(&bad, "robot = \"pendulum\"\n[agent]\nhorizn = 3\n").unwrap();
    let o = coadapt(&["latent", "--config", bad.to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("horizn"), "{}", String::from_utf8_lossy(&o.stderr));
    std::fs::write(&bad, "[camera]\nside = 32\n").unwrap();
    let o = coadapt(&["latent", "--config", bad.to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("embedding.shape"), "{}", String::from_utf8_lossy(&o.stderr));
    std::fs::remove_dir_all(&dir).ok();
}

/// `coadapt env-serve --pixels SIDE` in the background; its URL.
struct Server(std::process::Child, String);

impl Server {
    fn start(side: &str) -> Self {
        use std::io::BufRead;
        let mut child = Command::new(env!("CARGO_BIN_EXE_coadapt"))
            .args(["env-serve", "--env", "pendulum", "--pixels", side])
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        let mut line = String::new();
        std::io::BufReader::new(child.stdout.take().unwrap()).read_line(&mut line).unwrap();
        assert!(line.starts_with("dm-env-rpc://"), "{line}");
        Server(child, line.trim().to_string())
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[test]
fn a_served_camera_robot_learns_over_dm_env_rpc_and_a_wrong_frame_size_is_refused() {
    let dir = std::env::temp_dir().join(format!("coadapt-latent-served-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let server = Server::start("16");
    let cfg = dir.join("served.toml");
    let text = std::fs::read_to_string(TINY).unwrap().replace("robot = \"pendulum\"", &format!("robot = \"{}\"", server.1));
    std::fs::write(&cfg, text).unwrap();
    let out = dir.join("run");
    let emb = dir.join("emb.safetensors");
    let o = coadapt(&[
        "latent",
        "--config",
        cfg.to_str().unwrap(),
        "--embedding",
        emb.to_str().unwrap(),
        "--runs",
        "1",
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    // No state over the wire: the embedding's episodes follow OU noise alone, and say so.
    assert!(err.contains("shows no state"), "{err}");
    let r = rows(&std::fs::read_to_string(out.join("episodes.csv")).unwrap());
    assert_eq!(r.len(), 3);
    assert!(r.iter().all(|row| row[4] == 30.0 && row[2].is_finite() && row[3].is_finite()), "{r:?}");
    // A frame of the wrong size is refused before anything runs.
    let small = Server::start("8");
    let text = std::fs::read_to_string(TINY).unwrap().replace("robot = \"pendulum\"", &format!("robot = \"{}\"", small.1));
    std::fs::write(&cfg, text).unwrap();
    let o = coadapt(&[
        "latent",
        "--config",
        cfg.to_str().unwrap(),
        "--embedding",
        dir.join("other.safetensors").to_str().unwrap(),
        "--out",
        dir.join("x").to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("camera.side = 16 needs one RGB frame of 768"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn the_sparse_reach_stand_in_starts_from_demonstrations() {
    let dir = std::env::temp_dir().join(format!("coadapt-latent-reach-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let cfg = dir.join("reach.toml");
    let text = std::fs::read_to_string(TINY)
        .unwrap()
        .replace("robot = \"pendulum\"", "robot = \"reach\"\ndemonstrations = 3")
        .replace("episode-steps = 30", "episode-steps = 20");
    std::fs::write(&cfg, text).unwrap();
    let out = dir.join("run");
    let o = coadapt(&[
        "latent",
        "--config",
        cfg.to_str().unwrap(),
        "--embedding",
        dir.join("e.safetensors").to_str().unwrap(),
        "--runs",
        "1",
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("3 demonstrations in the replay (3 successful)"), "{err}");
    // Sparse returns: +1 (reached), -1 (left the workspace) or 0, within 20 steps.
    for row in rows(&std::fs::read_to_string(out.join("episodes.csv")).unwrap()) {
        assert!([-1.0, 0.0, 1.0].contains(&row[2]) && [-1.0, 0.0, 1.0].contains(&row[3]), "{row:?}");
        assert!(row[4] <= 20.0 && row[5] <= 20.0, "{row:?}");
    }
    // Only the reach robot has a demonstrator.
    let text = std::fs::read_to_string(TINY).unwrap().replace("robot = \"pendulum\"", "robot = \"pendulum\"\ndemonstrations = 3");
    std::fs::write(&cfg, text).unwrap();
    let o = coadapt(&["latent", "--config", cfg.to_str().unwrap(), "--out", dir.join("x").to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("demonstrations = 3: only robot = \"reach\""), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}

/// A run stopped part-way (here: its episodes.csv cut in the middle of the second run, the
/// last row half written) goes on with --resume: the finished run is kept, the unfinished one
/// runs again, and the rows equal an uninterrupted run's. A resume with another config is
/// refused naming the key.
#[test]
fn a_stopped_latent_run_resumes_from_its_first_unfinished_run() {
    let dir = std::env::temp_dir().join(format!("coadapt-latent-resume-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let emb = dir.join("emb.safetensors");
    let emb_s = emb.to_str().unwrap();
    let whole = dir.join("whole");
    let o = coadapt(&["latent", "--config", TINY, "--embedding", emb_s, "--out", whole.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let results = |out: &std::path::Path| -> Vec<String> {
        let csv = std::fs::read_to_string(out.join("episodes.csv")).unwrap();
        csv.lines().skip(1).map(|l| l.split(',').take(7).collect::<Vec<_>>().join(",")).collect()
    };
    let want = results(&whole);
    assert_eq!(want.len(), 6);
    // The "crash": run 0 whole, one episode of run 1, half a row.
    let cut = dir.join("cut");
    std::fs::create_dir_all(&cut).unwrap();
    std::fs::copy(whole.join("config.toml"), cut.join("config.toml")).unwrap();
    let csv = std::fs::read_to_string(whole.join("episodes.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    let partial = format!("{}\n{}", lines[..5].join("\n"), &lines[5][..10]);
    std::fs::write(cut.join("episodes.csv"), partial).unwrap();
    let o = coadapt(&["latent", "--config", TINY, "--embedding", emb_s, "--horizon", "4", "--out", cut.to_str().unwrap(), "--resume"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("config differs") && err.contains("agent.horizon"), "{err}");
    let o = coadapt(&["latent", "--config", TINY, "--embedding", emb_s, "--out", cut.to_str().unwrap(), "--resume"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("after its 1 finished run(s)") && err.contains("not a whole row"), "{err}");
    assert!(!err.contains("run 1/2 episode 1/3"), "run 0 ran again: {err}");
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(summary["resumed_after_runs"], 1);
    assert!(summary["plan_ms_mean"].as_f64().unwrap() > 0.0);
    assert_eq!(results(&cut), want);
    assert!(cut.join("run-1/agent.safetensors").exists() && cut.join("plots/returns.svg").exists());
}
