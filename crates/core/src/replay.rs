//! Replay buffers of flat transitions.
//!
//! Storage grows with use up to the capacity (a 1e7-transition population buffer costs memory
//! only as it fills), then overwrites the oldest transitions. Sampling is uniform with
//! replacement, as the reference (rlkit) does.

use rand::Rng;

/// One transition, borrowed from the caller.
#[derive(Clone, Copy, Debug)]
pub struct Transition<'a> {
    pub obs: &'a [f32],
    pub action: &'a [f32],
    pub reward: f32,
    pub next_obs: &'a [f32],
    /// True only for a real terminal state (not a time-limit truncation).
    pub terminated: bool,
}

#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ReplayError {
    #[error("transition field `{field}` has {got} values, expected {expected}")]
    Dim { field: &'static str, expected: usize, got: usize },
    #[error("transition field `{field}` has a non-finite value at index {index}")]
    NonFinite { field: &'static str, index: usize },
    #[error("cannot sample from an empty replay buffer")]
    Empty,
}

/// Why arrays saved by [`ReplayBuffer::raw`] do not fit the buffer they are restored into.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ReplayRestoreError {
    #[error(
        "replay arrays of {transitions} transitions do not fit widths {obs_dim}/{act_dim} and capacity {capacity} (obs {obs}, act {act}, next_obs {next_obs}, done {done})"
    )]
    Shape {
        transitions: usize,
        obs_dim: usize,
        act_dim: usize,
        capacity: usize,
        /// Lengths of the arrays given.
        obs: usize,
        act: usize,
        next_obs: usize,
        done: usize,
    },
    #[error("replay write position {next} does not fit {transitions} transitions and capacity {capacity}")]
    Position { next: usize, transitions: usize, capacity: usize },
    /// The first non-finite value, counted within its array.
    #[error("replay arrays hold a non-finite value (at {index})")]
    NonFinite { index: usize },
}

/// A ring buffer of transitions with fixed observation and action widths.
#[derive(Clone, Debug)]
pub struct ReplayBuffer {
    obs_dim: usize,
    act_dim: usize,
    capacity: usize,
    next: usize,
    obs: Vec<f32>,
    act: Vec<f32>,
    rew: Vec<f32>,
    next_obs: Vec<f32>,
    done: Vec<f32>,
}

/// A sampled batch, row-major, reused across updates.
#[derive(Clone, Debug, Default)]
pub struct Batch {
    pub rows: usize,
    pub obs: Vec<f32>,
    pub act: Vec<f32>,
    pub rew: Vec<f32>,
    pub next_obs: Vec<f32>,
    /// 1.0 where the transition ended in a terminal state.
    pub done: Vec<f32>,
}

impl Batch {
    pub fn new(rows: usize, obs_dim: usize, act_dim: usize) -> Self {
        Self {
            rows,
            obs: vec![0.0; rows * obs_dim],
            act: vec![0.0; rows * act_dim],
            rew: vec![0.0; rows],
            next_obs: vec![0.0; rows * obs_dim],
            done: vec![0.0; rows],
        }
    }
}

impl ReplayBuffer {
    pub fn new(obs_dim: usize, act_dim: usize, capacity: usize) -> Self {
        assert!(capacity > 0, "replay capacity must be positive");
        Self { obs_dim, act_dim, capacity, next: 0, obs: vec![], act: vec![], rew: vec![], next_obs: vec![], done: vec![] }
    }

    pub fn len(&self) -> usize {
        self.rew.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rew.is_empty()
    }

    pub fn capacity(&self) -> usize {
        self.capacity
    }

    pub fn obs_dim(&self) -> usize {
        self.obs_dim
    }

    pub fn act_dim(&self) -> usize {
        self.act_dim
    }

    /// Forgets every transition (FEAR empties the species buffer at each new design).
    pub fn clear(&mut self) {
        for v in [&mut self.obs, &mut self.act, &mut self.rew, &mut self.next_obs, &mut self.done] {
            v.clear();
        }
        self.next = 0;
    }

    /// Validates and stores `t`; nothing malformed or non-finite gets in.
    pub fn push(&mut self, t: &Transition<'_>) -> Result<(), ReplayError> {
        check("obs", t.obs, self.obs_dim)?;
        check("action", t.action, self.act_dim)?;
        check("reward", &[t.reward], 1)?;
        check("next_obs", t.next_obs, self.obs_dim)?;
        let done = if t.terminated { 1.0 } else { 0.0 };
        if self.len() < self.capacity {
            self.obs.extend_from_slice(t.obs);
            self.act.extend_from_slice(t.action);
            self.rew.push(t.reward);
            self.next_obs.extend_from_slice(t.next_obs);
            self.done.push(done);
        } else {
            let i = self.next;
            self.obs[i * self.obs_dim..(i + 1) * self.obs_dim].copy_from_slice(t.obs);
            self.act[i * self.act_dim..(i + 1) * self.act_dim].copy_from_slice(t.action);
            self.rew[i] = t.reward;
            self.next_obs[i * self.obs_dim..(i + 1) * self.obs_dim].copy_from_slice(t.next_obs);
            self.done[i] = done;
        }
        self.next = (self.next + 1) % self.capacity;
        Ok(())
    }

