//! Snapshots: a damaged newest one falls back to the one before, a resume that would change what
//! the run learns is refused naming the key, periodic ones wait while they would take more than
//! their share of the time.

use super::support::*;

#[test]
fn a_damaged_newest_snapshot_falls_back_to_the_one_before() {
    let dir = tmpdir("corrupt");
    let c = config();
    let want = reference(&dir, &c);
    let config = write_config(&dir, &c);
    let out = dir.join("run");
    let stderr = dir.join("stderr.txt");
    let mut run =
        coadapt(&["run", "--config", config.to_str().unwrap(), "--out", out.to_str().unwrap(), "--transport", "in-process"], &stderr);
    wait_until("ten episodes", &stderr, || rows(&out.join("episodes.csv")) >= 10);
    run.kill().unwrap();
    run.wait().unwrap();
    let snaps = coadapt_learner::snapshot::list(&out.join("snapshots")).unwrap();
    assert!(snaps.len() >= 2, "{snaps:?}");
    let newest = &snaps.last().unwrap().1;
    // One flipped bit in the middle of the arrays.
    let bin = newest.join("arrays.bin");
    let mut bytes = std::fs::read(&bin).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x10;
    std::fs::write(&bin, bytes).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_coadapt")).args(["run", "--resume", out.to_str().unwrap()]).output().unwrap();
    let log = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{log}");
    let name = newest.file_name().unwrap().to_string_lossy();
    assert!(log.contains(&format!("skipped snapshot {name}: damaged: arrays.bin: array")) && log.contains("checksum"), "{log}");
    let got = tables(&out);
    assert_eq!(got, want, "{log}");

    // A truncated snapshot is found out too, and with every snapshot damaged the run is
    // refused, naming each.
    for (_, s) in coadapt_learner::snapshot::list(&out.join("snapshots")).unwrap() {
        let f = std::fs::OpenOptions::new().write(true).open(s.join("arrays.bin")).unwrap();
        f.set_len(f.metadata().unwrap().len() / 2).unwrap();
    }
    let o = Command::new(env!("CARGO_BIN_EXE_coadapt")).args(["run", "--resume", out.to_str().unwrap()]).output().unwrap();
    let log = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(log.contains("no usable snapshot") && log.contains("arrays.bin has") && log.contains("the manifest says"), "{log}");
}

#[test]
fn a_resume_that_would_change_what_the_run_learns_is_refused_naming_the_key() {
    let dir = tmpdir("config");
    let mut c = config();
    c.schedule.designs = 3;
    let config = write_config(&dir, &c);
    let out = dir.join("run");
    let o = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["run", "--config", config.to_str().unwrap(), "--out", out.to_str().unwrap(), "--transport", "in-process"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // Another learning rate: refused, naming it.
    let mut other = c.clone();
    other.learner.sac.policy_lr = 1e-3;
    let other_path = dir.join("other.toml");
    std::fs::write(&other_path, toml::to_string(&other).unwrap()).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["run", "--resume", out.to_str().unwrap(), "--config", other_path.to_str().unwrap()])
        .output()
        .unwrap();
    let log = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(log.contains("`learner.sac.policy-lr`"), "{log}");
    // Another seed by flag: refused too.
    let o = Command::new(env!("CARGO_BIN_EXE_coadapt")).args(["run", "--resume", out.to_str().unwrap(), "--seed", "7"]).output().unwrap();
    assert!(String::from_utf8_lossy(&o.stderr).contains("`seed`"), "{}", String::from_utf8_lossy(&o.stderr));
    // A longer schedule may change: the finished run goes on to 5 designs.
    let o = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["run", "--resume", out.to_str().unwrap(), "--designs", "5", "--transport", "in-process"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(rows(&out.join("designs.csv")), 5);
    assert_eq!(rows(&out.join("episodes.csv")), 2 * 3 + 3 * 2);
}

/// The number of snapshots a finished run's learner reports taking (`learner: N snapshot(s)`).
fn snapshots_taken(stderr: &str) -> usize {
    let at = stderr.find(" snapshot(s) in ").unwrap_or_else(|| panic!("no snapshot count in: {stderr}"));
    let head = &stderr[..at];
    head[head.rfind(' ').map_or(0, |i| i + 1)..].parse().unwrap_or_else(|e| panic!("{e}: {stderr}"))
}

/// `snapshot.max-share` holds periodic snapshots back while the last one's write time would be
/// more than that share of the time since it: with a share of a millionth, a snapshot after
/// every episode (`every-episodes = 1`) becomes the first one and one at each design's end;
/// with a share of 1, one after every episode. The rows are the same either way.
#[test]
fn snapshots_wait_while_their_write_time_would_exceed_the_share() {
    let dir = tmpdir("share");
    let mut c = config();
    c.schedule.designs = 3;
    c.optimizer.pso.particles = 50;
    c.optimizer.pso.iterations = 5;
    c.snapshot.every_episodes = 1;
    let mut taken = vec![];
    let mut tables_of = vec![];
    for share in [1.0, 1e-6] {
        c.snapshot.max_share = share;
        let sub = dir.join(format!("share-{share}"));
        std::fs::create_dir_all(&sub).unwrap();
        let config = write_config(&sub, &c);
        let out = sub.join("run");
        let o = Command::new(env!("CARGO_BIN_EXE_coadapt"))
            .args(["run", "--config", config.to_str().unwrap(), "--out", out.to_str().unwrap(), "--transport", "in-process"])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr).to_string();
        assert!(o.status.success(), "{stderr}");
        taken.push(snapshots_taken(&stderr));
        tables_of.push(tables(&out));
    }
    // 3 designs: 3 + 3 + 2 episodes (3 initial episodes on each initial design, then 2).
    let episodes = rows(&dir.join("share-1/run/episodes.csv"));
    assert_eq!(episodes, 8, "the tiny protocol's episodes");
    // Share 1: after every episode but each design's last (the design's end takes that one).
    assert_eq!(taken[0], episodes - 3 + 3, "share 1: {taken:?}");
    // A millionth: the first periodic one, then only the designs' ends.
    assert_eq!(taken[1], 1 + 3, "share 1e-6: {taken:?}");
    assert_eq!(tables_of[0], tables_of[1], "the snapshots changed the rows");
}
