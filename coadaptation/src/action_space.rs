//! `coadapt action-space RUN_DIR`: the latent design-dependent action space of thesis section
//! 6.2 learned from a co-adaptation's experience. The run's newest snapshot gives the population
//! replay (states, designs, actions of every design it trained) and the population critic,
//! whose values weight Eq. 6.1 (`max(Q, 0)`); the autoencoder is trained on it and written with
//! its learning curve and the thesis's two figures:
//!
//! - `action_space.safetensors` (`encoder`, `decoder`), what `coadapt train --latent-exploration`
//!   reads;
//! - `loss.csv` (update, mean loss over the last 100 updates);
//! - `latent_plane.svg` (Fig. 6.1): the latent plane at one start state of the run, each code
//!   coloured by the critic's value of its decoded action;
//! - `decoded_grid.svg` (Fig. 6.2): one latent grid decoded for the run's design with the
//!   shortest legs and for the one with the longest, in action dimensions 2 and 4;
//! - `summary.json`: the data, the final loss and, per design of Fig. 6.2, the spread of the
//!   decoded grid in those two dimensions (does it contract or expand with leg length?).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use coadapt_learner::action_space::{ActionAutoencoder, ActionSpaceConfig};
use coadapt_learner::{networks, run_dir, snapshot};
use rand::Rng;

use crate::AppError;
use crate::error::{Context, bail_config};

/// What `coadapt action-space` is asked.
#[derive(Clone, Debug)]
pub struct ActionSpaceOptions {
    /// The co-adaptation's run directory.
    pub run: PathBuf,
    /// Where the files go (default `RUN/action-space`).
    pub out: Option<PathBuf>,
    pub cfg: ActionSpaceConfig,
    /// Adam updates.
    pub updates: usize,
    pub seed: u64,
}

/// The run's experience as the autoencoder reads it.
struct Data {
    obs_dim: usize,
    act_dim: usize,
    obs: Vec<f32>,
    act: Vec<f32>,
    weight: Vec<f32>,
    /// The critic that weighed it (for Fig. 6.1).
    critic: (coadapt_nn::Mlp, Vec<f32>),
    /// A start state of the run (state and design).
    start: Vec<f32>,
}

fn load(run: &Path) -> crate::Result<Data> {
    let cfg = crate::resume::stored_config(run)?;
    let root = crate::resume::snapshot_root(run);
    let (from, _, mut state, _) = snapshot::load_latest(&root).with_context(|| format!("{} has no readable snapshot", run.display()))?;
    coadapt_log::logln!("action-space: experience of {} from {}", run.display(), from.display());
    let mut take = |name: &str| state.f32s_any(name).with_context(|| format!("snapshot {}: {name}", from.display()));
    let (obs, act, start) = (take("replay.population.obs")?, take("replay.population.act")?, take("replay.start.obs")?);
    let rew = take("replay.population.rew")?;
    let q1 = take("population.q1")?;
    let n = rew.len();
    if n == 0 {
        bail_config!("{}: the population replay is empty (no design has trained it yet)", run.display());
    }
    let (obs_dim, act_dim) = (obs.len() / n, act.len() / n);
    let critic = networks::critic(obs_dim, act_dim, &cfg.learner.sac.hidden).map_err(AppError::library)?;
    if critic.n_params() != q1.len() {
        bail_config!(
            "{}: the critic has {} parameters, its config's learner.sac.hidden makes {}",
            run.display(),
            q1.len(),
            critic.n_params()
        );
    }
    let weight = critic_values(&critic, &q1, &obs, &act, obs_dim, act_dim).iter().map(|q| q.max(0.0)).collect();
    let start =
        start.get(..obs_dim).ok_or_else(|| AppError::Failed(format!("{}: no start state in the snapshot", run.display())))?.to_vec();
    Ok(Data { obs_dim, act_dim, obs, act, weight, critic: (critic, q1), start })
}

