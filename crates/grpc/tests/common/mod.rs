//! What the gRPC tests share: a fast-failing configuration and a learner on a free port.

use std::net::SocketAddr;
use std::time::Duration;

use coadapt_grpc::{GrpcConfig, LearnerLinks, LearnerServer, serve_learner};

/// Short deadlines and heartbeats, so failures show within a test's patience.
pub fn cfg() -> GrpcConfig {
    GrpcConfig {
        rpc_timeout: Duration::from_secs(2),
        connect_timeout: Duration::from_secs(2),
        heartbeat: Duration::from_millis(100),
        reconnect_backoff_max: Duration::from_millis(300),
        ..GrpcConfig::default()
    }
}

pub fn learner() -> (LearnerLinks, LearnerServer, String) {
    learner_with(&cfg())
}

pub fn learner_with(cfg: &GrpcConfig) -> (LearnerLinks, LearnerServer, String) {
    let addr: SocketAddr = "127.0.0.1:0".parse().expect("address");
    let (links, server) = serve_learner(addr, cfg).expect("learner server");
    let endpoint = format!("http://{}", server.local_addr());
    (links, server, endpoint)
}
