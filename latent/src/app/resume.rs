//! `coadapt latent --resume`: a stopped run directory goes on from its first unfinished run.
//!
//! A run (one seed) is deterministic given its seed, so the runs `episodes.csv` holds in full
//! are kept as they are and the first unfinished one starts again from its beginning: the
//! finished directory is the one an uninterrupted start would have written (the per-step
//! latency columns and times aside). At most one run's work is lost to a crash; the resumed
//! config must be the run's own (fleet and connection settings may change).

use std::path::Path;

use super::config::LatentConfig;
use coadapt_fleet::app::AppError;

/// The header `coadapt latent` writes.
pub(crate) const HEADER: &str = "run,episode,train_return,eval_return,train_steps,eval_steps,model_loss,plan_ms_mean,plan_ms_p90,seconds";

/// What the finished runs of a stopped run directory hold.
#[derive(Debug, Default)]
pub(crate) struct Finished {
    /// Runs kept (0..runs).
    pub runs: usize,
    /// Their rows, as written.
    pub rows: Vec<String>,
    pub train: Vec<Vec<f64>>,
    pub eval: Vec<Vec<f64>>,
    /// Sum of planning milliseconds over their planned steps, and how many steps.
    pub plan_ms: (f64, usize),
    /// The last kept row's time.
    pub seconds: f64,
}

/// The settings a resumed run may change: where its episodes run and how to reach them.
fn comparable(cfg: &LatentConfig) -> LatentConfig {
    let d = LatentConfig::default();
    LatentConfig {
        actors: d.actors,
        start_actors: d.start_actors,
        episode_lease_secs: d.episode_lease_secs,
        episode_deadline_secs: d.episode_deadline_secs,
        fleet: d.fleet,
        remote: d.remote,
        security: d.security,
        ..cfg.clone()
    }
}

/// The keys (dotted) in which `a` and `b` differ.
fn differing(a: &toml::Value, b: &toml::Value, prefix: &str, out: &mut Vec<String>) {
    match (a, b) {
        (toml::Value::Table(x), toml::Value::Table(y)) => {
            let mut keys: Vec<&String> = x.keys().chain(y.keys()).collect();
            keys.sort();
            keys.dedup();
            for k in keys {
                let p = if prefix.is_empty() { k.clone() } else { format!("{prefix}.{k}") };
                match (x.get(k), y.get(k)) {
                    (Some(u), Some(v)) => differing(u, v, &p, out),
                    _ => out.push(p),
                }
            }
        }
        _ if a != b => out.push(prefix.to_string()),
        _ => {}
    }
}

/// Reads `out`'s config and episodes and keeps its leading finished runs.
pub(crate) fn finished(out: &Path, cfg: &LatentConfig) -> Result<Finished, AppError> {
    let path = out.join("config.toml");
    let text = std::fs::read_to_string(&path).map_err(AppError::io(format!("--resume: reading {}", path.display())))?;
    let theirs: LatentConfig = toml::from_str(&text).map_err(|e| AppError::Config(format!("--resume: parsing {}: {e}", path.display())))?;
    let (a, b) = (comparable(&theirs), comparable(cfg));
    if a != b {
        let mut keys = Vec::new();
        let value = |c: &LatentConfig| toml::Value::try_from(c).map_err(|e| AppError::Config(e.to_string()));
        differing(&value(&a)?, &value(&b)?, "", &mut keys);
        return Err(AppError::Config(format!(
            "--resume: the config differs from the run's {} in {}; resume with --config {}",
            path.display(),
            keys.join(", "),
            path.display()
        )));
    }
    let path = out.join("episodes.csv");
    let text = std::fs::read_to_string(&path).map_err(AppError::io(format!("--resume: reading {}", path.display())))?;
    let mut lines = text.lines();
    if lines.next() != Some(HEADER) {
        return Err(AppError::Config(format!("--resume: {} does not start with coadapt latent's header", path.display())));
    }
    let mut f = Finished::default();
    let mut current: Vec<(String, [f64; 10])> = Vec::new();
    for (i, line) in lines.enumerate() {
        let cells: Vec<&str> = line.split(',').collect();
        let parsed: Option<Vec<f64>> = cells.iter().map(|c| c.parse::<f64>().ok()).collect();
        let Some(v) = parsed.filter(|v| v.len() == 10) else {
            // A row cut short by the crash ends the readable part.
            coadapt_log::logln!("latent: --resume: {} line {} is not a whole row; dropped with what follows", path.display(), i + 2);
            break;
        };
        let v: [f64; 10] = v.try_into().unwrap_or([f64::NAN; 10]);
        let (run, ep) = (v[0] as usize, v[1] as usize);
        if run != f.runs || ep != current.len() {
            coadapt_log::logln!(
                "latent: --resume: {} line {}: run {run} episode {ep} out of order; dropped with what follows",
                path.display(),
                i + 2
            );
            break;
        }
        current.push((line.to_string(), v));
        if current.len() == cfg.episodes {
            f.train.push(current.iter().map(|r| r.1[2]).collect());
            f.eval.push(current.iter().map(|r| r.1[3]).collect());
            for (_, r) in &current {
                if r[7].is_finite() && r[7] > 0.0 {
                    f.plan_ms.0 += r[7] * r[4];
                    f.plan_ms.1 += r[4] as usize;
                }
                f.seconds = r[9];
            }
            f.rows.extend(current.drain(..).map(|r| r.0));
            f.runs += 1;
            if f.runs == cfg.runs {
                break;
            }
        }
    }
    Ok(f)
}