    /// Removes the `k` newest transitions (an episode that failed half-way must leave nothing
    /// behind). A buffer that had wrapped keeps its other transitions, moved into the freed
    /// slots: uniform sampling does not care about order, only eviction order changes a little.
    pub fn pop_newest(&mut self, k: usize) {
        let (cap, k) = (self.capacity, k.min(self.len()));
        let mut slots: Vec<usize> = (0..k).map(|i| (self.next + cap * 2 - 1 - i) % cap).collect();
        // Highest slot first: the row moved into a freed slot is never one still to remove.
        slots.sort_unstable_by(|a, b| b.cmp(a));
        let (o, a) = (self.obs_dim, self.act_dim);
        for s in slots {
            let last = self.len() - 1;
            if s != last {
                self.obs.copy_within(last * o..(last + 1) * o, s * o);
                self.act.copy_within(last * a..(last + 1) * a, s * a);
                self.rew[s] = self.rew[last];
                self.next_obs.copy_within(last * o..(last + 1) * o, s * o);
                self.done[s] = self.done[last];
            }
            self.obs.truncate(last * o);
            self.act.truncate(last * a);
            self.rew.truncate(last);
            self.next_obs.truncate(last * o);
            self.done.truncate(last);
        }
        // Not full any more: the next push appends.
        self.next = self.len() % cap;
    }

    /// The stored arrays (`obs`, `act`, `rew`, `next_obs`, `done`) and the next slot to write,
    /// for a snapshot of the run.
    pub fn raw(&self) -> ([&[f32]; 5], usize) {
        ([&self.obs, &self.act, &self.rew, &self.next_obs, &self.done], self.next)
    }

    /// Restores arrays saved by [`Self::raw`] from a buffer of the same widths and capacity.
    pub fn restore_raw(&mut self, [obs, act, rew, next_obs, done]: [Vec<f32>; 5], next: usize) -> Result<(), ReplayRestoreError> {
        let n = rew.len();
        let (o, a) = (self.obs_dim, self.act_dim);
        if n > self.capacity || obs.len() != n * o || act.len() != n * a || next_obs.len() != n * o || done.len() != n {
            return Err(ReplayRestoreError::Shape {
                transitions: n,
                obs_dim: o,
                act_dim: a,
                capacity: self.capacity,
                obs: obs.len(),
                act: act.len(),
                next_obs: next_obs.len(),
                done: done.len(),
            });
        }
        if next >= self.capacity || (n < self.capacity && next != n % self.capacity) {
            return Err(ReplayRestoreError::Position { next, transitions: n, capacity: self.capacity });
        }
        if let Some(index) = [&obs, &act, &rew, &next_obs, &done].iter().find_map(|v| v.iter().position(|x| !x.is_finite())) {
            return Err(ReplayRestoreError::NonFinite { index });
        }
        (self.obs, self.act, self.rew, self.next_obs, self.done, self.next) = (obs, act, rew, next_obs, done, next);
        Ok(())
    }

    /// Transition `i` (0 is the oldest still stored when not yet wrapped).
    pub fn get(&self, i: usize) -> Transition<'_> {
        let (o, a) = (self.obs_dim, self.act_dim);
        Transition {
            obs: &self.obs[i * o..(i + 1) * o],
            action: &self.act[i * a..(i + 1) * a],
            reward: self.rew[i],
            next_obs: &self.next_obs[i * o..(i + 1) * o],
            terminated: self.done[i] != 0.0,
        }
    }

    /// Fills `batch` with `batch.rows` transitions drawn uniformly with replacement.
    pub fn sample<R: Rng + ?Sized>(&self, rng: &mut R, batch: &mut Batch) -> Result<(), ReplayError> {
        Self::sample_mixed(&[(self, batch.rows)], rng, batch)
    }

    /// Fills `batch` with `n_k` transitions from each buffer `k` of `parts`, in order (e.g.
    /// `[(population, 26), (species, 230)]`). The counts must add up to `batch.rows`.
    pub fn sample_mixed<R: Rng + ?Sized>(parts: &[(&ReplayBuffer, usize)], rng: &mut R, batch: &mut Batch) -> Result<(), ReplayError> {
        let total: usize = parts.iter().map(|p| p.1).sum();
        assert_eq!(total, batch.rows, "mixed batch counts must add up to the batch size");
        let mut row = 0;
        for (buf, n) in parts {
            if *n == 0 {
                continue;
            }
            if buf.is_empty() {
                return Err(ReplayError::Empty);
            }
            let (o, a) = (buf.obs_dim, buf.act_dim);
            for _ in 0..*n {
                let i = rng.random_range(0..buf.len());
                batch.obs[row * o..(row + 1) * o].copy_from_slice(&buf.obs[i * o..(i + 1) * o]);
                batch.act[row * a..(row + 1) * a].copy_from_slice(&buf.act[i * a..(i + 1) * a]);
                batch.rew[row] = buf.rew[i];
                batch.next_obs[row * o..(row + 1) * o].copy_from_slice(&buf.next_obs[i * o..(i + 1) * o]);
                batch.done[row] = buf.done[i];
                row += 1;
            }
        }
        Ok(())
    }
}

fn check(field: &'static str, v: &[f32], expected: usize) -> Result<(), ReplayError> {
    if v.len() != expected {
        return Err(ReplayError::Dim { field, expected, got: v.len() });
    }
    match v.iter().position(|x| !x.is_finite()) {
        Some(index) => Err(ReplayError::NonFinite { field, index }),
        None => Ok(()),
    }
}
