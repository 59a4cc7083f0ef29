//! `coadapt bench transport`: the fleet's links between separate processes, timed.
//!
//! - `weights_broadcast`: the learner publishes the acting policy (3 x 256, obs 23, act 6:
//!   140,812 values, 563 KB) and waits until each of N actor processes has received it and
//!   answered with a small chunk naming the version; the figure is that round trip, median
//!   and 99th percentile over many publishes, and the weights delivered per second at the
//!   median (N x 563 KB / median).
//! - `experience`: N actor processes send 250-transition chunks (obs 23, act 6: 213 bytes of
//!   payload per transition) as fast as the transport takes them; the learner receives and
//!   decodes; transitions/s and MB/s of payload.
//!
//! The actor side runs as children of this process, started by the caller's [`PeerCommand`]
//! (`coadapt bench transport --peer ...`), each running [`run`] with [`TransportOptions::peer`].

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use coadapt_fleet::{FleetConfig, TransportKind};
use coadapt_transport::{ExperienceChunk, Weights};

use crate::figure::emit;
use coadapt_fleet::app::AppError;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Peer {
    /// Answer every weights version with a chunk naming it.
    Echo,
    /// Send experience chunks for `--seconds`.
    Flood,
}

#[derive(Debug, Clone)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct TransportOptions {
    /// Transports to time.
    #[cfg_attr(feature = "clap", arg(long, value_enum, value_delimiter = ',', default_values = ["shm", "grpc"]))]
    pub transport: Vec<TransportKind>,
    /// Actor processes for the weight broadcast.
    #[cfg_attr(feature = "clap", arg(long, value_delimiter = ',', default_values_t = vec![1usize, 4, 16]))]
    pub actors: Vec<usize>,
    /// Actor processes sending experience.
    #[cfg_attr(feature = "clap", arg(long, value_delimiter = ',', default_values_t = vec![1usize, 4]))]
    pub senders: Vec<usize>,
    /// Seconds per figure.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 5.0))]
    pub seconds: f64,
    /// Internal: run as an actor-side peer of a running benchmark.
    #[cfg_attr(feature = "clap", arg(long, value_enum, hide = true))]
    pub peer: Option<Peer>,
    // A peer's fleet name, its learner's address (gRPC) and its actor id (hidden: internal).
    #[cfg_attr(feature = "clap", arg(long, hide = true, default_value = ""))]
    pub fleet: String,
    #[cfg_attr(feature = "clap", arg(long, hide = true, default_value = ""))]
    pub connect: String,
    #[cfg_attr(feature = "clap", arg(long, hide = true, default_value_t = 0))]
    pub id: u64,
    /// Time gRPC over TLS with the certificates in DIR (`coadapt tls new --out DIR`: ca.pem,
    /// server.pem, server-key.pem); the figures' configs end in `-tls`.
    #[cfg_attr(feature = "clap", arg(long, value_name = "DIR"))]
    pub tls: Option<std::path::PathBuf>,
}

/// How the benchmark starts an actor-side peer: `program args... --peer echo|flood ...`, a
/// process that parses those flags into [`TransportOptions`] and calls [`run`] (for the
/// `coadapt` binary: its own executable and `bench transport`).
#[derive(Debug, Clone)]
pub struct PeerCommand {
    pub program: PathBuf,
    pub args: Vec<String>,
}

/// The benchmark's TLS settings (none without `--tls`); the same for the learner and its
/// peer processes.
fn security(tls: Option<&Path>) -> coadapt_fleet::SecurityConfig {
    let Some(dir) = tls else { return coadapt_fleet::SecurityConfig::default() };
    let f = |n: &str| dir.join(n).display().to_string();
    coadapt_fleet::SecurityConfig {
        tls_cert: f("server.pem"),
        tls_key: f("server-key.pem"),
        tls_ca: f("ca.pem"),
        tls_server_name: "localhost".into(),
        ..Default::default()
    }
}

/// `-tls` when timing over TLS.
fn tls_suffix(tls: Option<&Path>) -> &'static str {
    if tls.is_some() { "-tls" } else { "" }
}

const OBS: usize = 23;
const ACT: usize = 6;
const ROWS: usize = 250;

fn policy_len() -> usize {
    let hidden = [256usize; 3];
    let mut n = 0;
    let mut fan_in = OBS;
    for h in hidden {
        n += fan_in * h + h;
        fan_in = h;
    }
    n + fan_in * 2 * ACT + 2 * ACT
}

