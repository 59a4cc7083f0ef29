//! The design objective over the critic, batched over particles x start states.
//!
//! Rows are (particle, start state) pairs. Each core takes a contiguous share of the particles
//! and pushes them through actor and critic in chunks of whole particles small enough to stay in
//! cache, with its own preallocated workspace: no allocation and no synchronisation inside a
//! pass. Single-threaded products of this size run near a core's peak, so splitting rows across
//! cores beats threading inside each product.

use coadapt_nn::{Activations, Mlp};
use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};

/// Which critic value scores a design.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum QMode {
    /// Q1 alone (the reference).
    First,
    /// min(Q1, Q2), as the SAC targets use.
    MinOfTwin,
    /// Pessimism where the critics disagree: per row, the critics' mean minus `k` times their
    /// standard deviation (over the heads, population form), for the twin `(Q1 + Q2)/2 - k
    /// |Q1 - Q2|/2` (`k = 1` is `MinOfTwin`), and over every head given when there are more
    /// (an ensemble lower confidence bound). The heads are trained on the same data from
    /// different initialisations, so they agree where data constrain them and drift apart
    /// where the critic extrapolates: far from the designs tried, where Q1 alone overestimates.
    MeanMinusKStd(f32),
    /// The mean of the critics beyond the twin (the third on): ensemble heads that regress on
    /// the twin's target and, with the learner's conservative term on, critics trained to be
    /// low where their own ascent over designs goes (a design critic that acts on nothing).
    Heads,
}

