//! `coadapt bench design`: what a design query costs and what it costs the learner.
//!
//! - Score latency (median, p10, p90) and designs/s for batches of 1, 100 and 10,000 designs,
//!   over gRPC on loopback (`grpc`, with `--tls DIR` also over TLS: `grpc-tls`) against the same
//!   Eq. 5.6 computed in process (`inproc`): the difference is the service's own cost.
//! - The learner's SAC updates/s (3 x 256, obs 23 with the design, batch 256) alone and while a
//!   client scores batches of 100 designs in a loop against a design server in the same process
//!   (the server's pool of `max-concurrent` = 1 thread), with no busy-share limit and with the
//!   learner's default share of 0.2 of a core: what serving costs the training.
//!
//! Networks are HalfCheetah-sized (state 17, design 6, action 6, 3 x 256), 32 start states (the
//! reference's start-state batch). Every design is drawn before the timed loops.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use coadapt_core::{BoxSpace, rng};
use coadapt_design_optimizer::{ObjectiveWorkspace, QMode};
use coadapt_design_service::{DesignModel, HistoryRow, ServeConfig, StaticSource};
use coadapt_learner::{Sac, SacConfig};
use coadapt_wire::pb;
use coadapt_wire::pb::design_service_client::DesignServiceClient;
use rand::Rng;

use crate::figure::{emit, rate};
use crate::nn::random_batch;
use coadapt_fleet::app::AppError;

#[derive(Debug, Clone)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct DesignOptions {
    /// Seconds per figure.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 5.0))]
    pub seconds: f64,
    /// Designs per Score call.
    #[cfg_attr(feature = "clap", arg(long, value_delimiter = ',', default_values_t = vec![1usize, 100, 10_000]))]
    pub batches: Vec<usize>,
    /// Also over TLS with `coadapt tls new --out DIR`'s certificates.
    #[cfg_attr(feature = "clap", arg(long, value_name = "DIR"))]
    pub tls: Option<std::path::PathBuf>,
    /// Skip the learner figures (Score only).
    #[cfg_attr(feature = "clap", arg(long))]
    pub score_only: bool,
}

const STATE: usize = 17;
const DESIGN: usize = 6;
const ACT: usize = 6;
const STATES: usize = 32;

fn model(sac: &Sac) -> Result<DesignModel, AppError> {
    let mut r = rng(11, 0);
    let starts: Vec<f32> = (0..STATES * (STATE + DESIGN)).map(|_| r.random_range(-1.0..1.0)).collect();
    let names = (0..DESIGN).map(|i| format!("d{i}")).collect();
    DesignModel::new(
        "half-cheetah".into(),
        names,
        BoxSpace::new(vec![0.5; DESIGN], vec![2.0; DESIGN])?,
        1,
        "bench".into(),
        (sac.policy(), sac.policy_params(), sac.critic(), &[sac.critic_params(0).0]),
        &starts,
        STATE,
        QMode::First,
    )
    .map_err(AppError::library)
}

fn designs(n: usize, seed: u64) -> Vec<f32> {
    let mut r = rng(seed, 1);
    (0..n * DESIGN).map(|_| r.random_range(0.5..2.0)).collect()
}

/// Times `f` for about `seconds` (after two warm-up calls); emits latency quantiles and
/// designs/s under `config`. `prepare` makes each call's input outside the timed region (the
/// gRPC side's request copy; nothing in process), so both sides time the same work. A failed
/// call ends the benchmark before any figure of `config` is printed.
fn time_calls<T>(
    config: &str,
    batch: usize,
    seconds: f64,
    mut prepare: impl FnMut() -> T,
    mut f: impl FnMut(T) -> Result<(), AppError>,
) -> Result<(), AppError> {
    f(prepare())?;
    f(prepare())?;
    let mut lat = Vec::new();
    let mut timed = 0.0;
    let start = Instant::now();
    while start.elapsed().as_secs_f64() < seconds || lat.len() < 3 {
        let input = prepare();
        let t = Instant::now();
        f(input)?;
        let dt = t.elapsed().as_secs_f64();
        timed += dt;
        lat.push(dt * 1e3);
    }
    // Throughput over the timed calls only.
    let total = timed;
    lat.sort_by(f64::total_cmp);
    let q = |p: f64| lat[((lat.len() - 1) as f64 * p).round() as usize];
    emit("design_score_latency_median", config, q(0.5), "ms");
    emit("design_score_latency_p10", config, q(0.1), "ms");
    emit("design_score_latency_p90", config, q(0.9), "ms");
    emit("design_score", config, (lat.len() * batch) as f64 / total, "designs/s");
    Ok(())
}

fn serve(m: DesignModel, tls: Option<&std::path::Path>) -> Result<coadapt_design_service::DesignServer, AppError> {
    serve_with(m, tls, 1.0)
}

fn serve_with(m: DesignModel, tls: Option<&std::path::Path>, share: f64) -> Result<coadapt_design_service::DesignServer, AppError> {
    let mut cfg = ServeConfig { max_busy_share: share, ..ServeConfig::default() };
    if let Some(dir) = tls {
        let f = |n: &str| dir.join(n).display().to_string();
        cfg.auth = coadapt_fleet::SecurityConfig { tls_cert: f("server.pem"), tls_key: f("server-key.pem"), ..Default::default() }
            .server_auth()?;
    }
    let source = StaticSource { model: Arc::new(m), history: Vec::<HistoryRow>::new() };
    let loopback = std::net::SocketAddr::from(([127, 0, 0, 1], 0));
    coadapt_design_service::serve(loopback, cfg, Arc::new(source)).map_err(AppError::io("starting the design server"))
}

