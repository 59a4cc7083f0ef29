//! The operator page in a real browser: a tiny run that waits for each prototype serves the
//! page (`--serve`, with TLS and role tokens); Chromium, driven over WebDriver by
//! `python/page_check.py`, logs in with a client token (it sees the proposal and no button),
//! has forged POSTs refused, then logs in as the operator and answers "as built" from the page;
//! designs.csv then holds the measured dimensions. Also over plain HTTP without a browser: a
//! finished run's page from `coadapt serve`, and what the page refuses.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::io::{BufRead, BufReader, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use coadapt_learner::prototype::{self, PROTOTYPE_FILE, Prototype, Status};

fn coadapt() -> Command {
    Command::new(env!("CARGO_BIN_EXE_coadapt"))
}

/// The tiny HalfCheetah config with every prototype to confirm, role tokens from `tokens` and,
/// with `tls`, the server certificate of `coadapt tls new --out tls`.
fn config(dir: &Path, tokens: &Path, tls: Option<&Path>) -> PathBuf {
    let mut t = coadapt_test_support::confirming_tiny_config();
    t.push_str(&format!("\n[metrics]\nlearner-listen = \"127.0.0.1:0\"\n\n[security]\ntokens-file = {:?}\n", tokens.display().to_string()));
    if let Some(tls) = tls {
        let p = |f: &str| tls.join(f).display().to_string();
        t.push_str(&format!("tls-cert = {:?}\ntls-key = {:?}\n", p("server.pem"), p("server-key.pem")));
    }
    let path = dir.join("run.toml");
    std::fs::write(&path, t).unwrap();
    path
}

/// Makes a token of `role` into `dir/ROLE.token`, its hash into `dir/tokens`.
fn token(dir: &Path, role: &str) -> PathBuf {
    let out = dir.join(format!("{role}.token"));
    let o =
        coadapt().args(["token", "new", "--role", role, "--out"]).arg(&out).arg("--tokens-file").arg(dir.join("tokens")).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    out
}

struct Run {
    child: Child,
    stderr: std::sync::mpsc::Receiver<String>,
}

