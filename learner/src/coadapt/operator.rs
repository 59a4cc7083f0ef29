//! The learner's waits for an operator, through the files of [`crate::prototype`]: a design's
//! prototype (`schedule.confirm-designs`: confirmed, built with other dimensions, or rejected,
//! when the optimiser is asked again) and a reset by hand before an episode
//! (`schedule.reset-needs-confirmation`).
//!
//! A wait is not a wait on the fleet: no silence limit applies (the actors have nothing to do
//! and say nothing), and outstanding episodes' leases start again afterwards. It polls for the
//! decision every `confirm-poll-secs`, returns at once on shutdown (the run ends interrupted),
//! and meanwhile makes `train-while-waiting` population updates per second on the population
//! buffer, so hours at the workbench still improve the critic the next design is chosen over.

use std::sync::atomic::Ordering;
use std::time::Instant;

use coadapt_transport::DesignKind;

use super::driver::{Learner, POLL};
use super::{CoadaptError, RunEvent};
use crate::prototype::{
    self, Outcome, PROTOTYPE_DECISION_FILE, PROTOTYPE_FILE, Prototype, RESET_DECISION_FILE, RESET_FILE, ResetDecision, ResetMode,
    ResetRequest, Status,
};
use crate::run_dir::{DesignRow, PROTOTYPE_AWAITING, PROTOTYPE_CONFIRMED, PROTOTYPE_REJECTED, RunWriter, prototype_as_built};

