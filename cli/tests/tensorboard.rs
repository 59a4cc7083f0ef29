//! TensorBoard event files of `coadapt run`, `train`, `latent` and `search` (issue 32), read by TensorBoard's own reader (its
//! EventAccumulator, in the bridge's virtualenv: `cli/tests/python/tb_check.py`): every tag of
//! the README's list, steps strictly increasing, values equal to episodes.csv and designs.csv;
//! a run killed with SIGKILL mid-run leaves a file the reader reads, a record torn in half
//! included, and its plots as of its last design; the run resumed continues its curves without
//! a step written twice.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const XI: &str = "back_thigh,back_shin,back_foot,front_thigh,front_shin,front_foot";

fn check(run: &Path, extra: &[&str]) -> String {
    let venv = coadapt_test_support::bridge_venv(env!("CARGO_TARGET_TMPDIR"));
    let script = coadapt_test_support::workspace_file("cli/tests/python/tb_check.py");
    let o = Command::new(venv.join("bin/python")).arg(script).arg(run).args(extra).output().unwrap();
    let out = format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success(), "tb_check {}: {out}", run.display());
    out
}

fn event_files(run: &Path) -> Vec<std::path::PathBuf> {
    let mut v: Vec<_> = std::fs::read_dir(run)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.file_name().unwrap().to_string_lossy().contains("tfevents"))
        .collect();
    v.sort();
    v
}

fn rows(path: &Path) -> usize {
    std::fs::read_to_string(path).map_or(0, |t| t.lines().count().saturating_sub(1))
}

#[test]
fn a_finished_run_shows_every_tag_in_tensorboard_equal_to_its_csv_files() {
    let dir = coadapt_test_support::scratch("cli", "tensorboard-run");
    let out = dir.join("run");
    let tiny = coadapt_test_support::workspace_file("configs/half-cheetah-tiny.toml");
    let o = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["run", "--config", tiny.to_str().unwrap(), "--out", out.to_str().unwrap(), "--transport", "in-process"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(event_files(&out).len(), 2, "the run's file and the landscape's: {:?}", event_files(&out));
    let said = check(&out, &["--xi", XI]);
    assert!(said.contains("tb_check: ok, 10 episodes"), "{said}");

    // A record torn in half (a writer killed mid-write): the reader takes the whole records
    // before it, and so does ours.
    let main = event_files(&out).into_iter().find(|p| p.to_string_lossy().ends_with(".coadapt")).unwrap();
    let bytes = std::fs::read(&main).unwrap();
    let (events, whole) = coadapt_tensorboard::read_events(&bytes).unwrap();
    assert_eq!(whole, bytes.len() as u64);
    let torn = &bytes[..bytes.len() - 9];
    let (fewer, at) = coadapt_tensorboard::read_events(torn).unwrap();
    assert_eq!(fewer.len(), events.len() - 1);
    assert!(at < torn.len() as u64);
    std::fs::write(&main, torn).unwrap();
    std::fs::remove_file(event_files(&out).into_iter().find(|p| p.to_string_lossy().ends_with(".landscape")).unwrap()).unwrap();
    check(&out, &["--partial"]);
}

#[test]
fn a_run_killed_mid_write_is_readable_and_resumes_without_a_step_twice() {
    let dir = coadapt_test_support::scratch("cli", "tensorboard-kill");
    std::fs::create_dir_all(&dir).unwrap();
    let mut c: coadapt_coadaptation::RunConfig = coadapt_test_support::read_config("configs/half-cheetah-tiny.toml");
    c.schedule.designs = 6;
    c.snapshot.every_episodes = 2;
    // Every 2 episodes, however short they are (no bound on the snapshots' share of the time).
    c.snapshot.max_share = 1.0;
    // A slower search, so the kill lands inside the run and not after it.
    c.optimizer.pso.particles = 5_000;
    c.optimizer.pso.iterations = 20;
    let config = dir.join("config.toml");
    std::fs::write(&config, toml::to_string(&c).unwrap()).unwrap();
    let out = dir.join("run");
    let mut run = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["run", "--config", config.to_str().unwrap(), "--out", out.to_str().unwrap(), "--transport", "in-process"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // 2 initial designs x 3 episodes, then 4 x 2: kill it in the chosen designs.
    let t = Instant::now();
    while rows(&out.join("episodes.csv")) < 8 {
        assert!(t.elapsed() < Duration::from_secs(120), "no 8th episode row");
        assert!(run.try_wait().unwrap().is_none(), "the run ended before the kill");
        std::thread::sleep(Duration::from_millis(5));
    }
    run.kill().unwrap(); // SIGKILL
    run.wait().unwrap();
    check(&out, &["--partial"]);
    // Killed before its end, the run has its plots all the same: they are redrawn whole at each
    // design's end (issue 32 section 3), never left half-written.
    for plot in ["learning_curves.svg", "best_return.svg"] {
        let svg = std::fs::read_to_string(out.join("plots").join(plot)).unwrap();
        assert!(svg.trim_end().ends_with("</svg>"), "{plot} is not whole");
    }

    let o = Command::new(env!("CARGO_BIN_EXE_coadapt")).args(["run", "--resume", out.to_str().unwrap()]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(rows(&out.join("episodes.csv")), 14);
    let files = event_files(&out);
    assert_eq!(files.len(), 2, "the resumed run went on in its own file: {files:?}");
    let said = check(&out, &["--xi", XI]);
    assert!(said.contains("tb_check: ok, 14 episodes"), "{said}");
}

#[test]
fn coadapt_train_writes_its_episodes_for_tensorboard_too() {
    let dir = coadapt_test_support::scratch("cli", "tensorboard-train");
    let out = dir.join("train");
    let o = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["train", "--env", "pendulum", "--algo", "sac", "--steps", "1400", "--quiet", "--out", out.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let said = check(&out, &["--train"]);
    assert!(said.contains("tb_check: ok, train, 7 episodes"), "{said}");
}

#[test]
fn latent_and_search_write_one_event_file_per_run_equal_to_their_csvs() {
    let dir = coadapt_test_support::scratch("cli", "tensorboard-latent-search");
    std::fs::create_dir_all(&dir).unwrap();
    let latent = dir.join("latent");
    let config = coadapt_test_support::workspace_file("configs/latent/pendulum-tiny.toml");
    let emb = dir.join("emb.safetensors");
    let o = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["latent", "--config", config.to_str().unwrap(), "--embedding", emb.to_str().unwrap(), "--out", latent.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let said = check(&latent, &["--latent"]);
    assert!(said.contains("tb_check: ok, latent, 2 runs, 6 rows"), "{said}");

    let search = dir.join("search");
    let config = coadapt_test_support::workspace_file("configs/search/planar-groups1.toml");
    let o = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["search", "--config", config.to_str().unwrap(), "--iterations", "3", "--runs", "2", "--out", search.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let said = check(&search, &["--search"]);
    assert!(said.contains("tb_check: ok, search, 2 runs, 6 rows"), "{said}");
}