impl Drop for Run {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Starts the run and returns it with the page's address (from its stderr line).
#[allow(clippy::zombie_processes)] // `Run`'s drop kills and waits for it
fn start(cfg: &Path, out: &Path) -> (Run, String) {
    let mut child = coadapt()
        .args(["run", "--config"])
        .arg(cfg)
        .arg("--out")
        .arg(out)
        .args(["--transport", "in-process", "--serve", "127.0.0.1:0"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    let err = child.stderr.take().unwrap();
    std::thread::spawn(move || {
        for line in BufReader::new(err).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let t = Instant::now();
    loop {
        let line = rx.recv_timeout(Duration::from_secs(120)).expect("the run said nothing about its page");
        if let Some(at) = line.split("operator page on ").nth(1) {
            return (Run { child, stderr: rx }, at.trim().trim_end_matches('/').to_string());
        }
        assert!(t.elapsed() < Duration::from_secs(120), "no page address");
    }
}

impl Run {
    /// The first line of the run's stderr from now on that holds `needle`.
    fn line(&self, needle: &str) -> String {
        loop {
            let line = self.stderr.recv_timeout(Duration::from_secs(120)).unwrap_or_else(|_| panic!("the run never said {needle:?}"));
            if line.contains(needle) {
                return line;
            }
        }
    }
}

fn awaiting(dir: &Path, index: usize) -> Prototype {
    let t = Instant::now();
    loop {
        if let Ok(Some(p)) = prototype::read_json::<Prototype>(&dir.join(PROTOTYPE_FILE))
            && (p.index, p.status) == (index, Status::Awaiting)
        {
            return p;
        }
        assert!(t.elapsed() < Duration::from_secs(300), "design {} never awaited its prototype", index + 1);
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn an_operator_answers_as_built_from_the_page_in_a_real_browser() {
    if coadapt_test_support::browser().is_none() {
        return;
    }
    let dir = coadapt_test_support::scratch_dir("operator_page", "browser");
    let (operator, client) = (token(&dir, "operator"), token(&dir, "client"));
    // Over TLS, as across machines (the browser takes HTTP/2, the server's only ALPN protocol).
    let tls = dir.join("tls");
    let o = coadapt().args(["tls", "new", "--out"]).arg(&tls).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = dir.join("run");
    let (run, url) = start(&config(&dir, &dir.join("tokens"), Some(&tls)), &out);
    assert!(url.starts_with("https://"), "{url}");
    awaiting(&out, 0);
    let shot = dir.join("page.png");
    let o = Command::new("python3")
        .arg(coadapt_test_support::workspace_file("cli/tests/python/page_check.py"))
        .arg(&url)
        .arg(&shot)
        .env("PAGE_OPERATOR_TOKEN_FILE", &operator)
        .env("PAGE_CLIENT_TOKEN_FILE", &client)
        .env("PAGE_CA_FILE", tls.join("ca.pem"))
        .output()
        .unwrap();
    let said: Vec<String> = run.stderr.try_iter().collect();
    assert!(
        o.status.success(),
        "page_check.py failed:\n{}\n{}\nrun:\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
        said.join("\n")
    );
    // The learner read the page's answer: design 1 as built, in designs.csv.
    let rows = coadapt_learner::run_dir::read_designs(&out.join("designs.csv"), std::fs::metadata(out.join("designs.csv")).unwrap().len())
        .unwrap();
    assert_eq!(rows[0].design, [1.05, 1.0, 1.0, 1.0, 0.95, 1.0], "{rows:?}");
    assert_eq!(rows[0].prototype, "as-built (requested 1;1;1;1;1;1)");
    assert!(said.iter().any(|l| l.contains("operator page: design 1 (proposal 1) built as back thigh 1.050")), "{said:?}");
    // Refusals are counted where an operator sees them: the forged POSTs and the bad login.
    let png = std::fs::read(&shot).unwrap();
    assert!(png.starts_with(b"\x89PNG") && png.len() > 10_000, "no screenshot");
    drop(run);
}

/// One HTTP/1.1 request on a fresh connection: the status line, headers and body.
fn http(addr: &str, request: &str) -> (u16, String, String) {
    let mut s = std::net::TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    s.write_all(request.as_bytes()).unwrap();
    let mut text = String::new();
    s.read_to_string(&mut text).unwrap();
    let (head, body) = text.split_once("\r\n\r\n").unwrap_or((&text, ""));
    let status = head.split(' ').nth(1).and_then(|c| c.parse().ok()).unwrap_or(0);
    (status, head.to_string(), body.to_string())
}

fn get(addr: &str, path: &str, cookie: &str) -> (u16, String, String) {
    http(addr, &format!("GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\nCookie: {cookie}\r\n\r\n"))
}

fn post(addr: &str, path: &str, cookie: &str, form: &str) -> (u16, String, String) {
    http(
        addr,
        &format!(
            "POST {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\nCookie: {cookie}\r\nContent-Type: application/x-www-form-urlencoded\r\nContent-Length: {}\r\n\r\n{form}",
            form.len()
        ),
    )
}

fn session_cookie(head: &str) -> String {
    let line = head.lines().find(|l| l.to_ascii_lowercase().starts_with("set-cookie:")).unwrap_or_else(|| panic!("no cookie in {head}"));
    line.split_once(':').unwrap().1.trim().split(';').next().unwrap().to_string()
}

#[test]
fn a_live_run_and_a_finished_one_show_their_page_and_refuse_what_they_must() {
    let dir = coadapt_test_support::scratch_dir("operator_page", "http");
    let client = token(&dir, "client");
    let actor = token(&dir, "actor");
    let operator = token(&dir, "operator");
    let out = dir.join("run");
    let (mut run, url) = start(&config(&dir, &dir.join("tokens"), None), &out);
    let addr = url.trim_start_matches("http://").to_string();
    let metrics = run.line("metrics on http://").split("http://").nth(1).unwrap().trim_end_matches("/metrics").to_string();
    awaiting(&out, 0);
    // No session: the login form, and the parts refuse.
    let (status, head, body) = get(&addr, "/", "");
    assert_eq!(status, 200);
    assert!(body.contains("name=\"token\"") && !body.contains("Build design"), "{body}");
    assert!(head.contains("content-security-policy: default-src 'none'"), "{head}");
    assert_eq!(get(&addr, "/live", "").0, 401);
    assert_eq!(get(&addr, "/plot/learning_curves.svg", "").0, 401);
    // The token goes in the body of a POST; an actor's is refused, a client's opens a session.
    let read = |p: &Path| std::fs::read_to_string(p).unwrap().trim().to_string();
    let (status, _, body) = post(&addr, "/login", "", &format!("token={}", read(&actor)));
    assert!(status == 401 && body.contains("may not view the page"), "{status} {body}");
    let (status, head, _) = post(&addr, "/login", "", &format!("token={}", read(&client)));
    assert_eq!(status, 303, "{head}");
    let cookie = session_cookie(&head);
    assert!(head.contains("HttpOnly; SameSite=Strict"), "{head}");
    let (status, _, body) = get(&addr, "/", &cookie);
    assert!(status == 200 && body.contains("Build design 1") && body.contains("View only") && !body.contains("id=\"confirm\""), "{body}");
    let (status, _, body) = get(&addr, "/plot/nope.svg", &cookie);
    assert!(status == 404 && body.contains("learning_curves.svg"), "{body}");
    // A POST from a client's session is refused, and so is one without the form's CSRF field.
    let (status, _, body) = post(&addr, "/act", &cookie, "action=confirm&index=0&proposal=1");
    assert!(status == 403 && body.contains("csrf"), "{status} {body}");
    // Every refusal so far is counted where an operator looks: the learner's /metrics.
    let (_, _, m) = get(&metrics, "/metrics", "");
    let count = |reason: &str| -> f64 {
        m.lines()
            .filter(|l| l.starts_with(&format!("coadapt_refusals_total{{server=\"operator_page\",reason=\"{reason}\"")))
            .filter_map(|l| l.rsplit(' ').next()?.parse::<f64>().ok())
            .sum()
    };
    assert_eq!((count("unauthenticated"), count("csrf")), (3.0, 1.0), "{m}");
    // An operator answers a proposal the page showed; an answer to an older one is refused.
    let (_, head, _) = post(&addr, "/login", "", &format!("token={}", read(&operator)));
    let op = session_cookie(&head);
    let (_, _, page) = get(&addr, "/", &op);
    let csrf = page.split("name=\"csrf\" value=\"").nth(1).unwrap().split('"').next().unwrap().to_string();
    let (status, _, body) = post(&addr, "/act", &op, &format!("csrf={csrf}&action=confirm&index=0&proposal=1&as_built=9"));
    assert_eq!(status, 303, "{body}");
    awaiting(&out, 1);
    let (status, _, _) = post(&addr, "/act", &op, &format!("csrf={csrf}&action=confirm&index=0&proposal=1"));
    assert_eq!(status, 303);
    let (_, _, page) = get(&addr, "/", &op);
    assert!(page.contains("not answered: this answer is to design 1 (proposal 1), but design 2 (proposal 1) awaits now"), "{page}");
    // Bad measured dimensions are refused as `coadapt confirm --as-built` refuses them.
    post(&addr, "/act", &op, &format!("csrf={csrf}&action=as-built&index=1&proposal=1&as_built=1&as_built=x"));
    let (_, _, page) = get(&addr, "/", &op);
    assert!(page.contains("as built, entry 2: &quot;x&quot; is not a number"), "{page}");
    post(&addr, "/act", &op, &format!("csrf={csrf}&action=as-built&index=1&proposal=1&as_built=1&as_built=1"));
    let (_, _, page) = get(&addr, "/", &op);
    assert!(page.contains("--as-built: 2 values, but the design has 6"), "{page}");
    // The rest from the command line, which keeps working beside the page.
    for i in 1..4 {
        awaiting(&out, i);
        let o = coadapt().arg("confirm").arg(&out).output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let status = run.child.wait().unwrap();
    assert!(status.success());
    drop(run);

    // The finished run's page from `coadapt serve`: every design, the figures, no waiting.
    let mut serve = coadapt()
        .arg("serve")
        .arg(&out)
        .args(["--listen", "127.0.0.1:0", "--tokens-file"])
        .arg(dir.join("tokens"))
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(serve.stdout.take().unwrap()).read_line(&mut line).unwrap();
    let addr = line.trim().trim_start_matches("grpc://").to_string();
    let (_, head, _) = post(&addr, "/login", "", &format!("token={}", read(&client)));
    let cookie = session_cookie(&head);
    let (status, _, body) = get(&addr, "/", &cookie);
    assert_eq!(status, 200);
    assert!(body.contains("nothing: the run is finished") && body.contains("the run directory"), "{body}");
    assert_eq!(body.matches("<tr><td>").count() - body.matches("colspan").count(), 4 + 1, "4 designs and 1 actor: {body}");
    for fig in ["learning_curves", "best_return", "landscape"] {
        let (status, head, body) = get(&addr, &format!("/plot/{fig}.svg"), &cookie);
        assert!(
            status == 200 && head.contains("image/svg+xml") && body.starts_with("<svg") && !body.contains("no data yet"),
            "{fig}: {body:.300}"
        );
    }
    let t = Instant::now();
    let (status, _, _) = get(&addr, "/live", &cookie);
    assert!(status == 200 && t.elapsed() < Duration::from_secs(1));
    let _ = serve.kill();
    let _ = serve.wait();
}
