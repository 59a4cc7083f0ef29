//! A learner that cannot make progress (no actor) turns its gRPC health NOT_SERVING after
//! `fleet.health-stall-secs`, so that a probe restarts it, and SERVING again once episodes come
//! back. Through the binary: `coadapt learner`, then `coadapt actor` and `coadapt optimizer`.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use coadapt_coadaptation::RunConfig;

fn wait_for(path: &Path, text: &str) {
    let t = Instant::now();
    loop {
        let log = std::fs::read_to_string(path).unwrap_or_default();
        if log.contains(text) {
            return;
        }
        assert!(t.elapsed() < Duration::from_secs(60), "waiting for {text:?}:\n{log}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn a_stalled_learner_goes_not_serving_and_recovers() {
    let dir = std::env::temp_dir().join(format!("coadapt-health-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let mut c: RunConfig = coadapt_test_support::read_config("configs/half-cheetah-tiny.toml");
    c.landscape_grid = 0;
    c.fleet.health_stall_secs = 1.0;
    c.fleet.name = "health-test".into();
    let config = dir.join("c.toml");
    std::fs::write(&config, toml::to_string(&c).unwrap()).unwrap();
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let cfg = config.to_str().unwrap();
    let log = dir.join("learner.txt");
    let listen = format!("127.0.0.1:{port}");
    let out = dir.join("run");
    let learner = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["learner", "--config", cfg, "--transport", "grpc", "--listen", &listen, "--out", out.to_str().unwrap()])
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&log).unwrap())
        .spawn()
        .unwrap();
    wait_for(&log, "health NOT_SERVING");
    let connect = format!("http://127.0.0.1:{port}");
    let mut others: Vec<_> = [vec!["actor", "--id", "0"], vec!["optimizer"]]
        .into_iter()
        .map(|mut a| {
            a.extend(["--config", cfg, "--transport", "grpc", "--connect", &connect]);
            Command::new(env!("CARGO_BIN_EXE_coadapt")).args(&a).stdout(Stdio::null()).stderr(Stdio::null()).spawn().unwrap()
        })
        .collect();
    wait_for(&log, "health SERVING");
    let o = learner.wait_with_output().unwrap();
    for p in &mut others {
        let _ = p.wait();
    }
    let text = std::fs::read_to_string(&log).unwrap();
    assert!(o.status.success(), "{text}");
    assert_eq!(std::fs::read_to_string(out.join("designs.csv")).unwrap().lines().count(), 1 + 4, "{text}");
}
