//! Ctrl-C: mid-design it stops the run with a snapshot to resume from, before the first
//! periodic snapshot too; while the learner trains it stops the run cleanly.

use super::support::*;

/// Ctrl-C in the middle of a design stops the run at once with a snapshot of where it stood;
/// `--resume` continues from it to the rows of a run never stopped.
#[test]
fn a_run_stopped_with_ctrl_c_mid_design_resumes_to_the_rows_of_a_run_never_stopped() {
    let dir = tmpdir("ctrl-c");
    let c = config();
    let want = reference(&dir, &c);
    let mut rng = kill_seed();
    // Rows 1-10: at least four episodes (more than a second) still to run when Ctrl-C lands; a
    // later point raced the run's end (CI: Ctrl-C after row 13 found the run finished).
    let at = 1 + draw(&mut rng, 10);
    let (out, stopped_at, log) = stop_after_row(&dir, &c, at, 0);
    assert!(stopped_at < 14, "the run went on to the end after Ctrl-C: {stopped_at} episodes");
    // Ctrl-C after a row always leaves a snapshot, even before the run's first periodic one
    // (CI once drew a Ctrl-C after the first episode, which then left none): see below.
    let snapshots = coadapt_learner::snapshot::list(&out.join("snapshots")).map(|s| s.len()).unwrap_or(0);
    assert!(snapshots > 0, "stopped after {stopped_at} episodes with no snapshot: {log}");
    resume_to(&dir, &out, &want, stopped_at, "");
}

/// Ctrl-C before the first periodic snapshot, with an episode out (most of the time is spent
/// waiting for episodes): the stop used to leave no snapshot (a stop waited for no episode and
/// snapshotted only when nothing was out), so a run stopped in its first design began again
/// (9 episodes of a campaign run lost so). Now a training episode out is handed out again on
/// resume (the snapshot is the one of the moment it was handed out) and an evaluation out is
/// waited for; either way the run resumes where it stopped, to the rows of a run never stopped.
#[test]
fn ctrl_c_before_the_first_periodic_snapshot_leaves_one_to_resume_from() {
    let dir = tmpdir("ctrl-c-first");
    let mut c = config();
    c.schedule.designs = 2;
    c.schedule.initial_episodes = 12;
    // No periodic snapshot in the whole run: what there is comes from the stop.
    c.snapshot.every_episodes = 1000;
    let want = reference(&dir, &c);
    let mut rng = kill_seed();
    // Past a row, into the next episodes by a random part of one (rows take ~0.1-0.3 s).
    let at = 1 + draw(&mut rng, 6);
    let (out, stopped_at, log) = stop_after_row(&dir, &c, at, draw(&mut rng, 200) as u64);
    assert!(stopped_at < 12, "the first design ran to its end after Ctrl-C ({stopped_at} episodes): nothing tested; {log}");
    let snaps = coadapt_learner::snapshot::list(&out.join("snapshots")).unwrap_or_default();
    assert_eq!(snaps.len(), 1, "one snapshot, the stop's, after {stopped_at} episodes: {snaps:?}; {log}");
    resume_to(&dir, &out, &want, stopped_at, &format!("design 0 episode {stopped_at}"));
}

/// Runs `c` in process, Ctrl-C `ms` milliseconds after row `at` of episodes.csv; the run
/// directory, the rows it stopped at, and its log. The run must stop cleanly, interrupted.
fn stop_after_row(dir: &Path, c: &RunConfig, at: usize, ms: u64) -> (PathBuf, usize, String) {
    let config = write_config(dir, c);
    let out = dir.join("run");
    let stderr = dir.join("stderr.txt");
    let run = coadapt(&["run", "--config", config.to_str().unwrap(), "--out", out.to_str().unwrap(), "--transport", "in-process"], &stderr);
    wait_until("episode rows", &stderr, || rows(&out.join("episodes.csv")) >= at);
    std::thread::sleep(Duration::from_millis(ms));
    assert!(Command::new("kill").args(["-INT", &run.id().to_string()]).status().unwrap().success());
    let o = run.wait_with_output().unwrap();
    let log = std::fs::read_to_string(&stderr).unwrap_or_default();
    assert!(o.status.success(), "{log}");
    let summary: serde_json::Value = serde_json::from_str(String::from_utf8_lossy(&o.stdout).lines().last().unwrap()).unwrap();
    assert_eq!(summary["interrupted"], true, "{summary}");
    let stopped_at = rows(&out.join("episodes.csv"));
    (out, stopped_at, log)
}

/// `--resume`s the run in `out` from a snapshot (whose label holds `label`) to the end, and
/// compares its tables with the run never stopped.
fn resume_to(dir: &Path, out: &Path, want: &(String, String), stopped_at: usize, label: &str) {
    let stderr2 = dir.join("stderr-resume.txt");
    let o = coadapt(&["run", "--resume", out.to_str().unwrap(), "--transport", "in-process"], &stderr2).wait_with_output().unwrap();
    let log2 = std::fs::read_to_string(&stderr2).unwrap_or_default();
    assert!(o.status.success(), "{log2}");
    assert!(log2.contains("learner: resuming") && log2.contains(label), "not resumed from a snapshot labelled {label:?}: {log2}");
    let got = tables(out);
    assert_eq!(got.0, want.0, "designs.csv differs from the run never stopped (stopped after {stopped_at} episodes); {log2}");
    assert_eq!(got.1, want.1, "episodes.csv differs from the run never stopped (stopped after {stopped_at} episodes); {log2}");
}

/// Ctrl-C while the learner trains (long updates, short episodes: the actor sits idle): the
/// in-process actor used to leave on the signal and close its channel under the learner's next
/// request, so the run failed with "the other side of the channel has closed" instead of
/// stopping. Now the roles stop when the learner is done: the run stops cleanly, interrupted.
#[test]
fn ctrl_c_while_the_learner_trains_stops_the_run_cleanly() {
    let dir = tmpdir("ctrl-c-training");
    let mut c = config();
    c.learner.individual_updates = 4000;
    let config = write_config(&dir, &c);
    let out = dir.join("run");
    let stderr = dir.join("stderr.txt");
    let run = coadapt(&["run", "--config", config.to_str().unwrap(), "--out", out.to_str().unwrap(), "--transport", "in-process"], &stderr);
    wait_until("the first episode row", &stderr, || rows(&out.join("episodes.csv")) >= 1);
    // The next episode takes milliseconds; its 4,000 updates far longer.
    std::thread::sleep(Duration::from_millis(150));
    assert!(Command::new("kill").args(["-INT", &run.id().to_string()]).status().unwrap().success());
    let o = run.wait_with_output().unwrap();
    let log = std::fs::read_to_string(&stderr).unwrap_or_default();
    assert!(o.status.success(), "{log}");
    assert!(!log.contains("channel has closed"), "{log}");
    let summary: serde_json::Value = serde_json::from_str(String::from_utf8_lossy(&o.stdout).lines().last().unwrap()).unwrap();
    assert_eq!(summary["interrupted"], true, "{summary}");
}
