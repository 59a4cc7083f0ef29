//! `coadapt score` and `coadapt history`: the DesignService from the command line.

use std::time::Duration;

use anyhow::Context;
use clap::Args;
use coadapt_wire::pb;
use coadapt_wire::pb::design_service_client::DesignServiceClient;

/// Where the design service is and how long a call may take.
#[derive(Debug, Args)]
pub struct ServerArgs {
    /// The design service: HOST:PORT or http://HOST:PORT (`coadapt serve` prints it).
    #[arg(long)]
    pub server: String,
    /// Deadline of each call, seconds.
    #[arg(long, default_value_t = 10.0)]
    pub timeout_secs: f64,
    /// TLS (--tls-ca, --tls-server-name, --client-cert/--client-key) and the token
    /// (--token-file, or COADAPT_TOKEN in the environment).
    #[command(flatten)]
    pub security: crate::security::SecurityArgs,
}

/// Score designs with a run's critic (Eq. 5.6: the mean over the run's start states of the
/// population critic's value, and its spread).
#[derive(Debug, Args)]
pub struct ScoreArgs {
    #[command(flatten)]
    pub server: ServerArgs,
    /// A design: its values, comma-separated, in the order `coadapt history` and Info name
    /// them (repeat for a batch).
    #[arg(long, required = true)]
    pub design: Vec<String>,
}

