//! `coadapt env-serve`: serves a built-in robot over dm_env_rpc v1, so any dm_env_rpc client
//! (DeepMind's Python `Connection` and `DmEnvAdaptor`, another coadapt fleet's actors) drives it.

use anyhow::Context;
use clap::Args;

/// Serve a built-in robot over dm_env_rpc v1 (gRPC), for any dm_env_rpc client.
///
/// The coadapt profile (proto/README.md): action `action` in the robot's action box; observations `observation`
/// (the state), `reward`, `discount` (0 only at a true end), `design`; world settings `design`
/// and `seed`. Each client connection creates its own worlds; they end with it.
#[derive(Debug, Args)]
pub struct EnvServeArgs {
    /// The robot: pendulum, half-cheetah, walker, hopper, daisy, or planar (the policy-search
    /// benchmark's two arms, for `coadapt search` with `robot = URL`).
    #[arg(long)]
    pub env: String,
    /// Serve the robot seen through the camera instead of its state: each observation is one
    /// SIDE x SIDE RGB frame, channel-major, in [0, 1] (for `coadapt latent` with
    /// `robot = URL`, or any client learning from pixels). 0: the state.
    #[arg(long, default_value_t = 0)]
    pub pixels: usize,
    /// With --pixels: robot steps per served step, with the same action (rewards summed).
    #[arg(long, default_value_t = 2)]
    pub action_repeat: usize,
    /// Address to listen on (port 0 picks a free port; the address is printed on stdout).
    /// Loopback only unless TLS is configured (--tls-cert, --tls-key) or --insecure is given.
    #[arg(long, default_value = "127.0.0.1:0")]
    pub listen: String,
    /// Worlds (live simulations) at once from all clients; CreateWorld beyond it is refused
    /// with RESOURCE_EXHAUSTED and the worlds already made go on.
    #[arg(long, default_value_t = coadapt_env_rpc::ServerLimits::default().max_worlds)]
    pub max_worlds: usize,
    /// TCP connections from one remote host at once; more are closed as they are accepted.
    #[arg(long, default_value_t = coadapt_env_rpc::ServerLimits::default().max_connections_per_peer)]
    pub max_connections_per_peer: usize,
    /// TCP connections at once from all hosts.
    #[arg(long, default_value_t = coadapt_env_rpc::ServerLimits::default().max_connections)]
    pub max_connections: usize,
    /// TLS and tokens (actors and operators may step the robot).
    #[command(flatten)]
    pub security: crate::security::SecurityArgs,
}

/// Serves until Ctrl-C or SIGTERM.
pub fn run(args: EnvServeArgs) -> anyhow::Result<()> {
    let name = args.env.clone();
    // Fail now, not at the first CreateWorld, on an unknown robot.
    if name != "planar" {
        coadapt_robots::make(&name)?;
    }
    let security = crate::security::from_args(&args.security);
    let auth = security.server_auth()?;
    if args.pixels > 1024 {
        anyhow::bail!("--pixels {}: at most 1024 (each observation is 3 x SIDE x SIDE values)", args.pixels);
    }
    if args.pixels > 0 {
        let px = coadapt_core::PixelsConfig { width: args.pixels, height: args.pixels, frames: 1, action_repeat: args.action_repeat };
        // Fail now on a robot that cannot be drawn or a bad camera.
        coadapt_core::Pixels::new(coadapt_robots::make(&name)?, px).context("--pixels")?;
    }
    let (pixels, repeat) = (args.pixels, args.action_repeat);
    // Each world is the robot in the world its CreateWorld settings describe (`friction`, ...:
    // a client's `[world]`); the planar benchmark has none.
    let factory: coadapt_env_rpc::EnvFactory = if name == "planar" {
        // The policy-search benchmark as a robot (`coadapt search` with `robot = URL`).
        coadapt_env_rpc::plain(|| Ok(Box::new(coadapt_policy_search::PlanarEnv::default()) as Box<dyn coadapt_core::Env>))
    } else {
        std::sync::Arc::new(move |settings: &coadapt_env_rpc::WorldSettings| {
            let world = coadapt_robots::World::from_settings(settings)?;
            let robot = coadapt_robots::make_in(&name, &world).map_err(|e| e.to_string())?;
            if pixels == 0 {
                return Ok(robot);
            }
            let px = coadapt_core::PixelsConfig { width: pixels, height: pixels, frames: 1, action_repeat: repeat };
            Ok(Box::new(coadapt_core::Pixels::new(robot, px).map_err(|e| e.to_string())?) as Box<dyn coadapt_core::Env>)
        })
    };
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().context("starting the runtime")?;
    rt.block_on(async move {
        let want: std::net::SocketAddr =
            args.listen.parse().with_context(|| format!("--listen: {:?} is not an address like 127.0.0.1:50051", args.listen))?;
        coadapt_fleet::check_listen("--listen", want, &security)?;
        let listener = tokio::net::TcpListener::bind(want).await.with_context(|| format!("listening on {}", args.listen))?;
        let addr = listener.local_addr()?;
        coadapt_log::logln!("env-serve: serving {} over dm_env_rpc on {addr} (Ctrl-C stops)", args.env);
        coadapt_log::print_stdout_line(&format!("dm-env-rpc://{addr}"));
        let (stopped_tx, stopped_rx) = tokio::sync::oneshot::channel::<()>();
        if args.max_worlds == 0 || args.max_connections_per_peer == 0 || args.max_connections == 0 {
            anyhow::bail!("--max-worlds, --max-connections-per-peer and --max-connections must be at least 1");
        }
        let limits = coadapt_env_rpc::ServerLimits {
            max_worlds: args.max_worlds,
            max_connections_per_peer: args.max_connections_per_peer,
            max_connections: args.max_connections,
        };
        let (handle, served) = coadapt_env_rpc::server::serve(listener, factory, &auth, limits, async {
            let _ = stopped_rx.await;
        });
        let server = tokio::spawn(served);
        wait_for_signal().await;
        let r = handle.refusals();
        coadapt_log::logln!(
            "env-serve: stopping (open streams get {GRACE:?} to finish); refused: {} worlds beyond --max-worlds, {} connections beyond --max-connections-per-peer, {} beyond --max-connections",
            r.worlds, r.connections_per_peer, r.connections_total
        );
        let _ = stopped_tx.send(());
        // Clients that keep their stream open would hold a graceful shutdown for ever.
        match tokio::time::timeout(GRACE, server).await {
            Ok(Ok(r)) => r.context("serving dm_env_rpc"),
            Ok(Err(e)) => Err(anyhow::anyhow!("the server task failed: {e}")),
            Err(_) => {
                coadapt_log::logln!("env-serve: clients still connected after {GRACE:?}; closing their streams");
                Ok(())
            }
        }
    })?;
    Ok(())
}

/// How long open streams may take to finish after Ctrl-C or SIGTERM.
const GRACE: std::time::Duration = std::time::Duration::from_secs(2);

pub(crate) async fn wait_for_signal() {
    let ctrl_c = tokio::signal::ctrl_c();
    #[cfg(unix)]
    {
        let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()).ok();
        let term = async {
            match term.as_mut() {
                Some(t) => {
                    t.recv().await;
                }
                None => std::future::pending().await,
            }
        };
        tokio::select! { _ = ctrl_c => {}, _ = term => {} }
    }
    #[cfg(not(unix))]
    let _ = ctrl_c.await;
}
