//! Stopping a queue run by `scripts/campaign.sh`, driven with the fake `coadapt` of
//! campaign_tree: `--stop` reaches a lane waiting for its fork and a run that cannot hear SIGINT
//! yet; `--stop-at-snapshot` waits for a snapshot newer than the call, or the deadline, but not
//! for a line that has just started.

use crate::campaign_tree;

use campaign_tree::*;
use std::time::{Duration, Instant};

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
