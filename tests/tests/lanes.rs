//! `scripts/lanes.sh`, which keeps lanes busy across queues (each lane runs its queues one after
//! another with `campaign.sh -j 1`), driven with the fake `coadapt` of campaign_tree: a lane's
//! second queue starts when its first has ended, the lanes run at once, a queue running already
//! is waited for, mujoco-* queues of two lanes share one Python bridge (kept while the other lane
//! is between runs), and a SIGTERM stops the
//! queue running (its run interrupted, not archived) and starts no other.

use crate::campaign_tree;

use campaign_tree::*;
use std::process::Command;

fn lanes(t: &Tree, args: &[&str]) -> Command {
    let mut c = Command::new("bash");
    c.arg(t.path("scripts/lanes.sh")).args(args).current_dir(&t.root).env("BIN", t.path("fake-coadapt")).env("FAKE_HOLD", &t.hold);
    c
}

fn queues(t: &Tree) {
    std::fs::write(t.path("a.queue"), "alpha cfg.toml 1\n").expect("a queue");
    std::fs::write(t.path("b.queue"), "beta cfg.toml 2\n").expect("a queue");
    std::fs::write(t.path("c.queue"), "gamma cfg.toml 3\n").expect("a queue");
}

#[test]
fn each_lane_runs_its_queues_in_order() {
    let t = Tree::new("lanes-order");
    queues(&t);
    let out = lanes(&t, &["a.queue b.queue", "c.queue"]).output().expect("running lanes.sh");
    let log = text(&out);
    assert!(out.status.success(), "{log}");
    for run in ["alpha-seed1", "beta-seed2", "gamma-seed3"] {
        assert!(t.path(&format!("docs/campaign/results/{run}/summary.json")).exists(), "{run} not archived: {log}");
    }
    let at = |s: &str| log.find(s).unwrap_or_else(|| panic!("no '{s}' in: {log}"));
    assert!(at("lane 1: a.queue ended") < at("lane 1: b.queue from"), "{log}");
    assert!(log.contains("lane 2: c.queue from"), "{log}");
    let a = std::fs::read_to_string(t.path("runs/campaign-a.log")).expect("a.queue's log");
    assert!(a.contains("done  runs/campaign/alpha-seed1"), "{a}");

    let bad = lanes(&t, &["a.queue missing.queue"]).output().expect("running lanes.sh");
    assert_eq!(bad.status.code(), Some(2), "{}", text(&bad));
    assert!(text(&bad).contains("no queue file missing.queue"), "{}", text(&bad));
    let past = lanes(&t, &["--until", "now - 1 hour", "a.queue"]).output().expect("running lanes.sh");
    assert_eq!(past.status.code(), Some(2), "{}", text(&past));
    let _ = std::fs::remove_dir_all(t.root.parent().expect("base"));
}

#[test]
fn a_term_stops_the_queue_running_and_starts_no_other() {
    let t = Tree::new("lanes-stop");
    queues(&t);
    std::fs::write(&t.hold, "").expect("the hold file");
    // Dropped on a failed assertion: the hold goes and lanes.sh is stopped.
    let mut running =
        Running(lanes(&t, &["a.queue b.queue"]).stdout(std::process::Stdio::piped()).spawn().expect("starting lanes.sh"), t.hold.clone());
    wait_for("alpha's run", || t.path("runs/campaign/alpha-seed1/episodes.csv").exists());
    let term = Command::new("kill").arg("-TERM").arg(running.0.id().to_string()).status().expect("kill");
    assert!(term.success());
    let code = running.exit_code();
    let mut out = String::new();
    std::io::Read::read_to_string(running.0.stdout.as_mut().expect("stdout"), &mut out).expect("lanes.sh's output");
    assert_eq!(code, Some(0), "{out}");
    assert!(t.path("runs/campaign/alpha-seed1.interrupted.json").exists(), "alpha was not stopped: {out}");
    assert!(!t.path("docs/campaign/results/alpha-seed1").exists(), "a stopped run was archived: {out}");
    assert!(!t.path("runs/campaign/beta-seed2").exists() && !out.contains("b.queue from"), "b.queue started after the stop: {out}");
    let _ = std::fs::remove_dir_all(t.root.parent().expect("base"));
}

