//! The `coadapt` binary as a user runs it.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::path::PathBuf;
use std::process::{Command, Output};

fn coadapt(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_coadapt")).args(args).output().expect("coadapt runs")
}

fn tmpdir(name: &str) -> PathBuf {
    coadapt_test_support::scratch("cli", name)
}

#[test]
fn train_writes_a_run_directory_and_prints_one_json_summary() {
    let out = tmpdir("train");
    let o = coadapt(&[
        "train",
        "--env",
        "pendulum",
        "--algo",
        "sac",
        "--steps",
        "600",
        "--seed",
        "3",
        "--hidden",
        "32,32",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "stderr: {}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8(o.stdout).unwrap();
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.len(), 1, "stdout is exactly the JSON summary: {stdout}");
    let v: serde_json::Value = serde_json::from_str(lines[0]).unwrap();
    assert_eq!(v["env"], "pendulum");
    assert_eq!(v["algo"], "sac");
    assert_eq!(v["steps"], 600);
    assert_eq!(v["episodes"], 3);
    assert!(v["mean_return_last_10"].as_f64().unwrap() < 0.0);
    assert!(String::from_utf8_lossy(&o.stderr).contains("episode    3"), "progress is shown");

    let csv = std::fs::read_to_string(out.join("episodes.csv")).unwrap();
    let rows: Vec<&str> = csv.lines().collect();
    assert_eq!(rows[0], "episode,step,return,length,mean_return_last_10,wall_s");
    assert_eq!(rows.len(), 4);
    assert!(rows[3].starts_with("3,600,"));
    let nets = coadapt_nn::load_networks(&out.join("checkpoint.safetensors")).unwrap();
    let names: Vec<&str> = nets.iter().map(|n| n.name.as_str()).collect();
    assert_eq!(names, ["policy", "q1", "q1_target", "q2", "q2_target"]);
    let cfg = std::fs::read_to_string(out.join("config.toml")).unwrap();
    assert!(cfg.contains("steps = 600") && cfg.contains("hidden = [\n    32,\n    32,\n]"), "{cfg}");
}

#[test]
fn bad_input_gets_a_clear_error_naming_what_is_wrong() {
    let cases: &[(&[&str], &str)] = &[
        (&["train", "--steps", "0"], "steps"),
        (&["train", "--env", "cartpole"], "unknown environment `cartpole`"),
        (&["train", "--alpha", "-1"], "--alpha"),
        (&["train", "--alpha", "lots"], "--alpha"),
        (&["train", "--design", "5,5"], "design[0] = 5"),
        (&["train", "--design", "1"], "design has 1 values, expected 2"),
        (&["train", "--hidden", "0,4"], "hidden"),
        (&["train", "--stop-at-target"], "--target-return"),
        (&["train", "--config", "/nonexistent/coadapt.toml"], "reading config"),
        (&["train", "--algo", "ppo"], "invalid value 'ppo'"),
    ];
    // In a directory of its own: a refused command must leave no run directory behind.
    let cwd = tmpdir("bad-input");
    std::fs::create_dir_all(&cwd).unwrap();
    for (args, needle) in cases {
        let o = Command::new(env!("CARGO_BIN_EXE_coadapt")).args(*args).current_dir(&cwd).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?} should fail");
        assert!(err.contains(needle), "{args:?}: stderr `{err}` does not mention `{needle}`");
        assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
        assert!(!cwd.join("runs").exists(), "{args:?} left a run directory behind");
    }
}

