//! What the tests of `scripts/campaign.sh` share (campaign_script.rs, campaign_stop.rs): a
//! temporary checkout with the scripts and a fake `coadapt` (a Python script that writes a run's
//! files and waits for a hold file to vanish, or for SIGINT, as the real binary snapshots and
//! exits), and the waits and checks around it.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

pub fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("the workspace root").to_path_buf()
}

pub const FAKE: &str = r#"#!/usr/bin/env python3
# `run --config C --seed S [--designs K] --out D` writes 2 episodes per design (return 10 d + e,
# or FAKE_SHIFT more), the files a run leaves and, given --designs, a snapshot at its end;
# `run --resume D` goes on; `train --env E ... --out D` writes the env and 12 returns; all wait while FAKE_HOLD exists and stop on SIGINT, as a run does.
import json, os, signal, sys, time
args = sys.argv[1:]
out = args[args.index("--out") + 1] if "--out" in args else args[args.index("--resume") + 1]
designs = int(args[args.index("--designs") + 1]) if "--designs" in args else 1
os.makedirs(out, exist_ok=True)
if args[0] == "train":
    # `train --env E ... --out D`: the config it ran (its env) and 12 episodes' returns.
    open(os.path.join(out, "config.toml"), "w").write(f'env = "{args[args.index("--env") + 1]}"\n')
    open(os.path.join(out, "episodes.csv"), "w").write("episode,return\n" + "".join(f"{i},{i}\n" for i in range(12)))
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

pub struct Tree {
    pub root: PathBuf,
    pub hold: PathBuf,
}

impl Tree {
    /// A tree of its own per test (the tests of this file run at once, in one process).
    pub fn new(test: &str) -> Self {
        let base = std::env::temp_dir().join(format!("coadapt-campaign-script-{test}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&base);
        // campaign.sh works in its script's parent and keeps runs/ beside it (../runs).
        let root = base.join("checkout");
        std::fs::create_dir_all(root.join("scripts")).expect("temp tree");
        for script in [
            "campaign.sh",
            "campaign_lines.sh",
            "campaign_status.py",
            "fork_run.sh",
            "config_with.py",
            "lanes.sh",
            "mujoco_lane.sh",
            "pick_design.py",
        ] {
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

    pub fn campaign(&self, args: &[&str]) -> Command {
        let mut c = Command::new("bash");
        c.arg(self.root.join("scripts/campaign.sh"))
            .args(args)
            .current_dir(&self.root)
            .env("BIN", self.root.join("fake-coadapt"))
            .env("FAKE_HOLD", &self.hold);
        c
    }

    pub fn run(&self, args: &[&str]) -> Output {
        self.campaign(args).output().expect("running campaign.sh")
    }

    /// `scripts/campaign_status.py q.queue` run in the tree.
    pub fn status(&self) -> String {
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
    pub fn archive_source(&self, designs: usize) {
        let arch = self.path("docs/campaign/results/src-seed1");
        std::fs::create_dir_all(&arch).expect("archive");
        let rows: String = (0..designs).flat_map(|d| (0..2).map(move |e| format!("{d},{e},{},{}\n", 10 * d + e, 10 * d + e))).collect();
        std::fs::write(arch.join("episodes.csv"), format!("design,episode,return,eval_return\n{rows}")).expect("rows");
        std::fs::write(arch.join("config.toml"), format!("[schedule]\ndesigns = {designs}\n")).expect("config");
        std::fs::write(arch.join("summary.json"), format!("{{\"interrupted\": false, \"designs\": {designs}}}")).expect("summary");
    }

    /// A finished run in the archive (`docs/campaign/results/RUN`) with one episode row per
    /// (design, episode, learner's seconds) and summary.json's `seconds` (the last start's).
    pub fn archive_paced(&self, run: &str, episodes: &[(u32, u32, f64)], summary_seconds: f64) {
        self.write_paced(&format!("docs/campaign/results/{run}"), episodes);
        let summary = format!("{{\"interrupted\": false, \"seconds\": {summary_seconds}}}");
        std::fs::write(self.path(&format!("docs/campaign/results/{run}/summary.json")), summary).expect("summary");
    }

    /// episodes.csv in DIR (from the root) with the rows of `archive_paced`.
    pub fn write_paced(&self, dir: &str, episodes: &[(u32, u32, f64)]) {
        let dir = self.path(dir);
        std::fs::create_dir_all(&dir).expect("a run directory");
        let rows: String = episodes.iter().map(|(d, e, s)| format!("{d},{e},1.0,1.0,{s}\n")).collect();
        std::fs::write(dir.join("episodes.csv"), format!("design,episode,return,eval_return,seconds\n{rows}")).expect("rows");
    }

    pub fn path(&self, p: &str) -> PathBuf {
        self.root.join(p)
    }
}

/// A failing assertion leaves no campaign behind: the hold goes (the fake run ends) and the
/// campaign is asked to stop.
pub struct Running(pub std::process::Child, pub PathBuf);

impl Running {
    /// The campaign's exit code, once it has ended (a minute at the most).
    pub fn exit_code(&mut self) -> Option<i32> {
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

pub fn text(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

/// Whether process PID runs: not gone, and not a zombie (left to a container's init that does
/// not reap).
pub fn alive(pid: &str) -> bool {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    stat.rsplit(')').next().and_then(|rest| rest.split_whitespace().next()).is_some_and(|s| s != "Z")
}

pub fn wait_for(what: &str, mut done: impl FnMut() -> bool) {
    let t = Instant::now();
    while !done() {
        assert!(t.elapsed() < Duration::from_secs(60), "waited a minute for {what}");
        std::thread::sleep(Duration::from_millis(50));
    }
}
