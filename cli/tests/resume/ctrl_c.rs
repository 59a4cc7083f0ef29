//! Ctrl-C: mid-design it stops the run with a snapshot to resume from; while the learner trains
//! it stops the run cleanly.

use crate::support::*;

/// Ctrl-C in the middle of a design stops the run at once with a snapshot of where it stood
/// (taken when no episode is out); `--resume` continues from it to the rows of a run never
/// stopped.
#[test]
fn a_run_stopped_with_ctrl_c_mid_design_resumes_to_the_rows_of_a_run_never_stopped() {
    let dir = tmpdir("ctrl-c");
    let c = config();
    let want = reference(&dir, &c);
    let mut rng = kill_seed();
    let config = write_config(&dir, &c);
    let out = dir.join("run");
    let stderr = dir.join("stderr.txt");
    let run = coadapt(&["run", "--config", config.to_str().unwrap(), "--out", out.to_str().unwrap(), "--transport", "in-process"], &stderr);
    // Rows 1-10: at least four episodes (more than a second) still to run when Ctrl-C lands; a
    // later point raced the run's end (CI: Ctrl-C after row 13 found the run finished).
    let at = 1 + draw(&mut rng, 10);
    wait_until("episode rows", &stderr, || rows(&out.join("episodes.csv")) >= at);
    assert!(Command::new("kill").args(["-INT", &run.id().to_string()]).status().unwrap().success());
    let o = run.wait_with_output().unwrap();
    let log = std::fs::read_to_string(&stderr).unwrap_or_default();
    assert!(o.status.success(), "{log}");
    let summary: serde_json::Value = serde_json::from_str(String::from_utf8_lossy(&o.stdout).lines().last().unwrap()).unwrap();
    assert_eq!(summary["interrupted"], true, "{summary}");
    let stopped_at = rows(&out.join("episodes.csv"));
    assert!(stopped_at < 14, "the run went on to the end after Ctrl-C: {stopped_at} episodes");
    // Ctrl-C while an episode is out stops without waiting for it; before the run's first
    // snapshot (CI drew a Ctrl-C after the first episode) there is nothing to resume from and
    // the run starts over, which must give the same rows too.
    let snapshots = coadapt_learner::snapshot::list(&out.join("snapshots")).map(|s| s.len()).unwrap_or(0);
    let stderr2 = dir.join("stderr-resume.txt");
    let o = coadapt(&["run", "--resume", out.to_str().unwrap(), "--transport", "in-process"], &stderr2).wait_with_output().unwrap();
    let log2 = std::fs::read_to_string(&stderr2).unwrap_or_default();
    assert!(o.status.success(), "{log2}");
    if snapshots > 0 {
        assert!(log2.contains("learner: resuming"), "{snapshots} snapshot(s), yet: {log2}");
    } else {
        assert!(log2.contains("has no snapshot yet: starting the run over"), "{log2}");
    }
    let got = tables(&out);
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