/// Q of each row (`obs` and `act` stacked by rows), in chunks.
fn critic_values(critic: &coadapt_nn::Mlp, theta: &[f32], obs: &[f32], act: &[f32], obs_dim: usize, act_dim: usize) -> Vec<f32> {
    let n = obs.len() / obs_dim;
    let chunk = 4096;
    let mut acts = critic.activations(chunk);
    let mut x = Vec::with_capacity(chunk * (obs_dim + act_dim));
    let mut out = Vec::with_capacity(n);
    for c in (0..n).step_by(chunk) {
        let rows = chunk.min(n - c);
        x.clear();
        for r in c..c + rows {
            x.extend_from_slice(&obs[r * obs_dim..(r + 1) * obs_dim]);
            x.extend_from_slice(&act[r * act_dim..(r + 1) * act_dim]);
        }
        out.extend_from_slice(&critic.forward(theta, &x, rows, &mut acts)[..rows]);
    }
    out
}

/// The designs of the run with the shortest and the longest legs (the smallest and largest mean
/// design value), for Fig. 6.2.
fn extreme_designs(run: &Path) -> crate::Result<[Vec<f32>; 2]> {
    let path = run.join("designs.csv");
    let len = std::fs::metadata(&path).with_context(|| format!("reading {}", path.display()))?.len();
    let rows = run_dir::read_designs(&path, len).with_context(|| format!("reading {}", path.display()))?;
    let mean = |d: &[f32]| d.iter().sum::<f32>() / d.len().max(1) as f32;
    let short = rows.iter().min_by(|a, b| mean(&a.design).total_cmp(&mean(&b.design)));
    let long = rows.iter().max_by(|a, b| mean(&a.design).total_cmp(&mean(&b.design)));
    match (short, long) {
        (Some(s), Some(l)) => Ok([s.design.clone(), l.design.clone()]),
        _ => bail_config!("{} has no design", path.display()),
    }
}

