//! Fleets killed with SIGKILL at random points, role by role or whole, resume to the rows of a
//! run never stopped; a restarted optimiser gets the pending request at once.

use super::support::*;

#[test]
fn a_shared_memory_fleet_killed_at_random_points_resumes_to_the_rows_of_a_run_never_stopped() {
    killed_fleet("shm");
}

#[test]
fn a_grpc_fleet_killed_at_random_points_resumes_to_the_rows_of_a_run_never_stopped() {
    killed_fleet("grpc");
}

fn killed_fleet(transport: &str) {
    let dir = tmpdir(&format!("kill-{transport}"));
    let c = config();
    let want = reference(&dir, &c);
    let mut rng = kill_seed();
    let config = write_config(&dir, &c);
    let out = dir.join("fleet");
    let stderr = dir.join("stderr.txt");
    let run = coadapt(&["run", "--config", config.to_str().unwrap(), "--out", out.to_str().unwrap(), "--transport", transport], &stderr);
    let episodes = out.join("episodes.csv");
    // 2 initial designs x 3 episodes, then 4 x 2: 14 rows.
    // An actor mid-episode, somewhere in the initial designs.
    let at = 1 + draw(&mut rng, 3);
    wait_until("episode rows", &stderr, || rows(&episodes) >= at);
    let actor = role_pids(run.id(), "actor");
    assert_eq!(actor.len(), 1, "{}", std::fs::read_to_string(&stderr).unwrap_or_default());
    kill9(actor[0]);
    // The optimiser while the learner waits for the first chosen design (design 3).
    let log = || std::fs::read_to_string(&stderr).unwrap_or_default();
    wait_until("design 2 to end", &stderr, || log().contains("design 2 done"));
    let opt = role_pids(run.id(), "optimizer");
    assert_eq!(opt.len(), 1, "{}", log());
    kill9(opt[0]);
    // The learner, anywhere in the chosen designs but with at least three episodes (about a
    // second on a quiet machine) still to run: a later point raced the run's end (rows 12-13
    // plus up to 0.5 s found the learner already finished on a fast machine).
    let at = 7 + draw(&mut rng, 5);
    wait_until("episode rows", &stderr, || rows(&episodes) >= at);
    std::thread::sleep(Duration::from_millis(draw(&mut rng, 150) as u64));
    let learner = role_pids(run.id(), "learner");
    assert_eq!(learner.len(), 1, "no learner to kill after {} episode rows; {}", rows(&episodes), log());
    kill9(learner[0]);
    let o = run.wait_with_output().unwrap();
    let log = log();
    assert!(o.status.success(), "{log}");
    assert!(log.contains("actor 0 (pid") && log.contains("ended with signal 9; starting it again"), "{log}");
    assert!(log.contains("the learner (pid") && log.contains("starting it again from the newest snapshot"), "{log}");
    assert!(log.contains("learner: resuming"), "{log}");
    assert!(log.contains("fleet: optimizer (pid") && log.contains("learner: resuming"), "{log}");
    if transport == "shm" {
        // Over shared memory the dead optimiser took the request with it: the learner sent it
        // again to the restarted one (as soon as it was there, or after the 1.5 s resend,
        // whichever came first). (Over gRPC the learner's server delivers an unanswered
        // request again to the optimiser's next session itself.)
        let again = log.contains("learner: the optimiser is back; sent design request 2 to it again")
            || log.contains("learner: no reply to design request 2 for 1.5s; sending it again");
        assert!(again, "{log}");
    }
    let got = tables(&out);
    assert_eq!(got.0, want.0, "designs.csv differs from the run never stopped; {log}");
    assert_eq!(got.1, want.1, "episodes.csv differs from the run never stopped; {log}");
    // Every transition once: the summary counts the replay, 14 episodes of 1000 steps.
    let summary: serde_json::Value = serde_json::from_str(String::from_utf8_lossy(&o.stdout).lines().last().unwrap()).unwrap();
    assert_eq!(summary["replay_transitions"], 14_000, "{summary}");
    assert_eq!(summary["start_states"], 14, "{summary}");
}

/// Issue 29: a dead optimiser must not cost the whole resend wait. With the resend at 10
/// minutes, the optimiser killed while it searches for design 3 is restarted by the supervisor
/// and gets the request at once (over shared memory the learner sends it again as soon as the
/// new optimiser is there; over gRPC the learner's server offers it to the new session): the
/// run ends within five minutes (before, it waited out the 10).
#[test]
fn a_restarted_optimiser_gets_the_pending_request_at_once_over_shm() {
    restarted_optimiser("shm", "learner: the optimiser is back; sent design request 2 to it again");
}

