//! `scripts/campaign.sh`, the queue runner every archived run of docs/campaign/results went
//! through, driven with a fake `coadapt` (a Python script that writes a run's files and waits
//! for a hold file to vanish, or for SIGINT, as the real binary snapshots and exits): one pid
//! file per queue, a second start of a running queue refused, `--stop` stops it and its run
//! reports itself interrupted (not archived), the queue started again starts the run over (no
//! snapshot) and archives it, and a third start skips what is done; `scripts/campaign_status.py`
//! says at each stage which lines run, stopped, wait, are copied or are archived, and the episodes left.
//! The other ways to stop a queue: campaign_stop.rs.

use crate::campaign_tree;

use campaign_tree::*;
use std::process::Command;

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

/// A fork whose archived source's first K designs are being run again (the source's directory
/// gone) is `prefix`, with that run's progress, not `pending`.
#[test]
fn a_fork_waiting_for_its_sources_prefix_says_so() {
    let t = Tree::new("prefix");
    t.archive_source(4);
    let cfg = "[schedule]\ndesigns = 4\ninitial-designs = [[1.0]]\ninitial-episodes = 2\nepisodes-per-design = 2\n";
    std::fs::write(t.path("docs/campaign/results/src-seed1/config.toml"), cfg).expect("the source's config");
    std::fs::write(t.path("q.queue"), "frk fork:src:2 1\n").expect("queue");
    std::fs::write(&t.hold, "").expect("the hold file");
    let _running = Running(t.campaign(&["-j", "1", "q.queue"]).spawn().expect("starting the queue"), t.hold.clone());
    wait_for("the prefix's rows", || t.path("runs/campaign/src-seed1.prefix/episodes.csv").exists());
    let status = t.status();
    assert!(status.contains("prefix   frk-seed1") && status.contains("0/4 episodes"), "{status}");
    assert!(status.contains("its source's first 2 designs again: 4/4"), "{status}");
    drop(_running);
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

/// A source to run again whose twin is here (another line's run of the same config and seed, its
/// archive the same rows, as transfer-src is hc-fear): the run goes on from a copy of the twin's
/// newest snapshot instead of starting over, and is checked against the source's archive all the
/// same; a directory whose archived rows differ is not taken.
#[test]
fn a_source_run_again_goes_on_from_the_same_run_of_another_line() {
    let t = Tree::new("twin");
    t.archive_source(3);
    for (name, shift) in [("other", 1), ("twin", 0)] {
        let rows: String = (0..3).flat_map(|d| (0..2).map(move |e| format!("{d},{e},{},{}\n", 10 * d + e + shift, 10 * d + e))).collect();
        let rows = format!("design,episode,return,eval_return\n{rows}");
        let arch = t.path(&format!("docs/campaign/results/{name}-seed1"));
        std::fs::create_dir_all(&arch).expect("archive");
        std::fs::write(arch.join("episodes.csv"), &rows).expect("rows");
        std::fs::write(arch.join("summary.json"), "{\"interrupted\": false, \"designs\": 3}").expect("summary");
        // Its run directory: a run of 3 designs with a snapshot at design 2.
        let dir = t.path(&format!("runs/campaign/{name}-seed1"));
        let snap = dir.join("snapshots/snap-00000002");
        std::fs::create_dir_all(&snap).expect("snapshot");
        std::fs::write(snap.join("state.json"), r#"{"values": {"progress": {"design": 2, "in_design": null}}}"#).expect("state");
        std::fs::write(dir.join("config.toml"), "[schedule]\ndesigns = 3\n").expect("config");
        std::fs::write(dir.join("episodes.csv"), &rows).expect("rows");
        std::fs::write(dir.join("designs.csv"), format!("{name}'s designs\n")).expect("designs");
    }
    std::fs::write(t.path("q.queue"), "tgt cfg.toml 1 --init-population runs/campaign/src-seed1\n").expect("queue");
    let done = t.run(&["-j", "1", "q.queue"]);
    let out = text(&done);
    assert!(done.status.success(), "{out}");
    assert!(out.contains("starts from a copy of runs/campaign/twin-seed1"), "{out}");
    assert!(!out.contains("copy of runs/campaign/other-seed1"), "{out}");
    assert!(out.contains("first 3 designs again, row for row the archived ones"), "{out}");
    let designs = std::fs::read_to_string(t.path("runs/campaign/src-seed1/designs.csv")).expect("the source again");
    assert_eq!(designs, "twin's designs\n", "the source was run from the start, not from its twin");
    assert!(t.path("docs/campaign/results/tgt-seed1/summary.json").exists(), "the line did not run: {out}");
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
    // alpha: 5 episodes over 3,600 s in two starts (summary.json: 60 s, the last start).
    t.archive_paced("alpha-seed1", &[(0, 0, 600.0), (0, 1, 1200.0), (0, 2, 1800.0), (1, 0, 3000.0), (1, 1, 3600.0)], 60.0);
    // frk: alpha's first design copied (3 rows), then its own 2 episodes in 720 s (10 per hour).
    t.archive_paced("frk-seed1", &[(0, 0, 600.0), (0, 1, 1200.0), (0, 2, 1800.0), (1, 0, 2160.0), (1, 1, 2520.0)], 1.0);
    // beta at 20 per hour: the median of 5, 10 and 20 is 10 per hour, so gamma's 5 episodes
    // left are half a lane-hour.
    let beta: Vec<(u32, u32, f64)> = (0..5).map(|i| (0, i, 180.0 * f64::from(i + 1))).collect();
    t.archive_paced("beta-seed2", &beta, 2.0);

    let status = t.status();
    assert!(status.contains("3 archived, 1 pending; 5 episodes left, about 0.5 lane-hours"), "{status}");
    assert!(status.contains("(10 episodes/h)"), "{status}");
    let _ = std::fs::remove_dir_all(t.root.parent().expect("base"));
}

/// `--until`: a line starts only if its estimate (`campaign_status.py --seconds`, from the pace
/// of finished runs) and a quarter more end before the time given; a line too long for it, or with
/// nothing to size it by, is skipped and stays pending, and the lanes go on down the queue.
#[test]
fn until_starts_only_the_lines_that_end_in_time() {
    let t = Tree::new("until");
    // One episode per second (3,600 an hour) for alpha, the queue's only finished run.
    let alpha: Vec<(u32, u32, f64)> = (0..5).map(|i| (i / 3, i % 3, f64::from(i + 1))).collect();
    t.archive_paced("alpha-seed1", &alpha, 5.0);
    // long: a million episodes (a million seconds at that pace); gamma: cfg.toml's 5 (5 s).
    std::fs::write(t.path("long.toml"), "[schedule]\ndesigns = 1\ninitial-designs = [[1.0]]\ninitial-episodes = 1000000\n").expect("long");
    // frk forks long, which is skipped: nothing to wait by.
    std::fs::write(t.path("q.queue"), "alpha cfg.toml 1\nlong long.toml 1\ngamma cfg.toml 2\nfrk fork:long:1 1\n").expect("queue");
    // Another queue without a finished run: nothing gives its line a pace.
    std::fs::write(t.path("p.queue"), "delta cfg.toml 3\n").expect("queue");

    let seconds = |queue: &str, name: &str, seed: &str| {
        Command::new("python3")
            .args(["scripts/campaign_status.py", queue, "--seconds", name, seed])
            .current_dir(&t.root)
            .output()
            .expect("campaign_status.py --seconds")
    };
    let gamma = seconds("q.queue", "gamma", "2");
    assert!(gamma.status.success(), "{}", text(&gamma));
    assert_eq!(String::from_utf8_lossy(&gamma.stdout).trim(), "5");
    // A lone lane of two threads: 1.6 times the pace of one.
    let two = Command::new("python3")
        .args(["scripts/campaign_status.py", "q.queue", "--seconds", "gamma", "2", "--threads", "2"])
        .current_dir(&t.root)
        .output()
        .expect("campaign_status.py --seconds --threads");
    assert_eq!(String::from_utf8_lossy(&two.stdout).trim(), "3", "{}", text(&two));
    assert_eq!(String::from_utf8_lossy(&seconds("q.queue", "long", "1").stdout).trim(), "1000000");
    let delta = seconds("p.queue", "delta", "3");
    assert_eq!(delta.status.code(), Some(3), "{}", text(&delta));

    let past = t.run(&["--until", "now - 1 hour", "q.queue"]);
    assert_eq!(past.status.code(), Some(2), "{}", text(&past));
    assert!(text(&past).contains("already past"), "{}", text(&past));
    let garbled = t.run(&["--until", "half past never", "q.queue"]);
    assert_eq!(garbled.status.code(), Some(2), "{}", text(&garbled));

    let out = t.run(&["-j", "1", "--until", "now + 1 hour", "q.queue"]);
    assert!(out.status.success(), "{}", text(&out));
    let log = text(&out);
    // 60 or 59 min left, by when the line is looked at.
    assert!(log.contains("long-seed1 skipped: it needs about 20833 min, ") && log.contains(" min are left before --until"), "{log}");
    assert!(log.contains("gamma-seed2 fits before --until"), "{log}");
    assert!(log.contains("frk-seed1 skipped: nothing to size it by"), "{log}");
    assert!(!t.path("runs/campaign/long-seed1").exists(), "{log}");
    assert!(t.path("docs/campaign/results/gamma-seed2/summary.json").exists(), "{log}");
    let status = t.status();
    assert!(status.contains("pending  long-seed1                               0/1000000 episodes, about 16667 min"), "{status}");

    let out = t.run(&["--until", "now + 1 hour", "p.queue"]);
    assert!(text(&out).contains("delta-seed3 skipped: nothing to size it by"), "{}", text(&out));
    assert!(!t.path("runs/campaign/delta-seed3").exists());
    let _ = std::fs::remove_dir_all(t.root.parent().expect("base"));
}

/// The estimates follow this machine: a run directory here going at twice the archived pace
/// halves them; its run, once archived, is not part of the pace it is set against; the factor
/// stops at 3.
#[test]
fn estimates_scale_with_this_machines_pace() {
    let t = Tree::new("speed");
    // The archive: alpha at one episode a second.
    let alpha: Vec<(u32, u32, f64)> = (0..20).map(|i| (0, i, f64::from(i + 1))).collect();
    t.archive_paced("alpha-seed1", &alpha, 20.0);
    std::fs::write(t.path("q.queue"), "alpha cfg.toml 1\nalpha cfg.toml 2\n").expect("queue");
    let seconds = || {
        let o = Command::new("python3")
            .args(["scripts/campaign_status.py", "q.queue", "--seconds", "alpha", "2"])
            .current_dir(&t.root)
            .output()
            .expect("campaign_status.py --seconds");
        String::from_utf8_lossy(&o.stdout).trim().to_string()
    };
    assert_eq!(seconds(), "5", "cfg.toml's 5 episodes at the archive's pace");
    // Here, alpha's seed 3 has gone on at 2.5 episodes a second past its initial design's 3.
    let here: Vec<(u32, u32, f64)> = (0..23).map(|i| (0, i, 0.4 * f64::from(i + 1))).collect();
    t.write_paced("runs/campaign/alpha-seed3", &here);
    std::fs::copy(t.path("cfg.toml"), t.path("runs/campaign/alpha-seed3/config.toml")).expect("its config");
    assert_eq!(seconds(), "2", "the same 5 episodes at this machine's pace, 2.5 times the archive's");
    // The lane-hours left too: alpha-seed1's 3,600 episodes an hour, archived elsewhere, are
    // 9,000 here.
    let status = t.status();
    assert!(status.contains("at the median pace of its finished runs (9000 episodes/h)"), "{status}");
    // Once alpha-seed3 ends it is archived too; its run directory here is still set against the
    // archive's other runs, not against itself (which would pull the factor to 1), and its own
    // pace, made here, is not scaled again (which would give 6.25 episodes a second).
    t.write_paced("docs/campaign/results/alpha-seed3", &here);
    std::fs::write(t.path("docs/campaign/results/alpha-seed3/summary.json"), "{\"interrupted\": false}").expect("summary");
    let status = t.status();
    assert!(status.contains("this machine: 2.50x the archive's pace (median over 1 run directory here)"), "{status}");
    assert_eq!(seconds(), "2", "alpha-seed1's pace scaled and alpha-seed3's as it is: 2.5 a second");
    // alpha-seed3 is not a line of q.queue: its pace is not the queue's; alpha-seed1's still 9,000.
    assert!(status.contains("(9000 episodes/h)"), "{status}");
    // With a second run at eight times the archive's pace the median (of two, the upper one) is
    // 8, taken as 3.
    let fast: Vec<(u32, u32, f64)> = (0..23).map(|i| (0, i, 0.125 * f64::from(i + 1))).collect();
    t.write_paced("runs/campaign/alpha-seed4", &fast);
    std::fs::copy(t.path("cfg.toml"), t.path("runs/campaign/alpha-seed4/config.toml")).expect("its config");
    let status = t.status();
    assert!(status.contains("this machine: 8.00x the archive's pace (median over 2 run directories here, taken as 3.00)"), "{status}");
    let _ = std::fs::remove_dir_all(t.root.parent().expect("base"));
}

/// A queue file that is not there (a mistyped name among several) stops the status listing with
/// its name and nothing printed for the others, not a Python traceback.
#[test]
fn a_missing_queue_file_is_named_before_anything_is_listed() {
    let t = Tree::new("noqueue");
    std::fs::write(t.root.join("q.queue"), "alpha cfg.toml 1\n").expect("the queue");
    let o = Command::new("python3")
        .args(["scripts/campaign_status.py", "q.queue", "nope.queue"])
        .current_dir(&t.root)
        .output()
        .expect("running campaign_status.py");
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    let out = text(&o);
    assert!(out.contains("cannot read queue file nope.queue"), "{out}");
    assert!(!out.contains("Traceback") && !out.contains("== q.queue"), "{out}");
    let _ = std::fs::remove_dir_all(t.root.parent().expect("base"));
}

/// A retrain line on a robot never retrained before is sized by its robot's co-adaptation pace
/// times what a training seed costs in co-adaptation episodes where retrains were made; without
/// it `--until` would never start the line.
#[test]
fn a_retrain_on_a_robot_never_retrained_is_sized_by_its_pace() {
    let t = Tree::new("retrain-pace");
    let env = |run: &str, e: &str| {
        std::fs::write(t.path(&format!("docs/campaign/results/{run}/config.toml")), format!("env = \"{e}\"\n")).expect("config");
    };
    // Robot a: one episode a second; its retrain's training seeds took 60 s each (60 episodes' worth).
    let a: Vec<(u32, u32, f64)> = (0..10).map(|i| (0, i, f64::from(i + 1))).collect();
    t.archive_paced("a-fear-seed1", &a, 10.0);
    env("a-fear-seed1", "a");
    for k in [1, 2] {
        let seed = t.path(&format!("docs/campaign/results/a-body-seed1/train-seed{k}"));
        std::fs::create_dir_all(&seed).expect("a training seed");
        std::fs::write(seed.join("config.toml"), "env = \"a\"\n").expect("its config");
        std::fs::write(seed.join("episodes.csv"), "episode,return,wall_s\n0,1.0,30.0\n1,1.0,60.0\n").expect("its rows");
    }
    std::fs::write(t.path("docs/campaign/results/a-body-seed1/summary.json"), "{}").expect("summary");
    // Robot b: half as fast, never retrained: two training seeds of 60 of its episodes, 240 s.
    let b: Vec<(u32, u32, f64)> = (0..10).map(|i| (0, i, 2.0 * f64::from(i + 1))).collect();
    t.archive_paced("b-fear-seed1", &b, 20.0);
    env("b-fear-seed1", "b");
    std::fs::write(t.path("q.queue"), "b-body retrain:b-fear:exploit 1\n").expect("queue");
    let seconds = |name: &str, seed: &str| {
        let o = Command::new("python3")
            .args(["scripts/campaign_status.py", "q.queue", "--seconds", name, seed])
            .current_dir(&t.root)
            .output()
            .expect("campaign_status.py --seconds");
        assert!(o.status.success(), "{}", text(&o));
        String::from_utf8_lossy(&o.stdout).trim().to_string()
    };
    assert_eq!(seconds("b-body", "1"), "240");
    let status = t.status();
    assert!(status.contains("pending  b-body-seed1") && status.contains("about 4 min"), "{status}");
    let _ = std::fs::remove_dir_all(t.root.parent().expect("base"));
}

/// A fork whose source finished on this machine (archived, its directory here) but kept only
/// its newest snapshots, not the one at design K: the source is set aside and its first K designs
/// are run again, as for a source whose directory is gone, instead of the fork failing.
#[test]
fn a_fork_of_a_finished_source_without_its_snapshot_runs_the_prefix_again() {
    let t = Tree::new("fork-pruned");
    t.archive_source(4);
    std::fs::write(t.path("q.queue"), "frk fork:src:2 1\n").expect("queue");
    // The source's directory here: finished, the archive's rows, only its last snapshot (design 4).
    let src = t.path("runs/campaign/src-seed1");
    let snap = src.join("snapshots/snap-00000009");
    std::fs::create_dir_all(&snap).expect("the source's snapshot");
    std::fs::write(snap.join("state.json"), r#"{"values": {"progress": {"design": 4, "in_design": null}}}"#).expect("its state");
    for f in ["episodes.csv", "config.toml", "summary.json"] {
        std::fs::copy(t.path(&format!("docs/campaign/results/src-seed1/{f}")), src.join(f)).expect("the source's files");
    }
    let has = |k: &str| {
        Command::new("bash")
            .arg(t.path("scripts/fork_run.sh"))
            .args(["--has", "runs/campaign/src-seed1", k])
            .status()
            .expect("fork_run.sh --has")
    };
    assert!(has("4").success() && !has("2").success(), "fork_run.sh --has");

    let done = t.run(&["-j", "1", "q.queue"]);
    let log = text(&done);
    assert!(done.status.success(), "{log}");
    assert!(log.contains("kept no snapshot at the start of design 2: set aside as runs/campaign/src-seed1.finished-"), "{log}");
    assert!(log.contains("row for row the archived ones"), "{log}");
    assert!(t.path("docs/campaign/results/frk-seed1/summary.json").exists(), "the fork was not archived: {log}");
    let aside = std::fs::read_dir(t.path("runs/campaign"))
        .expect("runs")
        .filter_map(|e| e.ok())
        .any(|e| e.file_name().to_string_lossy().starts_with("src-seed1.finished-"));
    assert!(aside, "the finished source was not kept aside: {log}");
    let _ = std::fs::remove_dir_all(t.root.parent().expect("base"));
}