/// Trains the autoencoder on `opts.run`'s experience and writes the files (see the module doc).
/// Returns the summary printed on stdout.
pub fn run(opts: &ActionSpaceOptions, shutdown: &AtomicBool) -> crate::Result<serde_json::Value> {
    if opts.updates == 0 || opts.cfg.batch_size == 0 {
        bail_config!("--updates and batch-size must be at least 1");
    }
    let data = load(&opts.run)?;
    let out = opts.out.clone().unwrap_or_else(|| opts.run.join("action-space"));
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let (no, na, n) = (data.obs_dim, data.act_dim, data.weight.len());
    let mut ae = ActionAutoencoder::new(no, na, opts.cfg.clone(), opts.seed).map_err(|e| AppError::Config(e.to_string()))?;
    let b = opts.cfg.batch_size;
    let mut rng = coadapt_core::rng(opts.seed, 0x4145_5452);
    let (mut bo, mut ba, mut bw) = (vec![0.0; b * no], vec![0.0; b * na], vec![0.0; b]);
    let loss_path = out.join("loss.csv");
    let mut csv = std::io::BufWriter::new(std::fs::File::create(&loss_path).with_context(|| format!("creating {}", loss_path.display()))?);
    writeln!(csv, "update,loss").with_context(|| format!("writing {}", loss_path.display()))?;
    let (mut window, mut last) = (0.0f64, f64::NAN);
    for u in 1..=opts.updates {
        if shutdown.load(Ordering::Relaxed) {
            return Err(AppError::Interrupted(format!(
                "stopped after {} of {} updates; nothing written but loss.csv",
                u - 1,
                opts.updates
            )));
        }
        for r in 0..b {
            let i = rng.random_range(0..n);
            bo[r * no..(r + 1) * no].copy_from_slice(&data.obs[i * no..(i + 1) * no]);
            ba[r * na..(r + 1) * na].copy_from_slice(&data.act[i * na..(i + 1) * na]);
            bw[r] = data.weight[i];
        }
        window += ae.update(&bo, &ba, &bw, b);
        if u % 100 == 0 {
            last = window / 100.0;
            window = 0.0;
            writeln!(csv, "{u},{last}").with_context(|| format!("writing {}", loss_path.display()))?;
        }
        if u % 5000 == 0 {
            coadapt_log::logln!("action-space: update {u}/{}: loss {last:.4}", opts.updates);
        }
    }
    csv.flush().with_context(|| format!("writing {}", loss_path.display()))?;
    ae.save(&out.join("action_space.safetensors")).map_err(AppError::library)?;

    // Fig. 6.1: the latent plane at the run's first start state; the grid spans the codes of the
    // data (2nd to 98th percentile of each coordinate, the wider of the two, both axes alike).
    let latent = ae.latent_dim();
    let sample = n.min(20_000);
    let z = ae.encode(&data.obs[..sample * no], &data.act[..sample * na], sample);
    let mut all: Vec<f64> = z.iter().map(|v| f64::from(*v)).collect();
    all.sort_by(f64::total_cmp);
    let (lo, hi) = (all[all.len() / 50], all[all.len() - 1 - all.len() / 50]);
    let r = lo.abs().max(hi.abs()).max(1e-3);
    let g = 41;
    let zs: Vec<f64> = (0..g).map(|i| -r + 2.0 * r * i as f64 / (g - 1) as f64).collect();
    let mut plane = Vec::new();
    if latent == 2 {
        let codes: Vec<f32> = (0..g * g).flat_map(|k| [zs[k % g] as f32, zs[k / g] as f32]).collect();
        let starts: Vec<f32> = (0..g * g).flat_map(|_| data.start.iter().copied()).collect();
        let decoded = ae.decode(&starts, &codes, g * g);
        plane = critic_values(&data.critic.0, &data.critic.1, &starts, &decoded, no, na).iter().map(|v| f64::from(*v)).collect();
        crate::plot::action_space::latent_plane(
            &out.join("latent_plane.svg"),
            &zs,
            &plane,
            "Latent plane at a start state, coloured by Q",
        )?;
    } else {
        coadapt_log::logln!("action-space: latent-dim {latent}: the two figures need a 2-D latent, skipped");
    }

    // Fig. 6.2: one latent grid decoded for the shortest- and the longest-legged design, the
    // start state's state part kept, in action dimensions 2 and 4 (or the last two).
    let designs = extreme_designs(&opts.run)?;
    let d = designs[0].len();
    let dims = if na >= 4 { (1, 3) } else { (0, na.saturating_sub(1)) };
    let k = 9;
    let mut grids = Vec::new();
    let mut spreads = Vec::new();
    if latent == 2 && d > 0 && d <= no {
        for (name, design) in ["shortest legs", "longest legs"].iter().zip(&designs) {
            let mut o = data.start.clone();
            o[no - d..].copy_from_slice(design);
            let codes: Vec<f32> = (0..k * k)
                .flat_map(|q| {
                    [
                        (zs[0] + (zs[g - 1] - zs[0]) * (q % k) as f64 / (k - 1) as f64) as f32,
                        (zs[0] + (zs[g - 1] - zs[0]) * (q / k) as f64 / (k - 1) as f64) as f32,
                    ]
                })
                .collect();
            let obs: Vec<f32> = (0..k * k).flat_map(|_| o.iter().copied()).collect();
            let a = ae.decode(&obs, &codes, k * k);
            let points: Vec<(f64, f64)> = (0..k * k).map(|q| (f64::from(a[q * na + dims.0]), f64::from(a[q * na + dims.1]))).collect();
            let sd = |f: &dyn Fn(&(f64, f64)) -> f64| {
                let m = points.iter().map(f).sum::<f64>() / points.len() as f64;
                (points.iter().map(|p| (f(p) - m).powi(2)).sum::<f64>() / (points.len() - 1) as f64).sqrt()
            };
            spreads.push(serde_json::json!({ "design": design, "sd_x": sd(&|p| p.0), "sd_y": sd(&|p| p.1) }));
            let mean = design.iter().sum::<f32>() / d as f32;
            grids.push((format!("{name} (mean {mean:.2})"), points));
        }
        crate::plot::action_space::decoded_grids(&out.join("decoded_grid.svg"), &grids, k, dims)?;
    }
    let summary = serde_json::json!({
        "run": opts.run.display().to_string(),
        "out": out.display().to_string(),
        "transitions": n,
        "weighted_transitions": data.weight.iter().filter(|w| **w > 0.0).count(),
        "latent_dim": latent,
        "hidden": opts.cfg.hidden,
        "updates": opts.updates,
        "final_loss": last,
        "latent_range": r,
        "q_on_plane": if plane.is_empty() { serde_json::Value::Null } else { serde_json::json!([plane.iter().copied().fold(f64::INFINITY, f64::min), plane.iter().copied().fold(f64::NEG_INFINITY, f64::max)]) },
        "grid_dims": [dims.0 + 1, dims.1 + 1],
        "grid_spread": spreads,
    });
    std::fs::write(out.join("summary.json"), summary.to_string())
        .with_context(|| format!("writing {}", out.join("summary.json").display()))?;
    Ok(summary)
}