#[test]
fn a_restarted_optimiser_gets_the_pending_request_at_once_over_grpc() {
    restarted_optimiser("grpc", "coadapt-grpc: a new optimiser session; 1 design request(s) another session had taken offered to it");
}

fn restarted_optimiser(transport: &str, says: &str) {
    let dir = tmpdir(&format!("optimizer-back-{transport}"));
    let mut c = config();
    c.schedule.design_request_resend_secs = 600.0;
    // A search of several seconds, so that the kill below lands inside it.
    c.optimizer.pso.particles = 60_000;
    c.optimizer.pso.iterations = 80;
    let config = write_config(&dir, &c);
    let out = dir.join("fleet");
    let stderr = dir.join("stderr.txt");
    let mut run =
        coadapt(&["run", "--config", config.to_str().unwrap(), "--out", out.to_str().unwrap(), "--transport", transport], &stderr);
    let log = || std::fs::read_to_string(&stderr).unwrap_or_default();
    wait_until("design 2 to end", &stderr, || log().contains("design 2 done"));
    // Into the search (20,000 particles x 40 iterations: seconds), so that the optimiser has
    // taken the request when it dies.
    std::thread::sleep(Duration::from_millis(1000));
    let opt = role_pids(run.id(), "optimizer");
    assert_eq!(opt.len(), 1, "{}", log());
    let t = Instant::now();
    kill9(opt[0]);
    let status = loop {
        if let Some(s) = run.try_wait().unwrap() {
            break s;
        }
        if t.elapsed() > Duration::from_secs(300) {
            let _ = run.kill();
            panic!("the run waited for the dead optimiser's request: {}", log());
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let log = log();
    assert!(status.success(), "{log}");
    assert!(log.contains("fleet: optimizer (pid") && log.contains(says), "{log}");
    assert_eq!(rows(&out.join("designs.csv")), 6, "{log}");
}

/// Over shared memory there is no run id: instead no actor or optimiser outlives the learner
/// start it served (their channels close when it dies), so nothing of a dead start (an
/// assignment id, an acknowledgement) can reach the next one. A learner killed with SIGKILL
/// under a fleet started by hand: the actor and the optimiser end by themselves.
#[test]
fn over_shared_memory_no_process_outlives_a_killed_learner() {
    let dir = tmpdir("shm-alone");
    let mut c = config();
    c.schedule.designs = 1000;
    c.optimizer.pso.particles = 40;
    c.optimizer.pso.iterations = 5;
    let config = write_config(&dir, &c);
    let fleet = format!("coadapt-test-{}-alone", std::process::id());
    let cfg = config.to_str().unwrap();
    let out = dir.join("run");
    let mut learner =
        coadapt(&["learner", "--config", cfg, "--transport", "shm", "--fleet", &fleet, "--out", out.to_str().unwrap()], &dir.join("l.txt"));
    let mut others = vec![
        coadapt(&["optimizer", "--config", cfg, "--transport", "shm", "--fleet", &fleet], &dir.join("o.txt")),
        coadapt(&["actor", "--config", cfg, "--transport", "shm", "--fleet", &fleet, "--id", "0"], &dir.join("a.txt")),
    ];
    // Past the initial designs: the optimiser has answered.
    wait_until("design 3 to start", &dir.join("l.txt"), || rows(&out.join("episodes.csv")) >= 8);
    kill9(learner.id());
    learner.wait().unwrap();
    let t = Instant::now();
    for p in &mut others {
        loop {
            if p.try_wait().unwrap().is_some() {
                break;
            }
            assert!(t.elapsed() < Duration::from_secs(60), "a process of the fleet outlived its learner by a minute");
            std::thread::sleep(Duration::from_millis(50));
        }
    }
    eprintln!("the fleet ended {:.1} s after its learner", t.elapsed().as_secs_f64());
}

/// The pod's role processes, killed when the test ends, passed or failed: a failed assertion
/// left a restarted optimiser waiting for its learner for ever.
struct Roles(Vec<Child>);

impl std::ops::Deref for Roles {
    type Target = Vec<Child>;
    fn deref(&self) -> &Vec<Child> {
        &self.0
    }
}

impl std::ops::DerefMut for Roles {
    fn deref_mut(&mut self) -> &mut Vec<Child> {
        &mut self.0
    }
}

impl Drop for Roles {
    fn drop(&mut self) {
        for p in &mut self.0 {
            let _ = p.kill();
            let _ = p.wait();
        }
    }
}

/// The Kubernetes shared-memory pod (deploy/k8s/examples/shm-pod): one container per role,
/// each started again by the kubelet whenever it ends, with no supervisor of ours. The learner
/// is killed with SIGKILL mid-run: it comes back alone with `--resume`, the actors and the
/// optimiser end with it (their channels close) and come back too, in whatever order, over the
/// dead start's shared memory; the run completes with the rows of a run never stopped.
#[test]
fn a_shared_memory_pod_restarted_role_by_role_resumes_to_the_rows_of_a_run_never_stopped() {
    let dir = tmpdir("pod");
    let c = config();
    let want = reference(&dir, &c);
    let mut rng = kill_seed();
    let config = write_config(&dir, &c);
    let cfg = config.to_str().unwrap();
    let out = dir.join("run");
    let out_s = out.to_str().unwrap().to_string();
    let state = dir.join("optimizer-state");
    let state_s = state.to_str().unwrap().to_string();
    let fleet = format!("coadapt-test-{}-pod", std::process::id());
    let args = |role: &str| -> Vec<String> {
        let mut a: Vec<String> =
            vec![role.into(), "--config".into(), cfg.into(), "--transport".into(), "shm".into(), "--fleet".into(), fleet.clone()];
        match role {
            "learner" => a.extend(["--out".into(), out_s.clone(), "--resume".into()]),
            "optimizer" => a.extend(["--state-dir".into(), state_s.clone()]),
            _ => a.extend(["--id".into(), "0".into()]),
        }
        a
    };
    let log = |role: &str, start: usize| dir.join(format!("{role}-{start}.txt"));
    let logs = || {
        let mut names: Vec<_> =
            std::fs::read_dir(&dir).unwrap().flatten().map(|e| e.path()).filter(|p| p.extension().is_some_and(|x| x == "txt")).collect();
        names.sort();
        names.iter().map(|p| format!("== {}\n{}", p.display(), std::fs::read_to_string(p).unwrap_or_default())).collect::<String>()
    };
    let roles = ["actor", "learner", "optimizer"];
    let mut starts = [0usize; 3];
    let start = |i: usize, starts: &mut [usize; 3]| {
        starts[i] += 1;
        let a = args(roles[i]);
        coadapt(&a.iter().map(String::as_str).collect::<Vec<_>>(), &log(roles[i], starts[i]))
    };
    // The kubelet starts the containers in no particular order: the actor first here.
    let mut procs = Roles((0..3).map(|i| start(i, &mut starts)).collect());
    let episodes = out.join("episodes.csv");
    let total = want.1.lines().count().saturating_sub(1);
    let at = 7 + draw(&mut rng, 5);
    let mut killed = false;
    let mut finished = false;
    let t = Instant::now();
    loop {
        assert!(t.elapsed() < Duration::from_secs(300), "the pod did not finish in 5 minutes; {}", logs());
        if !killed && rows(&episodes) >= at {
            std::thread::sleep(Duration::from_millis(draw(&mut rng, 150) as u64));
            kill9(procs[1].id());
            killed = true;
        }
        for i in 0..3 {
            if let Some(status) = procs[i].try_wait().unwrap() {
                if i == 1 && status.success() {
                    finished = true;
                }
                // Restarted like a container with restartPolicy Always, until the run is done.
                // An actor or optimiser that ends with the finished run (all its rows written)
                // can be seen before the learner's own exit: it is not started again, else it
                // would wait for a learner that never comes back.
                let run_done = i != 1 && rows(&episodes) >= total;
                if !finished && !run_done {
                    assert!(starts[i] < 6, "{} restarted {} times; {}", roles[i], starts[i], logs());
                    procs[i] = start(i, &mut starts);
                }
            }
        }
        if finished {
            break;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    // The others end by themselves once the learner has finished the run.
    for (i, p) in procs.iter_mut().enumerate() {
        let t = Instant::now();
        while p.try_wait().unwrap().is_none() {
            assert!(t.elapsed() < Duration::from_secs(60), "{} outlived the finished run; {}", roles[i], logs());
            std::thread::sleep(Duration::from_millis(20));
        }
    }
    assert!(killed, "the run ended before the kill point ({at} rows); {}", logs());
    assert!(starts[1] >= 2, "the learner was not started again; {}", logs());
    assert!(std::fs::read_to_string(log("learner", 2)).unwrap().contains("learner: resuming"), "{}", logs());
    let got = tables(&out);
    assert_eq!(got.0, want.0, "designs.csv differs from the run never stopped; {}", logs());
    assert_eq!(got.1, want.1, "episodes.csv differs from the run never stopped; {}", logs());
}

/// Issue 29 (6): a shared-memory run killed whole (SIGKILL of its process group, as an OOM
/// killer or a closed terminal does) at a random point resumes to the rows of a run never
/// stopped. Before, the roles (each in a process group of its own) ran on after their
/// supervisor died, and the resume reopened their fleet (`coadapt-<old pid>`, kept in
/// config.toml) beside them: every learner start failed with ExceedsMaxSupportedSubscribers.
/// Now the roles stop when their supervisor dies, and every start gets a fleet of its own.
#[test]
fn a_shared_memory_run_killed_whole_resumes_to_the_rows_of_a_run_never_stopped() {
    use std::os::unix::process::CommandExt;
    let dir = tmpdir("kill-group");
    let c = config();
    let want = reference(&dir, &c);
    let mut rng = kill_seed();
    let config = write_config(&dir, &c);
    let out = dir.join("run");
    let stderr = dir.join("stderr.txt");
    let run = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["run", "--config", config.to_str().unwrap(), "--out", out.to_str().unwrap(), "--transport", "shm"])
        .process_group(0)
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&stderr).unwrap())
        .spawn()
        .unwrap();
    // Early in the run (14 rows in all): a learner left running would have most of it to go.
    let at = 2 + draw(&mut rng, 4);
    wait_until("episode rows", &stderr, || rows(&out.join("episodes.csv")) >= at);
    let group = run.id();
    assert!(Command::new("kill").args(["-KILL", "--", &format!("-{group}")]).status().unwrap().success());
    let mut run = run;
    run.wait().unwrap();
    // The roles (each in a process group of its own) notice that their supervisor has gone and
    // stop; before, the learner ran on and wrote the run beside its resume.
    let holders = |role: &str| -> Vec<u32> {
        let needle = format!("{role}{}", out.to_str().unwrap());
        std::fs::read_dir("/proc")
            .unwrap()
            .flatten()
            .filter_map(|e| e.file_name().to_string_lossy().parse::<u32>().ok())
            .filter(|p| {
                let cmd = String::from_utf8_lossy(&std::fs::read(format!("/proc/{p}/cmdline")).unwrap_or_default()).replace('\0', " ");
                let stat = std::fs::read_to_string(format!("/proc/{p}/stat")).unwrap_or_default();
                let zombie = stat.rsplit_once(')').is_some_and(|(_, r)| r.trim_start().starts_with('Z'));
                cmd.contains(&needle) && !zombie
            })
            .collect()
    };
    // The learner (`--out RUN`) within 5 s (it checks for a stop every 100 ms; before, it ran the
    // rest of the run, searches included), every role of the run within 30 s.
    let t = Instant::now();
    while !holders("--out ").is_empty() {
        assert!(t.elapsed() < Duration::from_secs(5), "the learner outlived its killed supervisor by 5 s: {:?}", holders("--out "));
        std::thread::sleep(Duration::from_millis(50));
    }
    while !holders("").is_empty() {
        assert!(t.elapsed() < Duration::from_secs(30), "roles outlived their killed supervisor by 30 s: {:?}", holders(""));
        std::thread::sleep(Duration::from_millis(100));
    }
    let stderr2 = dir.join("stderr-resume.txt");
    let o = coadapt(&["run", "--resume", out.to_str().unwrap(), "--transport", "shm"], &stderr2).wait_with_output().unwrap();
    let log = std::fs::read_to_string(&stderr2).unwrap_or_default();
    assert!(o.status.success(), "killed after {at} rows: {log}");
    assert!(!log.contains("ExceedsMaxSupportedSubscribers") && !log.contains("left behind"), "{log}");
    let got = tables(&out);
    assert_eq!(got.0, want.0, "designs.csv differs from the run never stopped (killed after {at} rows); {log}");
    assert_eq!(got.1, want.1, "episodes.csv differs from the run never stopped (killed after {at} rows); {log}");
}
