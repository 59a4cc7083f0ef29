//! `coadapt serve RUN_DIR` through the binary, queried by the coadapt-client package
//! (`pip install ./clients/python`: stubs generated from proto/ as it builds) with its own
//! pytest suite, and by the example (clients/python/example.py: the package and Triton's Open
//! Inference Protocol client from PyPI), in a virtualenv that clients/python/setup_venv.sh
//! creates once under the target directory.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::io::{BufRead, BufReader};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;

fn workspace_file(rel: &str) -> PathBuf {
    coadapt_test_support::workspace_file(rel)
}

fn venv() -> &'static Path {
    static V: OnceLock<PathBuf> = OnceLock::new();
    V.get_or_init(|| {
        let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("py-client-venv");
        let status = Command::new("bash").arg(workspace_file("clients/python/setup_venv.sh")).arg(&dir).status().unwrap();
        assert!(status.success(), "clients/python/setup_venv.sh failed");
        dir
    })
}

fn coadapt() -> Command {
    Command::new(env!("CARGO_BIN_EXE_coadapt"))
}

/// A server killed when the test ends, passed or failed (a server left running would hold the
/// test's output open and hang the harness).
struct Server(std::process::Child);

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// A finished tiny run.
fn finished_run(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("coadapt-serve-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let o = coadapt()
        .args(["run", "--config", workspace_file("configs/half-cheetah-tiny.toml").to_str().unwrap(), "--transport", "in-process"])
        .arg("--out")
        .arg(&dir)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    dir
}

#[test]
fn python_clients_query_a_finished_run_through_both_protocols() {
    let run = finished_run("python");
    let mut server = Server(coadapt().arg("serve").arg(&run).args(["--listen", "127.0.0.1:0"]).stdout(Stdio::piped()).spawn().unwrap());
    let mut line = String::new();
    BufReader::new(server.0.stdout.take().unwrap()).read_line(&mut line).unwrap();
    let addr = line.trim().strip_prefix("grpc://").unwrap_or_else(|| panic!("no address line: {line:?}")).to_string();
    let o = Command::new(venv().join("bin/python"))
        .arg(workspace_file("clients/python/example.py"))
        .args(["--server", &addr, "--design", "1,1,1,1,1,1", "--design", "2,0.8,1.5,1.2,2,0.9"])
        .output()
        .unwrap();
    assert!(o.status.success(), "example.py: {}", String::from_utf8_lossy(&o.stderr));
    let got: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(got["robot"], "half-cheetah");
    assert_eq!(got["dimensions"].as_array().unwrap().len(), 6);
    assert_eq!(got["start_states"], 8, "the tiny config's start-state batch");
    assert!(got["weights_version"].as_u64().unwrap() >= 1);
    // The DesignService and the Open Inference Protocol give the same numbers.
    let objective: Vec<f64> = serde_json::from_value(got["objective"].clone()).unwrap();
    assert_eq!(objective.len(), 2);
    assert!(objective.iter().all(|v| v.is_finite()) && objective[0] != objective[1], "{objective:?}");
    assert_eq!(got["oip_value"], got["objective"]);
    // The served run has the twin critics: every score says how far they disagree.
    let gap: Vec<f64> = serde_json::from_value(got["disagreement"].clone()).unwrap();
    assert!(gap.len() == 2 && gap.iter().all(|g| g.is_finite() && *g >= 0.0) && gap[0] != gap[1], "{gap:?}");
    assert_eq!(got["oip_shape"], serde_json::json!([2, 1]));
    assert_eq!(got["oip_model_versions"], serde_json::json!([got["weights_version"].to_string()]));
    // Optimize to the end: an answer inside the box whose objective Score confirms below; and
    // a search cancelled after three iterations.
    let answer = &got["optimize_answer"];
    assert_eq!(answer["evaluations"], 300, "{answer}");
    assert_eq!(got["optimize_first_before_cancel"].as_array().unwrap().len(), 3);
    assert_eq!(got["optimize_cancelled"], true);
    let best: Vec<f32> = serde_json::from_value(answer["design"].clone()).unwrap();
    let o = coadapt()
        .args(["score", "--server", &addr, "--design", &best.iter().map(|v| v.to_string()).collect::<Vec<_>>().join(",")])
        .output()
        .unwrap();
    let line = String::from_utf8_lossy(&o.stdout).lines().nth(1).unwrap_or_default().to_string();
    assert_eq!(line.split(',').nth(1).and_then(|v| v.parse::<f32>().ok()), Some(answer["objective"].as_f64().unwrap() as f32), "{line}");
    // The same search from the command line gives the same answer.
    let o = coadapt().args(["optimize", "--server", &addr, "--particles", "30", "--iterations", "10", "--seed", "1"]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    let design: Vec<f32> = out.lines().nth(1).unwrap().split(',').next().unwrap().split(';').map(|v| v.parse().unwrap()).collect();
    assert_eq!(design, best, "{out}");
    assert_eq!(String::from_utf8_lossy(&o.stderr).matches("optimize: iteration").count(), 10);
    // The history, paged two rows at a time, is designs.csv.
    let csv = std::fs::read_to_string(run.join("designs.csv")).unwrap();
    let rows: Vec<&str> = csv.lines().skip(1).collect();
    let history = got["history"].as_array().unwrap();
    assert_eq!(history.len(), rows.len());
    for (h, r) in history.iter().zip(&rows) {
        let f: Vec<&str> = r.split(',').collect();
        assert_eq!(h["index"].to_string(), f[0]);
        assert_eq!(h["kind"], f[1]);
        assert_eq!(h["method"], f[8]);
    }
    // The landscape: a 5 x 5 grid of finite values over the plane of every design tried.
    let land = &got["landscape"];
    assert_eq!(land["pc1"].as_array().unwrap().len(), 5);
    assert_eq!(land["pc2"].as_array().unwrap().len(), 5);
    let values: Vec<f64> = serde_json::from_value(land["objective"].clone()).unwrap();
    assert!(values.len() == 25 && values.iter().all(|v| v.is_finite()), "{values:?}");
    assert_eq!(land["designs"].as_array().unwrap().len(), rows.len());
    assert_eq!(land["weights_version"], got["weights_version"]);
    // Watch on a finished run: every row, then the stream ends.
    let watched = got["watched"].as_array().unwrap();
    assert_eq!(watched.len(), rows.len(), "{watched:?}");
    for (w, r) in watched.iter().zip(&rows) {
        assert_eq!(w["index"].to_string(), r.split(',').next().unwrap());
    }
    // The command-line clients: the same scores, and designs.csv byte for byte.
    let o = coadapt().args(["score", "--server", &addr, "--design", "1,1,1,1,1,1", "--design", "2,0.8,1.5,1.2,2,0.9"]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    // Both print the f32 values, in their own shortest forms.
    let scored: Vec<f32> = out.lines().skip(1).map(|l| l.split(',').nth(1).unwrap().parse().unwrap()).collect();
    assert_eq!(scored, objective.iter().map(|&v| v as f32).collect::<Vec<_>>(), "{out}");
    let o = coadapt().args(["history", "--server", &format!("http://{addr}")]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(String::from_utf8_lossy(&o.stdout), csv);
    let o = coadapt().args(["score", "--server", &addr, "--design", "1,1,1"]).output().unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("InvalidArgument") && e.contains("designs[0].values: 3 values"), "{e}");
    assert!(Command::new("kill").args(["-TERM", &server.0.id().to_string()]).status().unwrap().success());
    assert!(server.0.wait().unwrap().success(), "coadapt serve did not stop cleanly on SIGTERM");
}

#[test]
fn serve_refuses_what_it_cannot_serve_safely() {
    let run = finished_run("refusals");
    let o = coadapt().arg("serve").arg(&run).args(["--listen", "0.0.0.0:0"]).output().unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("not a loopback address") && e.contains("--insecure"), "{e}");
    // TLS alone is not enough off loopback: without tokens every caller would be an operator.
    let o = coadapt().arg("serve").arg(&run).args(["--listen", "0.0.0.0:0", "--tls-cert", "c.pem", "--tls-key", "k.pem"]).output().unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("no role tokens (security.tokens-file") && !e.contains("no TLS"), "{e}");
    let o = coadapt().arg("serve").arg(&run).args(["--listen", "somewhere"]).output().unwrap();
    assert!(String::from_utf8_lossy(&o.stderr).contains("--listen: \"somewhere\" is not an address"));
    std::fs::remove_dir_all(run.join("snapshots")).unwrap();
    let o = coadapt().arg("serve").arg(&run).args(["--listen", "127.0.0.1:0"]).output().unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("has no readable snapshot"), "{e}");
    let o = coadapt().arg("serve").arg(run.join("nothing-here")).args(["--listen", "127.0.0.1:0"]).output().unwrap();
    assert!(String::from_utf8_lossy(&o.stderr).contains("a run directory?"), "{}", String::from_utf8_lossy(&o.stderr));
}