fn experience_chunk(id: u64) -> ExperienceChunk {
    ExperienceChunk {
        actor: id,
        assignment: 1,
        design_index: 0,
        weights_version: 0,
        first: false,
        obs: (0..ROWS * OBS).map(|i| (i % 97) as f32 * 0.01).collect(),
        actions: vec![0.5; ROWS * ACT],
        rewards: vec![0.1; ROWS],
        next_obs: (0..ROWS * OBS).map(|i| (i % 89) as f32 * 0.01).collect(),
        terminated: vec![false; ROWS],
        end: None,
    }
}

fn fleet_config(kind: TransportKind, fleet: &str, connect: &str) -> FleetConfig {
    FleetConfig { transport: kind, name: fleet.into(), listen: "127.0.0.1:0".into(), connect: connect.into(), ..FleetConfig::default() }
}

/// Times every figure `a` asks for, starting peers with `peers`; with `a.peer`, runs as one
/// of those peers instead.
pub fn run(a: &TransportOptions, peers: &PeerCommand) -> Result<(), AppError> {
    if let Some(peer) = a.peer {
        let kind = *a.transport.first().ok_or_else(|| AppError::Config("--peer needs --transport".into()))?;
        return run_peer(peer, &fleet_config(kind, &a.fleet, &a.connect), a);
    }
    let b = Bench { tls: a.tls.as_deref(), peers, seconds: a.seconds };
    for &kind in &a.transport {
        if kind == TransportKind::InProcess {
            return Err(AppError::Config("--transport: in-process has nothing to time here; use shm or grpc".into()));
        }
        for &n in &a.actors {
            broadcast(&b, kind, n)?;
        }
        for &n in &a.senders {
            experience(&b, kind, n)?;
        }
    }
    Ok(())
}

/// What every figure of one run shares.
struct Bench<'a> {
    tls: Option<&'a Path>,
    peers: &'a PeerCommand,
    seconds: f64,
}

/// The learner side of one figure: its links, and how peers reach it.
struct Learner {
    links: coadapt_transport::LearnerLinks,
    _guard: coadapt_fleet::LearnerGuard,
    fleet: String,
    connect: String,
}

fn learner(b: &Bench<'_>, kind: TransportKind, tag: &str) -> Result<Learner, AppError> {
    let fleet = format!("coadapt-bench-{}-{tag}", std::process::id());
    let cfg = fleet_config(kind, &fleet, "");
    let (links, guard) = cfg.learner_links(None, None, &security(b.tls))?;
    let connect = match &guard {
        coadapt_fleet::LearnerGuard::Grpc(s) => format!("http://{}", s.local_addr()),
        coadapt_fleet::LearnerGuard::None => String::new(),
    };
    Ok(Learner { links, _guard: guard, fleet, connect })
}

fn spawn_peers(b: &Bench<'_>, kind: TransportKind, l: &Learner, peer: &str, n: usize) -> Result<Vec<Child>, AppError> {
    (0..n)
        .map(|i| {
            Command::new(&b.peers.program)
                .args(&b.peers.args)
                .args(["--peer", peer, "--transport", kind.name(), "--fleet", &l.fleet, "--connect", &l.connect])
                .args(["--id", &i.to_string(), "--seconds", &b.seconds.to_string()])
                .args(b.tls.map(|d| vec!["--tls".to_string(), d.display().to_string()]).unwrap_or_default())
                .stdin(Stdio::null())
                .stdout(Stdio::null())
                .spawn()
                .map_err(AppError::io("starting a peer process"))
        })
        .collect()
}

fn reap(children: Vec<Child>) {
    for mut c in children {
        let deadline = Instant::now() + Duration::from_secs(10);
        while matches!(c.try_wait(), Ok(None)) && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = c.kill();
        let _ = c.wait();
    }
}

