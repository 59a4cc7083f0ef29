//! What the page shows, read from the run directory at each request (the files the learner
//! writes as it goes: `designs.csv`, `episodes.csv`, `prototype.json`, `reset.json`), and the
//! run's status derived from them: design i of N, the episode, the ETA, what the run waits for,
//! and the actors with their policy lag.

use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed};
use std::time::{SystemTime, UNIX_EPOCH};

use coadapt_learner::coadapt::{RunEvent, ScheduleConfig};
use coadapt_learner::prototype::{self, Prototype, ResetRequest, Status as Wait};
use coadapt_learner::run_dir::{self, DesignRow};

/// A row of `episodes.csv` (the columns the page uses).
#[derive(Clone, Debug, PartialEq)]
pub struct Episode {
    pub design: usize,
    pub episode: usize,
    pub global: usize,
    pub ret: f32,
    pub eval: Option<f32>,
    /// Since the run started.
    pub seconds: f64,
    pub actor: u64,
    pub lag: u64,
}

/// The run directory as the page reads it.
#[derive(Debug, Default)]
pub struct RunFiles {
    /// Trained designs and rejected proposals, in order.
    pub designs: Vec<DesignRow>,
    pub episodes: Vec<Episode>,
    pub prototype: Option<Prototype>,
    pub reset: Option<ResetRequest>,
    /// What could not be read, said on the page (a file being replaced, a damaged row).
    pub problems: Vec<String>,
}

impl RunFiles {
    pub fn read(dir: &Path) -> Self {
        let mut f = RunFiles::default();
        let path = dir.join("designs.csv");
        match std::fs::metadata(&path) {
            Ok(m) => match run_dir::read_designs(&path, m.len()) {
                Ok(d) => f.designs = d,
                Err(e) => f.problems.push(e.to_string()),
            },
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => f.problems.push(format!("{}: {e}", path.display())),
        }
        match std::fs::read_to_string(dir.join("episodes.csv")) {
            Ok(text) => f.episodes = parse_episodes(&text, &mut f.problems),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => f.problems.push(format!("episodes.csv: {e}")),
        }
        match prototype::read_json::<Prototype>(&dir.join(prototype::PROTOTYPE_FILE)) {
            Ok(p) => f.prototype = p,
            Err(e) => f.problems.push(e.to_string()),
        }
        match prototype::read_json::<ResetRequest>(&dir.join(prototype::RESET_FILE)) {
            Ok(r) => f.reset = r,
            Err(e) => f.problems.push(e.to_string()),
        }
        f
    }

    /// Adds the design in training, which `designs.csv` shows only once it ends: the live
    /// learner's row when it has one, else (a run's files alone) a row of what episodes.csv
    /// says (its index; kind and design unknown until the row is written).
    pub fn add_current(&mut self, live: Option<DesignRow>) {
        let last_row = self.trained().map(|d| d.index).max();
        let Some(index) = self.episodes.last().map(|e| e.design).or(live.as_ref().map(|d| d.index)) else { return };
        if last_row.is_some_and(|l| l >= index) {
            return;
        }
        let episodes = self.episodes.iter().filter(|e| e.design == index).count();
        let row = match live.filter(|d| d.index == index) {
            Some(mut d) => {
                d.episodes = episodes;
                d
            }
            None => DesignRow {
                index,
                kind: "?".into(),
                design: Vec::new(),
                episodes,
                best_eval_return: None,
                last_eval_return: None,
                predicted_objective: None,
                design_rollouts: 0,
                method: "in training: its row is written when it ends".into(),
                prototype: String::new(),
            },
        };
        self.designs.push(row);
    }

    /// The designs trained on (rejected proposals left out).
    pub fn trained(&self) -> impl Iterator<Item = &DesignRow> {
        self.designs.iter().filter(|d| d.prototype != run_dir::PROTOTYPE_REJECTED)
    }

    /// The prototype awaiting an answer, if any.
    pub fn awaiting_prototype(&self) -> Option<&Prototype> {
        self.prototype.as_ref().filter(|p| p.status == Wait::Awaiting)
    }

    /// The reset awaiting an answer, if any.
    pub fn awaiting_reset(&self) -> Option<&ResetRequest> {
        self.reset.as_ref().filter(|r| r.status == Wait::Awaiting)
    }
}

