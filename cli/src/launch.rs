//! `coadapt run` as a local fleet: the learner, the design optimiser and N actors as separate
//! processes of this binary (`coadapt learner|optimizer|actor`), supervised: a crashed actor or
//! optimiser is started again (the learner re-issues the episode it had), Ctrl-C or SIGTERM is
//! passed on once to every process, and when the learner is done the others are given a few
//! seconds to leave before they are stopped. Shared memory left by killed processes is cleaned
//! up when the fleet starts and when it ends.

use std::fs::File;
use std::os::unix::process::{CommandExt, ExitStatusExt};
use std::path::Path;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;

use crate::fleet::{TransportKind, clean_stale};
use crate::run::RunConfig;

/// How long the other processes get to leave after the learner is done.
const GRACE: Duration = Duration::from_secs(10);

struct Proc {
    name: String,
    args: Vec<String>,
    log: Option<std::path::PathBuf>,
    child: Child,
    started: Instant,
    /// The process has ended for good (finished, or could not be started again).
    ended: bool,
}

fn spawn(exe: &Path, name: &str, args: &[String], log: Option<&Path>) -> anyhow::Result<Proc> {
    let mut cmd = Command::new(exe);
    cmd.args(args).stdin(Stdio::null());
    // A process group of its own: a terminal's Ctrl-C reaches only the supervisor, which passes
    // it on exactly once (a second SIGINT means "abort now" to a role).
    cmd.process_group(0);
    // Each role stops when this supervisor dies (crate::progress::stop_when_orphaned).
    cmd.env(crate::progress::SUPERVISOR_PID_ENV, std::process::id().to_string());
    if let Some(log) = log {
        let f = File::options().create(true).append(true).open(log).with_context(|| format!("opening {}", log.display()))?;
        cmd.stdout(f.try_clone()?).stderr(f);
    }
    let child = cmd.spawn().with_context(|| format!("starting {name}"))?;
    Ok(Proc { name: name.into(), args: args.to_vec(), log: log.map(Path::to_path_buf), child, started: Instant::now(), ended: false })
}

fn signal(p: &Proc, sig: Signal) {
    if let Ok(pid) = i32::try_from(p.child.id()) {
        // The process may have exited already; nothing to do then.
        let _ = kill(Pid::from_raw(pid), sig);
    }
}

fn describe(s: ExitStatus) -> String {
    match (s.code(), s.signal()) {
        (Some(c), _) => format!("exit code {c}"),
        (None, Some(sig)) => format!("signal {sig}"),
        _ => "unknown status".into(),
    }
}

/// Restart times of one process, for the windowed budget.
#[derive(Default)]
struct Budget {
    restarts: Vec<Instant>,
}

impl Budget {
    /// Records a restart if the budget allows one more within the window.
    fn allow(&mut self, max: usize, window: Duration) -> bool {
        self.restarts.retain(|t| t.elapsed() < window);
        if self.restarts.len() >= max {
            return false;
        }
        self.restarts.push(Instant::now());
        true
    }
}

/// Stops `p` (SIGTERM, then SIGKILL after `grace`) and reaps it.
fn stop(p: &mut Proc, grace: Duration) {
    if matches!(p.child.try_wait(), Ok(None)) {
        signal(p, Signal::SIGTERM);
        let until = Instant::now() + grace;
        while matches!(p.child.try_wait(), Ok(None)) && Instant::now() < until {
            std::thread::sleep(Duration::from_millis(50));
        }
        let _ = p.child.kill();
    }
    let _ = p.child.wait();
}

/// The shared-memory fleet of this start. Every start gets its own name
/// (`coadapt-start-PID`): a run killed whole (SIGKILL of its process group, an OOM kill, a
/// reboot) leaves its channels behind with dead owners, and a resume that reopened them under
/// the old name failed ("ExceedsMaxSupportedSubscribers"); the name a previous start chose
/// comes back from the run's config.toml, so a generated name (this form, or `coadapt-PID` of
/// earlier versions) is replaced, never reused. A name the operator chose (to attach processes of
/// their own) is kept, but refused while another fleet's channels of that name exist.
pub fn shm_fleet_name(configured: &str, pid: u32) -> anyhow::Result<String> {
    let generated = |n: &str| {
        let digits = n.strip_prefix("coadapt-start-").or_else(|| n.strip_prefix("coadapt-"));
        digits.is_some_and(|d| !d.is_empty() && d.bytes().all(|b| b.is_ascii_digit()))
    };
    if configured.is_empty() || generated(configured) {
        return Ok(format!("coadapt-start-{pid}"));
    }
    match coadapt_shm::fleet_services(configured) {
        Ok(left) if !left.is_empty() => bail!(
            "fleet.name = {configured:?}: another fleet's shared-memory channels of that name exist ({}); stop that fleet, \
             or leave fleet.name empty so that each start gets a name of its own",
            left.join(", ")
        ),
        _ => Ok(configured.to_string()),
    }
}