/// A queue already running (started by hand) is waited for, not started twice: the lane starts
/// it only once the other campaign has ended, and then finds its lines done.
#[test]
fn a_queue_running_already_is_waited_for() {
    let t = Tree::new("lanes-wait");
    queues(&t);
    std::fs::write(&t.hold, "").expect("the hold file");
    let mut by_hand = Running(t.campaign(&["-j", "1", "a.queue"]).spawn().expect("starting a.queue by hand"), t.hold.clone());
    wait_for("alpha's run", || t.path("runs/campaign/alpha-seed1/episodes.csv").exists());
    let lane = lanes(&t, &["a.queue c.queue"]).stdout(std::process::Stdio::piped()).spawn().expect("starting lanes.sh");
    let mut lane = Running(lane, t.hold.clone());
    // Longer than the lane's 5 s poll: it would have started a.queue (refused: already running)
    // and gone on to c.queue.
    std::thread::sleep(std::time::Duration::from_secs(7));
    assert!(lane.0.try_wait().expect("lanes.sh").is_none(), "the lane ended while a.queue ran");
    assert!(!t.path("runs/campaign/gamma-seed3").exists(), "the lane went past a.queue while it ran");
    std::fs::remove_file(&t.hold).expect("ending the hold");
    assert_eq!(by_hand.exit_code(), Some(0), "a.queue started by hand");
    assert_eq!(lane.exit_code(), Some(0), "lanes.sh");
    let mut out = String::new();
    std::io::Read::read_to_string(lane.0.stdout.as_mut().expect("stdout"), &mut out).expect("lanes.sh's output");
    let a = std::fs::read_to_string(t.path("runs/campaign-a.log")).expect("the lane's a.queue log");
    assert!(a.contains("alpha-seed1 done already, skipped"), "{a}");
    assert!(!a.contains("already running"), "the lane started a.queue while it ran: {a}");
    assert!(t.path("docs/campaign/results/gamma-seed3/summary.json").exists(), "{out}");
    let _ = std::fs::remove_dir_all(t.root.parent().expect("base"));
}

/// Two lanes reaching mujoco-* queues (the MuJoCo cheetah, served by the Python bridge) share one
/// bridge, started by whichever came first (scripts/mujoco_lane.sh), and it outlives its own
/// lane's queue while the other lane still uses it; it is gone when both have ended.
#[test]
fn mujoco_queues_of_two_lanes_share_one_bridge() {
    let t = Tree::new("lanes-bridge");
    std::fs::write(t.path("mujoco-a.queue"), "mujoco-a cfg.toml 1\n").expect("a queue");
    std::fs::write(t.path("mujoco-b.queue"), "mujoco-b cfg.toml 2\n").expect("a queue");
    let port = fake_bridge(&t);
    std::fs::write(&t.hold, "").expect("the hold file");
    let lane =
        lanes(&t, &["mujoco-a.queue", "mujoco-b.queue"]).env("PORT", &port).stdout(std::process::Stdio::piped()).spawn().expect("lanes.sh");
    let mut lane = Running(lane, t.hold.clone());
    for run in ["mujoco-a-seed1", "mujoco-b-seed2"] {
        wait_for(run, || t.path(&format!("runs/campaign/{run}/episodes.csv")).exists());
    }
    let log = |q: &str| std::fs::read_to_string(t.path(&format!("runs/campaign-{q}.log"))).unwrap_or_default();
    let owner = if log("mujoco-a").contains("mujoco_lane: bridge pid") { "a" } else { "b" };
    let (first, other) = if owner == "a" { ("mujoco-a-seed1", "mujoco-b") } else { ("mujoco-b-seed2", "mujoco-a") };
    assert!(log(other).contains("using the bridge another lane started"), "{}\n{}", log("mujoco-a"), log("mujoco-b"));
    let pid = std::fs::read_to_string(t.path("runs/mujoco-bridge.pid")).expect("the bridge's pid file").trim().to_string();
    let _bridge = KillOnDrop(pid.clone());
    assert!(alive(&pid), "the bridge is not running");
    // The owner's run ends first: its queue finishes, the bridge stays for the other lane's run.
    std::fs::write(format!("{}.done-{first}", t.hold.display()), "").expect("ending the owner's run");
    wait_for("the owner's queue to finish", || log(&format!("mujoco-{owner}")).contains("finished"));
    std::thread::sleep(std::time::Duration::from_secs(2));
    assert!(alive(&pid), "the bridge went while the other lane used it: {}", log(other));
    std::fs::remove_file(&t.hold).expect("ending the hold");
    assert_eq!(lane.exit_code(), Some(0), "lanes.sh");
    let mut out = String::new();
    std::io::Read::read_to_string(lane.0.stdout.as_mut().expect("stdout"), &mut out).expect("lanes.sh's output");
    wait_for("the bridge to stop", || !alive(&pid));
    assert!(!t.path("runs/mujoco-bridge.pid").exists(), "{out}");
    for run in ["mujoco-a-seed1", "mujoco-b-seed2"] {
        assert!(t.path(&format!("docs/campaign/results/{run}/summary.json")).exists(), "{run} not archived: {out}");
    }
    let _ = std::fs::remove_dir_all(t.root.parent().expect("base"));
}