/// `episodes.csv`'s rows by its header's names; a line being written (no newline yet) is left
/// for the next read, a damaged one is skipped and said once.
fn parse_episodes(text: &str, problems: &mut Vec<String>) -> Vec<Episode> {
    let mut lines = text.split_inclusive('\n');
    let Some(header) = lines.next() else { return Vec::new() };
    let cols: Vec<&str> = header.trim_end().split(',').collect();
    let col = |name: &str| cols.iter().position(|c| *c == name);
    let (Some(d), Some(e), Some(g), Some(r), Some(s)) =
        (col("design"), col("episode"), col("global_episode"), col("return"), col("seconds"))
    else {
        problems.push("episodes.csv: its header lacks design, episode, global_episode, return or seconds".into());
        return Vec::new();
    };
    let (ev, actor, lag) = (col("eval_return"), col("actor"), col("policy_lag"));
    let mut out = Vec::new();
    let mut bad = 0usize;
    for (i, line) in lines.enumerate() {
        let Some(line) = line.strip_suffix('\n') else { break };
        let f: Vec<&str> = line.split(',').collect();
        let get = |c: usize| f.get(c).copied().unwrap_or("");
        let opt = |c: Option<usize>| c.map(get).filter(|v| !v.is_empty());
        let row = (|| {
            Some(Episode {
                design: get(d).parse().ok()?,
                episode: get(e).parse().ok()?,
                global: get(g).parse().ok()?,
                ret: get(r).parse().ok()?,
                eval: match opt(ev) {
                    Some(v) => Some(v.parse().ok()?),
                    None => None,
                },
                seconds: get(s).parse().ok()?,
                actor: opt(actor).map_or(Some(0), |v| v.parse().ok())?,
                lag: opt(lag).map_or(Some(0), |v| v.parse().ok())?,
            })
        })();
        match row {
            Some(row) => out.push(row),
            None => {
                if bad == 0 {
                    problems.push(format!("episodes.csv line {}: not a row of numbers (skipped)", i + 2));
                }
                bad += 1;
            }
        }
    }
    out
}

/// What the learner tells the page as it runs (a finished run's page has none).
#[derive(Debug, Default)]
pub struct Live {
    /// Milliseconds since the Unix epoch of the learner's last event.
    last_event_ms: AtomicU64,
    finished: AtomicBool,
    /// The design in training: `designs.csv` gets its row only when it ends.
    current: std::sync::Mutex<Option<DesignRow>>,
}

fn now_ms() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_millis() as u64)
}

impl Live {
    /// Notes an event of the learner.
    pub fn observe(&self, e: &RunEvent<'_>) {
        self.last_event_ms.store(now_ms(), Relaxed);
        if let RunEvent::DesignStart { row, .. } = e {
            *self.current.lock().unwrap_or_else(|e| e.into_inner()) = Some((*row).clone());
        }
    }