/// Launches the fleet for `cfg` into `dir` (continuing the run there with `resume`) and
/// supervises it until the learner is done. A learner that crashes is started again with
/// `--resume` from its newest snapshot, the other processes with it (actors hold nothing; the
/// optimiser continues from its state file), within `fleet.max-restarts` per
/// `fleet.restart-window-secs`.
pub fn launch(cfg: &RunConfig, dir: &Path, shutdown: &AtomicBool, resume: bool) -> anyhow::Result<()> {
    let mut cfg = cfg.clone();
    match cfg.fleet.transport {
        TransportKind::Shm => {
            clean_stale();
            cfg.fleet.name = shm_fleet_name(&cfg.fleet.name, std::process::id())?;
        }
        TransportKind::Grpc => {
            // A free loopback port for this fleet.
            let port = std::net::TcpListener::bind("127.0.0.1:0").and_then(|l| l.local_addr()).context("finding a free port")?.port();
            cfg.fleet.listen = format!("127.0.0.1:{port}");
            cfg.fleet.connect = format!("http://127.0.0.1:{port}");
        }
        TransportKind::InProcess => bail!("fleet.transport: in-process runs without a fleet"),
    }
    let window = Duration::try_from_secs_f64(cfg.fleet.restart_window_secs)
        .ok()
        .filter(|d| !d.is_zero())
        .with_context(|| format!("fleet.restart-window-secs: {} is not a positive number of seconds", cfg.fleet.restart_window_secs))?;
    let logs = dir.join("logs");
    std::fs::create_dir_all(&logs).with_context(|| format!("creating {}", logs.display()))?;
    let config = dir.join("fleet.toml");
    std::fs::write(&config, toml::to_string(&cfg)?).with_context(|| format!("writing {}", config.display()))?;
    let config = config.display().to_string();
    let common = ["--config".to_string(), config.clone(), "--transport".into(), cfg.fleet.transport.name().into()];

    let mut learner_args = vec!["learner".to_string()];
    learner_args.extend(common.iter().cloned());
    learner_args.extend(["--out".into(), dir.display().to_string()]);
    // Resolved once: a rebuild during a long run replaces the file, and a restart should still
    // find a binary at this path.
    let exe = std::env::current_exe().context("finding the coadapt binary")?;
    let mut opt_args = vec!["optimizer".to_string()];
    opt_args.extend(common.iter().cloned());
    opt_args.extend(["--state-dir".into(), crate::resume::optimizer_state_dir(dir).display().to_string()]);
    let start_fleet = |resume: bool| -> anyhow::Result<(Proc, Vec<Proc>)> {
        let mut args = learner_args.clone();
        if resume {
            args.push("--resume".into());
        }
        let learner = spawn(&exe, "learner", &args, None)?;
        let mut others = vec![spawn(&exe, "optimizer", &opt_args, Some(&logs.join("optimizer.log")))?];
        for i in 0..cfg.actors {
            let mut a = vec!["actor".to_string()];
            a.extend(common.iter().cloned());
            a.extend(["--id".into(), i.to_string()]);
            others.push(spawn(&exe, &format!("actor {i}"), &a, Some(&logs.join(format!("actor-{i}.log"))))?);
        }
        coadapt_log::logln!(
            "fleet {}: learner pid {}, {}; logs in {}",
            if cfg.fleet.name.is_empty() { cfg.fleet.connect.as_str() } else { cfg.fleet.name.as_str() },
            learner.child.id(),
            others.iter().map(|p| format!("{} pid {}", p.name, p.child.id())).collect::<Vec<_>>().join(", "),
            logs.display()
        );
        Ok((learner, others))
    };
    let (mut learner, mut others) = start_fleet(resume)?;

    let mut budgets: std::collections::HashMap<String, Budget> = Default::default();
    let mut interrupted = false;
    // A role that failed in a way a restart cannot mend (exit.rs): the fleet is stopped.
    let mut fatal: Option<crate::exit::NotTransient> = None;
    let not_transient = |name: &str, s: ExitStatus, why: &str| crate::exit::NotTransient {
        code: s.code().and_then(|c| u8::try_from(c).ok()).unwrap_or(1),
        message: format!(
            "the {name} ended with {} because {why}; it is not started again (it would fail the same way). Its error is {}; \
             once that is put right, `coadapt run --resume {}` continues from the newest snapshot",
            describe(s),
            if name == "learner" { "above".to_string() } else { format!("in {}", logs.display()) },
            dir.display()
        ),
    };
    let status = loop {
        if shutdown.load(Ordering::Relaxed) && !interrupted {
            interrupted = true;
            for p in std::iter::once(&learner).chain(&others) {
                signal(p, Signal::SIGINT);
            }
        }
        match learner.child.try_wait() {
            Ok(Some(s)) if !s.success() && !interrupted && crate::exit::not_transient(s.code()).is_some() => {
                let why = crate::exit::not_transient(s.code()).unwrap_or_default();
                break Err(anyhow::Error::new(not_transient("learner", s, why)));
            }
            Ok(Some(s))
                if !s.success() && !interrupted && budgets.entry("learner".into()).or_default().allow(cfg.fleet.max_restarts, window) =>
            {
                coadapt_log::logln!(
                    "fleet: the learner (pid {}) ended with {}; stopping the fleet and starting it again from the newest snapshot",
                    learner.child.id(),
                    describe(s)
                );
                for p in others.iter_mut() {
                    stop(p, Duration::from_secs(2));
                }
                if cfg.fleet.transport == TransportKind::Shm {
                    clean_stale();
                }
                std::thread::sleep(Duration::from_millis(500));
                match start_fleet(true) {
                    Ok((l, o)) => (learner, others) = (l, o),
                    Err(e) => break Err(e.context("starting the fleet again")),
                }
                continue;
            }
            Ok(Some(s)) => break Ok(s),
            Ok(None) => {}
            Err(e) => break Err(anyhow::Error::new(e).context("watching the learner")),
        }
        for p in others.iter_mut() {
            let Ok(Some(s)) = p.child.try_wait() else { continue };
            // A role that ends well has seen the learner finish; one that fails while the
            // learner still runs has crashed: start it again, after a pause if it failed
            // straight away.
            if s.success() || p.ended || interrupted {
                p.ended = true;
                continue;
            }
            if let Some(why) = crate::exit::not_transient(s.code()) {
                // The learner is stopped as on Ctrl-C (its snapshot taken if it can be), then
                // the run ends with this role's reason.
                let e = not_transient(&p.name, s, why);
                coadapt_log::logln!("fleet: {e}; stopping the fleet");
                fatal = Some(e);
                p.ended = true;
                interrupted = true;
                for q in std::iter::once(&learner).chain(others.iter()) {
                    signal(q, Signal::SIGINT);
                }
                break;
            }
            if !budgets.entry(p.name.clone()).or_default().allow(cfg.fleet.max_restarts, window) {
                coadapt_log::logln!(
                    "fleet: {} ended with {}, its {} restart(s) in {:?} are used up (fleet.max-restarts); it stays down",
                    p.name,
                    describe(s),
                    cfg.fleet.max_restarts,
                    window
                );
                p.ended = true;
                continue;
            }
            coadapt_log::logln!(
                "fleet: {} (pid {}) ended with {}; starting it again (log {})",
                p.name,
                p.child.id(),
                describe(s),
                p.log.as_ref().map_or("-".into(), |l| l.display().to_string())
            );
            if p.started.elapsed() < Duration::from_secs(2) {
                std::thread::sleep(Duration::from_secs(1));
            }
            match spawn(&exe, &p.name.clone(), &p.args.clone(), p.log.as_deref()) {
                Ok(new) => *p = new,
                Err(e) => {
                    coadapt_log::logln!("fleet: {e:#}; {} stays down", p.name);
                    p.ended = true;
                }
            }
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    if status.is_err() {
        others.push(learner);
    }
    let until = Instant::now() + GRACE;
    for p in others.iter_mut() {
        while matches!(p.child.try_wait(), Ok(None)) && Instant::now() < until {
            std::thread::sleep(Duration::from_millis(50));
        }
        if matches!(p.child.try_wait(), Ok(None)) {
            signal(p, Signal::SIGTERM);
            std::thread::sleep(Duration::from_millis(200));
            let _ = p.child.kill();
            let _ = p.child.wait();
        }
    }
    if cfg.fleet.transport == TransportKind::Shm {
        clean_stale();
        match coadapt_shm::fleet_services(&cfg.fleet.name) {
            Ok(left) if !left.is_empty() => coadapt_log::logln!("warning: shared memory of the fleet left behind: {left:?}"),
            Ok(_) => {}
            Err(e) => coadapt_log::logln!("warning: listing the fleet's shared memory: {e}"),
        }
    }
    if let Some(e) = fatal {
        return Err(e.into());
    }
    let status = status?;
    if !status.success() {
        bail!("the learner ended with {} (its output is above; actor and optimiser logs in {})", describe(status), logs.display());
    }
    Ok(())
}
