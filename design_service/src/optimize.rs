//! `Optimize`: PSO or CMA-ES over Eq. 5.6, streamed.

use std::ops::ControlFlow;
use std::sync::Arc;

use coadapt_core::BoxSpace;
use coadapt_design_optimizer::objective::ObjectiveWorkspace;
use coadapt_design_optimizer::{CmaesConfig, PsoConfig, cmaes, pso};
use coadapt_wire::pb;
use tokio::sync::mpsc;
use tonic::Status;

use crate::model::DesignModel;
use crate::shared::Shared;

/// A checked request: the search's box over the free coordinates, and the fixed ones.
#[derive(Debug)]
pub(crate) struct Search {
    cmaes: bool,
    particles: usize,
    iterations: usize,
    seed: u64,
    /// Per dimension: `Some(v)` fixed at `v`, `None` searched.
    fixed: Vec<Option<f32>>,
    free: BoxSpace,
}

impl Search {
    /// Checks `r` against the model's box and the server's budget; INVALID_ARGUMENT names the
    /// field.
    pub(crate) fn of(r: &pb::OptimizeRequest, m: &DesignModel, budget: u64) -> Result<Self, Status> {
        let bad = |field: &str, why: String| Status::invalid_argument(format!("{field}: {why}"));
        let cmaes = match r.method.as_str() {
            "" | "pso" => false,
            "cmaes" => true,
            other => return Err(bad("method", format!("{other:?}; pso or cmaes"))),
        };
        let dim = m.design_dim();
        let (mut low, mut high) = (m.bounds.low.clone(), m.bounds.high.clone());
        for (name, given, into) in [("low", &r.low, &mut low), ("high", &r.high, &mut high)] {
            if given.is_empty() {
                continue;
            }
            if given.len() != dim {
                return Err(bad(name, format!("{} values; the design has {dim} dimensions", given.len())));
            }
            for (j, &v) in given.iter().enumerate() {
                let (lo, hi) = (m.bounds.low[j], m.bounds.high[j]);
                if !(v.is_finite() && v >= lo && v <= hi) {
                    return Err(bad(&format!("{name}[{j}] ({})", m.names[j]), format!("{v} is outside the design box [{lo}, {hi}]")));
                }
                into[j] = v;
            }
        }
        if let Some(j) = (0..dim).find(|&j| low[j] > high[j]) {
            return Err(bad(&format!("low[{j}] ({})", m.names[j]), format!("{} is above high {}", low[j], high[j])));
        }
        let mut fixed = vec![None; dim];
        for (i, f) in r.fixed.iter().enumerate() {
            let j = f.dimension as usize;
            if j >= dim {
                return Err(bad(&format!("fixed[{i}].dimension"), format!("{j}; the design has {dim} dimensions (0 to {})", dim - 1)));
            }
            if fixed[j].is_some() {
                return Err(bad(&format!("fixed[{i}].dimension"), format!("{j} ({}) is fixed twice", m.names[j])));
            }
            if !(f.value.is_finite() && f.value >= low[j] && f.value <= high[j]) {
                return Err(bad(
                    &format!("fixed[{i}].value"),
                    format!("{} is outside [{}, {}] ({})", f.value, low[j], high[j], m.names[j]),
                ));
            }
            fixed[j] = Some(f.value);
        }
        let free_dims: Vec<usize> = (0..dim).filter(|&j| fixed[j].is_none()).collect();
        if free_dims.is_empty() {
            return Err(bad("fixed", "every coordinate is fixed: nothing to search (Score gives its value)".into()));
        }
        let free = BoxSpace::new(free_dims.iter().map(|&j| low[j]).collect(), free_dims.iter().map(|&j| high[j]).collect())
            .map_err(|e| bad("low", e.to_string()))?;
        let particles = match (r.particles, cmaes) {
            (0, false) => 700,
            (0, true) => 4 + (3.0 * (free_dims.len() as f64).ln()).floor() as usize,
            (p, _) => p as usize,
        };
        let iterations = if r.iterations == 0 { 250 } else { r.iterations as usize };
        let cost = particles as u64 * iterations as u64;
        if cost > budget {
            return Err(bad(
                "particles x iterations",
                format!("{particles} x {iterations} = {cost} designs, above the server's budget of {budget}"),
            ));
        }
        Ok(Self { cmaes, particles, iterations, seed: r.seed, fixed, free })
    }