/// A fleet killed when the test ends.
/// A fleet in a process group of its own, killed whole when the test ends: killing only `coadapt
/// run` on a failed assertion left its actor and optimiser reconnecting for ever.
struct Fleet(std::process::Child);

impl Drop for Fleet {
    fn drop(&mut self) {
        let _ = Command::new("kill").args(["-KILL", "--", &format!("-{}", self.0.id())]).status();
        let _ = self.0.wait();
    }
}

/// `coadapt run` of the tiny config with `extra` flags into `dir`, serving design queries on a
/// port of its choosing: the fleet, the service's address (from the learner's stderr line) and
/// the log so far.
fn serving_fleet(extra: &[&str], dir: &Path) -> (Fleet, String, std::sync::Arc<std::sync::Mutex<String>>) {
    let mut fleet = Fleet(
        coadapt()
            .args(["run", "--config", workspace_file("configs/half-cheetah-tiny.toml").to_str().unwrap()])
            .args(extra)
            .args(["--serve", "127.0.0.1:0", "--out"])
            .arg(dir)
            .stderr(Stdio::piped())
            .stdout(Stdio::null())
            .process_group(0)
            .spawn()
            .unwrap(),
    );
    // The learner names the service's address on stderr; the rest of the log is kept.
    let (tx, rx) = std::sync::mpsc::channel();
    let log = std::sync::Arc::new(std::sync::Mutex::new(String::new()));
    let keep = log.clone();
    let stderr = fleet.0.stderr.take().unwrap();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            if let Some(at) = line.split("design service").nth(1).and_then(|r| r.split("grpc://").nth(1)) {
                let _ = tx.send(at.split_whitespace().next().unwrap_or_default().to_string());
            }
            keep.lock().unwrap().push_str(&(line + "\n"));
        }
    });
    let addr = rx
        .recv_timeout(std::time::Duration::from_secs(60))
        .unwrap_or_else(|_| panic!("no design service address: {}", log.lock().unwrap()));
    (fleet, addr, log)
}