impl Learner<'_> {
    /// Calls `take` every `confirm-poll-secs` until it yields, training the population networks
    /// in between if configured; `None` on shutdown.
    fn wait_for<T>(&mut self, mut take: impl FnMut() -> Result<Option<T>, CoadaptError>) -> Result<Option<T>, CoadaptError> {
        let poll = self.cfg.poll_interval()?;
        let rate = self.cfg.train_while_waiting as f64;
        // At most one poll interval's updates at a time, so the decision is still read promptly
        // when updates are slower than asked for (the rate is then a ceiling).
        let most = (rate * poll.as_secs_f64()).ceil().max(1.0) as u64;
        let start = Instant::now();
        let mut owed_done = 0u64;
        loop {
            if self.shutdown.load(Ordering::Relaxed) {
                return Ok(None);
            }
            if let Some(t) = take()? {
                return Ok(Some(t));
            }
            let tick = Instant::now();
            if rate > 0.0 {
                let due = (rate * start.elapsed().as_secs_f64()) as u64;
                let batch = due.saturating_sub(owed_done).min(most);
                if batch > 0 {
                    let t = Instant::now();
                    let made = self.fear.train_population(batch as usize)? as u64;
                    self.time.training += t.elapsed().as_secs_f64();
                    // Counted even when the buffer is empty: no debt piles up.
                    owed_done += batch;
                    self.time.updates_while_waiting += made;
                    // The population policy may be the acting one.
                    self.acting_dirty |= made > 0;
                }
            }
            let wake = tick + poll;
            while !self.shutdown.load(Ordering::Relaxed) {
                let now = Instant::now();
                if now >= wake {
                    break;
                }
                std::thread::sleep(POLL.min(wake - now));
            }
        }
    }

    /// Design `index`: the fixed initial one or the optimiser's proposal and, with
    /// `confirm-designs`, the operator's verdict on its prototype: confirmed, built with the
    /// measured dimensions (which replace the requested ones), or rejected (the optimiser is
    /// asked again, told every rejected design so far). `None`: interrupted.
    pub(super) fn choose_design(
        &mut self,
        index: usize,
        chosen: &[f32],
        out: &mut RunWriter,
        on_event: &mut dyn FnMut(&RunEvent<'_>),
    ) -> Result<Option<DesignRow>, CoadaptError> {
        let mut proposal = 0;
        loop {
            proposal += 1;
            let mut row = match self.cfg.kind_of(index) {
                None => DesignRow {
                    index,
                    kind: "initial".into(),
                    design: self.cfg.initial_designs[index].clone(),
                    episodes: 0,
                    best_eval_return: None,
                    last_eval_return: None,
                    predicted_objective: None,
                    design_rollouts: 0,
                    method: "fixed".into(),
                    prototype: String::new(),
                },
                Some(kind) => {
                    let Some(reply) = self.request_design(index, kind, chosen)? else { return Ok(None) };
                    DesignRow {
                        index,
                        kind: if kind == DesignKind::Exploit { "exploit" } else { "explore" }.into(),
                        design: reply.design,
                        episodes: 0,
                        best_eval_return: None,
                        last_eval_return: None,
                        predicted_objective: reply.predicted_objective,
                        design_rollouts: reply.design_rollouts,
                        method: reply.method,
                        prototype: String::new(),
                    }
                }
            };
            if !self.cfg.confirm_designs {
                return Ok(Some(row));
            }
            let Some(outcome) = self.await_prototype(&mut row, proposal, out, on_event)? else { return Ok(None) };
            if outcome != Outcome::Rejected {
                return Ok(Some(row));
            }
            self.rejected.push(row);
        }
    }

    /// Shows `row` as awaiting its prototype (`designs.csv`, `prototype.json`, an event),
    /// waits for the operator and records the verdict in all three; `row` leaves with its
    /// `prototype` column set and, built as measured, the measured design.
    fn await_prototype(
        &mut self,
        row: &mut DesignRow,
        proposal: usize,
        out: &mut RunWriter,
        on_event: &mut dyn FnMut(&RunEvent<'_>),
    ) -> Result<Option<Outcome>, CoadaptError> {
        row.prototype = PROTOTYPE_AWAITING.into();
        out.design(row)?;
        let mut p = Prototype {
            index: row.index,
            proposal,
            kind: row.kind.clone(),
            method: row.method.clone(),
            design: row.design.clone(),
            dimensions: prototype::named_dimensions(&self.spec.design_names, &row.design),
            low: self.spec.design.low.clone(),
            high: self.spec.design.high.clone(),
            status: Status::Awaiting,
            waiting_since_unix: prototype::unix_now(),
            as_built: None,
        };
        let path = self.dir.join(PROTOTYPE_FILE);
        prototype::write_json(&path, &p)?;
        on_event(&RunEvent::AwaitingPrototype { index: row.index, row, names: &self.spec.design_names });
        let t = Instant::now();
        let dir = self.dir;
        let got = self.wait_for(|| {
            Ok(match prototype::take_decision(dir, PROTOTYPE_DECISION_FILE)? {
                None => None,
                Some(d) => match d.and_then(|d| prototype::accept(&p, &d)) {
                    Ok(o) => Some(o),
                    Err(why) => {
                        coadapt_log::logln!("learner: ignored {PROTOTYPE_DECISION_FILE}: {why}");
                        None
                    }
                },
            })
        });
        self.time.waiting_for_prototype += t.elapsed().as_secs_f64();
        let Some(outcome) = got? else {
            p.status = Status::Interrupted;
            prototype::write_json(&path, &p)?;
            return Ok(None);
        };
        let requested = row.design.clone();
        match &outcome {
            Outcome::Confirmed => {
                p.status = Status::Confirmed;
                row.prototype = PROTOTYPE_CONFIRMED.into();
            }
            Outcome::AsBuilt(v) => {
                p.status = Status::AsBuilt;
                p.as_built = Some(v.clone());
                row.prototype = prototype_as_built(&requested);
                row.design.clone_from(v);
            }
            Outcome::Rejected => {
                p.status = Status::Rejected;
                row.prototype = PROTOTYPE_REJECTED.into();
            }
        }
        prototype::write_json(&path, &p)?;
        out.design(row)?;
        on_event(&RunEvent::PrototypeDecided { row, outcome: &outcome, requested: &requested });
        Ok(Some(outcome))
    }

    /// With `reset-needs-confirmation`, waits for the operator to reset the robot before an
    /// episode (`reset.json`, an event); `false`: interrupted.
    pub(super) fn reset_before(
        &mut self,
        design_index: usize,
        episode: usize,
        episodes_in_design: usize,
        mode: ResetMode,
        on_event: &mut dyn FnMut(&RunEvent<'_>),
    ) -> Result<bool, CoadaptError> {
        if !self.cfg.reset_needs_confirmation {
            return Ok(true);
        }
        let mut r = ResetRequest { design_index, episode, mode, status: Status::Awaiting, waiting_since_unix: prototype::unix_now() };
        let path = self.dir.join(RESET_FILE);
        prototype::write_json(&path, &r)?;
        on_event(&RunEvent::AwaitingReset { design_index, episode, episodes_in_design, mode });
        let t = Instant::now();
        let dir = self.dir;
        let got = self.wait_for(|| {
            Ok(match prototype::take_decision::<ResetDecision>(dir, RESET_DECISION_FILE)? {
                None => None,
                Some(d) => match d.and_then(|d| prototype::accept_reset(&r, &d)) {
                    Ok(()) => Some(()),
                    Err(why) => {
                        coadapt_log::logln!("learner: ignored {RESET_DECISION_FILE}: {why}");
                        None
                    }
                },
            })
        });
        self.time.waiting_for_reset += t.elapsed().as_secs_f64();
        // Episodes already out (async flow) kept their actors busy, not silent: their leases
        // start again.
        self.fleet.renew_leases();
        let confirmed = got?.is_some();
        r.status = if confirmed { Status::Confirmed } else { Status::Interrupted };
        prototype::write_json(&path, &r)?;
        if confirmed {
            on_event(&RunEvent::ResetConfirmed { design_index, episode, mode });
        }
        Ok(confirmed)
    }
}