async fn client(
    addr: std::net::SocketAddr,
    tls: Option<&std::path::Path>,
) -> Result<DesignServiceClient<coadapt_auth::AuthChannel>, AppError> {
    let mut sec = coadapt_fleet::SecurityConfig::default();
    if let Some(dir) = tls {
        sec.tls_ca = dir.join("ca.pem").display().to_string();
        sec.tls_server_name = "localhost".into();
    }
    let auth = sec.client_auth()?;
    let channel = auth.endpoint(&addr.to_string())?.connect().await?;
    Ok(DesignServiceClient::with_interceptor(channel, auth.bearer())
        .max_decoding_message_size(16 << 20)
        .max_encoding_message_size(16 << 20))
}

/// The client's runtime: one thread, as `coadapt score`'s.
fn runtime() -> Result<tokio::runtime::Runtime, AppError> {
    tokio::runtime::Builder::new_current_thread().enable_all().build().map_err(AppError::io("starting the Tokio runtime"))
}

fn request(d: &[f32]) -> pb::ScoreRequest {
    pb::ScoreRequest { designs: d.chunks_exact(DESIGN).map(|v| pb::Design { values: v.to_vec() }).collect() }
}

pub fn run(a: &DesignOptions) -> Result<(), AppError> {
    let sac = Sac::new(STATE + DESIGN, ACT, SacConfig { hidden: vec![256; 3], ..SacConfig::default() }, 5)?;
    let rt = runtime()?;
    for &n in &a.batches {
        let d = designs(n, n as u64);
        // In process: Eq. 5.6 on this thread, as the server's pool computes it.
        let m = model(&sac)?;
        let (mut mean, mut spread, mut ws) = (vec![0.0; n], vec![0.0; n], ObjectiveWorkspace::default());
        time_calls(
            &format!("inproc-batch{n}-{STATES}states"),
            n,
            a.seconds,
            || (),
            |()| {
                m.score(&d, &mut mean, &mut spread, &mut ws);
                Ok(())
            },
        )?;
        let mut transports: Vec<(&str, Option<&std::path::Path>)> = vec![("grpc", None)];
        if let Some(dir) = &a.tls {
            transports.push(("grpc-tls", Some(dir.as_path())));
        }
        for (name, tls) in transports {
            let server = serve(model(&sac)?, tls)?;
            let mut c = rt.block_on(client(server.local_addr(), tls))?;
            let req = request(&d);
            time_calls(
                &format!("{name}-batch{n}-{STATES}states"),
                n,
                a.seconds,
                || req.clone(),
                |req| {
                    let got = rt.block_on(c.score(req))?.get_ref().scores.len();
                    if got != n {
                        return Err(AppError::Failed(format!("a Score call answered {got} scores for {n} designs")));
                    }
                    Ok(())
                },
            )?;
        }
    }
    if !a.score_only {
        learner_rates(a, &sac)?;
    }
    Ok(())
}

/// SAC updates/s alone, then with a client scoring batches of 100 in a loop.
fn learner_rates(a: &DesignOptions, sac: &Sac) -> Result<(), AppError> {
    let (obs, batch) = (STATE + DESIGN, random_batch(256, STATE + DESIGN, ACT, 2));
    let mut learner = Sac::new(obs, ACT, SacConfig { hidden: vec![256; 3], auto_alpha: true, ..SacConfig::default() }, 1)?;
    let alone = rate(a.seconds, || {
        learner.update(&batch);
    });
    emit("learner_updates", "3x256-obs23-alone", alone, "updates/s");
    for share in [1.0, 0.2] {
        beside_learner(a, sac, &mut learner, &batch, alone, share)?;
    }
    Ok(())
}

/// The learner's rate beside a client scoring in a loop against a server of `share`.
fn beside_learner(
    a: &DesignOptions,
    sac: &Sac,
    learner: &mut Sac,
    batch: &coadapt_core::Batch,
    alone: f64,
    share: f64,
) -> Result<(), AppError> {
    let server = serve_with(model(sac)?, None, share)?;
    let addr = server.local_addr();
    let stop = Arc::new(AtomicBool::new(false));
    let calls = Arc::new(AtomicU64::new(0));
    let (s, k) = (stop.clone(), calls.clone());
    let scorer = std::thread::spawn(move || -> Result<(), AppError> {
        let rt = runtime()?;
        let mut c = rt.block_on(client(addr, None))?;
        let req = request(&designs(100, 7));
        while !s.load(Ordering::Relaxed) {
            rt.block_on(c.score(req.clone()))?;
            k.fetch_add(1, Ordering::Relaxed);
        }
        Ok(())
    });
    std::thread::sleep(Duration::from_millis(200));
    let t = Instant::now();
    let before = calls.load(Ordering::Relaxed);
    let busy = rate(a.seconds, || {
        learner.update(batch);
    });
    let scored = (calls.load(Ordering::Relaxed) - before) as f64 * 100.0 / t.elapsed().as_secs_f64();
    stop.store(true, Ordering::Relaxed);
    scorer.join().map_err(|_| AppError::Failed("the scoring client panicked".into()))??;
    let tag = format!("score-client-batch100-busy-share{share}");
    emit("learner_updates", &format!("3x256-obs23-with-{tag}"), busy, "updates/s");
    emit("learner_updates_kept", &format!("with-{tag}"), busy / alone * 100.0, "%");
    emit("design_score", &format!("grpc-batch100-beside-learner-busy-share{share}"), scored, "designs/s");
    Ok(())
}
