//! The channels each role holds. A role is written against these and never names a transport.

use crate::messages::{Assignment, DesignReply, DesignRequest, ExperienceChunk, Weights};
use crate::traits::{Publisher, Receiver, Sender, Subscriber};

/// The learner's side: it takes experience, hands out episodes and weights, and asks for
/// designs.
pub struct LearnerLinks {
    pub experience: Box<dyn Receiver<ExperienceChunk>>,
    pub assignments: Box<dyn Sender<Assignment>>,
    /// The policy the actors act with (population during warm-up, then individual).
    pub acting_weights: Box<dyn Publisher<Weights>>,
    /// The population policy and critics, for the design optimiser.
    pub population_weights: Box<dyn Publisher<Weights>>,
    pub design_requests: Box<dyn Sender<DesignRequest>>,
    pub design_replies: Box<dyn Receiver<DesignReply>>,
}

/// An actor's side.
pub struct ActorLinks {
    pub assignments: Box<dyn Receiver<Assignment>>,
    pub weights: Box<dyn Subscriber<Weights>>,
    pub experience: Box<dyn Sender<ExperienceChunk>>,
}

/// The design optimiser's side.
pub struct OptimizerLinks {
    pub requests: Box<dyn Receiver<DesignRequest>>,
    pub replies: Box<dyn Sender<DesignReply>>,
    pub weights: Box<dyn Subscriber<Weights>>,
}

macro_rules! opaque_debug {
    ($($t:ty),*) => {$(
        impl std::fmt::Debug for $t {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str(stringify!($t))
            }
        }
    )*};
}
opaque_debug!(LearnerLinks, ActorLinks, OptimizerLinks);
