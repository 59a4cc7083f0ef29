//! `coadapt latent` with its episodes on actors that plan where the robot is: actor threads,
//! `coadapt latent-actor` processes over shared memory and over gRPC all give the in-process
//! run's episodes exactly (the same returns, model losses and trained networks), and each actor
//! records its planning latency per episode.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::process::Command;

fn coadapt(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_coadapt")).args(args).output().unwrap()
}

const TINY: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/latent/pendulum-tiny.toml");

/// episodes.csv without its latency and time columns (measured, not computed).
fn results(out: &std::path::Path) -> Vec<String> {
    let csv = std::fs::read_to_string(out.join("episodes.csv")).unwrap();
    csv.lines().skip(1).map(|l| l.split(',').take(7).collect::<Vec<_>>().join(",")).collect()
}

#[test]
fn a_latent_run_on_actors_equals_the_run_in_process() {
    let dir = std::env::temp_dir().join(format!("coadapt-latent-fleet-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let emb = dir.join("emb.safetensors");
    let emb_s = emb.to_str().unwrap();
    let local = dir.join("local");
    let o = coadapt(&["latent", "--config", TINY, "--embedding", emb_s, "--out", local.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let want = results(&local);
    assert_eq!(want.len(), 6, "2 runs x 3 episodes");
    for transport in ["in-process", "shm", "grpc"] {
        let out = dir.join(transport);
        let o = coadapt(&[
            "latent",
            "--config",
            TINY,
            "--embedding",
            emb_s,
            "--actors",
            "2",
            "--transport",
            transport,
            "--out",
            out.to_str().unwrap(),
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{transport}: {err}");
        assert_eq!(results(&out), want, "{transport}");
        let summary: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert!(summary["plan_ms_mean"].as_f64().unwrap() > 0.0, "{transport}: {summary}");
        // The checkpoints hold the same networks.
        for r in 0..2 {
            let f = format!("run-{r}/agent.safetensors");
            let params = |p: &std::path::Path| -> Vec<(String, Vec<f32>)> {
                coadapt_nn::load_networks(p).unwrap().into_iter().map(|n| (n.name, n.params)).collect()
            };
            assert!(params(&out.join(&f)) == params(&local.join(&f)), "{transport}: {f} differs");
        }
        // The actors ran every episode once (2 runs x 3 episodes x training and evaluation)
        // and timed the planning of every training step.
        let mut rows = Vec::new();
        for i in 0..2 {
            if let Ok(csv) = std::fs::read_to_string(out.join(format!("actors/actor-{i}.csv"))) {
                assert!(csv.starts_with("assignment,train,steps,return,plan_ms_mean,plan_ms_p90,seconds"), "{csv}");
                rows.extend(csv.lines().skip(1).map(str::to_string));
            }
        }
        assert_eq!(rows.len(), 12, "{transport}: {rows:?}");
        let mut assignments: Vec<u64> = rows.iter().map(|r| r.split(',').next().unwrap().parse().unwrap()).collect();
        assignments.sort_unstable();
        assignments.dedup();
        assert_eq!(assignments.len(), 12, "{transport}: an episode ran twice");
        for r in &rows {
            let v: Vec<&str> = r.split(',').collect();
            assert_eq!(v[2], "30", "{transport}: {r}");
            let ms: f64 = v[4].parse().unwrap();
            if v[1] == "true" { assert!(ms > 0.0, "{transport}: {r}") } else { assert_eq!(ms, 0.0, "{transport}: {r}") }
        }
    }
}

/// An actor pointed at a config whose networks differ from the learner's refuses the weights
/// naming the sizes (and ends), and the learner, waiting for actors started by hand, stops at
/// its episode deadline with an error instead of waiting for ever.
#[test]
fn an_actor_with_another_config_refuses_the_weights_and_the_run_stops() {
    let dir = std::env::temp_dir().join(format!("coadapt-latent-fleet-bad-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let emb = dir.join("emb.safetensors");
    let emb_s = emb.to_str().unwrap();
    let o = coadapt(&["latent", "--config", TINY, "--embedding", emb_s, "--embed-only"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let name = format!("coadapt-latent-bad-{}", std::process::id());
    let tiny = std::fs::read_to_string(TINY).unwrap();
    let fleet =
        format!("actors = 1\nstart-actors = false\nepisode-deadline-secs = 10\n{tiny}\n[fleet]\ntransport = \"shm\"\nname = \"{name}\"\n");
    let (right, wrong) = (dir.join("right.toml"), dir.join("wrong.toml"));
    std::fs::write(&right, &fleet).unwrap();
    // The actor's config has a wider actor network.
    std::fs::write(&wrong, fleet.replace("[agent.ddpg]\nhidden = [32, 32]", "[agent.ddpg]\nhidden = [32, 33]")).unwrap();
    let out = dir.join("run");
    let learner = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["latent", "--config", right.to_str().unwrap(), "--embedding", emb_s, "--out", out.to_str().unwrap()])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(500));
    let a = coadapt(&["latent-actor", "--config", wrong.to_str().unwrap(), "--id", "0"]);
    let actor_err = String::from_utf8_lossy(&a.stderr);
    assert!(!a.status.success(), "{actor_err}");
    assert!(actor_err.contains("acting weights") && actor_err.contains("same config?"), "{actor_err}");
    let o = learner.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(err.contains("not back after") && err.contains("are the actors running?"), "{err}");
}
