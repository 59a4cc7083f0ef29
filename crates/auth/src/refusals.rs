//! What every server of this process refused, by server, reason and peer address, where an
//! operator sees it: `/metrics` renders [`Ledger::rows`] as `coadapt_refusals_total`, the first
//! refusal from each peer is logged with its reason, and while refusals go on a summary line
//! is logged once a minute. Nothing here ever holds a token: callers pass the status message
//! the client was sent, which names the field at fault, never its value.
//!
//! One ledger per process ([`ledger`]): a learner serves the fleet and the live design service
//! from one process, and its `/metrics` shows both. Peers are counted one by one up to
//! [`MAX_PEERS`]; after that (a scan from many addresses) further peers are counted together
//! as `other`, so an attacker cannot grow the metrics or the memory without bound.

use std::collections::{BTreeMap, HashSet};
use std::net::IpAddr;
use std::sync::{Mutex, OnceLock};
use std::time::{Duration, Instant};

/// Distinct peer addresses counted one by one (later ones: `other`).
pub const MAX_PEERS: usize = 256;

/// How often a summary of new refusals is logged while they go on.
pub const SUMMARY_EVERY: Duration = Duration::from_secs(60);

/// One row of the ledger: `count` refusals of `reason` by `server` to `peer`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Row {
    pub server: &'static str,
    pub reason: &'static str,
    /// The peer's IP address, `unknown` (not a TCP connection) or `other` (past [`MAX_PEERS`]).
    pub peer: String,
    pub count: u64,
}

/// Whether a refusal is worth a log line of its own: hostile or misconfigured callers are;
/// what a learner restart makes normal clients do (a call of the previous start) is counted
/// only.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Notice {
    Log,
    CountOnly,
}

#[derive(Debug, Default)]
struct Inner {
    counts: BTreeMap<(&'static str, &'static str, String), u64>,
    peers: HashSet<String>,
    logged: HashSet<(&'static str, String)>,
    /// Refusals since the last summary, by reason.
    recent: BTreeMap<(&'static str, &'static str), u64>,
    recent_peers: HashSet<String>,
    last_summary: Option<Instant>,
}

/// A process's refusals (see the module documentation).
#[derive(Debug, Default)]
pub struct Ledger {
    inner: Mutex<Inner>,
}

/// This process's ledger; the first refusal starts the thread that logs summaries.
pub fn ledger() -> &'static Ledger {
    static LEDGER: OnceLock<Ledger> = OnceLock::new();
    LEDGER.get_or_init(Ledger::default)
}

/// Records one refusal in this process's [`ledger`].
pub fn record(server: &'static str, reason: &'static str, peer: Option<IpAddr>, message: &str, notice: Notice) {
    record_n(server, reason, peer, message, notice, 1);
}

/// Records `n` refusals (a queue purged at once, say) in this process's [`ledger`].
pub fn record_n(server: &'static str, reason: &'static str, peer: Option<IpAddr>, message: &str, notice: Notice, n: u64) {
    if n == 0 {
        return;
    }
    if let Some(line) = ledger().add(server, reason, peer, message, notice, n) {
        coadapt_log::logln!("{line}");
    }
    start_summaries();
}

fn start_summaries() {
    static STARTED: OnceLock<()> = OnceLock::new();
    STARTED.get_or_init(|| {
        let _ = std::thread::Builder::new().name("refusal-summary".into()).spawn(|| {
            loop {
                std::thread::sleep(SUMMARY_EVERY);
                if let Some(line) = ledger().summary(Instant::now()) {
                    coadapt_log::logln!("{line}");
                }
            }
        });
    });
}

impl Ledger {
    /// Counts `n` refusals; returns the line to log when this is the first refusal of `server`
    /// to this peer and `notice` asks for it.
    pub fn add(
        &self,
        server: &'static str,
        reason: &'static str,
        peer: Option<IpAddr>,
        message: &str,
        notice: Notice,
        n: u64,
    ) -> Option<String> {
        let mut g = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        let mut label = peer.map_or_else(|| "unknown".to_string(), |p| p.to_string());
        if !g.peers.contains(&label) {
            if g.peers.len() >= MAX_PEERS {
                label = "other".to_string();
            } else {
                g.peers.insert(label.clone());
            }
        }
        *g.counts.entry((server, reason, label.clone())).or_insert(0) += n;
        *g.recent.entry((server, reason)).or_insert(0) += n;
        g.recent_peers.insert(label.clone());
        if g.last_summary.is_none() {
            g.last_summary = Some(Instant::now());
        }
        if notice == Notice::CountOnly || !g.logged.insert((server, label.clone())) {
            return None;
        }
        let more = if label == "other" {
            format!(" (more than {MAX_PEERS} peers refused: later ones are counted together as peer \"other\")")
        } else {
            String::new()
        };
        Some(format!(
            "{server}: refused a call from {label}: {reason}: {message}{more}; further refusals from this peer are counted in \
             /metrics (coadapt_refusals_total) and summarised every {} s",
            SUMMARY_EVERY.as_secs()
        ))
    }

