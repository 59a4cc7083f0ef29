//! `scripts/campaign.sh`, the queue runner every archived run of docs/campaign/results went
//! through, driven with a fake `coadapt` (a Python script that writes a run's files and waits
//! for a hold file to vanish, or for SIGINT, as the real binary snapshots and exits): one pid
//! file per queue, a second start of a running queue refused, `--stop` stops it and its run
//! reports itself interrupted (not archived), the queue started again starts the run over (no
//! snapshot) and archives it, and a third start skips what is done; `scripts/campaign_status.py`
//! says at each stage which lines run, stopped, wait, are copied or are archived, and the episodes left.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("the workspace root").to_path_buf()
}

const FAKE: &str = r#"#!/usr/bin/env python3
# `run --config C --seed S [--designs K] --out D` writes 2 episodes per design (return 10 d + e,
# or FAKE_SHIFT more), the files a run leaves and, given --designs, a snapshot at its end;
# `run --resume D` goes on; both wait while FAKE_HOLD exists and stop on SIGINT, as a run does.
import json, os, signal, sys, time
args = sys.argv[1:]
out = args[args.index("--out") + 1] if "--out" in args else args[args.index("--resume") + 1]
designs = int(args[args.index("--designs") + 1]) if "--designs" in args else 1
os.makedirs(out, exist_ok=True)
if "--config" in args:
    open(os.path.join(out, "config.toml"), "w").write(open(args[args.index("--config") + 1]).read())
    open(os.path.join(out, "designs.csv"), "w").write("designs.csv\n")
    shift = int(os.environ.get("FAKE_SHIFT", "0"))
    rows = [f"{d},{e},{10 * d + e + shift},{10 * d + e}" for d in range(designs) for e in range(2)]
    open(os.path.join(out, "episodes.csv"), "w").write("design,episode,return,eval_return\n" + "\n".join(rows) + "\n")
    if "--designs" in args:
        snap = os.path.join(out, "snapshots", f"snap-{designs:08}")
        os.makedirs(snap, exist_ok=True)
        json.dump({"values": {"progress": {"design": designs, "in_design": None}}}, open(os.path.join(snap, "state.json"), "w"))
stopped = []
# FAKE_HANDLER_DELAY seconds without a SIGINT handler (Python's own put back to the default),
# as a Rust run before it installs its own: a SIGINT then ends it at once, as failed.
signal.signal(signal.SIGINT, signal.SIG_DFL)
time.sleep(float(os.environ.get("FAKE_HANDLER_DELAY", "0")))
signal.signal(signal.SIGINT, lambda *_: stopped.append(1))
hold = os.environ.get("FAKE_HOLD", "")
# While it holds, a file FAKE_HOLD.snap makes it write a snapshot (and delete the file), and a
# file FAKE_HOLD.done-NAME (NAME: the run directory's) ends the run named.
done = hold + ".done-" + os.path.basename(os.path.normpath(out))
while hold and os.path.exists(hold) and not os.path.exists(done) and not stopped:
    if os.path.exists(hold + ".snap"):
        snap = os.path.join(out, "snapshots", f"snap-{time.time_ns():020}")
        os.makedirs(snap)
        os.remove(hold + ".snap")
    time.sleep(0.05)
print(json.dumps({"interrupted": bool(stopped), "out": out}))
"#;

struct Tree {
    root: PathBuf,
    hold: PathBuf,
}