    /// The design in training, as chosen.
    pub fn current(&self) -> Option<DesignRow> {
        self.current.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// The run has ended (finished, or stopped): the page says so.
    pub fn finish(&self) {
        self.finished.store(true, Relaxed);
    }

    fn quiet_secs(&self) -> Option<f64> {
        let t = self.last_event_ms.load(Relaxed);
        (t > 0).then(|| now_ms().saturating_sub(t) as f64 / 1000.0)
    }
}

/// An actor as the episodes show it.
#[derive(Clone, Debug, PartialEq)]
pub struct Actor {
    pub id: u64,
    pub episodes: usize,
    /// The run's episode number of its last episode.
    pub last_global: usize,
    pub last_lag: u64,
    pub max_lag: u64,
    /// Its last episode came back within the last 2 x (actors) episodes of the run.
    pub recent: bool,
}

/// The run's status line.
#[derive(Clone, Debug, PartialEq)]
pub struct Status {
    pub designs_total: usize,
    /// The design in training or last trained (0-based), with its kind and method.
    pub design: Option<(usize, String, String)>,
    /// Episodes of that design done, and its number of episodes.
    pub design_episodes: (usize, usize),
    pub episodes_done: usize,
    pub episodes_total: usize,
    /// Seconds left at the rate of the last (up to 20) episodes.
    pub eta_secs: Option<f64>,
    /// Seconds since the run started, at its last episode.
    pub run_secs: f64,
    pub finished: bool,
    /// What the run waits for, in words.
    pub waiting_for: String,
    /// Served by the running learner (else from a directory's files, `coadapt serve`).
    pub live: bool,
}

/// The status of the run whose files are `f`, scheduled by `sched`.
pub fn status(f: &RunFiles, sched: &ScheduleConfig, live: Option<&Live>) -> Status {
    let trained: Vec<&DesignRow> = f.trained().collect();
    let episodes_total = sched.total_episodes();
    let last = trained.last();
    let design_episodes = last.map_or((0, 0), |d| (d.episodes, sched.episodes_of(d.index)));
    let done_all = trained.len() >= sched.designs && last.is_some_and(|d| d.episodes >= sched.episodes_of(d.index) && !d.design.is_empty());
    let finished = live.map_or(done_all, |l| l.finished.load(Relaxed) || done_all);
    let eps = &f.episodes;
    let eta_secs = (!finished && eps.len() >= 2).then(|| {
        let k = eps.len().min(21);
        let window = &eps[eps.len() - k..];
        let per = (window[k - 1].seconds - window[0].seconds) / (k - 1) as f64;
        per.max(0.0) * episodes_total.saturating_sub(eps.len()) as f64
    });
    let waiting_for = if finished {
        if done_all {
            "nothing: the run is finished".into()
        } else {
            "nothing: the run stopped before its end (resume it with coadapt run --resume)".into()
        }
    } else if let Some(p) = f.awaiting_prototype() {
        format!("the operator: design {}'s prototype (proposal {}) to be built", p.index + 1, p.proposal)
    } else if let Some(r) = f.awaiting_reset() {
        format!("the operator: the robot to be reset before {}", prototype::reset_name(r.mode, r.episode, r.design_index))
    } else if last.is_none_or(|d| d.episodes >= sched.episodes_of(d.index)) {
        if trained.is_empty() { "the run's start".into() } else { "the optimiser's next design".into() }
    } else {
        let quiet = live.and_then(Live::quiet_secs).unwrap_or(0.0);
        if quiet > 60.0 {
            format!("experience from the actors (nothing for {})", coadapt_log::duration(quiet))
        } else {
            "experience from the actors (training)".into()
        }
    };
    Status {
        designs_total: sched.designs,
        design: last.map(|d| (d.index, d.kind.clone(), d.method.clone())),
        design_episodes,
        episodes_done: eps.len(),
        episodes_total,
        eta_secs,
        run_secs: eps.last().map_or(0.0, |e| e.seconds),
        finished,
        waiting_for,
        live: live.is_some(),
    }
}

/// The actors that ran the run's episodes, by id.
pub fn actors(eps: &[Episode]) -> Vec<Actor> {
    let mut by: std::collections::BTreeMap<u64, Actor> = std::collections::BTreeMap::new();
    for e in eps {
        let a = by.entry(e.actor).or_insert(Actor { id: e.actor, episodes: 0, last_global: 0, last_lag: 0, max_lag: 0, recent: false });
        a.episodes += 1;
        a.last_global = a.last_global.max(e.global);
        a.last_lag = e.lag;
        a.max_lag = a.max_lag.max(e.lag);
    }
    let newest = eps.iter().map(|e| e.global).max().unwrap_or(0);
    let n = by.len().max(1);
    by.into_values()
        .map(|mut a| {
            a.recent = newest - a.last_global < 2 * n;
            a
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_design_in_training_is_shown_before_its_row_is_written() {
        let ep = |design, episode| Episode { design, episode, global: 0, ret: 0.0, eval: None, seconds: 0.0, actor: 0, lag: 0 };
        let row = |index, episodes| DesignRow {
            index,
            kind: "exploit".into(),
            design: vec![1.0],
            episodes,
            best_eval_return: None,
            last_eval_return: None,
            predicted_objective: Some(3.0),
            design_rollouts: 0,
            method: "pso-q".into(),
            prototype: String::new(),
        };
        let mut f = RunFiles { designs: vec![row(0, 2)], episodes: vec![ep(0, 0), ep(0, 1), ep(1, 0)], ..Default::default() };
        f.add_current(None);
        assert_eq!((f.designs.len(), f.designs[1].index, f.designs[1].episodes, f.designs[1].kind.as_str()), (2, 1, 1, "?"));
        let mut f = RunFiles { designs: vec![row(0, 2)], episodes: vec![ep(0, 0), ep(0, 1), ep(1, 0)], ..Default::default() };
        f.add_current(Some(row(1, 0)));
        assert_eq!((f.designs[1].kind.as_str(), f.designs[1].episodes, f.designs[1].predicted_objective), ("exploit", 1, Some(3.0)));
        // Nothing to add once the row is written, or before any design.
        f.add_current(Some(row(1, 0)));
        assert_eq!(f.designs.len(), 2);
        let mut f = RunFiles::default();
        f.add_current(None);
        assert!(f.designs.is_empty());
    }

    #[test]
    fn episodes_parse_by_name_and_a_line_being_written_waits() {
        let mut p = Vec::new();
        let text = "design,episode,global_episode,steps,return,eval_return,weights_version,seconds,actor,policy_lag\n\
                    0,0,0,1000,8.5,1.25,1,0.2,0,0\n0,1,1,2000,9.5,,2,0.4,1,2\nx,1\n0,2,2,30";
        let e = parse_episodes(text, &mut p);
        assert_eq!(e.len(), 2);
        assert_eq!(e[0], Episode { design: 0, episode: 0, global: 0, ret: 8.5, eval: Some(1.25), seconds: 0.2, actor: 0, lag: 0 });
        assert_eq!((e[1].eval, e[1].actor, e[1].lag), (None, 1, 2));
        assert_eq!(p, vec!["episodes.csv line 4: not a row of numbers (skipped)".to_string()]);
        let a = actors(&e);
        assert_eq!((a.len(), a[1].max_lag, a[0].recent), (2, 2, true));
    }
}
