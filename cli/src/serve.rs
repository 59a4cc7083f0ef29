//! `coadapt serve RUN_DIR`: a run's design critic for clients in any language, from its newest
//! snapshot and its designs.csv: `coadapt.v1.DesignService` and the Open Inference Protocol
//! model `design-critic` (`proto/README.md`).

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Context;
use clap::Args;
use coadapt_coadaptation::serve::load;
use coadapt_design_service::ServeConfig;

/// Serve a run's design critic: DesignService (Info, Score, History) and the Open Inference
/// Protocol model `design-critic` (input `design` FP32 [N, D]; outputs `value`, `spread` and
/// `disagreement`, FP32 [N, 1] each), and the run's operator page in a browser on the same
/// address (`http://ADDR/`, or https with TLS: status, learning curves, designs, landscape,
/// bodies, actors; with --tokens-file a client token views it and an operator token may also
/// answer a waiting prototype step, the token given in the page's login form, never a URL).
///
/// The values are the thesis's Eq. 5.6 with the population networks of the run's newest
/// snapshot, averaged over a batch of `schedule.start-state-batch` start states drawn from the
/// run's start-state buffer (the same draw every time the run is served), with the run's
/// `optimizer.q` (Q1, min of twin, pessimistic, or the heads beyond the twin). Serves until
/// Ctrl-C or SIGTERM; the address is printed on stdout as `grpc://ADDR`.
///
/// How far to trust a difference between two scores: the README's "Reading a score" gives the
/// critic's calibration on the design benchmark per robot (how often the body it preferred
/// reached the higher return once trained, and what a difference of 1 was worth in return),
/// generated from docs/campaign/results. On 2026-12-03 (FEAR's runs: 5 seeds on HalfCheetah, 3
/// on Walker, Hopper and Daisy, 1 on MuJoCo's cheetah) its preference for a chosen body over
/// bodies the run had trained held 75-94 % of the time; over the untried random body proposed
/// next it held 16 of 25 times on HalfCheetah, 4 of 15 on Walker, 2 of 15 on Hopper, 6 of 9 on
/// Daisy and 4 of 5 on MuJoCo's cheetah: use scores to decide which bodies to try, not as their
/// returns, and check the robot's row before trusting a preference for an untried body.
#[derive(Debug, Args)]
pub struct ServeArgs {
    /// The run directory (of `coadapt run` or `coadapt learner`).
    pub run_dir: PathBuf,
    /// Address to listen on (port 0 picks a free port).
    #[arg(long, default_value = "127.0.0.1:50061")]
    pub listen: String,
    /// TLS (--tls-cert, --tls-key; --client-auth with --tls-ca for mutual TLS) and tokens
    /// (--tokens-file: clients, optimisers and operators may query). Without TLS only loopback
    /// addresses are served unless --insecure: anyone who reaches the port would read the
    /// run's designs and critic.
    #[command(flatten)]
    pub security: crate::security::SecurityArgs,
    /// Most designs one Score or ModelInfer call may carry.
    #[arg(long, default_value_t = 10_000)]
    pub max_score_batch: usize,
}

/// Serves until Ctrl-C or SIGTERM.
pub fn run(args: ServeArgs) -> anyhow::Result<()> {
    let addr: SocketAddr =
        args.listen.parse().with_context(|| format!("--listen: {:?} is not an address like 127.0.0.1:50061", args.listen))?;
    let security = crate::security::from_args(&args.security);
    coadapt_fleet::check_listen("--listen", addr, &security)?;
    let auth = security.server_auth()?;
    if args.max_score_batch == 0 {
        anyhow::bail!("--max-score-batch: 0 would refuse every request; at least 1");
    }
    let source: Arc<dyn coadapt_design_service::ModelSource> = Arc::new(load(&args.run_dir)?);
    let pages = coadapt_coadaptation::serve::page(&args.run_dir, source.clone(), &auth)?;
    let https = auth.tls.is_some();
    let cfg = ServeConfig { max_score_batch: args.max_score_batch, auth, pages: Some(pages), ..ServeConfig::default() };
    let server = coadapt_design_service::serve(addr, cfg, source).with_context(|| format!("listening on {addr}"))?;
    let at = server.local_addr();
    coadapt_log::logln!(
        "serve: coadapt.v1.DesignService and design-critic (Open Inference Protocol) on {at}; the run's operator page on {}://{at}/ (Ctrl-C stops)",
        if https { "https" } else { "http" }
    );
    coadapt_log::print_stdout_line(&format!("grpc://{at}"));
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().context("starting the runtime")?;
    rt.block_on(crate::env_serve::wait_for_signal());
    coadapt_log::logln!("serve: stopping");
    drop(server);
    Ok(())
}
