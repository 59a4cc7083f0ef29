//! `coadapt run`: a whole co-adaptation (FEAR or a baseline) on one robot. The learner, the
//! design optimiser and the actors run as separate processes over shared memory (the default;
//! [`crate::launch`] launches and supervises them), or as threads of this process over the
//! in-process transport (`--transport in-process`, [`run_config`]).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use coadapt_design_optimizer::landscape::{self, Pca2};
use coadapt_design_optimizer::{CriticObjective, DesignObjective, QMode, SwarmObjective};
use coadapt_fleet::TransportKind;
use coadapt_learner::coadapt;
use coadapt_learner::fear::{ActingPolicy, FearLearner};
use coadapt_log::print_stdout_line;
use coadapt_transport::in_process;

use crate::AppError;
use crate::config::{RunConfig, check, default_out, resolve_initial_designs};
use crate::error::bail;
use crate::roles;

/// Runs the co-adaptation described by `cfg` into `dir`, every role a thread of this process
/// over the in-process transport.
pub fn run_config(cfg: &RunConfig, dir: &Path, shutdown: &AtomicBool, resume: bool) -> crate::Result<coadapt::RunOutcome> {
    let spec = cfg.make_env()?.spec().clone();
    check(cfg, &spec)?;
    let (mut learner_links, actor_links, mut optimizer_links) = in_process::fleet(cfg.actors);
    // The actors and the optimiser stop when the learner is done, not on Ctrl-C themselves: an
    // actor that left on the signal while the learner was still training closed its channel
    // under the learner's next request ("the other side of the channel has closed") instead of
    // the learner stopping at its next step with a snapshot.
    let roles_stop = AtomicBool::new(false);
    let roles_stop = &roles_stop;
    std::thread::scope(|s| -> crate::Result<coadapt::RunOutcome> {
        let spec = &spec;
        // A role that fails stops the run: in one process nothing would restart it.
        let stop_on_error = |r: crate::Result<()>| {
            if r.is_err() {
                shutdown.store(true, Ordering::Relaxed);
            }
            r
        };
        let actors: Vec<_> = actor_links
            .into_iter()
            .enumerate()
            .map(|(i, mut links)| s.spawn(move || stop_on_error(roles::actor(cfg, spec, i as u64, &mut links, roles_stop))))
            .collect();
        let state = crate::resume::optimizer_state_dir(dir);
        let opt = s.spawn(move || stop_on_error(roles::optimizer(cfg, spec, &mut optimizer_links, roles_stop, Some(&state))));
        let result = roles::learner(cfg, spec, dir, &mut learner_links, shutdown, resume);
        // Closing the learner's channels lets the other roles finish.
        roles_stop.store(true, Ordering::Relaxed);
        drop(learner_links);
        // The first role failure keeps its kind: a bad setting read by the optimiser exits 78.
        let mut first = None;
        for t in actors.into_iter().map(|t| t.join()).chain(std::iter::once(opt.join())) {
            let e = match t {
                Ok(Ok(())) => continue,
                Ok(Err(e)) => e,
                Err(_) => crate::error::failed!("a role thread panicked"),
            };
            first.get_or_insert(e);
        }
        match (result, first) {
            (Ok(o), Some(first)) if o.interrupted => Err(first),
            (Ok(o), first) => {
                if let Some(e) = first {
                    coadapt_log::logln!("warning: {e:#}");
                }
                Ok(o)
            }
            // The learner broke because a role went away (its links closed) and that role's
            // failure is one a restart cannot mend (a setting, a full disk): that is the cause.
            (Err(e), Some(first)) if e.exit_code().is_none() && first.exit_code().is_some() => {
                coadapt_log::logln!("warning: the learner then stopped: {e:#}");
                Err(first)
            }
            (Err(e), Some(first)) => Err(e.context(format!("first role failure: {first:#}"))),
            (Err(e), None) => Err(e),
        }
    })
}