#[test]
fn config_files_are_validated_by_field() {
    let dir = tmpdir("cfg");
    std::fs::create_dir_all(&dir).unwrap();
    let unknown = dir.join("unknown.toml");
    std::fs::write(&unknown, "steps = 100\n[sac]\nlearning-rate = 0.1\n").unwrap();
    let o = coadapt(&["train", "--config", unknown.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(err.contains("learning-rate"), "{err}");

    let bad_gamma = dir.join("gamma.toml");
    std::fs::write(&bad_gamma, "[sac]\ngamma = 1.5\n").unwrap();
    let o = coadapt(&["train", "--config", bad_gamma.to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("gamma"));

    let good = dir.join("good.toml");
    std::fs::write(&good, "steps = 250\nlearning-starts = 50\n[sac]\nhidden = [16]\nauto-alpha = true\n").unwrap();
    let out = dir.join("run");
    let o = coadapt(&["train", "--config", good.to_str().unwrap(), "--quiet", "--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["steps"], 250);
}

#[test]
fn init_weights_resume_from_a_checkpoint_and_bad_files_are_clear_errors() {
    let dir = tmpdir("weights");
    let first = dir.join("first");
    let o = coadapt(&["train", "--steps", "200", "--hidden", "16", "--quiet", "--out", first.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let ckpt = first.join("checkpoint.safetensors");
    let second = dir.join("second");
    let o = coadapt(&[
        "train",
        "--steps",
        "200",
        "--hidden",
        "16",
        "--quiet",
        "--init-weights",
        ckpt.to_str().unwrap(),
        "--out",
        second.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    let cases = [
        (dir.join("missing.safetensors"), None, "cannot read weights file"),
        (dir.join("corrupt.safetensors"), Some(b"garbage bytes, not safetensors".to_vec()), "not a valid safetensors file"),
    ];
    for (path, content, needle) in cases {
        if let Some(c) = content {
            std::fs::write(&path, c).unwrap();
        }
        let o = coadapt(&[
            "train",
            "--steps",
            "200",
            "--hidden",
            "16",
            "--quiet",
            "--init-weights",
            path.to_str().unwrap(),
            "--out",
            dir.join("x").to_str().unwrap(),
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success());
        assert!(err.contains(needle) && err.contains(path.file_name().unwrap().to_str().unwrap()), "{err}");
        assert!(!err.contains("panicked"), "{err}");
    }
    // A checkpoint of other shapes names the network and both shapes.
    let o = coadapt(&[
        "train",
        "--steps",
        "200",
        "--hidden",
        "32",
        "--quiet",
        "--init-weights",
        ckpt.to_str().unwrap(),
        "--out",
        dir.join("y").to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("network `policy`") && err.contains("[5, 16, 2]") && err.contains("[5, 32, 2]"), "{err}");
}

#[test]
fn help_explains_the_commands() {
    let o = coadapt(&["--help"]);
    let s = String::from_utf8_lossy(&o.stdout);
    assert!(s.contains("train") && s.contains("bench"));
    let o = coadapt(&["train", "--help"]);
    let s = String::from_utf8_lossy(&o.stdout);
    assert!(s.contains("episodes.csv") && s.contains("--target-return"));
}

/// Issue 29 (5): progress lines that cannot be written (stderr on a full device, as when the
/// log lives on a full disk) never take the run down: the fleet of processes runs to the end
/// and writes every row. Before, `eprintln!` panicked and the run exited 101.
#[test]
fn a_run_whose_stderr_cannot_be_written_still_runs_to_the_end() {
    let out = tmpdir("dev-full");
    let config = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/half-cheetah-tiny.toml");
    let full = std::fs::OpenOptions::new().write(true).open("/dev/full").unwrap();
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["run", "--config", config.to_str().unwrap(), "--out", out.join("run").to_str().unwrap()])
        .stderr(full)
        .output()
        .unwrap();
    assert!(o.status.success(), "exit {:?}; stdout {}", o.status, String::from_utf8_lossy(&o.stdout));
    let summary: serde_json::Value = serde_json::from_str(String::from_utf8_lossy(&o.stdout).lines().last().unwrap()).unwrap();
    assert_eq!(summary["interrupted"], false, "{summary}");
    let rows = std::fs::read_to_string(out.join("run/episodes.csv")).unwrap().lines().count() - 1;
    assert_eq!(rows, 10, "every episode of the tiny protocol");
}

/// Issue 29 (3): an initial design outside the design box is refused when the config is read,
/// naming the key, the entry and the bounds; before, it was accepted, the actor failed on it and
/// the run waited on its lease for ever.
#[test]
fn an_initial_design_outside_the_box_is_refused_at_load_naming_the_key_and_bounds() {
    let dir = tmpdir("outside-box");
    std::fs::create_dir_all(&dir).unwrap();
    let tiny = std::fs::read_to_string(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/half-cheetah-tiny.toml")).unwrap();
    let bad = tiny.replace("[1.41, 0.96, 1.97, 1.73, 1.97, 1.17]", "[1.41, 0.96, 0.5, 1.73, 1.97, 1.17]");
    assert_ne!(bad, tiny, "the tiny config's second initial design is where the test puts 0.5");
    let cfg = dir.join("outside.toml");
    std::fs::write(&cfg, bad).unwrap();
    let t = std::time::Instant::now();
    let o = coadapt(&["run", "--config", cfg.to_str().unwrap(), "--out", dir.join("run").to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(err.contains("schedule.initial-designs[1]") && err.contains("design[2] = 0.5") && err.contains("[0.8, 2]"), "{err}");
    assert!(t.elapsed() < std::time::Duration::from_secs(30), "refused at load, not after a lease: {:?}", t.elapsed());
}

/// Issue 29 (1): off loopback every server needs TLS **and** role tokens unless `--insecure`:
/// with TLS and no tokens file, the learner's fleet endpoint, a run's live design service,
/// `coadapt serve` and `coadapt env-serve` all refuse to start, naming the tokens file; before,
/// they started and let every caller in as an operator. With tokens too they get past the check.
#[test]
fn off_loopback_every_server_needs_tls_and_tokens() {
    let dir = tmpdir("tls-no-tokens");
    std::fs::create_dir_all(&dir).unwrap();
    let o = coadapt(&["tls", "new", "--out", dir.join("tls").to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let tokens = dir.join("tokens");
    let o = coadapt(&[
        "token",
        "new",
        "--role",
        "actor",
        "--out",
        dir.join("actor.token").to_str().unwrap(),
        "--tokens-file",
        tokens.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (cert, key) = (dir.join("tls/server.pem"), dir.join("tls/server-key.pem"));
    let tls = ["--tls-cert", cert.to_str().unwrap(), "--tls-key", key.to_str().unwrap()];
    let config = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/half-cheetah-tiny.toml");
    let config = config.to_str().unwrap();
    let out = dir.join("learner");
    let servers: Vec<(&str, Vec<&str>)> = vec![
        (
            "fleet.listen",
            vec!["learner", "--config", config, "--transport", "grpc", "--listen", "0.0.0.0:0", "--out", out.to_str().unwrap()],
        ),
        (
            "design-service.listen",
            vec![
                "learner",
                "--config",
                config,
                "--transport",
                "grpc",
                "--listen",
                "127.0.0.1:0",
                "--serve",
                "0.0.0.0:0",
                "--out",
                out.to_str().unwrap(),
            ],
        ),
        ("--listen", vec!["env-serve", "--env", "half-cheetah", "--listen", "0.0.0.0:0"]),
    ];
    for (key, args) in &servers {
        let all: Vec<&str> = args.iter().copied().chain(tls).collect();
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_coadapt")).args(&all).output().unwrap();
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{key}: started with TLS and no tokens: {e}");
        assert!(e.contains(key) && e.contains("no role tokens (security.tokens-file") && e.contains("--insecure"), "{key}: {e}");
        assert!(!e.contains("no TLS"), "{key}: TLS was given: {e}");
    }
    // Without TLS either, both are named.
    let o = coadapt(&["env-serve", "--env", "half-cheetah", "--listen", "0.0.0.0:0"]);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("no TLS") && e.contains("no role tokens"), "{e}");
    // TLS and tokens: env-serve starts (stopped at once).
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["env-serve", "--env", "half-cheetah", "--listen", "0.0.0.0:0", "--tokens-file", tokens.to_str().unwrap()])
        .args(tls)
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut line = String::new();
    std::io::BufRead::read_line(&mut std::io::BufReader::new(child.stderr.take().unwrap()), &mut line).unwrap();
    let _ = child.kill();
    let _ = child.wait();
    assert!(line.contains("env-serve: serving"), "{line}");
}

/// `coadapt ARGS`, killed if it has not ended within `secs` (a restart loop would not end).
fn coadapt_within(args: &[&str], secs: u64) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(args)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("coadapt runs");
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(secs);
    while child.try_wait().unwrap().is_none() {
        if std::time::Instant::now() > deadline {
            child.kill().unwrap();
            let o = child.wait_with_output().unwrap();
            panic!("{args:?} still ran after {secs} s: {}", String::from_utf8_lossy(&o.stderr));
        }
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    child.wait_with_output().unwrap()
}

/// A setting that cannot work fails the same way every time: every command exits 78
/// (`EX_CONFIG`) for it, so a supervisor (the local fleet's, systemd's, Slurm's) does not start
/// it again, whichever process meets it (the optimiser's settings are read by the optimiser).
#[test]
fn a_setting_that_cannot_work_exits_78_from_any_role() {
    let dir = tmpdir("exit78");
    std::fs::create_dir_all(&dir).unwrap();
    let tiny = std::fs::read_to_string(coadapt_test_support::workspace_file("configs/half-cheetah-tiny.toml")).unwrap();
    let bad = dir.join("pessimism.toml");
    std::fs::write(&bad, tiny.replace("[optimizer]\n", "[optimizer]\npessimism = -1.0\n")).unwrap();
    let bad = bad.to_str().unwrap();
    let critics = dir.join("critics.toml");
    std::fs::write(&critics, tiny.replace("[learner]\n", "[learner]\npopulation-critics = 1\n")).unwrap();
    let critics = critics.to_str().unwrap();
    let conservative = dir.join("conservative.toml");
    std::fs::write(&conservative, format!("{tiny}\n[learner.conservative]\nweight = 1.0\nstep = 0.0\n")).unwrap();
    let conservative = conservative.to_str().unwrap();
    let no_head = dir.join("no-head.toml");
    std::fs::write(&no_head, format!("{tiny}\n[learner.conservative]\nweight = 1.0\n")).unwrap();
    let no_head = no_head.to_str().unwrap();
    let heads = dir.join("heads.toml");
    std::fs::write(&heads, tiny.replace("[optimizer]\n", "[optimizer]\nq = \"heads\"\n")).unwrap();
    let heads = heads.to_str().unwrap();
    let good = coadapt_test_support::workspace_file("configs/half-cheetah-tiny.toml");
    let good = good.to_str().unwrap();
    let search = coadapt_test_support::workspace_file("configs/search/planar-groups1.toml");
    let search = search.to_str().unwrap();
    let v = |a: &[&str]| a.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    let cases: Vec<(Vec<String>, &str)> = vec![
        (v(&["train", "--steps", "0"]), "steps"),
        (v(&["search-actor", "--config", search, "--id", "0", "--transport", "in-process"]), "fleet.transport"),
        (v(&["run", "--config", bad, "--transport", "in-process"]), "optimizer.pessimism: -1 is not a finite number >= 0"),
        (v(&["run", "--config", critics, "--transport", "in-process"]), "learner.population-critics: 1 is fewer than 2"),
        (v(&["run", "--config", conservative, "--transport", "in-process"]), "learner.conservative.step: 0 is not in (0, 1] box widths"),
        (v(&["run", "--config", no_head, "--transport", "in-process"]), "learner.conservative.weight: the term trains the ensemble heads"),
        (
            v(&["run", "--config", heads, "--transport", "in-process"]),
            "optimizer.q: \"heads\" scores designs with the critics beyond the twin",
        ),
        // The supervisor stops the fleet naming the role; the role's log names the setting.
        (
            v(&["run", "--config", bad, "--transport", "shm", "--actors", "1"]),
            "the optimizer ended with exit code 78 because its configuration is invalid",
        ),
        (v(&["run", "--config", good, "--serve", "not-an-address"]), "design-service.listen"),
    ];
    for (i, (args, needle)) in cases.iter().enumerate() {
        let out = dir.join(format!("run{i}"));
        let mut args: Vec<&str> = args.iter().map(String::as_str).collect();
        if args[0] == "run" {
            args.extend(["--out", out.to_str().unwrap()]);
        }
        let o = coadapt_within(&args, 120);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(78), "{args:?}: {err}");
        assert!(err.contains(needle), "{args:?}: stderr `{err}` does not mention `{needle}`");
        if args.contains(&"shm") {
            let log = std::fs::read_to_string(out.join("logs").join("optimizer.log")).unwrap();
            assert!(log.contains("optimizer.pessimism: -1 is not a finite number >= 0"), "{log}");
        }
    }
}
