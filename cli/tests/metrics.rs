//! `/metrics` of the learner and the optimiser, scraped during a run through the binary.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::io::{Read, Write};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use coadapt_coadaptation::RunConfig;

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

fn get(port: u16, path: &str) -> Option<String> {
    let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(5))).ok()?;
    write!(s, "GET {path} HTTP/1.1\r\nHost: x\r\n\r\n").ok()?;
    let mut out = String::new();
    s.read_to_string(&mut out).ok()?;
    Some(out)
}

/// The value of the sample `name` (with its labels) in a Prometheus text body.
fn value(body: &str, name: &str) -> Option<f64> {
    body.lines().find_map(|l| l.strip_prefix(name).and_then(|r| r.strip_prefix(' ')).and_then(|v| v.trim().parse().ok()))
}

#[test]
fn learner_and_optimizer_metrics_are_scraped_during_a_run() {
    let dir = std::env::temp_dir().join(format!("coadapt-metrics-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let mut c: RunConfig = coadapt_test_support::read_config("configs/half-cheetah-tiny.toml");
    c.landscape_grid = 0;
    c.schedule.designs = 6;
    let (lp, op) = (free_port(), free_port());
    c.metrics.learner_listen = format!("127.0.0.1:{lp}");
    c.metrics.optimizer_listen = format!("127.0.0.1:{op}");
    let config = dir.join("c.toml");
    std::fs::write(&config, toml::to_string(&c).unwrap()).unwrap();
    let out = dir.join("run");
    let child = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["run", "--config", config.to_str().unwrap(), "--out", out.to_str().unwrap()])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Scrape the learner until the fifth design has begun, then the optimiser.
    let t = Instant::now();
    let learner = loop {
        assert!(t.elapsed() < Duration::from_secs(120), "no learner metrics");
        if let Some(body) = get(lp, "/metrics")
            && value(&body, "coadapt_learner_design_index").is_some_and(|d| d >= 4.0)
        {
            break body;
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let optimizer = get(op, "/metrics").expect("optimizer metrics");
    let missing = get(lp, "/nothing").unwrap();
    let health = get(lp, "/healthz").unwrap();
    assert!(health.starts_with("HTTP/1.1 200 OK") && health.ends_with("SERVING\n"), "{health}");
    let o = child.wait_with_output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(learner.starts_with("HTTP/1.1 200 OK") && learner.contains("text/plain; version=0.0.4"), "{learner}");
    assert!(missing.starts_with("HTTP/1.1 404"), "{missing}");
    let v = |name: &str| value(&learner, name).unwrap_or_else(|| panic!("{name} missing:\n{learner}"));
    // Design 4 (0-based) has begun: 2 x 3 + 2 x 2 episodes are done at least.
    assert!(v("coadapt_learner_episodes_total") >= 10.0);
    assert_eq!(v("coadapt_learner_transitions_total"), v("coadapt_learner_episodes_total") * 1000.0);
    assert_eq!(v("coadapt_learner_replay_transitions{buffer=\"population\"}"), v("coadapt_learner_transitions_total"));
    assert!(v("coadapt_learner_updates_total{pair=\"individual\"}") > 0.0);
    assert!(v("coadapt_learner_snapshots_total") >= 4.0);
    assert!(v("coadapt_learner_snapshot_age_seconds") >= 0.0);
    assert!(v("coadapt_learner_design_request_seconds") > 0.0);
    assert_eq!(v("coadapt_learner_episodes_refused_total{reason=\"magnitude\"}"), 0.0);
    assert!(v("coadapt_learner_disk_free_bytes") > 0.0 && v("coadapt_learner_disk_needed_bytes") >= 16.0 * 1024.0 * 1024.0);
    assert_eq!(v("coadapt_learner_disk_low"), 0.0);
    assert!(learner.contains("# TYPE coadapt_learner_updates_total counter"), "{learner}");
    // Two designs chosen by the optimiser so far (index 2 and 3), each by a search.
    let searches = value(&optimizer, "coadapt_optimizer_searches_total").unwrap();
    assert!(searches >= 2.0, "{optimizer}");
    assert!(value(&optimizer, "coadapt_optimizer_search_seconds_total").unwrap() > 0.0, "{optimizer}");
}

#[test]
fn the_grafana_dashboard_charts_only_metrics_that_exist() {
    use coadapt_coadaptation::metrics::{Source, render};
    let disk =
        std::sync::Arc::new(coadapt_learner::disk::DiskWatch::new(&std::env::temp_dir(), &std::env::temp_dir().join("no-snapshots-here")));
    let text = render(&Source::Learner(Default::default(), Some(disk))) + &render(&Source::Optimizer(Default::default()));
    let dash = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/grafana/coadapt.json")).unwrap();
    let dash: serde_json::Value = serde_json::from_str(&dash).unwrap();
    let mut names = Vec::new();
    for p in dash["panels"].as_array().unwrap() {
        for t in p["targets"].as_array().unwrap() {
            let e = t["expr"].as_str().unwrap();
            for (i, _) in e.match_indices("coadapt_") {
                let name: String = e[i..].chars().take_while(|c| c.is_ascii_alphanumeric() || *c == '_').collect();
                names.push(name);
            }
        }
    }
    assert!(names.len() >= 12, "{names:?}");
    for n in names {
        assert!(text.contains(&format!("# TYPE {n} ")), "the dashboard charts {n}, which no /metrics has");
    }
}

/// Issue 29 (2): refused calls leave a trace. A learner with role tokens is called 30 times
/// without a token and 3 times with a client's token (not a fleet role): `/metrics` counts
/// them by server, reason and peer, the first refusal from the peer is logged once with its
/// reason, and no token appears in the log.
#[test]
fn refused_calls_are_counted_by_reason_and_peer_and_the_first_is_logged() {
    use coadapt_wire::pb;
    let dir = std::env::temp_dir().join(format!("coadapt-refusals-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let tokens = dir.join("tokens");
    let client_token = dir.join("client.token");
    for (role, out) in [("actor", dir.join("actor.token")), ("client", client_token.clone())] {
        let o = Command::new(env!("CARGO_BIN_EXE_coadapt"))
            .args(["token", "new", "--role", role, "--out", out.to_str().unwrap(), "--tokens-file", tokens.to_str().unwrap()])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let secret = std::fs::read_to_string(&client_token).unwrap().trim().to_string();
    let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/half-cheetah-tiny.toml");
    let (fp, mp) = (free_port(), free_port());
    let log = dir.join("learner.log");
    let mut child = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["learner", "--config", config.to_str().unwrap(), "--transport", "grpc"])
        .args(["--listen", &format!("127.0.0.1:{fp}"), "--metrics", &format!("127.0.0.1:{mp}")])
        .args(["--tokens-file", tokens.to_str().unwrap(), "--out", dir.join("run").to_str().unwrap()])
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&log).unwrap())
        .spawn()
        .unwrap();
    let t = Instant::now();
    while get(mp, "/metrics").is_none() {
        assert!(t.elapsed() < Duration::from_secs(60), "the learner never served /metrics: {}", std::fs::read_to_string(&log).unwrap());
        std::thread::sleep(Duration::from_millis(50));
    }
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
    let codes: Vec<tonic::Code> = rt.block_on(async {
        let mut fleet = loop {
            match pb::fleet_client::FleetClient::connect(format!("http://127.0.0.1:{fp}")).await {
                Ok(c) => break c,
                Err(_) if t.elapsed() < Duration::from_secs(60) => tokio::time::sleep(Duration::from_millis(50)).await,
                Err(e) => panic!("the fleet endpoint: {e}"),
            }
        };
        let mut codes = Vec::new();
        for i in 0..33 {
            let mut req = tonic::Request::new(pb::Beat::default());
            if i >= 30 {
                req.metadata_mut().insert("authorization", format!("Bearer {secret}").parse().unwrap());
            }
            codes.push(fleet.heartbeat(req).await.unwrap_err().code());
        }
        codes
    });
    let body = get(mp, "/metrics").unwrap();
    let _ = child.kill();
    let _ = child.wait();
    let text = std::fs::read_to_string(&log).unwrap();
    assert!(codes[..30].iter().all(|c| *c == tonic::Code::Unauthenticated), "{codes:?}");
    assert!(codes[30..].iter().all(|c| *c == tonic::Code::PermissionDenied), "{codes:?}");
    let v = |reason: &str| value(&body, &format!("coadapt_refusals_total{{server=\"fleet\",reason=\"{reason}\",peer=\"127.0.0.1\"}}"));
    assert_eq!(v("unauthenticated"), Some(30.0), "{body}");
    assert_eq!(v("permission_denied"), Some(3.0), "{body}");
    let firsts: Vec<&str> = text.lines().filter(|l| l.contains("refused a call from 127.0.0.1")).collect();
    assert_eq!(firsts.len(), 1, "one line for the peer's first refusal:\n{text}");
    assert!(firsts[0].contains("unauthenticated") && firsts[0].contains("authorization: missing"), "{}", firsts[0]);
    assert!(!text.contains(&secret), "the token was logged:\n{text}");
}