impl QMode {
    /// Which of `n` loaded critics the mode reads.
    fn critics(self, n: usize) -> std::ops::Range<usize> {
        match self {
            QMode::First => 0..1.min(n),
            QMode::MinOfTwin => 0..2.min(n),
            QMode::MeanMinusKStd(_) => 0..n,
            QMode::Heads => 2.min(n)..n,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ObjectiveError {
    #[error("{what}: {why}")]
    Shape { what: &'static str, why: String },
}

/// Eq. 5.6 for a fixed policy, critic(s) and start-state batch.
///
/// The first layer of both networks is affine in its input, and a row's input is
/// `[state s, design xi]` (plus the action for the critic), so its pre-activation splits into a
/// part per start state, a part per design and (for the critic) a part per action:
/// `W [s, xi, a] + b = (W_s s + b) + W_xi xi + W_a a`. The first two are computed once per state
/// and once per particle instead of once per row; only the deeper layers and `W_a a` run per
/// row. The result is the same function, for about 9 % less work.
#[derive(Clone, Debug)]
pub struct DesignObjective {
    actor: Split,
    /// The policy after its first layer, restricted to the mean head: `hidden -> act`.
    actor_tail: Mlp,
    actor_tail_params: Vec<f32>,
    critics: Vec<Split>,
    critic_tail: Mlp,
    critic_tail_params: Vec<Vec<f32>>,
    n_states: usize,
    act_dim: usize,
    design_dim: usize,
    model_flops_per_row: usize,
}

/// A first layer split into its per-state, per-design and per-action parts.
#[derive(Clone, Debug)]
struct Split {
    width: usize,
    /// `W_s s + b` for every start state (`n_states x width`).
    per_state: Vec<f32>,
    /// `W_xi` (`width x design_dim`, row-major).
    w_design: Vec<f32>,
    /// `W_a^T` (`act_dim x width`, row-major; empty for the actor).
    w_action_t: Vec<f32>,
}

impl Split {
    /// Splits layer 0 of `mlp` (parameters `p`), whose input is `[obs, extra]` with the design
    /// at `design_at..design_at + design_dim` of `obs`, and `extra` the action (critic) or
    /// nothing (actor).
    fn new(mlp: &Mlp, p: &[f32], start_states: &[f32], obs_dim: usize, design_at: usize, design_dim: usize) -> Self {
        let l = mlp.layers()[0];
        let w = &p[l.w..l.b];
        let design = design_at..design_at + design_dim;
        let mut per_state = Vec::with_capacity(start_states.len() / obs_dim * l.n_out);
        for s in start_states.chunks_exact(obs_dim) {
            for (o, row) in w.chunks_exact(l.n_in).enumerate() {
                let mut v = p[l.b + o];
                for (j, (wj, sj)) in row[..obs_dim].iter().zip(s).enumerate() {
                    if !design.contains(&j) {
                        v += wj * sj;
                    }
                }
                per_state.push(v);
            }
        }
        let w_design = w.chunks_exact(l.n_in).flat_map(|row| row[design.clone()].to_vec()).collect();
        let extra = l.n_in - obs_dim;
        let w_action_t = (0..extra).flat_map(|j| w.chunks_exact(l.n_in).map(move |row| row[obs_dim + j])).collect();
        Self { width: l.n_out, per_state, w_design, w_action_t }
    }

    /// `W_xi xi` for one design into `out` (`width`).
    fn design_part(&self, xi: &[f32], out: &mut [f32]) {
        for (o, row) in out.iter_mut().zip(self.w_design.chunks_exact(xi.len())) {
            *o = row.iter().zip(xi).map(|(a, b)| a * b).sum();
        }
    }
}

fn tail(mlp: &Mlp, p: &[f32], out_rows: Option<usize>) -> Result<(Mlp, Vec<f32>), ObjectiveError> {
    let mut sizes = mlp.sizes()[1..].to_vec();
    if let Some(n) = out_rows {
        *sizes.last_mut().expect("a tail has layers") = n;
    }
    // The tail computes as the network it comes from (f32 or bf16 products).
    let t = Mlp::new(&sizes).map_err(|e| ObjectiveError::Shape { what: "network", why: e.to_string() })?.with_precision(mlp.precision());
    let last = mlp.layers().len() - 1;
    let mut params = Vec::with_capacity(t.n_params());
    for (i, l) in mlp.layers().iter().enumerate().skip(1) {
        let out = if i == last { out_rows.unwrap_or(l.n_out) } else { l.n_out };
        params.extend_from_slice(&p[l.w..l.w + out * l.n_in]);
        params.extend_from_slice(&p[l.b..l.b + out]);
    }
    Ok((t, params))
}

/// One core's scratch.
#[derive(Clone, Debug, Default)]
pub struct ObjectiveWorkspace {
    h_actor: Vec<f32>,
    h_critic: Vec<f32>,
    actions: Vec<f32>,
    design_part: Vec<f32>,
    q: Vec<f32>,
    /// Welford's sum of squared deviations per row, over more than two heads.
    q_m2: Vec<f32>,
    act_pi: Activations,
    act_q: Activations,
}

impl DesignObjective {
    /// `policy` outputs `[mean, log_std]` (the SAC head); `thetas` holds one critic (Q1), two
    /// (Q1, Q2) or the twin and ensemble heads. `start_states` is `n_states x obs_dim`; the design occupies the observation
    /// columns `design_at..design_at + design_dim`. Both networks need a hidden layer.
    pub fn new(
        policy: &Mlp,
        phi: &[f32],
        critic: &Mlp,
        thetas: &[&[f32]],
        start_states: &[f32],
        design_at: usize,
        design_dim: usize,
    ) -> Result<Self, ObjectiveError> {
        let shape = |what, why: String| Err(ObjectiveError::Shape { what, why });
        let obs_dim = policy.n_in();
        if !policy.n_out().is_multiple_of(2) {
            return shape("policy", format!("output width {} is not [mean, log_std]", policy.n_out()));
        }
        let act_dim = policy.n_out() / 2;
        if critic.n_in() != obs_dim + act_dim || critic.n_out() != 1 {
            return shape("critic", format!("sizes {:?} do not take [obs {obs_dim}, act {act_dim}] to 1", critic.sizes()));
        }
        if policy.layers().len() < 2 || critic.layers().len() < 2 {
            return shape("networks", "policy and critic need at least one hidden layer".into());
        }
        if thetas.is_empty() || thetas.iter().any(|t| t.len() != critic.n_params()) {
            return shape("critic parameters", "need one or more parameter vectors of the critic's size".into());
        }
        if phi.len() != policy.n_params() {
            return shape("policy parameters", format!("{} values, expected {}", phi.len(), policy.n_params()));
        }
        if start_states.is_empty() || !start_states.len().is_multiple_of(obs_dim) {
            return shape("start states", format!("{} values is not a positive multiple of obs {obs_dim}", start_states.len()));
        }
        if design_at + design_dim > obs_dim {
            return shape("design columns", format!("{design_at}..{} beyond obs {obs_dim}", design_at + design_dim));
        }
        // The log-std head does not enter Eq. 5.6: keep only the mean rows of the last layer.
        let (actor_tail, actor_tail_params) = tail(policy, phi, Some(act_dim))?;
        let (critic_tail, _) = tail(critic, thetas[0], None)?;
        let critic_tail_params = thetas.iter().map(|t| tail(critic, t, None).map(|t| t.1)).collect::<Result<_, _>>()?;
        let mean_macs = policy.macs_per_row() - policy.layers().last().map_or(0, |l| act_dim * l.n_in);
        Ok(Self {
            actor: Split::new(policy, phi, start_states, obs_dim, design_at, design_dim),
            critics: thetas.iter().map(|t| Split::new(critic, t, start_states, obs_dim, design_at, design_dim)).collect(),
            actor_tail,
            actor_tail_params,
            critic_tail,
            critic_tail_params,
            n_states: start_states.len() / obs_dim,
            act_dim,
            design_dim,
            model_flops_per_row: 2 * (mean_macs + critic.macs_per_row()),
        })
    }

    pub fn n_states(&self) -> usize {
        self.n_states
    }

    pub fn design_dim(&self) -> usize {
        self.design_dim
    }

    /// Floating-point operations of one row through the actor's mean head and one critic, as a
    /// plain forward pass computes them (the split first layers do less).
    pub fn flops_per_row(&self) -> usize {
        self.model_flops_per_row
    }

    /// Scores `designs` (`particles x design_dim`) into `out` (`particles`), splitting the
    /// particles across `workspaces.len()` cores, in chunks of about `chunk_rows` rows.
    pub fn evaluate(&self, designs: &[f32], mode: QMode, chunk_rows: usize, out: &mut [f32], workspaces: &mut [ObjectiveWorkspace]) {
        let p = out.len();
        assert_eq!(designs.len(), p * self.design_dim, "designs are not particles x design_dim");
        assert!(!workspaces.is_empty(), "need at least one workspace");
        let per_core = p.div_ceil(workspaces.len()).max(1);
        let per_chunk = (chunk_rows / self.n_states).max(1);
        rayon::scope(|s| {
            for ((out, designs), ws) in out.chunks_mut(per_core).zip(designs.chunks(per_core * self.design_dim)).zip(workspaces.iter_mut())
            {
                s.spawn(move |_| {
                    for (o, d) in out.chunks_mut(per_chunk).zip(designs.chunks(per_chunk * self.design_dim)) {
                        self.evaluate_chunk(d, mode, o, ws);
                    }
                });
            }
        });
    }

    /// `h = relu(per_state[s] + W_xi xi_k (+ extra row))` for every (particle k, state s) row.
    fn first_layer(&self, split: &Split, designs: &[f32], h: &mut [f32], design_part: &mut Vec<f32>, add_existing: bool) {
        let width = split.width;
        design_part.resize(width, 0.0);
        let rows_per = self.n_states * width;
        for (xi, block) in designs.chunks_exact(self.design_dim).zip(h.chunks_exact_mut(rows_per)) {
            split.design_part(xi, design_part);
            for (row, st) in block.chunks_exact_mut(width).zip(split.per_state.chunks_exact(width)) {
                for ((v, a), b) in row.iter_mut().zip(st).zip(design_part.iter()) {
                    let pre = a + b + if add_existing { *v } else { 0.0 };
                    *v = pre.max(0.0);
                }
            }
        }
    }

    fn evaluate_chunk(&self, designs: &[f32], mode: QMode, out: &mut [f32], ws: &mut ObjectiveWorkspace) {
        let n = self.n_states;
        self.rows(designs, mode, out.len(), ws);
        for (o, qs) in out.iter_mut().zip(ws.q.chunks_exact(n)) {
            *o = qs.iter().sum::<f32>() / n as f32;
        }
    }

    /// Scores `designs` (`particles x design_dim`) on this thread: the objective into `mean`
    /// and its standard deviation over the start states into `spread` (both `particles`), in
    /// chunks of about `chunk_rows` rows.
    pub fn evaluate_with_spread(
        &self,
        designs: &[f32],
        mode: QMode,
        chunk_rows: usize,
        mean: &mut [f32],
        spread: &mut [f32],
        ws: &mut ObjectiveWorkspace,
    ) {
        let (p, n) = (mean.len(), self.n_states);
        assert_eq!(designs.len(), p * self.design_dim, "designs are not particles x design_dim");
        assert_eq!(spread.len(), p, "spread is not one per particle");
        let per_chunk = (chunk_rows / n).max(1);
        for ((m, s), d) in mean.chunks_mut(per_chunk).zip(spread.chunks_mut(per_chunk)).zip(designs.chunks(per_chunk * self.design_dim)) {
            self.rows(d, mode, m.len(), ws);
            for ((m, s), qs) in m.iter_mut().zip(s.iter_mut()).zip(ws.q.chunks_exact(n)) {
                let mu = qs.iter().map(|&v| f64::from(v)).sum::<f64>() / n as f64;
                let var = qs.iter().map(|&v| (f64::from(v) - mu).powi(2)).sum::<f64>() / n as f64;
                *m = mu as f32;
                *s = var.sqrt() as f32;
            }
        }
    }

    /// Critic heads loaded (1: Q1 alone; 2: the twin critics).
    pub fn heads(&self) -> usize {
        self.critics.len()
    }

    /// Whether `mode` has critics to read here: [`QMode::Heads`] needs a critic beyond the twin
    /// (scoring with none would score every design NaN).
    pub fn check_mode(&self, mode: QMode) -> Result<(), ObjectiveError> {
        if mode.critics(self.critics.len()).is_empty() {
            return Err(ObjectiveError::Shape {
                what: "critic parameters",
                why: format!(
                    "the objective reads the critics beyond the twin (optimizer.q = \"heads\") and the learner sent {} critics, none beyond \
                     the twin (learner.population-critics = 2)",
                    self.critics.len()
                ),
            });
        }
        Ok(())
    }

    /// How far the critics disagree about each design: per design the mean over the start
    /// states of their standard deviation over the heads (population form: for the twin
    /// `|Q1 - Q2| / 2`, the two heads are that far either side of their mean), into `out`
    /// (`particles`), on this thread. `false` (and `out` untouched) with one head.
    pub fn disagreement(&self, designs: &[f32], chunk_rows: usize, out: &mut [f32], ws: &mut ObjectiveWorkspace) -> bool {
        if self.critics.len() < 2 {
            return false;
        }
        let (p, n) = (out.len(), self.n_states);
        assert_eq!(designs.len(), p * self.design_dim, "designs are not particles x design_dim");
        let per_chunk = (chunk_rows / n).max(1);
        let mut mean_rows = Vec::new();
        for (o, d) in out.chunks_mut(per_chunk).zip(designs.chunks(per_chunk * self.design_dim)) {
            // Per row: the mean with k = 0, and the mean minus one sd with k = 1.
            self.rows(d, QMode::MeanMinusKStd(0.0), o.len(), ws);
            mean_rows.clear();
            mean_rows.extend_from_slice(&ws.q);
            self.rows(d, QMode::MeanMinusKStd(1.0), o.len(), ws);
            for ((o, m), low) in o.iter_mut().zip(mean_rows.chunks_exact(n)).zip(ws.q.chunks_exact(n)) {
                *o = m.iter().zip(low).map(|(m, l)| f64::from(m - l)).sum::<f64>() as f32 / n as f32;
            }
        }
        true
    }

    /// The value of every (particle, start state) row into `ws.q` (`particles x n_states`).
    fn rows(&self, designs: &[f32], mode: QMode, particles: usize, ws: &mut ObjectiveWorkspace) {
        let (n, act) = (self.n_states, self.act_dim);
        let rows = particles * n;
        let ObjectiveWorkspace { h_actor, h_critic, actions, design_part, q, q_m2, act_pi, act_q } = ws;
        h_actor.resize(rows * self.actor.width, 0.0);
        self.first_layer(&self.actor, designs, h_actor, design_part, false);
        let mean = self.actor_tail.forward(&self.actor_tail_params, h_actor, rows, act_pi);
        actions.resize(rows * act, 0.0);
        for (a, m) in actions.iter_mut().zip(mean) {
            *a = m.tanh();
        }
        q.resize(rows, 0.0);
        let read = mode.critics(self.critics.len());
        if read.is_empty() {
            // `check_mode` refuses this before a search; never a silent score.
            q.fill(f32::NAN);
            return;
        }
        let n_critics = read.len();
        // Over more than two heads (and for the heads' mean), `q` holds the running mean and
        // `q_m2` Welford's sum of squared deviations (a two-pass-free sd that keeps its digits
        // when Q is large); the twin keeps its closed form, so its scores are the ones archived
        // runs made.
        let ensemble = (matches!(mode, QMode::MeanMinusKStd(_)) && n_critics > 2) || mode == QMode::Heads;
        if ensemble {
            q_m2.clear();
            q_m2.resize(rows, 0.0);
        }
        for (i, (split, params)) in self.critics[read.clone()].iter().zip(&self.critic_tail_params[read]).enumerate() {
            h_critic.resize(rows * split.width, 0.0);
            // W_a a for every row, then the per-state and per-design parts on top.
            matmul(
                MatMut::from_row_major_slice_mut(h_critic, rows, split.width),
                Accum::Replace,
                MatRef::from_row_major_slice(actions, rows, act),
                MatRef::from_row_major_slice(&split.w_action_t, act, split.width),
                1.0f32,
                Par::Seq,
            );
            self.first_layer(split, designs, h_critic, design_part, true);
            let qi = self.critic_tail.forward(params, h_critic, rows, act_q);
            match (i, mode) {
                (0, _) => q.copy_from_slice(qi),
                (_, QMode::MeanMinusKStd(_) | QMode::Heads) if ensemble => {
                    let c = (i + 1) as f32;
                    for ((m, m2), x) in q.iter_mut().zip(q_m2.iter_mut()).zip(qi) {
                        let delta = x - *m;
                        *m += delta / c;
                        *m2 += delta * (x - *m);
                    }
                }
                (_, QMode::MeanMinusKStd(k)) => {
                    for (a, b) in q.iter_mut().zip(qi) {
                        *a = 0.5 * (*a + b) - k * 0.5 * (*a - b).abs();
                    }
                }
                _ => {
                    for (a, b) in q.iter_mut().zip(qi) {
                        *a = a.min(*b);
                    }
                }
            }
        }
        if let (true, QMode::MeanMinusKStd(k)) = (ensemble, mode) {
            let c = n_critics as f32;
            for (m, m2) in q.iter_mut().zip(q_m2.iter()) {
                *m -= k * (m2.max(0.0) / c).sqrt();
            }
        }
    }
}

/// [`DesignObjective`] as a [`SwarmObjective`](crate::SwarmObjective): a search scores each
/// iteration's whole swarm in one batched pass over `workspaces.len()` cores.
#[derive(Debug)]
pub struct CriticObjective<'a> {
    pub objective: &'a DesignObjective,
    pub mode: QMode,
    /// Rows (particle x start state) per chunk; 256 (8 particles x 32 states) keeps a chunk's
    /// activations in L2 (BENCHMARKS.md).
    pub chunk_rows: usize,
    /// One per core.
    pub workspaces: Vec<ObjectiveWorkspace>,
}

impl<'a> CriticObjective<'a> {
    /// Scores with `mode` on `cores` cores (at least one), in chunks of 256 rows.
    pub fn new(objective: &'a DesignObjective, mode: QMode, cores: usize) -> Self {
        Self { objective, mode, chunk_rows: 256, workspaces: vec![ObjectiveWorkspace::default(); cores.max(1)] }
    }
}

impl crate::SwarmObjective for CriticObjective<'_> {
    fn evaluate(&mut self, designs: &[f32], scores: &mut [f32]) {
        self.objective.evaluate(designs, self.mode, self.chunk_rows, scores, &mut self.workspaces);
    }
}