impl Tree {
    /// A tree of its own per test (the tests of this file run at once, in one process).
    fn new(test: &str) -> Self {
        let base = std::env::temp_dir().join(format!("coadapt-campaign-script-{test}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&base);
        // campaign.sh works in its script's parent and keeps runs/ beside it (../runs).
        let root = base.join("checkout");
        std::fs::create_dir_all(root.join("scripts")).expect("temp tree");
        for script in ["campaign.sh", "campaign_status.py", "fork_run.sh", "config_with.py"] {
            std::fs::copy(repo().join("scripts").join(script), root.join("scripts").join(script)).expect("copying the scripts");
        }
        std::fs::write(root.join("fake-coadapt"), FAKE).expect("the fake binary");
        std::fs::write(root.join("q.queue"), "# two runs\nalpha cfg.toml 1\nbeta  cfg.toml 2\n").expect("the queue");
        // Two designs: 3 episodes of the initial one, then 2 (5 in all; the fake writes 2 rows).
        let cfg = "[schedule]\ndesigns = 2\ninitial-designs = [[1.0]]\ninitial-episodes = 3\nepisodes-per-design = 2\n";
        std::fs::write(root.join("cfg.toml"), cfg).expect("a config");
        std::fs::create_dir_all(root.join("docs/campaign")).expect("docs");
        let chmod = Command::new("chmod").arg("+x").arg(root.join("fake-coadapt")).status().expect("chmod");
        assert!(chmod.success());
        let hold = base.join("hold");
        Tree { root, hold }
    }

    fn campaign(&self, args: &[&str]) -> Command {
        let mut c = Command::new("bash");
        c.arg(self.root.join("scripts/campaign.sh"))
            .args(args)
            .current_dir(&self.root)
            .env("BIN", self.root.join("fake-coadapt"))
            .env("FAKE_HOLD", &self.hold);
        c
    }

    fn run(&self, args: &[&str]) -> Output {
        self.campaign(args).output().expect("running campaign.sh")
    }

    /// `scripts/campaign_status.py q.queue` run in the tree.
    fn status(&self) -> String {
        let o = Command::new("python3")
            .arg("scripts/campaign_status.py")
            .arg("q.queue")
            .current_dir(&self.root)
            .output()
            .expect("running campaign_status.py");
        assert!(o.status.success(), "{}", text(&o));
        text(&o)
    }

    /// An archived run `src-seed1` of `designs` designs, 2 episodes each, with the rows the
    /// fake writes (its run directory is not there).
    fn archive_source(&self, designs: usize) {
        let arch = self.path("docs/campaign/results/src-seed1");
        std::fs::create_dir_all(&arch).expect("archive");
        let rows: String = (0..designs).flat_map(|d| (0..2).map(move |e| format!("{d},{e},{},{}\n", 10 * d + e, 10 * d + e))).collect();
        std::fs::write(arch.join("episodes.csv"), format!("design,episode,return,eval_return\n{rows}")).expect("rows");
        std::fs::write(arch.join("config.toml"), format!("[schedule]\ndesigns = {designs}\n")).expect("config");
        std::fs::write(arch.join("summary.json"), format!("{{\"interrupted\": false, \"designs\": {designs}}}")).expect("summary");
    }

    fn path(&self, p: &str) -> PathBuf {
        self.root.join(p)
    }
}

/// A failing assertion leaves no campaign behind: the hold goes (the fake run ends) and the
/// campaign is asked to stop.
struct Running(std::process::Child, PathBuf);

impl Running {
    /// The campaign's exit code, once it has ended (a minute at the most).
    fn exit_code(&mut self) -> Option<i32> {
        let mut status = None;
        wait_for("the stopped campaign to end", || {
            status = self.0.try_wait().expect("polling the campaign");
            status.is_some()
        });
        status.and_then(|s| s.code())
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.1);
        let _ = Command::new("kill").arg("-TERM").arg(self.0.id().to_string()).status();
        let _ = self.0.wait();
    }
}

fn text(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

/// Whether process PID runs: not gone, and not a zombie (left to a container's init that does
/// not reap).
fn alive(pid: &str) -> bool {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    stat.rsplit(')').next().and_then(|rest| rest.split_whitespace().next()).is_some_and(|s| s != "Z")
}

fn wait_for(what: &str, mut done: impl FnMut() -> bool) {
    let t = Instant::now();
    while !done() {
        assert!(t.elapsed() < Duration::from_secs(60), "waited a minute for {what}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn a_queue_runs_stops_resumes_and_is_not_started_twice() {
    let t = Tree::new("stop");
    std::fs::write(&t.hold, "").expect("the hold file");
    let mut first = Running(t.campaign(&["-j", "1", "q.queue"]).spawn().expect("starting the queue"), t.hold.clone());
    let pidfile = t.path("runs/campaign/q.pid");
    wait_for("the pid file", || std::fs::read_to_string(&pidfile).is_ok_and(|p| p.trim() == first.0.id().to_string()));
    wait_for("the first run", || t.path("runs/campaign/alpha-seed1/episodes.csv").exists());

    let status = t.status();
    assert!(status.contains("running  alpha-seed1") && status.contains("2/5 episodes"), "{status}");
    assert!(status.contains("pending  beta-seed2") && status.contains("0/5 episodes"), "{status}");
    assert!(status.contains("1 pending, 1 running; 8 episodes left"), "{status}");

    let again = t.run(&["q.queue"]);
    assert_eq!(again.status.code(), Some(2), "{}", text(&again));
    assert!(text(&again).contains("already running"), "{}", text(&again));

    let stop = t.run(&["--stop", "q.queue"]);
    assert!(stop.status.success(), "{}", text(&stop));
    assert_eq!(first.exit_code(), Some(130), "a stopped queue exits 130");
    assert!(!pidfile.exists(), "the pid file outlives its campaign");
    let interrupted = std::fs::read_to_string(t.path("runs/campaign/alpha-seed1.interrupted.json")).expect("the interrupted summary");
    assert!(interrupted.contains("\"interrupted\": true"), "{interrupted}");
    assert!(!t.path("docs/campaign/results/alpha-seed1").exists(), "an interrupted run was archived");
    assert!(!t.path("runs/campaign/beta-seed2").exists(), "the queue went on after the stop");

    let status = t.status();
    assert!(status.contains("stopped  alpha-seed1") && status.contains("1 pending, 1 stopped; 8 episodes left"), "{status}");

    let none = t.run(&["--stop", "q.queue"]);
    assert_eq!(none.status.code(), Some(1), "{}", text(&none));
    assert!(text(&none).contains("no campaign of q.queue is running"), "{}", text(&none));

    // Started again without the hold: alpha had no snapshot, so it is set aside and starts over;
    // both runs finish and are archived.
    std::fs::remove_file(&t.hold).expect("removing the hold");
    let done = t.run(&["-j", "2", "q.queue"]);
    assert!(done.status.success(), "{}", text(&done));
    assert!(text(&done).contains("finished"), "{}", text(&done));
    for run in ["alpha-seed1", "beta-seed2"] {
        let summary = std::fs::read_to_string(t.path(&format!("docs/campaign/results/{run}/summary.json"))).expect("an archived summary");
        assert!(summary.contains("\"interrupted\": false"), "{run}: {summary}");
        for f in ["config.toml", "designs.csv", "episodes.csv"] {
            assert!(t.path(&format!("docs/campaign/results/{run}/{f}")).exists(), "{run}/{f} not archived");
        }
    }
    let aside = std::fs::read_dir(t.path("runs/campaign"))
        .expect("runs")
        .filter_map(|e| e.ok())
        .any(|e| e.file_name().to_string_lossy().starts_with("alpha-seed1.partial-"));
    assert!(aside, "the unfinished run without a snapshot was not set aside");

    let status = t.status();
    assert!(status.contains("2 archived; 0 episodes left"), "{status}");

    let skip = t.run(&["q.queue"]);
    assert!(skip.status.success(), "{}", text(&skip));
    assert_eq!(text(&skip).matches("done already, skipped").count(), 2, "{}", text(&skip));

    let bad = t.run(&["-j", "two", "q.queue"]);
    assert_eq!(bad.status.code(), Some(2), "{}", text(&bad));
    let _ = std::fs::remove_dir_all(t.root.parent().expect("base"));
}

/// A fork line whose source is archived but whose run directory is gone (runs/ of another
/// machine): its first K designs are run again, checked row for row against the archive, and
/// forked; a binary that does not reproduce them is refused, and the queue still ends.
#[test]
fn a_fork_of_an_archived_source_runs_its_prefix_again_and_checks_it() {
    let t = Tree::new("fork");
    // The archived source: 4 designs of 2 episodes, the rows the fake writes.
    t.archive_source(4);
    std::fs::write(t.path("q.queue"), "frk fork:src:2+optimizer.exploit=\"x\" 1\n").expect("queue");

    let done = t.run(&["-j", "1", "q.queue"]);
    assert!(done.status.success(), "{}", text(&done));
    assert!(text(&done).contains("row for row the archived ones"), "{}", text(&done));
    let fork = t.path("runs/campaign/frk-seed1");
    let config = std::fs::read_to_string(fork.join("config.toml")).expect("the fork's config");
    assert!(config.contains("designs = 4") && config.contains("exploit = \"x\""), "the fork's config: {config}");
    assert!(std::fs::read_to_string(fork.join("forked-from.txt")).expect("forked-from").contains("start of design 2"));
    assert!(t.path("docs/campaign/results/frk-seed1/summary.json").exists(), "the fork was not archived");
    assert!(t.path("runs/campaign/src-seed1/snapshots").exists(), "the prefix is not in the source's place");

    // Another archived source whose rows this binary does not reproduce: refused, and the queue
    // ends (its fork's watcher is not left waiting).
    std::fs::remove_dir_all(t.path("runs/campaign/src-seed1")).expect("clearing the source");
    std::fs::remove_dir_all(t.path("docs/campaign/results/frk-seed1")).expect("clearing the fork");
    std::fs::remove_dir_all(&fork).expect("clearing the fork");
    let bad = Command::new("bash")
        .arg(t.path("scripts/campaign.sh"))
        .args(["-j", "1", "q.queue"])
        .current_dir(&t.root)
        .env("BIN", t.path("fake-coadapt"))
        .env("FAKE_SHIFT", "1")
        .output()
        .expect("running campaign.sh");
    let out = text(&bad);
    assert!(out.contains("does not reproduce the archived first 2 designs") && out.contains("row 1"), "{out}");
    assert!(!fork.exists() && !t.path("runs/campaign/src-seed1").exists(), "a fork from a prefix that differs: {out}");
    let watcher = std::fs::read_to_string(t.path("runs/campaign/frk-seed1.fork.pid")).expect("the watcher's pid");
    assert!(!alive(watcher.trim()), "the fork's watcher outlived its queue (pid {})", watcher.trim());
    let _ = std::fs::remove_dir_all(t.root.parent().expect("base"));
}

/// A stop reaches a lane that waits for its fork (the source still before design K): the queue
/// ends instead of waiting for ever for a fork that will not come.
#[test]
fn a_stop_reaches_a_lane_waiting_for_its_fork() {
    let t = Tree::new("wait");
    std::fs::write(&t.hold, "").expect("the hold file");
    std::fs::write(t.path("q.queue"), "src cfg.toml 1\nfrk fork:src:1 1\n").expect("queue");
    let mut first = Running(t.campaign(&["-j", "2", "q.queue"]).spawn().expect("starting the queue"), t.hold.clone());
    wait_for("the source to start", || t.path("runs/campaign/src-seed1/episodes.csv").exists());
    wait_for("the fork's lane", || t.status().contains("pending  frk-seed1"));
    std::thread::sleep(Duration::from_secs(1));
    let stop = t.run(&["--stop", "q.queue"]);
    assert!(stop.status.success(), "{}", text(&stop));
    assert_eq!(first.exit_code(), Some(130), "a stopped queue exits 130");
    let _ = std::fs::remove_dir_all(t.root.parent().expect("base"));
}

/// A stop that lands before a run has its SIGINT handler in place (as when a run starts just as
/// the queue is stopped: at a fork's hand-off, or loading its snapshot) stops it cleanly: the stop
/// signals only processes with a handler (SIGINT's default action would kill the run without a
/// snapshot), and the lane, finding its run missing from the list, signals it once its handler
/// is there. The run reports itself interrupted, is not archived, and the queue exits 130.
#[test]
fn a_stop_before_a_run_can_hear_it_still_stops_the_run() {
    let t = Tree::new("late-handler");
    std::fs::write(&t.hold, "").expect("the hold file");
    std::fs::write(t.path("q.queue"), "alpha cfg.toml 1\n").expect("queue");
    let mut queue = Running(t.campaign(&["q.queue"]).env("FAKE_HANDLER_DELAY", "3").spawn().expect("starting the queue"), t.hold.clone());
    // The fake writes its files before it waits without a handler.
    wait_for("the run to start", || t.path("runs/campaign/alpha-seed1/episodes.csv").exists());
    let stop = t.run(&["--stop", "q.queue"]);
    assert!(stop.status.success(), "{}", text(&stop));
    assert_eq!(queue.exit_code(), Some(130), "a stopped queue exits 130");
    let interrupted = std::fs::read_to_string(t.path("runs/campaign/alpha-seed1.interrupted.json")).expect("the run's interrupted summary");
    assert!(interrupted.contains("\"interrupted\": true"), "{interrupted}");
    assert!(!t.path("docs/campaign/results/alpha-seed1").exists(), "a stopped run was archived");
    let _ = std::fs::remove_dir_all(t.root.parent().expect("base"));
}

/// `--stop-at-snapshot` waits while the queue's run has written no snapshot since the call
/// (an older one does not count), stops the queue once it has; with nothing snapshotted, the
/// deadline stops it; a deadline `date` cannot read is refused.
#[test]
fn a_stop_at_snapshot_waits_for_a_new_one_or_the_deadline() {
    let t = Tree::new("at-snapshot");
    std::fs::write(&t.hold, "").expect("the hold file");
    // --designs 1: the fake run starts with a snapshot, from before the call.
    std::fs::write(t.path("q.queue"), "alpha cfg.toml 1 --designs 1\n").expect("queue");
    let mut first = Running(t.campaign(&["q.queue"]).spawn().expect("starting the queue"), t.hold.clone());
    wait_for("the run's first snapshot", || t.path("runs/campaign/alpha-seed1/snapshots").exists());
    let bad = t.run(&["--stop-at-snapshot", "q.queue", "half past never"]);
    assert_eq!(bad.status.code(), Some(2), "{}", text(&bad));
    assert!(text(&bad).contains("the deadline 'half past never' is not a time"), "{}", text(&bad));
    std::thread::sleep(Duration::from_millis(1100));
    let mut stopper = t.campaign(&["--stop-at-snapshot", "q.queue"]).env("CAMPAIGN_POLL", "0.2").spawn().expect("the stopper");
    std::thread::sleep(Duration::from_secs(2));
    assert!(stopper.try_wait().expect("polling").is_none(), "it stopped the queue without a new snapshot");
    assert!(first.0.try_wait().expect("polling").is_none(), "the queue ended before its run snapshotted");
    let snap = t.hold.with_extension("snap");
    std::fs::write(&snap, "").expect("asking for a snapshot");
    wait_for("the stopper", || stopper.try_wait().expect("polling").is_some());
    assert!(!snap.exists(), "the fake run did not snapshot");
    assert_eq!(first.exit_code(), Some(130), "a stopped queue exits 130");
    assert!(t.status().contains("stopped  alpha-seed1"), "{}", t.status());

    // Started again: no new snapshot comes; the deadline stops the queue.
    let mut second = Running(t.campaign(&["q.queue"]).spawn().expect("starting the queue again"), t.hold.clone());
    wait_for("the resumed run", || t.status().contains("running  alpha-seed1"));
    // Past the second its lane took it in: a run started since the call counts as just started.
    std::thread::sleep(Duration::from_millis(1100));
    let stop = t.campaign(&["--stop-at-snapshot", "q.queue", "now + 2 seconds"]).env("CAMPAIGN_POLL", "0.2").output().expect("stopper");
    assert!(stop.status.success() && text(&stop).contains("deadline; no new snapshot yet of alpha-seed1"), "{}", text(&stop));
    assert_eq!(second.exit_code(), Some(130));
    let none = t.run(&["--stop-at-snapshot", "q.queue"]);
    assert!(!none.status.success() && text(&none).contains("no campaign of q.queue is running"), "{}", text(&none));
    let _ = std::fs::remove_dir_all(t.root.parent().expect("base"));
}

/// A line that starts between two polls of `--stop-at-snapshot`, as the one before it ends,
/// has nothing to lose: the queue stops at the next poll, not at the deadline.
#[test]
fn a_stop_at_snapshot_does_not_wait_for_a_line_that_has_just_started() {
    let t = Tree::new("at-snapshot-next");
    std::fs::write(&t.hold, "").expect("the hold file");
    let mut queue = Running(t.campaign(&["-j", "1", "q.queue"]).spawn().expect("starting the queue"), t.hold.clone());
    wait_for("alpha", || t.status().contains("running  alpha-seed1"));
    std::thread::sleep(Duration::from_millis(1100));
    let started = Instant::now();
    let stopper = t
        .campaign(&["--stop-at-snapshot", "q.queue", "now + 40 seconds"])
        .env("CAMPAIGN_POLL", "2")
        .stdout(std::process::Stdio::piped())
        .spawn()
        .expect("the stopper");
    std::thread::sleep(Duration::from_millis(500));
    // alpha ends (it took no snapshot: the stopper waited for it) and beta starts.
    std::fs::write(t.hold.with_file_name("hold.done-alpha-seed1"), "").expect("ending alpha");
    wait_for("beta", || t.status().contains("running  beta-seed2"));
    let out = stopper.wait_with_output().expect("the stopper");
    assert!(out.status.success(), "{}", text(&out));
    assert!(text(&out).contains("has snapshotted since") && text(&out).contains("or has just started"), "{}", text(&out));
    assert!(started.elapsed() < Duration::from_secs(20), "it waited {:?} for beta's first snapshot", started.elapsed());
    assert_eq!(queue.exit_code(), Some(130), "a stopped queue exits 130");
    assert!(t.path("docs/campaign/results/alpha-seed1/summary.json").exists(), "alpha, finished, was not archived");
    let status = t.status();
    assert!(status.contains("1 archived") && status.contains("stopped  beta-seed2"), "{status}");
    let _ = std::fs::remove_dir_all(t.root.parent().expect("base"));
}

/// A retrain line whose `coadapt train` runs (it names a seed's directory inside the line's)
/// is `running`, not `stopped`.
#[test]
fn a_retrain_line_training_a_seed_is_running() {
    let t = Tree::new("retrain");
    t.archive_source(2);
    std::fs::write(t.path("q.queue"), "body retrain:src:exploit 1\n").expect("queue");
    let seed = t.path("runs/campaign/body-seed1/train-seed1");
    std::fs::create_dir_all(&seed).expect("the seed's directory");
    assert!(t.status().contains("stopped  body-seed1"), "{}", t.status());
    let train = Command::new("python3")
        .args(["-c", "import time; time.sleep(60)", "--out", "runs/campaign/body-seed1/train-seed1"])
        .current_dir(&t.root)
        .spawn()
        .expect("a process naming the seed's directory");
    let mut train = Running(train, t.hold.clone());
    let status = t.status();
    train.0.kill().expect("ending it");
    assert!(status.contains("running  body-seed1"), "{status}");
    let _ = std::fs::remove_dir_all(t.root.parent().expect("base"));
}

/// A fork copied from its source at design K but not started holds the source's rows only: it
/// is `copied` with all its own episodes left, and `stopped` once it has rows of its own.
#[test]
fn a_fork_copied_but_not_started_says_so() {
    let t = Tree::new("copied");
    std::fs::write(t.path("q.queue"), "src cfg.toml 1\nfrk fork:src:1 1\n").expect("queue");
    let fork = t.path("runs/campaign/frk-seed1");
    std::fs::create_dir_all(&fork).expect("the fork's directory");
    // The source's first design: 3 episodes (cfg.toml's initial-episodes), then design 1's 2.
    let prefix = "design,episode,return,eval_return\n0,0,1,1\n0,1,1,1\n0,2,1,1\n";
    std::fs::write(fork.join("episodes.csv"), prefix).expect("the copied rows");
    let status = t.status();
    assert!(status.contains("copied   frk-seed1") && status.contains("0/2 episodes"), "{status}");
    std::fs::write(fork.join("episodes.csv"), format!("{prefix}1,0,2,2\n")).expect("a row of its own");
    let status = t.status();
    assert!(status.contains("stopped  frk-seed1") && status.contains("1/2 episodes"), "{status}");
    let _ = std::fs::remove_dir_all(t.root.parent().expect("base"));
}

/// A line that starts from an archived run's population networks whose run directory is gone:
/// the whole source is run again and checked before the line starts; a stale lock of a killed
/// campaign does not stop it.
#[test]
fn an_init_population_source_that_is_gone_is_run_again() {
    let t = Tree::new("init");
    t.archive_source(3);
    std::fs::write(t.path("q.queue"), "tgt cfg.toml 1 --init-population runs/campaign/src-seed1\n").expect("queue");
    // The lock of a lane that died with its campaign.
    std::fs::create_dir_all(t.path("runs/campaign/src-seed1.prefix.lock")).expect("a stale lock");
    std::fs::write(t.path("runs/campaign/src-seed1.prefix.lock/pid"), "999999999").expect("its pid");

    let done = t.run(&["-j", "1", "q.queue"]);
    let out = text(&done);
    assert!(done.status.success(), "{out}");
    assert!(out.contains("first 3 designs again, row for row the archived ones"), "{out}");
    let regenerated = std::fs::read_to_string(t.path("runs/campaign/src-seed1/episodes.csv")).expect("the source again");
    assert_eq!(regenerated.lines().count(), 7, "{regenerated}");
    assert!(t.path("docs/campaign/results/tgt-seed1/summary.json").exists(), "the line did not run: {out}");

    // A source neither here nor archived: the line fails with a reason, the queue goes on.
    std::fs::write(t.path("q.queue"), "tgt2 cfg.toml 1 --init-population runs/campaign/nowhere-seed1\n").expect("queue");
    let out = text(&t.run(&["-j", "1", "q.queue"]));
    assert!(out.contains("no such run, archived or not") && out.contains("FAILED"), "{out}");
    let _ = std::fs::remove_dir_all(t.root.parent().expect("base"));
}

/// Two queues that share a line (as seed3.queue shares design-bench's): while one runs it, the
/// other skips it, and once it is done, nobody runs it again; the lock goes with the lane.
#[test]
fn a_line_two_queues_share_runs_once() {
    let t = Tree::new("share");
    std::fs::write(&t.hold, "").expect("the hold file");
    std::fs::write(t.path("other.queue"), "alpha cfg.toml 1\n").expect("queue");
    let mut first = Running(t.campaign(&["-j", "1", "q.queue"]).spawn().expect("starting the queue"), t.hold.clone());
    wait_for("the first run", || t.path("runs/campaign/alpha-seed1/episodes.csv").exists());
    let second = t.run(&["-j", "1", "other.queue"]);
    assert!(second.status.success(), "{}", text(&second));
    assert!(text(&second).contains("alpha-seed1 is being run by another campaign"), "{}", text(&second));
    std::fs::remove_file(&t.hold).expect("removing the hold");
    assert_eq!(first.exit_code(), Some(0));
    assert!(!t.path("runs/campaign/alpha-seed1.lock").exists(), "the lock outlived its lane");
    let third = t.run(&["other.queue"]);
    assert!(text(&third).contains("alpha-seed1 done already, skipped"), "{}", text(&third));

    // A lock whose lane is gone while its run lives on (a campaign killed outright leaves the
    // run orphaned): not taken over.
    std::fs::create_dir_all(t.path("runs/campaign/gamma-seed2.lock")).expect("a lock");
    std::fs::write(t.path("runs/campaign/gamma-seed2.lock/pid"), "999999999").expect("a dead lane");
    let mut orphan = Command::new("bash")
        .args(["-c", "exec -a 'coadapt run --out runs/campaign/gamma-seed2 --transport in-process' sleep 60"])
        .spawn()
        .expect("an orphaned run");
    std::fs::write(t.path("other.queue"), "gamma cfg.toml 2\n").expect("queue");
    let fourth = t.run(&["other.queue"]);
    let _ = orphan.kill();
    let _ = orphan.wait();
    assert!(text(&fourth).contains("gamma-seed2 is being run by another campaign"), "{}", text(&fourth));
    // Once it has gone, the stale lock is taken over and the line runs.
    let fifth = t.run(&["other.queue"]);
    assert!(text(&fifth).contains("done  runs/campaign/gamma-seed2"), "{}", text(&fifth));
    let _ = std::fs::remove_dir_all(t.root.parent().expect("base"));
}

/// A queue that ends (or stops) ends only its own fork watchers: another queue running beside
/// it keeps the watcher its fork line waits on.
#[test]
fn a_queue_ends_only_its_own_fork_watchers() {
    let t = Tree::new("watchers");
    // Queue x waits for a fork whose source nobody runs (its watcher waits too).
    std::fs::write(t.path("x.queue"), "frk fork:src:1 1\n").expect("queue");
    let mut x = Running(t.campaign(&["-j", "1", "x.queue"]).spawn().expect("starting x"), t.hold.clone());
    let pidfile = t.path("runs/campaign/frk-seed1.fork.pid");
    wait_for("x's watcher", || std::fs::read_to_string(&pidfile).is_ok_and(|p| !p.trim().is_empty()));
    let watcher = std::fs::read_to_string(&pidfile).expect("the watcher's pid").trim().to_string();
    assert!(alive(&watcher), "x's watcher did not start");
    // Queue y runs one line to its end, and is stopped once too.
    std::fs::write(t.path("y.queue"), "alpha cfg.toml 1\n").expect("queue");
    let y = t.run(&["-j", "1", "y.queue"]);
    assert!(text(&y).contains("finished"), "{}", text(&y));
    assert!(alive(&watcher), "y's end killed x's watcher");
    // x stopped: its own watcher goes.
    let stop = t.run(&["--stop", "x.queue"]);
    assert!(stop.status.success(), "{}", text(&stop));
    assert_eq!(x.exit_code(), Some(130));
    wait_for("x's watcher to end", || !alive(&watcher));
    let _ = std::fs::remove_dir_all(t.root.parent().expect("base"));
}

/// The hours left are priced at the pace of the finished runs by the learner's own clock (the
/// seconds column of episodes.csv, which goes on across resumes), not by summary.json's seconds
/// (the last start only), and a fork's pace counts its own rows only.
#[test]
fn hours_left_follow_the_learners_clock_of_finished_runs() {
    let t = Tree::new("pace");
    std::fs::write(t.root.join("q.queue"), "alpha cfg.toml 1\nfrk fork:alpha:1 1\nbeta cfg.toml 2\ngamma cfg.toml 3\n").expect("the queue");
    // A finished run in the archive: one episode row per (design, episode, learner's seconds),
    // and summary.json's seconds (the last start's, which the pricing must not read).
    let archive = |run: &str, episodes: &[(u32, u32, f64)], summary_seconds: f64| {
        let dir = t.path(&format!("docs/campaign/results/{run}"));
        std::fs::create_dir_all(&dir).expect("archive");
        let rows: String = episodes.iter().map(|(d, e, s)| format!("{d},{e},1.0,1.0,{s}\n")).collect();
        std::fs::write(dir.join("episodes.csv"), format!("design,episode,return,eval_return,seconds\n{rows}")).expect("rows");
        std::fs::write(dir.join("summary.json"), format!("{{\"interrupted\": false, \"seconds\": {summary_seconds}}}")).expect("summary");
    };
    // alpha: 5 episodes over 3,600 s in two starts (summary.json: 60 s, the last start).
    archive("alpha-seed1", &[(0, 0, 600.0), (0, 1, 1200.0), (0, 2, 1800.0), (1, 0, 3000.0), (1, 1, 3600.0)], 60.0);
    // frk: alpha's first design copied (3 rows), then its own 2 episodes in 720 s (10 per hour).
    archive("frk-seed1", &[(0, 0, 600.0), (0, 1, 1200.0), (0, 2, 1800.0), (1, 0, 2160.0), (1, 1, 2520.0)], 1.0);
    // beta at 20 per hour: the median of 5, 10 and 20 is 10 per hour, so gamma's 5 episodes
    // left are half a lane-hour.
    let beta: Vec<(u32, u32, f64)> = (0..5).map(|i| (0, i, 180.0 * f64::from(i + 1))).collect();
    archive("beta-seed2", &beta, 2.0);

    let status = t.status();
    assert!(status.contains("3 archived, 1 pending; 5 episodes left, about 0.5 lane-hours"), "{status}");
    assert!(status.contains("(10 episodes/h)"), "{status}");
    let _ = std::fs::remove_dir_all(t.root.parent().expect("base"));
}
