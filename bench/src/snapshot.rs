//! `coadapt bench snapshot`: a snapshot of a learner whose population buffer holds N
//! HalfCheetah-sized transitions (random values, drawn before anything is timed), written and
//! read back through the same code a run uses; seconds and MB/s of each, several rounds.

use std::path::PathBuf;
use std::time::Instant;

use coadapt_core::{Transition, rng};
use coadapt_learner::fear::{FearLearner, FearLearnerConfig};
use coadapt_learner::snapshot;
use rand::Rng;
use serde_json::json;

use coadapt_fleet::app::AppError;

#[derive(Debug, Clone)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct SnapshotOptions {
    /// Transitions in the population buffer (comma-separated list: one figure each).
    #[cfg_attr(feature = "clap", arg(long, value_delimiter = ',', default_values_t = vec![1_000_000usize, 10_000_000]))]
    pub transitions: Vec<usize>,
    /// Where to write (a directory on the disk to measure; removed afterwards).
    #[cfg_attr(feature = "clap", arg(long, default_value = "target/bench-snapshot"))]
    pub dir: PathBuf,
    /// Write/read rounds per size.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 3))]
    pub rounds: usize,
    /// Drop the page cache before each read (needs root), so reads come from the disk.
    #[cfg_attr(feature = "clap", arg(long))]
    pub drop_caches: bool,
}

pub fn run(a: &SnapshotOptions) -> Result<(), AppError> {
    // HalfCheetah: 17 state + 6 design observation columns, 6 actions.
    let (obs, act) = (23, 6);
    for &n in &a.transitions {
        let cfg = FearLearnerConfig {
            population_capacity: n.max(1),
            species_capacity: 1,
            start_state_capacity: 1,
            ..FearLearnerConfig::default()
        };
        let mut l = FearLearner::new(obs, act, cfg.clone(), 1)?;
        let mut r = rng(1, 99);
        let mut o = vec![0f32; obs];
        let mut next = vec![0f32; obs];
        let mut u = vec![0f32; act];
        for _ in 0..n {
            o.iter_mut().chain(next.iter_mut()).chain(u.iter_mut()).for_each(|x| *x = r.random_range(-1.0..1.0));
            l.add_transition(&Transition { obs: &o, action: &u, reward: r.random(), next_obs: &next, terminated: false })?;
        }
        let root = a.dir.join(format!("n{n}"));
        for round in 0..a.rounds {
            let _ = std::fs::remove_dir_all(&root);
            let t = Instant::now();
            let dir = snapshot::write(&root, round as u64, "bench", "bench", 2, |out| l.save_state(out))
                // Its message names the file and what became of the partial snapshot.
                .map_err(snapshot::SnapshotError::Io)?;
            let write = t.elapsed().as_secs_f64();
            let bytes: u64 = std::fs::read_dir(&dir)
                .map_err(AppError::io(format!("reading {}", dir.display())))?
                .filter_map(|e| e.ok()?.metadata().ok())
                .map(|m| m.len())
                .sum();
            let mut fresh = FearLearner::new(obs, act, cfg.clone(), 2)?;
            if a.drop_caches {
                std::fs::write("/proc/sys/vm/drop_caches", "3\n")
                    .map_err(|e| AppError::Failed(format!("--drop-caches: {e} (needs root)")))?;
            }
            let t = Instant::now();
            let (_, mut state) = snapshot::load(&dir)?;
            fresh.load_state(&mut state)?;
            let read = t.elapsed().as_secs_f64();
            if fresh.population_transitions() != n {
                return Err(AppError::Failed(format!("read back {} transitions of {n}", fresh.population_transitions())));
            }
            let mb = bytes as f64 / 1e6;
            for (what, s) in [("write", write), ("read", read)] {
                let line = json!({"bench": format!("snapshot_{what}"), "config": format!("{n} transitions, {mb:.0} MB, round {}", round + 1), "value": s, "unit": "s", "mb_per_s": mb / s});
                coadapt_log::print_stdout_line(&line.to_string());
            }
        }
        std::fs::remove_dir_all(&root).map_err(AppError::io(format!("removing {}", root.display())))?;
    }
    Ok(())
}
