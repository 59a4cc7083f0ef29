//! `coadapt search` through the binary: the run directory it writes, and refusals named.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::process::Command;

fn coadapt(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_coadapt")).args(args).output().unwrap()
}

#[test]
fn a_search_writes_its_run_directory_and_learns() {
    let dir = std::env::temp_dir().join(format!("coadapt-search-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let out = dir.join("g4");
    let o = coadapt(&["search", "--runs", "2", "--iterations", "15", "--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(summary["method"], "groups");
    let csv = std::fs::read_to_string(out.join("iterations.csv")).unwrap();
    let rows: Vec<Vec<f64>> = csv.lines().skip(1).map(|l| l.split(',').map(|v| v.parse().unwrap()).collect()).collect();
    assert_eq!(rows.len(), 30);
    // The mean policy's distance falls over each run (column 3), rollouts count up by 30.
    for run in [0.0, 1.0] {
        let r: Vec<&Vec<f64>> = rows.iter().filter(|x| x[0] == run).collect();
        assert!(r[14][3] < r[0][3], "run {run}: {} -> {}", r[0][3], r[14][3]);
        assert_eq!(r[14][2], 450.0);
    }
    assert_eq!(std::fs::read_to_string(out.join("rollouts.csv")).unwrap().lines().count(), 1 + 2 * 15 * 30);
    for f in ["config.toml", "run-0/policy.safetensors", "run-1/policy.safetensors", "plots/learning_curve.svg"] {
        assert!(out.join(f).exists(), "{f} missing");
    }
    // Run 0's synergies after every iteration (and before the first), and their plots.
    let bytes = std::fs::read(out.join("run-0/history.safetensors")).unwrap();
    let header_len = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + header_len]).unwrap();
    assert_eq!(header["W"]["shape"], serde_json::json!([16, 12, 6]));
    assert_eq!(header["M"]["shape"], serde_json::json!([16, 12, 11]));
    // A square per entry of W in each of the 5 panels (iterations 1, 2, 4, 8, 15); both arms in
    // each of the 9 poses.
    let svg = std::fs::read_to_string(out.join("plots/synergies.svg")).unwrap();
    assert!(svg.matches("<rect").count() >= 5 * 12 * 6 * 2, "synergies.svg: {svg:.300}");
    let svg = std::fs::read_to_string(out.join("plots/synergy_poses.svg")).unwrap();
    assert_eq!(svg.matches("<polyline").count(), 18, "synergy_poses.svg: {svg:.300}");
    // The policy file holds M (12 x 11) and W (12 x 6) as f64.
    let bytes = std::fs::read(out.join("run-0/policy.safetensors")).unwrap();
    let header_len = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + header_len]).unwrap();
    assert_eq!(header["M"]["shape"], serde_json::json!([12, 11]));
    assert_eq!(header["W"]["shape"], serde_json::json!([12, 6]));
    assert_eq!(header["M"]["dtype"], "F64");
    // Reuse of synergies: a second search takes the first's W after iteration 8 as W-hat.
    let cfg = dir.join("reuse.toml");
    let w = out.join("run-0/w-iter8.safetensors");
    assert!(!w.exists(), "saved without save-w-at");
    std::fs::write(&cfg, "save-w-at = 3\n").unwrap();
    let src = dir.join("src");
    let o = coadapt(&["search", "--config", cfg.to_str().unwrap(), "--runs", "1", "--iterations", "4", "--out", src.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let w = src.join("run-0/w-iter3.safetensors");
    assert!(w.exists());
    std::fs::write(
        &cfg,
        format!("w-hat = {:?}\n[groups-settings]\npool = 20\nfirst-rollouts = 20\nrollouts = 10\nbest = 10\n", w.display().to_string()),
    )
    .unwrap();
    let o = coadapt(&[
        "search",
        "--config",
        cfg.to_str().unwrap(),
        "--runs",
        "1",
        "--iterations",
        "3",
        "--out",
        dir.join("reuse").to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // 20 rollouts first, then 10 per iteration with the pool.
    let csv = std::fs::read_to_string(dir.join("reuse/iterations.csv")).unwrap();
    let counts: Vec<&str> = csv.lines().skip(1).map(|l| l.split(',').nth(2).unwrap()).collect();
    assert_eq!(counts, ["20", "30", "40"]);
    // A W of another latent dimension is refused, naming the shapes.
    std::fs::write(&cfg, format!("w-hat = {:?}\n[groups-settings]\nlatent = 4\n", w.display().to_string())).unwrap();
    let o = coadapt(&[
        "search",
        "--config",
        cfg.to_str().unwrap(),
        "--runs",
        "1",
        "--iterations",
        "1",
        "--out",
        dir.join("bad-w").to_str().unwrap(),
    ]);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("expected F64 [12, 4]"), "{e}");
    // Refusals: an existing search, an unknown method, a grouping that is not a partition.
    let o = coadapt(&["search", "--runs", "1", "--iterations", "1", "--out", out.to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("already holds a search"));
    let o = coadapt(&["search", "--method", "sgd", "--out", dir.join("x").to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("method: \"sgd\"; groups, pepper, power or nac"));
    let cfg = dir.join("bad.toml");
    std::fs::write(&cfg, "groups = [[0, 1, 2], [2, 3]]\n").unwrap();
    let o = coadapt(&["search", "--config", cfg.to_str().unwrap(), "--iterations", "1", "--out", dir.join("y").to_str().unwrap()]);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("groups: action 2 is in 2 groups"), "{e}");
    // Settings that would degrade silently are refused, naming the key.
    for (text, key) in [
        ("method = \"power\"\n[power]\nvariance = 0.0\n", "power.variance = 0"),
        ("method = \"power\"\n[power]\nbest = 40\n", "power.best = 40"),
        ("method = \"nac\"\n[nac]\nlearning-rate = -1.0\n", "nac.learning-rate = -1"),
        ("[groups-settings]\nbest = 31\n", "best = 31"),
    ] {
        std::fs::write(&cfg, text).unwrap();
        let o = coadapt(&["search", "--config", cfg.to_str().unwrap(), "--iterations", "1", "--out", dir.join("z").to_str().unwrap()]);
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && e.contains(key), "{text}: {e}");
    }
}

/// Every shipped search config (`configs/search/`) parses and names a method and a partition.
#[test]
fn every_shipped_search_config_is_valid() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/search");
    let mut seen = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "toml") {
            continue;
        }
        let c: coadapt_cli::search::SearchConfig =
            toml::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        assert!(["groups", "pepper", "power", "nac"].contains(&c.method.as_str()), "{}: {}", path.display(), c.method);
        let mut all: Vec<usize> = c.groups.iter().flatten().copied().collect();
        all.sort_unstable();
        assert_eq!(all, (0..12).collect::<Vec<_>>(), "{}: the groups partition the 12 actions", path.display());
        seen += 1;
    }
    assert!(seen >= 10, "{seen} configs");
}