    /// The whole design of the free coordinates `x`.
    fn expand(&self, x: &[f32], out: &mut Vec<f32>) {
        let mut free = x.iter();
        out.clear();
        out.extend(self.fixed.iter().map(|f| f.unwrap_or_else(|| free.next().copied().unwrap_or(f32::NAN))));
    }

    /// Runs the search on this thread, sending progress to `tx`; a closed `tx` (the client
    /// cancelled) ends the search after the iteration under way.
    pub(crate) fn run(&self, m: &DesignModel, busy_share: f64, tx: &mpsc::Sender<Result<pb::OptimizeProgress, Status>>) {
        let mut cancelled = false;
        let mut ws = ObjectiveWorkspace::default();
        let (mut full, mut spread, mut one) = (Vec::new(), Vec::new(), Vec::new());
        let mut objective = |xs: &[f32], scores: &mut [f32]| {
            full.clear();
            for x in xs.chunks_exact(self.free.dim()) {
                self.expand(x, &mut one);
                full.extend_from_slice(&one);
            }
            spread.resize(scores.len(), 0.0);
            let t = std::time::Instant::now();
            m.score(&full, scores, &mut spread, &mut ws);
            // The busy share holds for searches too: rest in proportion after each batch.
            std::thread::sleep(crate::shared::rest_after(busy_share, t.elapsed()));
        };
        let mut best = Vec::new();
        let progress = |p: &coadapt_design_optimizer::swarm::Progress<'_>| {
            self.expand(p.best, &mut best);
            let msg = pb::OptimizeProgress {
                iteration: p.iteration as u32,
                evaluations: p.evaluations as u64,
                best: Some(pb::Design { values: best.clone() }),
                best_objective: p.best_score,
                done: false,
                best_spread: 0.0,
                weights_version: m.weights_version,
            };
            if tx.blocking_send(Ok(msg)).is_err() {
                cancelled = true;
                return ControlFlow::Break(());
            }
            ControlFlow::Continue(())
        };
        let result = if self.cmaes {
            let cfg = CmaesConfig { population: Some(self.particles), generations: self.iterations, ..CmaesConfig::default() };
            cmaes::maximise_with(&mut objective, &self.free, &cfg, self.seed, progress)
        } else {
            let cfg = PsoConfig { particles: self.particles, iterations: self.iterations, ..PsoConfig::default() };
            pso::maximise_with(&mut objective, &self.free, &cfg, self.seed, progress)
        };
        if cancelled {
            return;
        }
        let last = match result {
            Ok(r) => {
                let mut design = Vec::new();
                self.expand(&r.design, &mut design);
                let (mut mean, mut sd) = ([0.0], [0.0]);
                m.score(&design, &mut mean, &mut sd, &mut ws);
                Ok(pb::OptimizeProgress {
                    iteration: r.history.len().saturating_sub(1) as u32,
                    evaluations: r.evaluations as u64,
                    best: Some(pb::Design { values: design }),
                    best_objective: mean[0],
                    done: true,
                    best_spread: sd[0],
                    weights_version: m.weights_version,
                })
            }
            Err(e) => Err(Status::invalid_argument(format!("the search refused its settings: {e}"))),
        };
        let _ = tx.blocking_send(last);
    }
}

/// Starts `search` on the bounded pool; its progress arrives on the returned stream.
pub(crate) async fn start(
    shared: &Shared,
    m: Arc<DesignModel>,
    search: Search,
) -> Result<tokio_stream::wrappers::ReceiverStream<Result<pb::OptimizeProgress, Status>>, Status> {
    let permit = shared.permit().await?;
    let (tx, rx) = mpsc::channel(16);
    let share = shared.cfg.max_busy_share;
    tokio::task::spawn_blocking(move || {
        let _permit = permit;
        search.run(&m, share, &tx);
    });
    Ok(tokio_stream::wrappers::ReceiverStream::new(rx))
}
