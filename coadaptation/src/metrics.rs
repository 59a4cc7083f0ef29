//! `/metrics` in the Prometheus text format (version 0.0.4) for the learner and the optimiser:
//! a small HTTP/1.1 responder on its own thread (one request per connection, `GET /metrics`
//! only, requests read with a deadline and a size cap), rendering what the role last reported.
//! Documented metric by metric in `deploy/README.md`; `deploy/grafana/coadapt.json` charts them.

use std::fmt::Write as _;
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::Ordering::Relaxed;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use crate::error::Context;
use coadapt_design_optimizer::role::Counters;
use coadapt_learner::coadapt::Stats;
use serde::{Deserialize, Serialize};

/// The `[metrics]` table.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct MetricsConfig {
    /// Address of the learner's `/metrics` (e.g. `0.0.0.0:9464`; empty: none).
    pub learner_listen: String,
    /// Address of the optimiser's `/metrics` (empty: none).
    pub optimizer_listen: String,
}

/// What a role's `/metrics` renders from.
#[derive(Debug)]
pub enum Source {
    /// The learner's counters, and the free space of its run directory's disk.
    Learner(Arc<Mutex<Stats>>, Option<Arc<coadapt_learner::disk::DiskWatch>>),
    Optimizer(Arc<Counters>),
}

/// Serves `/metrics` on `addr` until the process ends; returns the bound address (port 0: any).
pub fn serve(addr: &str, source: Source) -> crate::Result<SocketAddr> {
    let listener = TcpListener::bind(addr).with_context(|| format!("metrics: binding {addr}"))?;
    let local = listener.local_addr()?;
    let source = Arc::new(source);
    std::thread::Builder::new().name("metrics".into()).spawn(move || {
        for stream in listener.incoming().flatten() {
            // One slow or hostile client must not hold the others up for long.
            let _ = answer(stream, &source);
        }
    })?;
    Ok(local)
}

fn answer(mut s: TcpStream, source: &Source) -> std::io::Result<()> {
    s.set_read_timeout(Some(Duration::from_secs(2)))?;
    s.set_write_timeout(Some(Duration::from_secs(2)))?;
    let mut buf = [0u8; 4096];
    let mut got = 0;
    // The request line and headers, up to the blank line (at most 4 KiB, within 2 s in all: a
    // client sending a byte at a time must not hold the only responder thread).
    let deadline = std::time::Instant::now() + Duration::from_secs(2);
    while got < buf.len() {
        let left = deadline.saturating_duration_since(std::time::Instant::now());
        if left.is_zero() {
            break;
        }
        s.set_read_timeout(Some(left))?;
        let n = s.read(&mut buf[got..])?;
        if n == 0 {
            break;
        }
        got += n;
        if buf[..got].windows(4).any(|w| w == b"\r\n\r\n") {
            break;
        }
    }
    let head = String::from_utf8_lossy(&buf[..got]);
    let line = head.lines().next().unwrap_or_default();
    let is = |path: &str| line.starts_with(&format!("GET {path} ")) || line == format!("GET {path}");
    let (status, body, kind) = if is("/metrics") {
        ("200 OK", render(source), "text/plain; version=0.0.4; charset=utf-8")
    } else if is("/healthz") {
        // The learner's health as its gRPC health service says it, for probes that cannot
        // speak TLS (Kubernetes' gRPC probes): 503 once it has stalled.
        match crate::health::watched_health() {
            Some(false) => ("503 Service Unavailable", "NOT_SERVING\n".to_string(), "text/plain; charset=utf-8"),
            _ => ("200 OK", "SERVING\n".to_string(), "text/plain; charset=utf-8"),
        }
    } else {
        ("404 Not Found", "only GET /metrics and GET /healthz here\n".to_string(), "text/plain; charset=utf-8")
    };
    write!(s, "HTTP/1.1 {status}\r\nContent-Type: {kind}\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}", body.len())?;
    s.flush()
}

fn metric(out: &mut String, name: &str, kind: &str, help: &str, samples: &[(&str, f64)]) {
    let _ = writeln!(out, "# HELP {name} {help}\n# TYPE {name} {kind}");
    for (labels, v) in samples {
        let _ = writeln!(out, "{name}{labels} {v}");
    }
}

