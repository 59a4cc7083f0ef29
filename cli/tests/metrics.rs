//! `/metrics` of the learner and the optimiser, scraped during a run through the binary.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::io::{Read, Write};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use coadapt_cli::run::RunConfig;

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
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/half-cheetah-tiny.toml");
    let mut c: RunConfig = toml::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
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
    assert!(learner.contains("# TYPE coadapt_learner_updates_total counter"), "{learner}");
    // Two designs chosen by the optimiser so far (index 2 and 3), each by a search.
    let searches = value(&optimizer, "coadapt_optimizer_searches_total").unwrap();
    assert!(searches >= 2.0, "{optimizer}");
    assert!(value(&optimizer, "coadapt_optimizer_search_seconds_total").unwrap() > 0.0, "{optimizer}");
}

#[test]
fn the_grafana_dashboard_charts_only_metrics_that_exist() {
    use coadapt_cli::metrics::{Source, render};
    let text = render(&Source::Learner(Default::default())) + &render(&Source::Optimizer(Default::default()));
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
