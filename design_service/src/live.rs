//! A running learner's model and designs, fed by the learner as it goes.

use std::sync::{Arc, Mutex, RwLock};

use tokio::sync::broadcast;

use crate::model::{DesignEvent, DesignModel, HistoryError, HistoryPage, HistoryRow, ModelSource};

/// Design changes a slow Watch stream may fall behind by before it is sent the history again.
const EVENTS: usize = 1024;

/// The prototype column of a proposal the operator would not build.
const REJECTED: &str = "rejected";

#[derive(Debug, Default)]
struct Rows {
    /// Rows of design indices before the newest: they no longer change.
    closed: Vec<HistoryRow>,
    /// The rows of the newest index.
    open: Vec<HistoryRow>,
    ended: bool,
}

/// The model of the optimiser's latest design request and the run's designs so far, set by
/// the learner ([`LiveSource::set_model`], [`LiveSource::upsert`], [`LiveSource::end`])
/// and read by the server's handlers.
#[derive(Debug)]
pub struct LiveSource {
    model: RwLock<Option<Arc<DesignModel>>>,
    rows: Mutex<Rows>,
    events: broadcast::Sender<DesignEvent>,
}

impl LiveSource {
    /// A source that starts from `history` (a resumed run's rows; empty for a new run).
    pub fn new(history: Vec<HistoryRow>) -> Self {
        let (events, _) = broadcast::channel(EVENTS);
        // The newest index's rows may still change.
        let mut closed = history;
        let open_from = closed.last().map_or(0, |r| closed.partition_point(|x| x.index < r.index));
        let open = closed.split_off(open_from);
        Self { model: RwLock::new(None), rows: Mutex::new(Rows { closed, open, ended: false }), events }
    }

    /// The model queries use from now on (queries under way finish with the one they took).
    pub fn set_model(&self, m: DesignModel) {
        *self.model.write().unwrap_or_else(|e| e.into_inner()) = Some(Arc::new(m));
    }

    /// A design row, new or in a newer state, by designs.csv's rule: a row of a newer index
    /// closes the rows before it; a row replaces the open row of its index that is not a
    /// rejected proposal (a rejected proposal keeps its row). Sent to watchers.
    pub fn upsert(&self, r: HistoryRow) {
        let mut rows = self.rows.lock().unwrap_or_else(|e| e.into_inner());
        if rows.open.last().is_some_and(|d| d.index != r.index) {
            let old = std::mem::take(&mut rows.open);
            rows.closed.extend(old);
        }
        match rows.open.iter().rposition(|d| d.prototype != REJECTED) {
            Some(i) => rows.open[i] = r.clone(),
            None => rows.open.push(r.clone()),
        }
        // Sent under the lock, so watchers see the changes in the order the rows took them.
        let _ = self.events.send(DesignEvent::Row(r));
    }

    /// The run has ended: Watch streams end after what they were sent.
    pub fn end(&self) {
        let mut rows = self.rows.lock().unwrap_or_else(|e| e.into_inner());
        rows.ended = true;
        let _ = self.events.send(DesignEvent::Ended);
    }
}

impl ModelSource for LiveSource {
    fn model(&self) -> Option<Arc<DesignModel>> {
        self.model.read().unwrap_or_else(|e| e.into_inner()).clone()
    }

    fn history(&self, from: usize, max: usize) -> Result<HistoryPage, HistoryError> {
        let rows = self.rows.lock().unwrap_or_else(|e| e.into_inner());
        let (closed, open) = (&rows.closed, &rows.open);
        // The closed rows then the open ones: ordered by index.
        let n = closed.len() + open.len();
        let at = |i: usize| if i < closed.len() { &closed[i] } else { &open[i - closed.len()] };
        let start = match closed.last() {
            Some(r) if r.index >= from => closed.partition_point(|r| r.index < from),
            _ => closed.len() + open.partition_point(|r| r.index < from),
        };
        let mut end = (start + max.max(1)).min(n);
        while end < n && at(end).index == at(end - 1).index {
            end += 1;
        }
        Ok(HistoryPage { rows: (start..end).map(|i| at(i).clone()).collect(), more: end < n })
    }

    fn subscribe(&self) -> Option<broadcast::Receiver<DesignEvent>> {
        // Under the lock: a subscriber either sees the end or gets its event.
        let rows = self.rows.lock().unwrap_or_else(|e| e.into_inner());
        (!rows.ended).then(|| self.events.subscribe())
    }
}