fn broadcast(b: &Bench<'_>, kind: TransportKind, n: usize) -> Result<(), AppError> {
    let seconds = b.seconds;
    let mut l = learner(b, kind, &format!("w{n}"))?;
    let peers = spawn_peers(b, kind, &l, "echo", n)?;
    let len = policy_len();
    let mut version = 0u64;
    let publish = |l: &mut Learner, version: u64| -> Result<(), AppError> {
        let policy = (0..len).map(|i| (i as f32 * 1e-4) + version as f32).collect();
        l.links.acting_weights.publish(Weights { version, policy, q1: vec![], q2: vec![], heads: vec![] })?;
        Ok(())
    };
    // Until every peer has answered once, they are still starting.
    let mut seen = vec![false; n];
    let ready_by = Instant::now() + Duration::from_secs(60);
    while seen.iter().any(|s| !s) {
        version += 1;
        publish(&mut l, version)?;
        let t = Instant::now();
        while t.elapsed() < Duration::from_millis(200) {
            if let Some(c) = l.links.experience.recv_timeout(Duration::from_millis(50))?
                && let Some(s) = seen.get_mut(c.actor as usize)
            {
                *s = true;
            }
        }
        if Instant::now() > ready_by {
            return Err(AppError::Failed(format!("the {n} peer processes did not all answer within 60 s")));
        }
    }
    let mut times = Vec::new();
    let start = Instant::now();
    while start.elapsed().as_secs_f64() < seconds || times.len() < 20 {
        version += 1;
        let t = Instant::now();
        publish(&mut l, version)?;
        let mut got = 0;
        while got < n {
            match l.links.experience.recv_timeout(Duration::from_secs(10))? {
                Some(c) if c.weights_version == version => got += 1,
                Some(_) => {}
                None => return Err(AppError::Failed(format!("a peer did not answer version {version} within 10 s"))),
            }
        }
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    drop(l);
    reap(peers);
    times.sort_by(f64::total_cmp);
    let config = format!("{}-{n}actors-{}KB{}", kind.name(), len * 4 / 1000, tls_suffix(b.tls));
    emit("weights_broadcast_median", &config, times[times.len() / 2], "ms");
    emit("weights_broadcast_p99", &config, times[(times.len() * 99 / 100).min(times.len() - 1)], "ms");
    // Weights delivered per second of median round trip, all actors together.
    emit("weights_broadcast", &config, (n * len * 4) as f64 / (times[times.len() / 2] / 1e3) / 1e6, "MB/s");
    Ok(())
}

fn experience(b: &Bench<'_>, kind: TransportKind, n: usize) -> Result<(), AppError> {
    let mut l = learner(b, kind, &format!("e{n}"))?;
    let peers = spawn_peers(b, kind, &l, "flood", n)?;
    let bytes_per_row = (2 * OBS + ACT + 1) * 4 + 1;
    let (mut rows, mut first, mut last) = (0usize, None, Instant::now());
    let mut idle = Instant::now();
    loop {
        match l.links.experience.recv_timeout(Duration::from_millis(200)) {
            Ok(Some(c)) => {
                // The clock starts at the first chunk, so process start-up is not counted.
                if first.is_none() {
                    first = Some(Instant::now());
                } else {
                    rows += c.len();
                }
                last = Instant::now();
                idle = Instant::now();
            }
            Ok(None) | Err(coadapt_transport::TransportError::Closed) => {
                let waited = if first.is_some() { Duration::from_secs(2) } else { Duration::from_secs(60) };
                if idle.elapsed() > waited {
                    break;
                }
            }
            Err(e) => return Err(e.into()),
        }
    }
    drop(l);
    reap(peers);
    let Some(first) = first else { return Err(AppError::Failed(format!("no experience arrived from {n} peer processes"))) };
    let secs = last.duration_since(first).as_secs_f64().max(1e-9);
    let config = format!("{}-{n}senders-{ROWS}rows{}", kind.name(), tls_suffix(b.tls));
    emit("experience", &config, rows as f64 / secs, "transitions/s");
    emit("experience", &config, (rows * bytes_per_row) as f64 / secs / 1e6, "MB/s");
    Ok(())
}

fn run_peer(peer: Peer, cfg: &FleetConfig, a: &TransportOptions) -> Result<(), AppError> {
    let mut links = cfg.actor_links(a.id, &security(a.tls.as_deref()))?;
    match peer {
        Peer::Echo => {
            let mut seen = 0;
            loop {
                let w = match links.weights.wait_for(seen + 1, Duration::from_secs(5)) {
                    Ok(Some(w)) => w,
                    Ok(None) | Err(coadapt_transport::TransportError::Closed) => return Ok(()),
                    Err(e) => return Err(e.into()),
                };
                seen = w.version;
                let ack = ExperienceChunk { actor: a.id, weights_version: w.version, ..ExperienceChunk::default() };
                if links.experience.send(ack).is_err() {
                    return Ok(());
                }
            }
        }
        Peer::Flood => {
            let chunk = experience_chunk(a.id);
            let start = Instant::now();
            while start.elapsed().as_secs_f64() < a.seconds {
                if links.experience.send(chunk.clone()).is_err() {
                    break;
                }
            }
            Ok(())
        }
    }
}
