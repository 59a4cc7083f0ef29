//! The local fleet's process supervisor: one learner and the other roles (an optimiser,
//! actors) as processes of this binary, restarted when they crash within a windowed budget.
//!
//! A learner that crashes takes the fleet down and starts it again with its resume flag (from
//! its newest snapshot); another role that crashes is started again alone. A role that exits
//! with a code a restart cannot mend ([`exit`]) stops the fleet, saying why. Ctrl-C is passed on
//! once to every role (each runs in a process group of its own), and each role stops by itself
//! when the supervisor dies ([`stop_when_orphaned`]).

use std::fs::File;
use std::os::unix::process::{CommandExt, ExitStatusExt};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;

use crate::SetupError;

/// Exit codes that tell a supervisor whether starting a process again can help. Most failures
/// are worth a restart (a crash, a lost connection); a full disk or a bad config fails the same
/// way every time, and restarting only hides the cause under ten copies of it.
pub mod exit {
    /// `EX_CANTCREAT`: the disk holding the run directory is full, over quota or read-only.
    pub const DISK: u8 = 73;
    /// `EX_CONFIG`: the configuration is invalid.
    pub const CONFIG: u8 = 78;

    /// Whether an I/O error of this kind means the disk cannot take what is written (full, over
    /// quota, read-only): no retry can mend it.
    pub fn is_disk_full(kind: std::io::ErrorKind) -> bool {
        use std::io::ErrorKind;
        matches!(kind, ErrorKind::StorageFull | ErrorKind::QuotaExceeded | ErrorKind::ReadOnlyFilesystem)
    }

    /// An error that can say whether a restart could mend it: `Some(code)` ([`DISK`],
    /// [`CONFIG`]) when it cannot. A binary maps its error to an exit code with it, and the
    /// supervisor reads the code.
    ///
    /// Every error an application converts with `?` says it (the default: a restart may mend
    /// it); the libraries below the fleet, which do not know this trait, say it here.
    pub trait ExitCode {
        fn exit_code(&self) -> Option<u8> {
            None
        }
    }

    impl ExitCode for crate::SetupError {
        fn exit_code(&self) -> Option<u8> {
            match self {
                crate::SetupError::Config(_) => Some(CONFIG),
                e if e.io_kind().is_some_and(is_disk_full) => Some(DISK),
                _ => None,
            }
        }
    }

    impl ExitCode for std::io::Error {
        fn exit_code(&self) -> Option<u8> {
            is_disk_full(self.kind()).then_some(DISK)
        }
    }

    /// Why a process that exited with `code` is not started again (`None`: it may be).
    pub fn not_transient(code: Option<i32>) -> Option<&'static str> {
        match u8::try_from(code?).ok()? {
            DISK => Some("the disk holding the run directory is full (or over quota, or read-only)"),
            CONFIG => Some("its configuration is invalid"),
            _ => None,
        }
    }
}

/// The environment variable that tells a role the pid of the supervisor that started it.
pub const SUPERVISOR_PID_ENV: &str = "COADAPT_SUPERVISOR_PID";

/// A role started by a supervisor stops (sets `flag`, as on Ctrl-C: snapshot kept) when the
/// supervisor dies. Each role has a process group of its own, so a SIGKILL of the supervisor's
/// group (an OOM killer, a closed terminal) used to leave the roles running on: a learner still
/// writing the run that `--resume` then started again beside it. Polled from a thread
/// (`getppid` changes when the parent dies); no unsafe `pre_exec`.
pub fn stop_when_orphaned(flag: &Arc<AtomicBool>) {
    let Some(supervisor) = std::env::var(SUPERVISOR_PID_ENV).ok().and_then(|v| v.parse::<i32>().ok()) else { return };
    if nix::unistd::getppid().as_raw() != supervisor {
        return; // not (or no longer) the supervisor's child: a role started by hand
    }
    let f = flag.clone();
    let _ = std::thread::Builder::new().name("orphan-watch".into()).spawn(move || {
        loop {
            std::thread::sleep(Duration::from_millis(250));
            if nix::unistd::getppid().as_raw() != supervisor {
                if !f.swap(true, Ordering::SeqCst) {
                    coadapt_log::logln!("the supervisor (pid {supervisor}) has gone: stopping and keeping what is written");
                }
                return;
            }
        }
    });
}