/// A fake bridge where mujoco_lane.sh looks for the real one (it listens, as the bridge does), and
/// a port of its own for it, not the real bridge's 50071 (a lane may be using it on this machine).
fn fake_bridge(t: &Tree) -> String {
    let bin = t.path("runs/venv-bridge/bin");
    std::fs::create_dir_all(&bin).expect("the bridge's venv");
    let fake = "#!/usr/bin/env python3\nimport socket, sys\ns = socket.socket()\ns.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)\n\
                s.bind(('127.0.0.1', int(sys.argv[sys.argv.index('--port') + 1])))\ns.listen(8)\nwhile True:\n    s.accept()[0].close()\n";
    std::fs::write(bin.join("coadapt-gym-serve"), fake).expect("the fake bridge");
    assert!(Command::new("chmod").arg("+x").arg(bin.join("coadapt-gym-serve")).status().expect("chmod").success());
    std::net::TcpListener::bind("127.0.0.1:0").expect("a free port").local_addr().expect("its address").port().to_string()
}

/// The bridge's owner ends while the other lane is between runs (here: a retrain line waiting for
/// its source to finish, no run of its own alive): the bridge stays for that lane, and goes when
/// it has ended. Without it, the other lane's next MuJoCo run would find no bridge and fail.
#[test]
fn the_bridge_waits_for_a_lane_between_its_runs() {
    let t = Tree::new("lanes-bridge-gap");
    let port = fake_bridge(&t);
    std::fs::write(t.path("mujoco-a.queue"), "mujoco-a cfg.toml 1\n").expect("a queue");
    std::fs::write(t.path("mujoco-w.queue"), "mujoco-w retrain:mujoco-src:exploit 1\n").expect("a queue");
    std::fs::write(&t.hold, "").expect("the hold file");
    let lane = |q: &str| {
        Command::new("bash")
            .arg(t.path("scripts/mujoco_lane.sh"))
            .arg(q)
            .current_dir(&t.root)
            .env("BIN", t.path("fake-coadapt"))
            .env("FAKE_HOLD", &t.hold)
            .env("PORT", &port)
            .stdout(std::fs::File::create(t.path(&format!("{q}.out"))).expect("the lane's output"))
            .stderr(std::fs::File::create(t.path(&format!("{q}.err"))).expect("the lane's errors"))
            .spawn()
            .expect("mujoco_lane.sh")
    };
    // The owner: it starts the bridge, then its run holds.
    let mut owner = Running(lane("mujoco-a.queue"), t.hold.clone());
    wait_for("the owner's run", || t.path("runs/campaign/mujoco-a-seed1/episodes.csv").exists());
    let pid = std::fs::read_to_string(t.path("runs/mujoco-bridge.pid")).expect("the bridge's pid file").trim().to_string();
    let _bridge = KillOnDrop(pid.clone());
    // The other lane: its one line waits for mujoco-src-seed1, which is not there yet.
    let mut other = Running(lane("mujoco-w.queue"), t.hold.clone());
    // What each lane says (its own lines and its queue's).
    let log = |q: &str| {
        ["out", "err"].iter().map(|e| std::fs::read_to_string(t.path(&format!("{q}.queue.{e}"))).unwrap_or_default()).collect::<String>()
            + &std::fs::read_to_string(t.path(&format!("runs/campaign-{q}.log"))).unwrap_or_default()
    };
    wait_for("the other lane to find the bridge", || log("mujoco-w").contains("using the bridge another lane started"));
    std::fs::write(format!("{}.done-mujoco-a-seed1", t.hold.display()), "").expect("ending the owner's run");
    wait_for("the owner's queue to finish", || log("mujoco-a").contains("finished"));
    std::thread::sleep(std::time::Duration::from_secs(2));
    assert!(alive(&pid), "the bridge went while the other lane waited between its runs: {}", log("mujoco-a"));
    assert_eq!(owner.0.try_wait().expect("polling the owner"), None, "the owner left with its bridge in use: {}", log("mujoco-a"));
    // A TERM to the owner while it waits (lanes.sh stopping its lanes) neither ends it nor
    // leaves the bridge behind it: it goes on waiting for the other lane.
    assert!(Command::new("kill").arg("-TERM").arg(owner.0.id().to_string()).status().expect("kill").success());
    std::thread::sleep(std::time::Duration::from_secs(2));
    assert!(alive(&pid), "a TERM took the bridge from the other lane: {}", log("mujoco-a"));
    assert_eq!(owner.0.try_wait().expect("polling the owner"), None, "a TERM ended the owner before its bridge: {}", log("mujoco-a"));
    // The source finishes: the other lane retrains its body (up to 30 s: the wait polls), ends,
    // and then the owner stops the bridge and ends.
    // (A run of this machine: the line waits on the directory it found at its start.)
    let src = t.path("runs/campaign/mujoco-src-seed1");
    std::fs::create_dir_all(&src).expect("the source's directory");
    std::fs::write(src.join("config.toml"), format!("env = \"dm-env-rpc://127.0.0.1:{port}\"\n")).expect("its config");
    std::fs::write(src.join("designs.csv"), "index,kind,design,best_eval_return\n0,exploit,1;1,5\n").expect("its designs");
    std::fs::write(src.join("summary.json"), "{}").expect("its summary");
    std::fs::remove_file(&t.hold).expect("ending the hold");
    let end = std::time::Instant::now();
    while other.0.try_wait().expect("polling the other lane").is_none() {
        assert!(end.elapsed() < std::time::Duration::from_secs(90), "the other lane did not end: {}", log("mujoco-w"));
        std::thread::sleep(std::time::Duration::from_millis(200));
    }
    assert!(t.path("docs/campaign/results/mujoco-w-seed1/summary.json").exists(), "{}", log("mujoco-w"));
    assert_eq!(owner.exit_code(), Some(0), "{}", log("mujoco-a"));
    assert!(!alive(&pid) && !t.path("runs/mujoco-bridge.pid").exists(), "the bridge outlived both lanes");
    let _ = std::fs::remove_dir_all(t.root.parent().expect("base"));
}

/// The fake bridge goes when its test ends, passed or failed (a failed test left one running,
/// orphaned, with its port).
struct KillOnDrop(String);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        // Only the fake bridge: its pid may be another process's by now.
        let cmdline = std::fs::read(format!("/proc/{}/cmdline", self.0)).unwrap_or_default();
        if String::from_utf8_lossy(&cmdline).contains("coadapt-gym-serve") {
            let _ = Command::new("kill").arg("-KILL").arg(&self.0).status();
        }
    }
}
