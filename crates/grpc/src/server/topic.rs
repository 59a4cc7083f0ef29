//! A weight topic on the learner: a `watch` channel holds the newest encoded version, so a
//! publish is one encode and every stream sends the same buffers (`Bytes` are shared, not
//! copied), and a stream that falls behind simply reads the newest value next.

use coadapt_transport::messages::Dims;
use coadapt_transport::{Publisher, TransportError, Validate, Weights};
use coadapt_wire::Wire;
use coadapt_wire::pb;
use prost::Message;
use tokio::sync::watch;

/// The newest value of a topic.
#[derive(Clone, Debug, Default)]
pub(crate) struct Snapshot {
    pub(crate) weights: Option<pb::Weights>,
    pub(crate) version: u64,
    /// The learner dropped its publisher: nothing newer will come.
    pub(crate) closed: bool,
}

pub(crate) fn topic(max_message_bytes: usize) -> (WeightsPublisher, watch::Receiver<Snapshot>) {
    let (tx, rx) = watch::channel(Snapshot::default());
    (WeightsPublisher { tx, max_message_bytes }, rx)
}

/// The learner's end of a weight topic.
#[derive(Debug)]
pub(crate) struct WeightsPublisher {
    tx: watch::Sender<Snapshot>,
    max_message_bytes: usize,
}

impl Publisher<Weights> for WeightsPublisher {
    fn publish(&mut self, w: Weights) -> Result<(), TransportError> {
        let current = self.tx.borrow().version;
        if self.tx.borrow().weights.is_some() && w.version <= current {
            return Err(TransportError::Invalid(format!("version {} after {current}", w.version)));
        }
        // The same checks a receiver makes, so a bad publish fails here, not in every actor.
        w.validate(&Dims { obs: 0, act: 0, design: 0 }).map_err(|e| TransportError::Invalid(e.to_string()))?;
        let pb = w.to_pb();
        let bytes = pb::WeightsUpdate { weights: Some(pb.clone()), publisher_closed: false }.encoded_len();
        if bytes > self.max_message_bytes {
            return Err(TransportError::Invalid(format!(
                "weights version {} encode to {bytes} bytes, above the message limit of {} bytes (GrpcConfig::max_message_bytes)",
                w.version, self.max_message_bytes
            )));
        }
        self.tx.send_modify(|s| {
            s.weights = Some(pb);
            s.version = w.version;
        });
        Ok(())
    }
}

impl Drop for WeightsPublisher {
    fn drop(&mut self) {
        self.tx.send_modify(|s| s.closed = true);
    }
}
