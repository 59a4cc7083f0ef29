//! `Watch`: the run's designs, then every change as it happens.

use std::sync::Arc;

use coadapt_wire::pb;
use tokio::sync::{broadcast, mpsc};
use tonic::Status;

use crate::model::{DesignEvent, HistoryRow};
use crate::shared::Shared;

/// Messages a slow watcher may have unread before the stream waits for it.
const BUFFER: usize = 64;

type Tx = mpsc::Sender<Result<pb::DesignEvent, Status>>;

/// Sends the history from `from` on; false when the client is gone.
async fn send_history(shared: &Shared, mut from: usize, tx: &Tx) -> bool {
    loop {
        let p = match shared.source.history(from, shared.cfg.history_page) {
            Ok(p) => p,
            Err(e) => {
                let _ = tx.send(Err(Status::internal(format!("reading the history: {e}")))).await;
                return false;
            }
        };
        let Some(last) = p.rows.last() else { return true };
        from = last.index + 1;
        for r in p.rows {
            if !send(tx, r).await {
                return false;
            }
        }
        if !p.more {
            return true;
        }
    }
}

async fn send(tx: &Tx, r: HistoryRow) -> bool {
    tx.send(Ok(pb::DesignEvent { design: Some(crate::design::record(r)) })).await.is_ok()
}

/// Starts the stream of `from` on: subscribed before the history is read, so no change falls
/// between the two (a row may come twice: then the second is its newer state).
pub(crate) fn start(shared: Arc<Shared>, from: usize) -> tokio_stream::wrappers::ReceiverStream<Result<pb::DesignEvent, Status>> {
    let (tx, rx) = mpsc::channel(BUFFER);
    let events = shared.source.subscribe();
    tokio::spawn(async move {
        if !send_history(&shared, from, &tx).await {
            return;
        }
        let Some(mut events) = events else { return };
        loop {
            let stop = shared.stopping();
            let e = tokio::select! {
                e = events.recv() => e,
                () = stop => return,
                () = tx.closed() => return,
            };
            match e {
                Ok(DesignEvent::Row(r)) if r.index >= from => {
                    if !send(&tx, r).await {
                        return;
                    }
                }
                Ok(DesignEvent::Row(_)) => {}
                Ok(DesignEvent::Ended) | Err(broadcast::error::RecvError::Closed) => return,
                // Fell behind by more than the channel holds: the history again (rows repeat,
                // in their newest state), then on.
                Err(broadcast::error::RecvError::Lagged(_)) => {
                    if !send_history(&shared, from, &tx).await {
                        return;
                    }
                }
            }
        }
    });
    tokio_stream::wrappers::ReceiverStream::new(rx)
}