/// Search a run's critic for the best design (PSO or CMA-ES over Eq. 5.6) on the server,
/// printing the best design so far after every iteration (stderr) and the answer (stdout).
#[derive(Debug, Args)]
pub struct OptimizeArgs {
    #[command(flatten)]
    pub server: ServerArgs,
    /// pso or cmaes.
    #[arg(long, default_value = "pso")]
    pub method: String,
    /// PSO particles, or CMA-ES candidates per generation (0: the method's default).
    #[arg(long, default_value_t = 0)]
    pub particles: u32,
    /// PSO iterations, or CMA-ES generations at most (0: 250).
    #[arg(long, default_value_t = 0)]
    pub iterations: u32,
    /// Narrower lower bounds, comma-separated, one per dimension.
    #[arg(long)]
    pub low: Option<String>,
    /// Narrower upper bounds, comma-separated, one per dimension.
    #[arg(long)]
    pub high: Option<String>,
    /// A coordinate held fixed, DIMENSION=VALUE (0-based, repeatable), e.g. --fix 3=1.2.
    #[arg(long)]
    pub fix: Vec<String>,
    /// The search's seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

fn floats(flag: &str, text: &str) -> anyhow::Result<Vec<f32>> {
    text.split(',').map(|v| v.trim().parse::<f32>().with_context(|| format!("{flag}: {v:?} is not a number"))).collect()
}

pub fn optimize(a: OptimizeArgs) -> anyhow::Result<()> {
    let fixed = a
        .fix
        .iter()
        .map(|f| {
            let (d, v) = f.split_once('=').ok_or_else(|| anyhow::anyhow!("--fix {f:?}: expected DIMENSION=VALUE"))?;
            Ok(pb::FixedCoordinate {
                dimension: d.trim().parse().with_context(|| format!("--fix {f:?}: {d:?} is not a dimension index"))?,
                value: v.trim().parse().with_context(|| format!("--fix {f:?}: {v:?} is not a number"))?,
            })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let req = pb::OptimizeRequest {
        method: a.method.clone(),
        particles: a.particles,
        iterations: a.iterations,
        low: a.low.as_deref().map(|t| floats("--low", t)).transpose()?.unwrap_or_default(),
        high: a.high.as_deref().map(|t| floats("--high", t)).transpose()?.unwrap_or_default(),
        fixed,
        seed: a.seed,
    };
    // A search may take longer than one call's deadline: the stream gets 100 of them.
    let (rt, mut c, _) = client(&ServerArgs {
        server: a.server.server.clone(),
        timeout_secs: a.server.timeout_secs * 100.0,
        security: a.server.security.clone(),
    })?;
    rt.block_on(async move {
        let mut s = c.optimize(req).await.map_err(status)?.into_inner();
        while let Some(m) = s.message().await.map_err(status)? {
            let d: Vec<String> = m.best.as_ref().map(|d| d.values.iter().map(|v| v.to_string()).collect()).unwrap_or_default();
            if m.done {
                println!("design,objective,spread,evaluations,weights_version");
                println!("{},{},{},{},{}", d.join(";"), m.best_objective, m.best_spread, m.evaluations, m.weights_version);
                return Ok(());
            }
            coadapt_log::logln!(
                "optimize: iteration {} ({} designs scored): best {} at {}",
                m.iteration + 1,
                m.evaluations,
                m.best_objective,
                d.join(";")
            );
        }
        anyhow::bail!("the design service ended the search without an answer")
    })
}

/// Print a run's designs as CSV (designs.csv's columns), paged from the server.
#[derive(Debug, Args)]
pub struct HistoryArgs {
    #[command(flatten)]
    pub server: ServerArgs,
    /// The first design index.
    #[arg(long, default_value_t = 0)]
    pub from: u32,
}

type Client = DesignServiceClient<coadapt_auth::AuthChannel>;

fn client(a: &ServerArgs) -> anyhow::Result<(tokio::runtime::Runtime, Client, Duration)> {
    let t = Duration::try_from_secs_f64(a.timeout_secs)
        .ok()
        .filter(|d| !d.is_zero())
        .ok_or_else(|| anyhow::anyhow!("--timeout-secs: {} is not a positive number of seconds", a.timeout_secs))?;
    let auth = crate::security::from_args(&a.security).client_auth()?;
    let endpoint =
        auth.endpoint(&a.server).with_context(|| format!("--server: {:?} is not an address", a.server))?.connect_timeout(t).timeout(t);
    let url = endpoint.uri().to_string();
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
    let channel = rt.block_on(endpoint.connect()).with_context(|| format!("connecting to the design service at {url}"))?;
    Ok((rt, DesignServiceClient::with_interceptor(channel, auth.bearer()), t))
}

fn status(e: tonic::Status) -> anyhow::Error {
    anyhow::anyhow!("the design service answered {:?}: {}", e.code(), e.message())
}

pub fn score(a: ScoreArgs) -> anyhow::Result<()> {
    let designs = a
        .design
        .iter()
        .enumerate()
        .map(|(i, d)| {
            d.split(',')
                .map(|v| v.trim().parse::<f32>().with_context(|| format!("--design #{}: {v:?} is not a number", i + 1)))
                .collect::<anyhow::Result<Vec<f32>>>()
                .map(|values| pb::Design { values })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let (rt, mut c, _) = client(&a.server)?;
    let r = rt.block_on(c.score(pb::ScoreRequest { designs: designs.clone() })).map_err(status)?.into_inner();
    println!("design,objective,spread,disagreement");
    for (d, s) in designs.iter().zip(&r.scores) {
        let v: Vec<String> = d.values.iter().map(|v| v.to_string()).collect();
        let gap = s.disagreement.map(|d| d.to_string()).unwrap_or_default();
        println!("{},{},{},{gap}", v.join(";"), s.objective, s.spread);
    }
    coadapt_log::logln!("score: population weights version {}, mean over {} start states", r.weights_version, r.start_states);
    Ok(())
}

pub fn history(a: HistoryArgs) -> anyhow::Result<()> {
    use coadapt_learner::run_dir::{DESIGNS_HEADER, DesignRow, design_lines};
    use std::io::Write;
    let (rt, mut c, _) = client(&a.server)?;
    println!("{DESIGNS_HEADER}");
    let mut from = a.from;
    loop {
        let p = rt.block_on(c.history(pb::HistoryRequest { from_index: from, max_rows: 0 })).map_err(status)?.into_inner();
        // The rows as the run wrote them, by the same writer.
        let rows: Vec<DesignRow> = p
            .designs
            .iter()
            .map(|r| DesignRow {
                index: r.index as usize,
                kind: r.kind.clone(),
                design: r.design.as_ref().map(|d| d.values.clone()).unwrap_or_default(),
                episodes: r.episodes as usize,
                best_eval_return: r.best_eval_return,
                last_eval_return: r.last_eval_return,
                predicted_objective: r.predicted_objective,
                design_rollouts: r.design_rollouts,
                method: r.method.clone(),
                prototype: r.prototype.clone(),
            })
            .collect();
        std::io::stdout().write_all(&design_lines(&rows)?)?;
        if !p.more || p.next_index <= from {
            return Ok(());
        }
        from = p.next_index;
    }
}