/// How long the other processes get to leave after the learner is done.
const GRACE: Duration = Duration::from_secs(10);

/// One role to start: `exe args...`, its output appended to `log` (`None`: this terminal).
#[derive(Clone, Debug)]
pub struct Role {
    pub name: String,
    pub args: Vec<String>,
    pub log: Option<PathBuf>,
}

/// What the supervisor runs and how far it goes to keep it running.
pub struct Plan {
    /// The binary (resolved once: a rebuild during a long run replaces the file, and a restart
    /// should still find a binary at this path).
    pub exe: PathBuf,
    pub learner: Role,
    /// Appended to the learner's arguments when it starts again after a crash.
    pub resume_arg: String,
    pub others: Vec<Role>,
    /// Restarts of one role allowed within `window`; one more and it stays down (the learner:
    /// the run stops).
    pub max_restarts: usize,
    pub window: Duration,
    /// Names the fleet in the line that lists its processes.
    pub name: String,
    /// Where the roles' logs are (for messages).
    pub logs: PathBuf,
    /// What a user runs to continue once a not-transient failure is put right.
    pub resume_hint: String,
    /// Run before the fleet starts again (shared memory: clean what the dead left).
    pub before_restart: Box<dyn Fn() + Send>,
}

impl std::fmt::Debug for Plan {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Plan").field("learner", &self.learner).field("others", &self.others).finish_non_exhaustive()
    }
}