/// The text of `/metrics`.
pub fn render(source: &Source) -> String {
    let mut o = String::new();
    match source {
        Source::Learner(stats, disk) => {
            let s = *stats.lock().unwrap_or_else(|e| e.into_inner());
            let t = s.time;
            let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64());
            let m = &mut o;
            metric(m, "coadapt_learner_design_index", "gauge", "The design being trained (0-based).", &[("", s.design as f64)]);
            metric(m, "coadapt_learner_episodes_total", "counter", "Episodes finished in the run.", &[("", s.episodes as f64)]);
            metric(
                m,
                "coadapt_learner_transitions_total",
                "counter",
                "Transitions of training episodes accepted.",
                &[("", s.steps as f64)],
            );
            metric(
                m,
                "coadapt_learner_episodes_refused_total",
                "counter",
                "Episodes refused and run again, by reason.",
                &[
                    ("{reason=\"magnitude\"}", t.episodes_rejected as f64),
                    ("{reason=\"lease\"}", t.reissued as f64),
                    ("{reason=\"restarted_by_actor\"}", t.restarted as f64),
                ],
            );
            metric(
                m,
                "coadapt_learner_updates_total",
                "counter",
                "SAC updates, by network pair (rate() gives updates/s).",
                &[("{pair=\"population\"}", s.updates_population as f64), ("{pair=\"individual\"}", s.updates_individual as f64)],
            );
            metric(m, "coadapt_learner_rollbacks_total", "counter", "Non-finite updates rolled back.", &[("", t.rollbacks as f64)]);
            metric(
                m,
                "coadapt_learner_policy_lag",
                "gauge",
                "Policy lag of the last episode (weights versions).",
                &[("", s.policy_lag as f64)],
            );
            metric(m, "coadapt_learner_policy_lag_max", "gauge", "Largest policy lag so far.", &[("", t.max_policy_lag as f64)]);
            metric(
                m,
                "coadapt_learner_replay_transitions",
                "gauge",
                "Transitions held, by buffer.",
                &[
                    ("{buffer=\"population\"}", s.replay_population as f64),
                    ("{buffer=\"species\"}", s.replay_species as f64),
                    ("{buffer=\"start_states\"}", s.start_states as f64),
                ],
            );
            metric(
                m,
                "coadapt_learner_snapshots_total",
                "counter",
                "Snapshots taken by this start of the learner.",
                &[("", s.snapshots as f64)],
            );
            metric(m, "coadapt_learner_snapshot_seconds_total", "counter", "Seconds spent taking snapshots.", &[("", s.snapshot_seconds)]);
            metric(m, "coadapt_learner_snapshot_bytes", "gauge", "Size of the newest snapshot.", &[("", s.snapshot_bytes as f64)]);
            let age = if s.snapshot_unix > 0.0 { now - s.snapshot_unix } else { f64::NAN };
            metric(m, "coadapt_learner_snapshot_age_seconds", "gauge", "Seconds since the newest snapshot (NaN: none yet).", &[("", age)]);
            metric(
                m,
                "coadapt_learner_resumes_total",
                "counter",
                "Learner starts that resumed this run from a snapshot.",
                &[("", s.resumes as f64)],
            );
            metric(
                m,
                "coadapt_learner_design_request_seconds",
                "gauge",
                "Seconds the last design request took.",
                &[("", s.design_request_seconds)],
            );
            metric(
                m,
                "coadapt_learner_design_requests_resent_total",
                "counter",
                "Design requests sent again after their deadline.",
                &[("", t.design_requests_resent as f64)],
            );
            metric(
                m,
                "coadapt_learner_design_replies_refused_total",
                "counter",
                "Design replies refused.",
                &[("", t.design_replies_refused as f64)],
            );
            if let Some(d) = disk {
                let (free, need, low) = d.reading();
                let free = if free == u64::MAX { f64::NAN } else { free as f64 };
                metric(
                    m,
                    "coadapt_learner_disk_free_bytes",
                    "gauge",
                    "Bytes free on the run directory's disk (NaN: unknown).",
                    &[("", free)],
                );
                metric(
                    m,
                    "coadapt_learner_disk_needed_bytes",
                    "gauge",
                    "Bytes the next snapshot needs (the last one and a quarter, and 16 MiB).",
                    &[("", need as f64)],
                );
                metric(
                    m,
                    "coadapt_learner_disk_low",
                    "gauge",
                    "1 while free space is below what the next snapshot needs.",
                    &[("", f64::from(u8::from(low)))],
                );
            }
            metric(
                m,
                "coadapt_learner_seconds_total",
                "counter",
                "Where the learner's time went.",
                &[("{activity=\"waiting\"}", t.waiting), ("{activity=\"sending\"}", t.sending), ("{activity=\"training\"}", t.training)],
            );
        }
        Source::Optimizer(c) => {
            let m = &mut o;
            let f = |bits: &std::sync::atomic::AtomicU64| f64::from_bits(bits.load(Relaxed));
            metric(
                m,
                "coadapt_optimizer_searches_total",
                "counter",
                "Design requests answered by a search.",
                &[("", c.searched.load(Relaxed) as f64)],
            );
            metric(
                m,
                "coadapt_optimizer_answered_again_total",
                "counter",
                "Requests answered from the stored replies.",
                &[("", c.answered_again.load(Relaxed) as f64)],
            );
            metric(m, "coadapt_optimizer_rollouts_total", "counter", "Design rollouts spent.", &[("", c.rollouts.load(Relaxed) as f64)]);
            metric(m, "coadapt_optimizer_search_seconds", "gauge", "Seconds of the last search.", &[("", f(&c.last_seconds_bits))]);
            metric(m, "coadapt_optimizer_search_seconds_total", "counter", "Seconds of all searches.", &[("", f(&c.total_seconds_bits))]);
        }
    }
    // Every role: log lines lost because stderr could not be written (a full disk, /dev/full,
    // a closed pipe); the process carries on without them.
    metric(
        &mut o,
        "coadapt_log_lines_lost_total",
        "counter",
        "Log and progress lines that could not be written to stderr.",
        &[("", coadapt_log::failed_writes() as f64)],
    );
    refusals(&mut o);
    o
}

/// Every role: what this process's servers refused (the fleet, the live design service), by
/// server, reason and peer address, from the process's refusal ledger. The learner's own
/// reasons are the fields of `coadapt_grpc::Refusals`; the gates add `unauthenticated` and
/// `permission_denied`, the listeners `connections_per_peer` and `connections_total`.
fn refusals(o: &mut String) {
    let rows = coadapt_auth::refusals::ledger().rows();
    let _ = writeln!(
        o,
        "# HELP coadapt_refusals_total Calls and connections refused, by server, reason and peer address (peers past {} counted as \"other\").\n# TYPE coadapt_refusals_total counter",
        coadapt_auth::refusals::MAX_PEERS
    );
    for r in rows {
        // Label values are our own names and IP addresses: nothing to escape but to be sure.
        let peer = r.peer.replace(['\\', '"', '\n'], "_");
        let _ = writeln!(o, "coadapt_refusals_total{{server=\"{}\",reason=\"{}\",peer=\"{peer}\"}} {}", r.server, r.reason, r.count);
    }
}
