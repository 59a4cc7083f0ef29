//! The prototype step through the binary: `coadapt run` with `schedule.confirm-designs = true`
//! waits at every design, and the real `coadapt confirm RUN_DIR` answers it (as asked,
//! `--as-built`, `--reject`); and what `coadapt confirm` refuses.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use coadapt_learner::prototype::{
    self, PROTOTYPE_DECISION_FILE, PROTOTYPE_FILE, Prototype, PrototypeDecision, RESET_FILE, ResetMode, ResetRequest, Status,
};

fn tmpdir(name: &str) -> PathBuf {
    coadapt_test_support::scratch("confirm", name)
}

fn confirm(dir: &Path, flags: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_coadapt")).arg("confirm").arg(dir).args(flags).output().unwrap()
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// Waits until the run in `dir` shows design `index`'s proposal `proposal` awaiting.
fn awaiting(dir: &Path, index: usize, proposal: usize, child: &mut std::process::Child) -> Prototype {
    let t = Instant::now();
    loop {
        if let Ok(Some(p)) = prototype::read_json::<Prototype>(&dir.join(PROTOTYPE_FILE))
            && (p.index, p.proposal, p.status) == (index, proposal, Status::Awaiting)
        {
            return p;
        }
        assert!(child.try_wait().unwrap().is_none(), "the run ended before design {index} proposal {proposal} awaited its prototype");
        assert!(t.elapsed() < Duration::from_secs(600), "design {index} proposal {proposal} never awaited its prototype");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// The tiny HalfCheetah config, shrunk (2 episodes per initial design, 1 per chosen one, no
/// landscape), with every design's prototype to confirm.
fn confirming_config(name: &str) -> PathBuf {
    let t = coadapt_test_support::confirming_tiny_config();
    let path = tmpdir(name).with_extension("toml");
    std::fs::write(&path, t).unwrap();
    path
}

#[test]
fn a_run_waits_for_each_prototype_and_coadapt_confirm_answers_it() {
    let out = tmpdir("run");
    let cfg = confirming_config("run");
    let mut child = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["run", "--config", cfg.to_str().unwrap(), "--out", out.to_str().unwrap(), "--transport", "in-process"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Drain stderr as it comes, so the run never blocks on a full pipe.
    let mut stderr_pipe = child.stderr.take().unwrap();
    let stderr = std::thread::spawn(move || {
        let mut s = String::new();
        stderr_pipe.read_to_string(&mut s).unwrap();
        s
    });

    // Design 1 of 4 (fixed): it cannot be rejected; built as asked.
    let p = awaiting(&out, 0, 1, &mut child);
    assert_eq!(
        p.dimensions.iter().map(|d| d.0.as_str()).collect::<Vec<_>>(),
        ["back thigh", "back shin", "back foot", "front thigh", "front shin", "front foot"]
    );
    let o = confirm(&out, &["--reject"]);
    assert!(!o.status.success() && text(&o.stderr).contains("fixed initial design"), "{}", text(&o.stderr));
    let o = confirm(&out, &[]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(text(&o.stdout).contains("design 1 [initial fixed] confirmed as built: back thigh 1.000"), "{}", text(&o.stdout));
    // Design 2 (fixed, [1.41, 0.96, 1.97, 1.73, 1.97, 1.17]): built a little differently.
    awaiting(&out, 1, 1, &mut child);
    let o = confirm(&out, &["--as-built", "1.4,0.96,1.97,1.73,1.95,1.17"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(text(&o.stdout).contains("built as back thigh 1.400"), "{}", text(&o.stdout));
    // Design 3 (PSO over Q): rejected, then the optimiser's next proposal confirmed.
    let rejected = awaiting(&out, 2, 1, &mut child);
    let o = confirm(&out, &["--reject"]);
    assert!(o.status.success() && text(&o.stdout).contains("rejected"), "{}", text(&o.stderr));
    let next = awaiting(&out, 2, 2, &mut child);
    assert_ne!(next.design, rejected.design);
    assert!(confirm(&out, &[]).status.success());
    // Design 4 (novelty): as asked.
    awaiting(&out, 3, 1, &mut child);
    assert!(confirm(&out, &[]).status.success());

    let mut stdout = String::new();
    child.stdout.take().unwrap().read_to_string(&mut stdout).unwrap();
    let status = child.wait().unwrap();
    let stderr = stderr.join().unwrap();
    assert!(status.success(), "stderr: {stderr}");
    let shown = std::fs::canonicalize(&out).unwrap();
    for line in [
        format!(
            "design 1/4 [initial fixed] awaits a prototype: back thigh 1.000, back shin 1.000, back foot 1.000, front thigh 1.000, \
             front shin 1.000, front foot 1.000; build it, then: coadapt confirm {} [--as-built ...]\n",
            shown.display()
        ),
        "design 2/4: built as [1.4, 0.96, 1.97, 1.73, 1.95, 1.17] (requested [1.41, 0.96, 1.97, 1.73, 1.97, 1.17])".into(),
        format!("design 3/4 [exploit pso-q] awaits a prototype: back thigh {:.3}", rejected.design[0]),
        format!("; build it, then: coadapt confirm {} [--as-built ...|--reject]\n", shown.display()),
        "design 3/4: prototype rejected; asking the optimiser for its next-best design".into(),
        "design 1/4: prototype confirmed".into(),
    ] {
        assert!(stderr.contains(&line), "no {line:?} in the progress lines: {stderr}");
    }

    let summary: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    assert_eq!(summary["designs"], 4);
    assert_eq!(summary["interrupted"], false);
    assert_eq!(summary["prototypes_rejected"], 1);
    assert!(summary["prototype_waiting_seconds"].as_f64().unwrap() > 0.0, "{summary}");

    let csv = std::fs::read_to_string(out.join("designs.csv")).unwrap();
    let rows: Vec<Vec<&str>> = csv.lines().map(|l| l.split(',').collect()).collect();
    let col = |name: &str| {
        let i = rows[0].iter().position(|h| *h == name).unwrap();
        rows[1..].iter().map(|r| r[i]).collect::<Vec<_>>()
    };
    assert_eq!(col("index"), ["0", "1", "2", "2", "3"]);
    assert_eq!(col("prototype"), ["confirmed", "as-built (requested 1.41;0.96;1.97;1.73;1.97;1.17)", "rejected", "confirmed", "confirmed"]);
    assert_eq!(col("design")[1], "1.4;0.96;1.97;1.73;1.95;1.17");
    assert_eq!(col("episodes"), ["2", "2", "0", "1", "1"]);
    assert_eq!(col("best_eval_return")[2], "");
    assert!(out.join("plots/best_return.svg").exists(), "the plots are drawn with a rejected row in designs.csv");
    // The run is over: nothing awaits.
    let o = confirm(&out, &[]);
    assert!(!o.status.success() && text(&o.stderr).contains("awaits a prototype"), "{}", text(&o.stderr));
}

/// A prototype awaiting in `dir`, as the learner writes it: HalfCheetah's names and box.
fn waiting_cheetah(dir: &Path, status: Status) -> Prototype {
    std::fs::create_dir_all(dir).unwrap();
    let names = coadapt_robots::make("half-cheetah").unwrap().spec().design_names.clone();
    let p = Prototype {
        index: 4,
        proposal: 2,
        kind: "exploit".into(),
        method: "pso-q".into(),
        design: vec![1.27, 0.87, 1.0, 1.5, 1.2, 0.9],
        dimensions: prototype::named_dimensions(&names, &[1.27, 0.87, 1.0, 1.5, 1.2, 0.9]),
        low: vec![0.8; 6],
        high: vec![2.0; 6],
        status,
        waiting_since_unix: prototype::unix_now(),
        as_built: None,
    };
    prototype::write_json(&dir.join(PROTOTYPE_FILE), &p).unwrap();
    p
}

#[test]
fn coadapt_confirm_refuses_what_does_not_fit() {
    let dir = tmpdir("refuse");
    let o = confirm(&dir, &[]);
    assert!(!o.status.success());
    assert!(text(&o.stderr).contains(&format!("nothing in {} awaits a prototype", dir.display())), "{}", text(&o.stderr));
    waiting_cheetah(&dir, Status::Awaiting);
    for (flags, why) in [
        (["--as-built", "1,1,1"], "--as-built: 3 values, but the design has 6 (back thigh, back shin"),
        (["--as-built", "1,1,1,1,1,2.5"], "--as-built: entry 6 (front foot) = 2.5 is outside the design box [0.8, 2]"),
        (["--as-built", "1,1,nan,1,1,1"], "--as-built: entry 3 (back foot) is NaN, not a finite number"),
        (["--as-built", "1,1,1,inf,1,1"], "--as-built: entry 4 (front thigh) is inf, not a finite number"),
    ] {
        let o = confirm(&dir, &flags);
        assert!(!o.status.success(), "{flags:?}");
        assert!(text(&o.stderr).contains(why), "{flags:?}: {}", text(&o.stderr));
        assert!(!dir.join(PROTOTYPE_DECISION_FILE).exists(), "{flags:?}: a refused answer writes nothing");
    }
    let o = confirm(&dir, &["--reset"]);
    assert!(!o.status.success() && text(&o.stderr).contains("awaits a reset"), "{}", text(&o.stderr));
    let o = confirm(&dir, &["--as-built", "1,1,1,1,1,1", "--reject"]);
    assert!(!o.status.success() && text(&o.stderr).contains("cannot be used with"), "{}", text(&o.stderr));

    // What fits is written for the learner to read.
    let o = confirm(&dir, &["--as-built", "1.25,0.88,1,1.5,1.2,0.8"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(text(&o.stdout).contains("design 5 [exploit pso-q] built as back thigh 1.250"), "{}", text(&o.stdout));
    let d: PrototypeDecision = prototype::read_json(&dir.join(PROTOTYPE_DECISION_FILE)).unwrap().unwrap();
    assert_eq!((d.index, d.proposal, d.as_built), (4, 2, Some(vec![1.25, 0.88, 1.0, 1.5, 1.2, 0.8])));
    let o = confirm(&dir, &["--reject"]);
    assert!(text(&o.stdout).contains("replacing an earlier answer"), "{}", text(&o.stdout));

    // Once the learner has moved on, nothing awaits.
    waiting_cheetah(&dir, Status::Confirmed);
    let o = confirm(&dir, &[]);
    assert!(text(&o.stderr).contains("awaits a prototype (design 5's prototype is confirmed already)"), "{}", text(&o.stderr));

    // A reset.
    let r = ResetRequest { design_index: 2, episode: 3, mode: ResetMode::Train, status: Status::Awaiting, waiting_since_unix: 0.0 };
    prototype::write_json(&dir.join(RESET_FILE), &r).unwrap();
    let o = confirm(&dir, &["--reset"]);
    assert!(o.status.success() && text(&o.stdout).contains("reset confirmed: episode 4 of design 3 may start"), "{}", text(&o.stdout));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Ctrl-C while the first prototype is awaited: the run ends at once with its summary (nothing
/// trained, nothing to plot), and the wait is marked moot.
#[test]
fn ctrl_c_while_a_prototype_is_awaited_ends_the_run_with_a_summary() {
    let out = tmpdir("ctrl-c");
    let cfg = confirming_config("ctrl-c");
    let mut child = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["run", "--config", cfg.to_str().unwrap(), "--out", out.to_str().unwrap(), "--transport", "in-process"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    awaiting(&out, 0, 1, &mut child);
    assert!(Command::new("kill").args(["-INT", &child.id().to_string()]).status().unwrap().success());
    let o = child.wait_with_output().unwrap();
    let stderr = text(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    let summary: serde_json::Value = serde_json::from_str(text(&o.stdout).trim()).unwrap();
    assert_eq!((summary["interrupted"].as_bool(), summary["designs"].as_u64()), (Some(true), Some(0)), "{summary}");
    let p: Prototype = prototype::read_json(&out.join(PROTOTYPE_FILE)).unwrap().unwrap();
    assert_eq!(p.status, Status::Interrupted);
    let o = confirm(&out, &[]);
    assert!(text(&o.stderr).contains("the run stopped while it waited"), "{}", text(&o.stderr));
}

/// A run killed (SIGKILL, a power cut) while a prototype is awaited, after the operator had
/// rejected a proposal: `--resume` goes back to the newest snapshot (the end of the design
/// before), asks again for the same designs (the optimiser's stored replies), and the operator
/// answers as before; the run completes with the rows of a run never stopped.
#[test]
fn a_run_killed_while_a_prototype_is_awaited_resumes_and_asks_again_for_the_same_designs() {
    let out = tmpdir("killed");
    let cfg = confirming_config("killed");
    let run = |resume: bool| {
        let mut c = Command::new(env!("CARGO_BIN_EXE_coadapt"));
        if resume {
            c.args(["run", "--resume", out.to_str().unwrap(), "--transport", "in-process"]);
        } else {
            c.args(["run", "--config", cfg.to_str().unwrap(), "--out", out.to_str().unwrap(), "--transport", "in-process"]);
        }
        c.stdout(Stdio::piped()).stderr(std::fs::File::create(out.with_extension(format!("{resume}.log"))).unwrap()).spawn().unwrap()
    };
    let mut child = run(false);
    awaiting(&out, 0, 1, &mut child);
    assert!(confirm(&out, &[]).status.success());
    awaiting(&out, 1, 1, &mut child);
    assert!(confirm(&out, &[]).status.success());
    let first = awaiting(&out, 2, 1, &mut child);
    assert!(confirm(&out, &["--reject"]).status.success());
    let second = awaiting(&out, 2, 2, &mut child);
    child.kill().unwrap();
    child.wait().unwrap();

    let mut child = run(true);
    let again = awaiting(&out, 2, 1, &mut child);
    assert_eq!(again.design, first.design, "a resumed run proposed another design 3");
    assert!(confirm(&out, &["--reject"]).status.success());
    assert_eq!(awaiting(&out, 2, 2, &mut child).design, second.design, "the next-best design changed");
    assert!(confirm(&out, &[]).status.success());
    awaiting(&out, 3, 1, &mut child);
    assert!(confirm(&out, &[]).status.success());
    let o = child.wait_with_output().unwrap();
    assert!(o.status.success());
    let summary: serde_json::Value = serde_json::from_str(text(&o.stdout).trim()).unwrap();
    assert_eq!((summary["designs"].as_u64(), summary["interrupted"].as_bool()), (Some(4), Some(false)), "{summary}");
    let csv = std::fs::read_to_string(out.join("designs.csv")).unwrap();
    let rows: Vec<Vec<&str>> = csv.lines().map(|l| l.split(',').collect()).collect();
    let col = |name: &str| {
        let i = rows[0].iter().position(|h| *h == name).unwrap();
        rows[1..].iter().map(|r| r[i]).collect::<Vec<_>>()
    };
    assert_eq!(col("index"), ["0", "1", "2", "2", "3"], "{csv}");
    assert_eq!(col("prototype"), ["confirmed", "confirmed", "rejected", "confirmed", "confirmed"]);
    assert_eq!(col("episodes"), ["2", "2", "0", "1", "1"]);
}

/// Confirms every reset the run in `dir` awaits until `until` is awaited (returned unanswered)
/// or, with `None`, until the run ends.
fn answer_resets(dir: &Path, child: &mut std::process::Child, until: Option<(usize, usize, ResetMode)>) {
    let t = Instant::now();
    let mut last = None;
    loop {
        if let Ok(Some(q)) = prototype::read_json::<ResetRequest>(&dir.join(RESET_FILE))
            && q.status == Status::Awaiting
            && last != Some((q.design_index, q.episode, q.mode))
        {
            let now = (q.design_index, q.episode, q.mode);
            if Some(now) == until {
                return;
            }
            let o = confirm(dir, &["--reset"]);
            assert!(o.status.success(), "{}", text(&o.stderr));
            last = Some(now);
        }
        if child.try_wait().unwrap().is_some() {
            assert!(until.is_none(), "the run ended before the reset {until:?} was awaited");
            return;
        }
        assert!(t.elapsed() < Duration::from_secs(600), "the resets never reached {until:?}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Ctrl-C during a reset wait in which the learner trained its population networks
/// (`train-while-waiting`): the stop's snapshot is the quiet point before the wait with the
/// acting weights marked stale, as the wait marked them, since the networks it holds were
/// trained in it. (It restored the point's flag before: a resumed run whose acting policy is
/// the population's would have handed out the trained networks under the weights version of
/// the ones before, had its own wait not trained again.) The resume completes the run.
#[test]
fn ctrl_c_during_a_reset_wait_keeps_what_the_wait_trained_marked_for_publishing() {
    let out = tmpdir("reset-ctrl-c");
    let cfg = out.with_extension("toml");
    let t = coadapt_test_support::confirming_tiny_config()
        .replace("confirm-designs = true\n", "reset-needs-confirmation = true\ntrain-while-waiting = 200\n");
    std::fs::write(&cfg, t).unwrap();
    let spawn = |args: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_coadapt"))
            .args(args)
            .args(["--transport", "in-process"])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    };
    let mut child = spawn(&["run", "--config", cfg.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    // Episode 0 of design 0 and its evaluation, then the wait before episode 1: the population
    // replay holds episode 0, so the wait trains.
    answer_resets(&out, &mut child, Some((0, 1, ResetMode::Train)));
    std::thread::sleep(Duration::from_millis(600));
    assert!(Command::new("kill").args(["-INT", &child.id().to_string()]).status().unwrap().success());
    let o = child.wait_with_output().unwrap();
    let stderr = text(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    let summary: serde_json::Value = serde_json::from_str(text(&o.stdout).trim()).unwrap();
    assert_eq!(summary["interrupted"].as_bool(), Some(true), "{summary}");
    let made = summary["population_updates_while_waiting"].as_u64();
    assert!(made.is_some_and(|m| m > 0), "the waits trained nothing: {summary}");

    let snaps = out.join("snapshots");
    let newest = std::fs::read_dir(&snaps).unwrap().map(|e| e.unwrap().path()).max().unwrap();
    let manifest: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(newest.join("MANIFEST.json")).unwrap()).unwrap();
    assert_eq!(manifest["label"].as_str(), Some("design 0 episode 1 (stopped)"), "{manifest}");
    let state: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(newest.join("state.json")).unwrap()).unwrap();
    let progress = &state["values"]["progress"];
    assert_eq!(
        progress["acting_dirty"].as_bool(),
        Some(true),
        "the networks trained in the wait are not marked for publishing: {progress}"
    );

    let mut child = spawn(&["run", "--resume", out.to_str().unwrap()]);
    answer_resets(&out, &mut child, None);
    let o = child.wait_with_output().unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    let summary: serde_json::Value = serde_json::from_str(text(&o.stdout).trim()).unwrap();
    assert_eq!((summary["interrupted"].as_bool(), summary["designs"].as_u64()), (Some(false), Some(4)), "{summary}");
    let episodes = std::fs::read_to_string(out.join("episodes.csv")).unwrap();
    let rows: Vec<Vec<&str>> = episodes.lines().map(|l| l.split(',').collect()).collect();
    let v = rows[0].iter().position(|h| *h == "weights_version").unwrap();
    let versions: Vec<u64> = rows[1..].iter().map(|r| r[v].parse().unwrap()).collect();
    assert_eq!(versions.len(), 2 + 2 + 1 + 1, "{episodes}");
    assert!(versions.windows(2).all(|w| w[0] < w[1]), "weights versions must grow episode by episode: {versions:?}");
}