    /// Every count so far, ordered by server, reason and peer.
    pub fn rows(&self) -> Vec<Row> {
        let g = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        g.counts.iter().map(|((server, reason, peer), &count)| Row { server, reason, peer: peer.clone(), count }).collect()
    }

    /// The summary line of the refusals since the last one, if there were any and
    /// [`SUMMARY_EVERY`] has passed since it (`now` as the clock reads).
    pub fn summary(&self, now: Instant) -> Option<String> {
        let mut g = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        let last = g.last_summary?;
        if g.recent.is_empty() || now.saturating_duration_since(last) < SUMMARY_EVERY {
            return None;
        }
        let total: u64 = g.recent.values().sum();
        let parts: Vec<String> = g.recent.iter().map(|((server, reason), n)| format!("{server} {reason} {n}")).collect();
        let line = format!(
            "refusals in the last {:.0} s: {total} from {} peer(s) ({})",
            now.saturating_duration_since(last).as_secs_f64(),
            g.recent_peers.len(),
            parts.join(", ")
        );
        g.recent.clear();
        g.recent_peers.clear();
        g.last_summary = Some(now);
        Some(line)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ip(s: &str) -> Option<IpAddr> {
        s.parse().ok()
    }

    #[test]
    fn the_first_refusal_per_peer_is_logged_and_every_one_counted() {
        let l = Ledger::default();
        let first = l.add("fleet", "unauthenticated", ip("10.0.0.7"), "authorization: missing", Notice::Log, 1);
        let line = first.expect("the first refusal from a peer is logged");
        assert!(line.contains("10.0.0.7") && line.contains("unauthenticated") && line.contains("authorization: missing"), "{line}");
        assert_eq!(l.add("fleet", "unauthenticated", ip("10.0.0.7"), "x", Notice::Log, 1), None);
        assert_eq!(l.add("fleet", "permission_denied", ip("10.0.0.7"), "x", Notice::Log, 2), None);
        assert!(l.add("fleet", "unauthenticated", ip("10.0.0.8"), "x", Notice::Log, 1).is_some());
        assert_eq!(l.add("fleet", "other_run", ip("10.0.0.9"), "x", Notice::CountOnly, 1), None);
        assert!(l.add("design_service", "unauthenticated", ip("10.0.0.7"), "x", Notice::Log, 1).is_some(), "a peer is logged per server");
        let rows = l.rows();
        let count =
            |server, reason, peer: &str| rows.iter().find(|r| r.server == server && r.reason == reason && r.peer == peer).map(|r| r.count);
        assert_eq!(count("fleet", "unauthenticated", "10.0.0.7"), Some(2));
        assert_eq!(count("fleet", "permission_denied", "10.0.0.7"), Some(2));
        assert_eq!(count("fleet", "other_run", "10.0.0.9"), Some(1));
        assert_eq!(rows.len(), 5);
    }

    #[test]
    fn peers_beyond_the_cap_are_counted_together() {
        let l = Ledger::default();
        for i in 0..MAX_PEERS + 10 {
            let a = IpAddr::from([10, 1, (i / 256) as u8, (i % 256) as u8]);
            l.add("fleet", "unauthenticated", Some(a), "x", Notice::Log, 1);
        }
        let rows = l.rows();
        assert_eq!(rows.len(), MAX_PEERS + 1);
        assert_eq!(rows.iter().find(|r| r.peer == "other").map(|r| r.count), Some(10));
    }

    #[test]
    fn a_summary_covers_what_came_since_the_last_one() {
        let l = Ledger::default();
        let t0 = Instant::now();
        assert_eq!(l.summary(t0 + SUMMARY_EVERY), None, "nothing refused: no summary");
        l.add("fleet", "unauthenticated", ip("10.0.0.7"), "x", Notice::Log, 3);
        l.add("fleet", "seq_jump", ip("10.0.0.8"), "x", Notice::Log, 1);
        assert_eq!(l.summary(Instant::now()), None, "not before a minute has passed");
        let later = Instant::now() + SUMMARY_EVERY;
        let s = l.summary(later).expect("a summary after a minute");
        assert!(s.contains(": 4 from 2 peer(s)") && s.contains("fleet unauthenticated 3") && s.contains("fleet seq_jump 1"), "{s}");
        assert_eq!(l.summary(later + SUMMARY_EVERY), None, "nothing new: no summary");
    }
}