/// The rollouts through a fleet of actor processes (shared memory and gRPC, started by the
/// search) and of actor threads: every transport gives the same iterations, within the f32
/// rewards' precision of the search run in process, and every rollout ran once on an actor.
#[test]
fn a_search_runs_its_rollouts_on_a_fleet_of_actor_processes() {
    let dir = std::env::temp_dir().join(format!("coadapt-search-fleet-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let table = |out: &std::path::Path| -> Vec<Vec<f64>> {
        let csv = std::fs::read_to_string(out.join("iterations.csv")).unwrap();
        csv.lines().skip(1).map(|l| l.split(',').map(|v| v.parse().unwrap()).collect()).collect()
    };
    let local = dir.join("local");
    let o = coadapt(&["search", "--runs", "1", "--iterations", "4", "--out", local.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let want = table(&local);
    let mut fleets = Vec::new();
    for transport in ["in-process", "shm", "grpc"] {
        let out = dir.join(transport);
        let o = coadapt(&[
            "search",
            "--runs",
            "1",
            "--iterations",
            "4",
            "--actors",
            "3",
            "--transport",
            transport,
            "--out",
            out.to_str().unwrap(),
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{transport}: {err}");
        let got = table(&out);
        assert_eq!(got.len(), want.len());
        for (g, w) in got.iter().zip(&want) {
            for (c, (x, y)) in g.iter().zip(w).enumerate() {
                assert!((x - y).abs() <= 1e-5 * y.abs().max(1.0), "{transport}: column {c}: {x} vs {y} in process");
            }
        }
        if transport != "in-process" {
            // Each actor process says how many rollouts it ran: 4 iterations of 30 in all.
            let ran: u64 = (0..3)
                .map(|i| {
                    let log = std::fs::read_to_string(out.join(format!("logs/actor-{i}.log"))).unwrap();
                    let n =
                        log.lines().find_map(|l| l.split("done after ").nth(1)).unwrap_or_else(|| panic!("{transport} actor {i}: {log}"));
                    n.split_whitespace().next().unwrap().parse::<u64>().unwrap()
                })
                .sum();
            assert_eq!(ran, 120, "{transport}: every rollout once");
        }
        fleets.push(got);
    }
    // The transports carry the same f32 values: identical iterations.
    assert_eq!(fleets[0], fleets[1]);
    assert_eq!(fleets[1], fleets[2]);
}

/// The search's actors stepping a robot served over dm_env_rpc (`coadapt env-serve --env
/// planar`): the same iterations as in process, within f32; and actors that cannot reach their
/// robot end the search at once, naming their logs.
#[test]
fn a_search_runs_its_rollouts_on_a_dm_env_rpc_robot() {
    let dir = std::env::temp_dir().join(format!("coadapt-search-remote-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let mut server = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["env-serve", "--env", "planar", "--listen", "127.0.0.1:0"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    std::io::BufRead::read_line(&mut std::io::BufReader::new(server.stdout.take().unwrap()), &mut line).unwrap();
    let url = line.trim().to_string();
    assert!(url.starts_with("dm-env-rpc://"), "{url}");
    let table = |out: &std::path::Path| -> Vec<Vec<f64>> {
        let csv = std::fs::read_to_string(out.join("iterations.csv")).unwrap();
        csv.lines().skip(1).map(|l| l.split(',').map(|v| v.parse().unwrap()).collect()).collect()
    };
    let local = dir.join("local");
    let o = coadapt(&["search", "--runs", "1", "--iterations", "3", "--out", local.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let cfg = dir.join("remote.toml");
    std::fs::write(&cfg, format!("robot = \"{url}\"\nactors = 2\n[fleet]\ntransport = \"shm\"\n")).unwrap();
    let out = dir.join("remote");
    let o = coadapt(&["search", "--config", cfg.to_str().unwrap(), "--runs", "1", "--iterations", "3", "--out", out.to_str().unwrap()]);
    let _ = server.kill();
    let _ = server.wait();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for (g, w) in table(&out).iter().zip(&table(&local)) {
        for (c, (x, y)) in g.iter().zip(w).enumerate() {
            assert!((x - y).abs() <= 1e-5 * y.abs().max(1.0), "column {c}: {x} over dm_env_rpc vs {y} in process");
        }
    }
    // Nobody at the robot's address: the actors fail, the search says so at once.
    std::fs::write(&cfg, "robot = \"dm-env-rpc://127.0.0.1:1\"\nactors = 2\n[fleet]\ntransport = \"shm\"\n[remote]\nconnect-timeout-secs = 0.5\nreconnect-secs = 1.0\n").unwrap();
    let t = std::time::Instant::now();
    let o = coadapt(&[
        "search",
        "--config",
        cfg.to_str().unwrap(),
        "--runs",
        "1",
        "--iterations",
        "3",
        "--out",
        dir.join("bad").to_str().unwrap(),
    ]);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("every search actor has ended"), "{e}");
    assert!(t.elapsed() < std::time::Duration::from_secs(60), "the search waited {:?} for actors that had ended", t.elapsed());
}
