//! The frames of the two queues that flow to the learner. Both carry a sender id, a sequence
//! number and either a payload or the sender's clean close (`fin`), and both are acknowledged
//! cumulatively; this trait lets one client and one server implementation serve both.

use std::future::Future;
use std::pin::Pin;

use coadapt_transport::{DesignReply, ExperienceChunk, Validate};
use coadapt_wire::Wire;
use coadapt_wire::pb;
use coadapt_wire::pb::fleet_client::FleetClient;
use tokio_stream::wrappers::ReceiverStream;

pub(crate) type AckStream = tonic::Streaming<pb::Ack>;
type Opening = Pin<Box<dyn Future<Output = Result<tonic::Response<AckStream>, tonic::Status>> + Send>>;

/// A frame of a client-to-learner queue.
pub(crate) trait Frame: prost::Message + Default + Clone + Send + Sync + 'static {
    /// The domain message it carries.
    type Item: Wire<Pb: Clone + Send + Sync> + Validate + Send + 'static;
    /// What the payload is called in errors ("chunk", "reply").
    const PAYLOAD: &'static str;

    fn build(sender: u64, seq: u64, payload: Option<<Self::Item as Wire>::Pb>) -> Self;
    /// (sender, seq, payload, fin)
    fn parts(self) -> (u64, u64, Option<<Self::Item as Wire>::Pb>, bool);
    fn seq(&self) -> u64;
    fn set_seq(&mut self, seq: u64);
    /// Opens the bidirectional stream that carries these frames.
    #[doc(hidden)]
    fn open(client: FleetClient<coadapt_auth::AuthChannel>, frames: tonic::Request<ReceiverStream<Self>>) -> Opening;
}

impl Frame for pb::ExperienceFrame {
    type Item = ExperienceChunk;
    const PAYLOAD: &'static str = "chunk";

    fn build(sender: u64, seq: u64, chunk: Option<pb::ExperienceChunk>) -> Self {
        Self { sender, seq, fin: chunk.is_none(), chunk }
    }

    fn parts(self) -> (u64, u64, Option<pb::ExperienceChunk>, bool) {
        (self.sender, self.seq, self.chunk, self.fin)
    }

    fn seq(&self) -> u64 {
        self.seq
    }

    fn set_seq(&mut self, seq: u64) {
        self.seq = seq;
    }

    fn open(mut client: FleetClient<coadapt_auth::AuthChannel>, frames: tonic::Request<ReceiverStream<Self>>) -> Opening {
        Box::pin(async move { client.push_experience(frames).await })
    }
}

impl Frame for pb::DesignReplyFrame {
    type Item = DesignReply;
    const PAYLOAD: &'static str = "reply";

    fn build(sender: u64, seq: u64, reply: Option<pb::DesignReply>) -> Self {
        Self { sender, seq, fin: reply.is_none(), reply }
    }

    fn parts(self) -> (u64, u64, Option<pb::DesignReply>, bool) {
        (self.sender, self.seq, self.reply, self.fin)
    }

    fn seq(&self) -> u64 {
        self.seq
    }

    fn set_seq(&mut self, seq: u64) {
        self.seq = seq;
    }

    fn open(mut client: FleetClient<coadapt_auth::AuthChannel>, frames: tonic::Request<ReceiverStream<Self>>) -> Opening {
        Box::pin(async move { client.push_design_replies(frames).await })
    }
}