/// Why the supervised fleet did not finish well.
#[derive(Debug, thiserror::Error)]
pub enum SuperviseError {
    /// A role failed in a way a restart cannot mend; `code` is its exit code.
    #[error("{message}")]
    NotTransient { code: u8, message: String },
    /// The learner ended badly, its restarts used up.
    #[error("the learner ended with {status} (its output is above; actor and optimiser logs in {logs})")]
    Learner { status: String, logs: String },
    #[error(transparent)]
    Setup(#[from] SetupError),
}

impl exit::ExitCode for SuperviseError {
    fn exit_code(&self) -> Option<u8> {
        match self {
            Self::NotTransient { code, .. } => Some(*code),
            Self::Learner { .. } => None,
            Self::Setup(e) => e.exit_code(),
        }
    }
}

struct Proc {
    role: Role,
    child: Child,
    started: Instant,
    /// The process has ended for good (finished, or could not be started again).
    ended: bool,
}

fn spawn(exe: &Path, role: &Role) -> Result<Proc, SetupError> {
    let mut cmd = Command::new(exe);
    cmd.args(&role.args).stdin(Stdio::null());
    // A process group of its own: a terminal's Ctrl-C reaches only the supervisor, which passes
    // it on exactly once (a second SIGINT means "abort now" to a role).
    cmd.process_group(0);
    cmd.env(SUPERVISOR_PID_ENV, std::process::id().to_string());
    if let Some(log) = &role.log {
        let what = || format!("opening {}", log.display());
        let f = File::options().create(true).append(true).open(log).map_err(SetupError::io(what()))?;
        cmd.stdout(f.try_clone().map_err(SetupError::io(what()))?).stderr(f);
    }
    let child = cmd.spawn().map_err(SetupError::io(format!("starting {}", role.name)))?;
    Ok(Proc { role: role.clone(), child, started: Instant::now(), ended: false })
}

fn signal(p: &Proc, sig: Signal) {
    if let Ok(pid) = i32::try_from(p.child.id()) {
        // The process may have exited already; nothing to do then.
        let _ = kill(Pid::from_raw(pid), sig);
    }
}

/// `exit code 3`, `signal 9`.
pub fn describe(s: ExitStatus) -> String {
    match (s.code(), s.signal()) {
        (Some(c), _) => format!("exit code {c}"),
        (None, Some(sig)) => format!("signal {sig}"),
        _ => "unknown status".into(),
    }
}

/// Restart times of one process, for the windowed budget.
#[derive(Debug, Default)]
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

fn start(plan: &Plan, resume: bool) -> Result<(Proc, Vec<Proc>), SetupError> {
    let mut learner = plan.learner.clone();
    if resume {
        learner.args.push(plan.resume_arg.clone());
    }
    let learner = spawn(&plan.exe, &learner)?;
    let others = plan.others.iter().map(|r| spawn(&plan.exe, r)).collect::<Result<Vec<_>, _>>()?;
    coadapt_log::logln!(
        "fleet {}: learner pid {}, {}; logs in {}",
        plan.name,
        learner.child.id(),
        others.iter().map(|p| format!("{} pid {}", p.role.name, p.child.id())).collect::<Vec<_>>().join(", "),
        plan.logs.display()
    );
    Ok((learner, others))
}

/// Starts the fleet of `plan` (the learner resuming with `resume`) and supervises it until the
/// learner is done; `shutdown` (Ctrl-C) is passed on to every role once.
pub fn supervise(plan: &Plan, shutdown: &AtomicBool, resume: bool) -> Result<(), SuperviseError> {
    let (mut learner, mut others) = start(plan, resume)?;
    let mut budgets: std::collections::HashMap<String, Budget> = Default::default();
    let mut interrupted = false;
    // A role that failed in a way a restart cannot mend: the fleet is stopped.
    let mut fatal: Option<SuperviseError> = None;
    let not_transient = |name: &str, s: ExitStatus, why: &str| SuperviseError::NotTransient {
        code: s.code().and_then(|c| u8::try_from(c).ok()).unwrap_or(1),
        message: format!(
            "the {name} ended with {} because {why}; it is not started again (it would fail the same way). Its error is {}; \
             once that is put right, `{}` continues from the newest snapshot",
            describe(s),
            if name == "learner" { "above".to_string() } else { format!("in {}", plan.logs.display()) },
            plan.resume_hint
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
            Ok(Some(s)) if !s.success() && !interrupted && exit::not_transient(s.code()).is_some() => {
                let why = exit::not_transient(s.code()).unwrap_or_default();
                break Err(not_transient("learner", s, why));
            }
            Ok(Some(s))
                if !s.success() && !interrupted && budgets.entry("learner".into()).or_default().allow(plan.max_restarts, plan.window) =>
            {
                coadapt_log::logln!(
                    "fleet: the learner (pid {}) ended with {}; stopping the fleet and starting it again from the newest snapshot",
                    learner.child.id(),
                    describe(s)
                );
                for p in others.iter_mut() {
                    stop(p, Duration::from_secs(2));
                }
                (plan.before_restart)();
                std::thread::sleep(Duration::from_millis(500));
                match start(plan, true) {
                    Ok((l, o)) => (learner, others) = (l, o),
                    Err(e) => {
                        coadapt_log::logln!("fleet: starting the fleet again failed");
                        break Err(e.into());
                    }
                }
                continue;
            }
            Ok(Some(s)) => break Ok(s),
            Ok(None) => {}
            Err(e) => break Err(SetupError::Io { what: "watching the learner".into(), error: e }.into()),
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
            if let Some(why) = exit::not_transient(s.code()) {
                // The learner is stopped as on Ctrl-C (its snapshot taken if it can be), then
                // the run ends with this role's reason.
                let e = not_transient(&p.role.name, s, why);
                coadapt_log::logln!("fleet: {e}; stopping the fleet");
                fatal = Some(e);
                p.ended = true;
                interrupted = true;
                for q in std::iter::once(&learner).chain(others.iter()) {
                    signal(q, Signal::SIGINT);
                }
                break;
            }
            if !budgets.entry(p.role.name.clone()).or_default().allow(plan.max_restarts, plan.window) {
                coadapt_log::logln!(
                    "fleet: {} ended with {}, its {} restart(s) in {:?} are used up (fleet.max-restarts); it stays down",
                    p.role.name,
                    describe(s),
                    plan.max_restarts,
                    plan.window
                );
                p.ended = true;
                continue;
            }
            coadapt_log::logln!(
                "fleet: {} (pid {}) ended with {}; starting it again (log {})",
                p.role.name,
                p.child.id(),
                describe(s),
                p.role.log.as_ref().map_or("-".into(), |l| l.display().to_string())
            );
            if p.started.elapsed() < Duration::from_secs(2) {
                std::thread::sleep(Duration::from_secs(1));
            }
            match spawn(&plan.exe, &p.role) {
                Ok(new) => *p = new,
                Err(e) => {
                    coadapt_log::logln!("fleet: {e}; {} stays down", p.role.name);
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
    if let Some(e) = fatal {
        return Err(e);
    }
    let status = status?;
    if !status.success() {
        return Err(SuperviseError::Learner { status: describe(status), logs: plan.logs.display().to_string() });
    }
    Ok(())
}
