//! The population critic's ensemble (`learner.population-critics`, issue 28 section 3) through
//! the binary, over shared memory: the heads reach the design optimiser (its pessimistic choice,
//! and the conservative heads' choice under `q = "heads"`, differ from the twin's alone, while
//! the episodes before it are the plain run's, episode for episode) and the run ends as any run
//! does.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::path::Path;
use std::process::Command;

const TINY: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/half-cheetah-tiny.toml");

fn run(dir: &Path, name: &str, learner_extra: &str, q: &str) -> (Vec<String>, Vec<String>) {
    let tiny = std::fs::read_to_string(TINY).unwrap();
    let cfg = dir.join(format!("{name}.toml"));
    let text = tiny
        .replace("[learner]\n", &format!("[learner]\n{learner_extra}"))
        .replace("[optimizer]\n", &format!("[optimizer]\nq = \"{q}\"\n"));
    std::fs::write(&cfg, text).unwrap();
    let out = dir.join(name);
    let o = Command::new(env!("CARGO_BIN_EXE_coadapt"))
        .args(["run", "--config", cfg.to_str().unwrap(), "--transport", "shm", "--actors", "2", "--out", out.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{name}: {}", String::from_utf8_lossy(&o.stderr));
    let read = |f: &str| std::fs::read_to_string(out.join(f)).unwrap().lines().map(str::to_string).collect::<Vec<_>>();
    (read("designs.csv"), read("episodes.csv"))
}

/// The episodes.csv columns that do not depend on timing or on which actor ran the episode.
fn episode_rows(rows: &[String]) -> Vec<String> {
    let header: Vec<&str> = rows[0].split(',').collect();
    let keep: Vec<usize> =
        header.iter().enumerate().filter(|(_, h)| !matches!(**h, "seconds" | "actor" | "wall_s")).map(|(i, _)| i).collect();
    rows.iter().map(|r| keep.iter().map(|&i| r.split(',').nth(i).unwrap_or("")).collect::<Vec<_>>().join(",")).collect()
}

#[test]
fn ensemble_heads_reach_the_optimiser_and_change_its_pessimistic_choice_only() {
    let dir = coadapt_test_support::scratch("cli", "ensemble");
    std::fs::create_dir_all(&dir).unwrap();
    let (twin_designs, twin_eps) = run(&dir, "twin", "", "pessimistic");
    let (ens_designs, ens_eps) = run(&dir, "ensemble", "population-critics = 5\n", "pessimistic");
    assert_eq!(ens_designs.len(), 5, "header and four designs: {ens_designs:?}");
    // The initial designs and their episodes are the plain run's: the heads only watch.
    assert_eq!(twin_designs[..3], ens_designs[..3]);
    let initial_episodes = 2 * 3 + 1; // header + 2 initial designs x 3 episodes
    assert_eq!(episode_rows(&twin_eps)[..initial_episodes], episode_rows(&ens_eps)[..initial_episodes]);
    // The exploitation design is chosen with five heads' mean - 2 sd, not the twin's.
    let design = |rows: &[String]| rows[3].split(',').nth(2).unwrap().to_string();
    assert_ne!(design(&twin_designs), design(&ens_designs), "the heads did not reach the optimiser");
    let predicted: f64 = ens_designs[3].split(',').nth(6).unwrap().parse().unwrap();
    assert!(predicted.is_finite(), "{}", ens_designs[3]);
}

/// COMs' conservative term on one head beyond the twin, which alone scores designs
/// (`q = "heads"`): everything before the first chosen design is FEAR's, episode for episode
/// (the head acts on nothing) and the chosen design is the head's. Against the same head without
/// the term, the choice differs too: the config's term reaches the head through the binary.
#[test]
fn a_conservative_head_scores_the_designs_and_changes_nothing_else() {
    let dir = coadapt_test_support::scratch("cli", "conservative-head");
    std::fs::create_dir_all(&dir).unwrap();
    let (fear_designs, fear_eps) = run(&dir, "fear", "", "q1");
    let (cons_designs, cons_eps) = run(&dir, "conservative", "population-critics = 3\nconservative = { weight = 1.0 }\n", "heads");
    let (head_designs, _) = run(&dir, "head-only", "population-critics = 3\n", "heads");
    assert_eq!(cons_designs.len(), 5, "header and four designs: {cons_designs:?}");
    assert_eq!(fear_designs[..3], cons_designs[..3]);
    let initial_episodes = 2 * 3 + 1; // header + 2 initial designs x 3 episodes
    assert_eq!(episode_rows(&fear_eps)[..initial_episodes], episode_rows(&cons_eps)[..initial_episodes]);
    let design = |rows: &[String]| rows[3].split(',').nth(2).unwrap().to_string();
    assert_ne!(design(&fear_designs), design(&cons_designs), "the head did not reach the optimiser");
    assert_ne!(design(&head_designs), design(&cons_designs), "the term did not reach the head");
    let predicted: f64 = cons_designs[3].split(',').nth(6).unwrap().parse().unwrap();
    assert!(predicted.is_finite(), "{}", cons_designs[3]);
}