/// Scores the design objective on a grid over the first two principal components of the
/// designs tried (thesis Fig. 5.9) with the final population networks, and writes
/// `landscape.csv` (pc1, pc2, objective) and `landscape_designs.csv` (the designs, projected).
pub fn write_landscape(cfg: &RunConfig, dir: &Path, outcome: &mut coadapt::RunOutcome) -> crate::Result<()> {
    let n = cfg.landscape_grid;
    if n == 0 || outcome.designs.is_empty() {
        return Ok(());
    }
    let spec = cfg.make_env()?.spec().clone();
    let dim = spec.design_dim();
    let designs: Vec<f32> = outcome.designs.iter().flat_map(|d| d.design.clone()).collect();
    let pca = Pca2::fit(&designs, dim).map_err(AppError::library)?;
    let grid = landscape::grid(&pca, &designs, &spec.design, n).map_err(AppError::library)?;
    let learner: &mut FearLearner = &mut outcome.learner;
    let Some(states) = learner.sample_start_states(cfg.landscape_start_states.max(1)) else { return Ok(()) };
    let pop = learner.agent(ActingPolicy::Population);
    let objective =
        DesignObjective::new(pop.policy(), pop.policy_params(), pop.critic(), &[pop.critic_params(0).0], &states, spec.state_dim, dim)
            .map_err(AppError::library)?;
    let mut scores = vec![0.0; n * n];
    CriticObjective::new(&objective, QMode::First, 2).evaluate(&grid.designs, &mut scores);
    let mut f = std::io::BufWriter::new(std::fs::File::create(dir.join("landscape.csv"))?);
    writeln!(f, "pc1,pc2,objective")?;
    for (pc, s) in grid.pc.iter().zip(&scores) {
        writeln!(f, "{},{},{}", pc[0], pc[1], s)?;
    }
    f.flush()?;
    let mut f = std::io::BufWriter::new(std::fs::File::create(dir.join("landscape_designs.csv"))?);
    writeln!(f, "index,kind,pc1,pc2")?;
    let mut tried = Vec::with_capacity(outcome.designs.len());
    for d in &outcome.designs {
        let p = pca.project(&d.design);
        writeln!(f, "{},{},{},{}", d.index, d.kind, p[0], p[1])?;
        tried.push(p);
    }
    f.flush()?;
    // The same landscape for TensorBoard's image dashboard (`run/landscape`), in a file of its
    // own beside the run's event file (TensorBoard reads every event file of the directory).
    let (w, h, rgb) = landscape_raster(n, &grid.pc, &scores, &tried);
    let mut events = coadapt_tensorboard::EventWriter::create(dir, "landscape")?;
    events.image("run/landscape", outcome.designs.len() as i64, coadapt_tensorboard::png_rgb(w, h, &rgb), w, h)?;
    events.sync()?;
    Ok(())
}

/// Thesis Fig. 5.9 as an RGB raster: the grid's objective coloured from dark blue (low) through
/// green to yellow (high), pc1 to the right and pc2 up, `CELL` pixels a grid point, and the
/// designs tried as white dots with a black rim.
fn landscape_raster(n: usize, pc: &[[f32; 2]], scores: &[f32], tried: &[[f32; 2]]) -> (u32, u32, Vec<u8>) {
    const CELL: usize = 16;
    let side = n * CELL;
    let (lo, hi) = scores.iter().filter(|v| v.is_finite()).fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), &v| (l.min(v), h.max(v)));
    let span = if hi > lo { hi - lo } else { 1.0 };
    // Viridis at five stops.
    const STOPS: [[f32; 3]; 5] = [[68.0, 1.0, 84.0], [59.0, 82.0, 139.0], [33.0, 145.0, 140.0], [94.0, 201.0, 98.0], [253.0, 231.0, 37.0]];
    let colour = |v: f32| -> [u8; 3] {
        let t = if v.is_finite() { ((v - lo) / span).clamp(0.0, 1.0) * 4.0 } else { 0.0 };
        let i = (t.floor() as usize).min(3);
        let f = t - i as f32;
        let mut c = [0u8; 3];
        for (k, c) in c.iter_mut().enumerate() {
            *c = (STOPS[i][k] + f * (STOPS[i + 1][k] - STOPS[i][k])).round() as u8;
        }
        c
    };
    let mut rgb = vec![0u8; side * side * 3];
    for (k, s) in scores.iter().enumerate().take(n * n) {
        let (i1, i2) = (k % n, k / n);
        let c = colour(*s);
        for y in 0..CELL {
            let row = (n - 1 - i2) * CELL + y;
            for x in 0..CELL {
                let at = (row * side + i1 * CELL + x) * 3;
                rgb[at..at + 3].copy_from_slice(&c);
            }
        }
    }
    if n >= 2 && pc.len() >= n * n {
        let (x0, x1, y0, y1) = (pc[0][0], pc[n - 1][0], pc[0][1], pc[n * (n - 1)][1]);
        for p in tried {
            let fx = if x1 > x0 { (p[0] - x0) / (x1 - x0) } else { 0.5 };
            let fy = if y1 > y0 { (p[1] - y0) / (y1 - y0) } else { 0.5 };
            let (cx, cy) = ((fx * (n - 1) as f32 + 0.5) * CELL as f32, ((1.0 - fy) * (n - 1) as f32 + 0.5) * CELL as f32);
            for y in 0..side {
                for x in 0..side {
                    let d = ((x as f32 - cx).powi(2) + (y as f32 - cy).powi(2)).sqrt();
                    if d <= 5.0 {
                        let c = if d <= 3.5 { 255 } else { 0 };
                        rgb[(y * side + x) * 3..(y * side + x) * 3 + 3].fill(c);
                    }
                }
            }
        }
    }
    (side as u32, side as u32, rgb)
}