#[test]
fn python_clients_query_a_running_fleet_and_watch_its_designs() {
    let dir = std::env::temp_dir().join(format!("coadapt-serve-{}-live", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    // The client's virtualenv first: built on a clean checkout it takes a minute or more, in
    // which the fleet would run far into (or through) its designs before anything watched.
    let python = venv().join("bin/python");
    let (mut fleet, addr, log) = serving_fleet(&["--transport", "grpc", "--designs", "60"], &dir);
    let o = Command::new(python)
        .arg(workspace_file("clients/python/example.py"))
        .args(["--server", &addr, "--watch-rows", "12"])
        .output()
        .unwrap();
    assert!(o.status.success(), "example.py: {}\nfleet: {}", String::from_utf8_lossy(&o.stderr), log.lock().unwrap());
    let got: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(got["robot"], "half-cheetah");
    assert!(got["weights_version"].as_u64().unwrap() >= 1, "served from the first design request on");
    // The learner's critic through both protocols: the same numbers (same version).
    assert_eq!(got["oip_value"], got["objective"]);
    assert_eq!(got["oip_shape"], serde_json::json!([3, 1]));
    assert_eq!(got["optimize_answer"]["evaluations"], 300);
    assert_eq!(got["optimize_cancelled"], true);
    assert!(!got["history"].as_array().unwrap().is_empty());
    assert_eq!(got["landscape"]["objective"].as_array().unwrap().len(), 25);
    // Watch went past the history into changes made while it watched: a design sent when
    // chosen (no episodes yet) and again when its episodes were done.
    let watched = got["watched"].as_array().unwrap();
    assert_eq!(watched.len(), 12, "{watched:?}");
    let again = watched
        .iter()
        .enumerate()
        .any(|(i, w)| w["episodes"] == 0 && watched[i + 1..].iter().any(|l| l["index"] == w["index"] && l["episodes"].as_u64() > Some(0)));
    assert!(again, "no design seen chosen and then done: {watched:?}");
    // The run is still going: the service did not stop it. Ctrl-C ends it cleanly.
    assert!(fleet.0.try_wait().unwrap().is_none(), "the fleet ended early: {}", log.lock().unwrap());
    assert!(Command::new("kill").args(["-INT", &fleet.0.id().to_string()]).status().unwrap().success());
    let status = fleet.0.wait().unwrap();
    assert!(status.success(), "{}", log.lock().unwrap());
}

fn read_addr(server: &mut Server) -> String {
    let mut line = String::new();
    BufReader::new(server.0.stdout.take().unwrap()).read_line(&mut line).unwrap();
    line.trim().strip_prefix("grpc://").unwrap_or_else(|| panic!("no address line: {line:?}")).to_string()
}

#[test]
fn a_secured_server_answers_only_tls_and_known_tokens_of_its_roles() {
    let run = finished_run("secured");
    let sec = run.join("sec");
    let ok = |o: std::process::Output| {
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        o
    };
    ok(coadapt().args(["tls", "new", "--out"]).arg(sec.join("tls")).output().unwrap());
    for role in ["client", "actor"] {
        ok(coadapt()
            .args(["token", "new", "--role", role, "--out"])
            .arg(sec.join(format!("{role}.token")))
            .arg("--tokens-file")
            .arg(sec.join("tokens"))
            .output()
            .unwrap());
    }
    let p = |n: &str| sec.join(n).display().to_string();
    // With TLS configured, a non-loopback address needs no --insecure.
    let mut server = Server(
        coadapt()
            .arg("serve")
            .arg(&run)
            .args(["--listen", "0.0.0.0:0", "--tls-cert", &p("tls/server.pem"), "--tls-key", &p("tls/server-key.pem")])
            .args(["--tokens-file", &p("tokens")])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let port = read_addr(&mut server).rsplit(':').next().unwrap().to_string();
    let addr = format!("127.0.0.1:{port}");
    let score = |extra: &[&str]| {
        coadapt().args(["score", "--server", &addr, "--design", "1,1,1,1,1,1", "--timeout-secs", "5"]).args(extra).output().unwrap()
    };
    let err = |o: std::process::Output| {
        assert!(!o.status.success(), "accepted: {}", String::from_utf8_lossy(&o.stdout));
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    // Plaintext to a TLS port: refused.
    err(score(&[]));
    let e = err(score(&["--tls-ca", &p("tls/ca.pem")]));
    assert!(e.contains("Unauthenticated") && e.contains("authorization: missing"), "{e}");
    let e = err(score(&["--tls-ca", &p("tls/ca.pem"), "--token-file", &p("actor.token")]));
    assert!(e.contains("PermissionDenied") && e.contains("role actor"), "{e}");
    let o = ok(score(&["--tls-ca", &p("tls/ca.pem"), "--token-file", &p("client.token")]));
    let scored: f32 = String::from_utf8_lossy(&o.stdout).lines().nth(1).unwrap().split(',').nth(1).unwrap().parse().unwrap();
    // The Python client over TLS with the client token: the DesignService and Triton's client.
    let o = Command::new(venv().join("bin/python"))
        .arg(workspace_file("clients/python/example.py"))
        .args(["--server", &addr, "--design", "1,1,1,1,1,1", "--tls-ca", &p("tls/ca.pem"), "--token-file", &p("client.token")])
        .output()
        .unwrap();
    assert!(o.status.success(), "example.py over TLS: {}", String::from_utf8_lossy(&o.stderr));
    let got: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(got["objective"][0].as_f64().map(|v| v as f32), Some(scored));
    assert_eq!(got["oip_value"], got["objective"]);
    // Without the token the Python client is refused too.
    let o = Command::new(venv().join("bin/python"))
        .arg(workspace_file("clients/python/example.py"))
        .args(["--server", &addr, "--tls-ca", &p("tls/ca.pem"), "--timeout", "3"])
        .output()
        .unwrap();
    assert!(
        !o.status.success() && String::from_utf8_lossy(&o.stderr).contains("UNAUTHENTICATED"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    // No secret in the server's log.
    assert!(Command::new("kill").args(["-TERM", &server.0.id().to_string()]).status().unwrap().success());
    let out = server.0.wait_with_output_ref();
    for role in ["client", "actor"] {
        let token = std::fs::read_to_string(sec.join(format!("{role}.token"))).unwrap();
        assert!(!out.contains(token.trim()), "the {role} token is in the server's log");
    }
}

trait WaitLog {
    fn wait_with_output_ref(&mut self) -> String;
}

impl WaitLog for std::process::Child {
    /// Waits for the child and returns its stderr.
    fn wait_with_output_ref(&mut self) -> String {
        let mut s = String::new();
        if let Some(mut e) = self.stderr.take() {
            let _ = std::io::Read::read_to_string(&mut e, &mut s);
        }
        let _ = self.wait();
        s
    }
}

/// Runs the coadapt-client package's own tests (`clients/python/tests`, pytest) with `env`.
fn client_tests(env: &[(&str, &str)], select: &str) -> String {
    let o = Command::new(venv().join("bin/python"))
        .args(["-m", "pytest", "-q", "-p", "no:cacheprovider", "-k", select])
        .arg(workspace_file("clients/python/tests"))
        .envs(env.iter().copied())
        .env_remove("COADAPT_TOKEN")
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(o.status.success(), "pytest failed:\n{out}\n{}", String::from_utf8_lossy(&o.stderr));
    out
}

#[test]
fn the_python_client_package_passes_its_tests_against_a_finished_run_and_a_running_fleet() {
    // `pip install ./clients/python` (setup_venv.sh does it as a user would): a finished run.
    let run = finished_run("package");
    let mut server = Server(coadapt().arg("serve").arg(&run).args(["--listen", "127.0.0.1:0"]).stdout(Stdio::piped()).spawn().unwrap());
    let addr = read_addr(&mut server);
    let out = client_tests(&[("COADAPT_TEST_SERVER", &addr), ("COADAPT_TEST_RUN_DIR", run.to_str().unwrap())], "not live");
    assert!(out.contains("8 passed"), "{out}");
    drop(server);
    // A fleet of processes (shared memory) whose learner serves while it runs: watched to its end.
    let dir = std::env::temp_dir().join(format!("coadapt-serve-{}-package-live", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let (mut fleet, live, _log) = serving_fleet(&[], &dir);
    let out = client_tests(&[("COADAPT_TEST_LIVE", &live)], "live");
    assert!(out.contains("1 passed"), "{out}");
    assert!(fleet.0.wait().unwrap().success());
}
