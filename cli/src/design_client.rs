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

/// Print a run's designs as CSV (designs.csv's columns), paged from the server.
#[derive(Debug, Args)]
pub struct HistoryArgs {
    #[command(flatten)]
    pub server: ServerArgs,
    /// The first design index.
    #[arg(long, default_value_t = 0)]
    pub from: u32,
}

fn client(a: &ServerArgs) -> anyhow::Result<(tokio::runtime::Runtime, DesignServiceClient<tonic::transport::Channel>, Duration)> {
    let t = Duration::try_from_secs_f64(a.timeout_secs)
        .ok()
        .filter(|d| !d.is_zero())
        .ok_or_else(|| anyhow::anyhow!("--timeout-secs: {} is not a positive number of seconds", a.timeout_secs))?;
    let url = if a.server.contains("://") { a.server.clone() } else { format!("http://{}", a.server) };
    let endpoint = tonic::transport::Endpoint::from_shared(url.clone())
        .with_context(|| format!("--server: {:?} is not an address", a.server))?
        .connect_timeout(t)
        .timeout(t);
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
    let channel = rt.block_on(endpoint.connect()).with_context(|| format!("connecting to the design service at {url}"))?;
    Ok((rt, DesignServiceClient::new(channel), t))
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
    println!("design,objective,spread");
    for (d, s) in designs.iter().zip(&r.scores) {
        let v: Vec<String> = d.values.iter().map(|v| v.to_string()).collect();
        println!("{},{},{}", v.join(";"), s.objective, s.spread);
    }
    eprintln!("score: population weights version {}, mean over {} start states", r.weights_version, r.start_states);
    Ok(())
}

pub fn history(a: HistoryArgs) -> anyhow::Result<()> {
    let (rt, mut c, _) = client(&a.server)?;
    let opt = |v: Option<f32>| v.map(|v| v.to_string()).unwrap_or_default();
    println!("{}", coadapt_learner::run_dir::DESIGNS_HEADER);
    let mut from = a.from;
    loop {
        let p = rt.block_on(c.history(pb::HistoryRequest { from_index: from, max_rows: 0 })).map_err(status)?.into_inner();
        let mut w = csv::WriterBuilder::new().terminator(csv::Terminator::Any(b'\n')).from_writer(std::io::stdout());
        for r in &p.designs {
            let d: Vec<String> = r.design.as_ref().map(|d| d.values.iter().map(|v| v.to_string()).collect()).unwrap_or_default();
            w.write_record([
                r.index.to_string(),
                r.kind.clone(),
                d.join(";"),
                r.episodes.to_string(),
                opt(r.best_eval_return),
                opt(r.last_eval_return),
                opt(r.predicted_objective),
                r.design_rollouts.to_string(),
                r.method.clone(),
                r.prototype.clone(),
            ])?;
        }
        w.flush()?;
        if !p.more || p.next_index <= from {
            return Ok(());
        }
        from = p.next_index;
    }
}