/// What a finished learner leaves besides its rows: the design landscape, the plots, and the
/// one JSON summary line on stdout.
pub fn finish(cfg: &RunConfig, dir: &Path, outcome: &mut coadapt::RunOutcome, shutdown: &AtomicBool, start: Instant) -> crate::Result<()> {
    if let Err(e) = write_landscape(cfg, dir, outcome) {
        coadapt_log::logln!("warning: design landscape not written: {e:#}");
    }
    let interrupted = outcome.interrupted || shutdown.load(Ordering::Relaxed);
    let plots = match crate::plot::draw_run(dir) {
        Ok(p) => p,
        // Stopped before anything was learned (say, Ctrl-C while the first prototype was
        // awaited): the summary still says where the run got to.
        Err(e) if interrupted => {
            coadapt_log::logln!("warning: no plots: {e:#}");
            Vec::new()
        }
        Err(e) => return Err(e.context("drawing the plots")),
    };
    for p in &plots {
        coadapt_log::logln!("wrote {}", p.display());
    }
    let best = outcome.designs.iter().filter_map(|d| d.best_eval_return.map(|r| (r, d))).max_by(|a, b| a.0.total_cmp(&b.0));
    let t = outcome.time;
    let mut summary = serde_json::json!({
        "run_dir": dir.display().to_string(),
        "env": cfg.env,
        "exploit": cfg.optimizer.exploit.name(),
        "transport": cfg.fleet.transport.name(),
        "designs": outcome.designs.len(),
        "interrupted": interrupted,
        "best_eval_return": best.map(|b| b.0),
        "best_design": best.map(|b| b.1.design.clone()),
        "design_rollouts": outcome.designs.iter().map(|d| d.design_rollouts).sum::<u64>(),
        "seconds": start.elapsed().as_secs_f64(),
        "learner_waiting_seconds": t.waiting,
        "learner_sending_seconds": t.sending,
        "learner_training_seconds": t.training,
        "episodes_reissued": t.reissued,
        "episodes_restarted": t.restarted,
        "design_requests_resent": t.design_requests_resent,
        "design_replies_refused": t.design_replies_refused,
        "episodes_rejected": t.episodes_rejected,
        "rollbacks": t.rollbacks,
        "max_policy_lag": t.max_policy_lag,
        // The prototype step (schedule.confirm-designs, schedule.reset-needs-confirmation).
        "prototype_waiting_seconds": t.waiting_for_prototype,
        "reset_waiting_seconds": t.waiting_for_reset,
        "prototypes_rejected": outcome.rejected.len(),
        "population_updates_while_waiting": t.updates_while_waiting,
        // Every transition in the replay, and every episode start: only whole episodes get in.
        "replay_transitions": outcome.learner.population_transitions(),
        "start_states": outcome.learner.start_states(),
    });
    // Only when set: a run in the robot's own world from scratch keeps the summary it had.
    if !cfg.world.is_default() {
        summary["world"] = serde_json::json!(cfg.world);
    }
    if !cfg.init_population.is_off() {
        summary["init_population"] = serde_json::json!(cfg.init_population);
    }
    // Which kernel the bf16 products ran on here (timings and bits depend on it).
    if cfg.learner.sac.precision == coadapt_nn::Precision::Bf16 {
        summary["products"] = serde_json::json!(coadapt_nn::bf16::bf16_kernel());
    }
    print_stdout_line(&summary.to_string());
    Ok(())
}

/// `coadapt run`: the co-adaptation of `cfg` (named `name`) into `out` (default:
/// `runs/<name>-seed<seed>`), or continuing the run in `resume`; until done or `shutdown`.
pub fn run(mut cfg: RunConfig, name: &str, out: Option<PathBuf>, resume: Option<PathBuf>, shutdown: &AtomicBool) -> crate::Result<()> {
    let spec = cfg.make_env()?.spec().clone();
    resolve_initial_designs(&mut cfg, &spec);
    check(&cfg, &spec)?;
    let resuming = resume.is_some();
    let dir = match resume {
        Some(d) => {
            crate::resume::check_compatible(&crate::resume::stored_config(&d)?, &cfg)?;
            d
        }
        None => out.unwrap_or_else(|| default_out(name, cfg.seed)),
    };
    if !resuming && dir.join("designs.csv").exists() {
        bail!("{} already holds a run (designs.csv exists); choose another --out, or --resume it", dir.display());
    }
    coadapt_log::logln!(
        "coadapt run: {} on {}, {} designs ({} episodes), exploit {}, explore {}, {} actor(s) over {}, into {}",
        name,
        cfg.env,
        cfg.schedule.designs,
        cfg.schedule.total_episodes(),
        cfg.optimizer.exploit.name(),
        if cfg.schedule.alternate { format!("{:?}", cfg.optimizer.explore).to_lowercase() } else { "none".into() },
        cfg.actors,
        cfg.fleet.transport.name(),
        dir.display()
    );
    if cfg.fleet.transport != TransportKind::InProcess {
        return crate::launch::launch(&cfg, &dir, shutdown, resuming);
    }
    let start = Instant::now();
    let mut outcome = run_config(&cfg, &dir, shutdown, resuming)?;
    finish(&cfg, &dir, &mut outcome, shutdown, start)
}
