//! Design queries for clients in any language (standing above the design optimiser, whose
//! objective and searches it serves): `coadapt.v1.DesignService`
//! (`proto/coadapt/v1/design.proto`) and the design critic as the Open Inference Protocol model
//! `design-critic` (`inference.GRPCInferenceService`, `proto/inference/grpc_predict_v2.proto`),
//! so Triton's and KServe's clients work unchanged.
//!
//! # Layout
//! - `model`: [`DesignModel`], the thesis's Eq. 5.6 over fixed population networks and a fixed
//!   start-state batch (the optimiser's [`DesignObjective`](coadapt_design_optimizer::objective::DesignObjective)),
//!   with its spread over the start states; [`ModelSource`], where a server gets the current
//!   model and the run's history ([`HistoryError`] when it cannot read it): [`StaticSource`]
//!   (a finished run's files) or, in `live`,
//!   [`LiveSource`] (fed by a running learner at each design request and design row).
//! - `design`: the DesignService handlers (`optimize`: the streamed search; `landscape`: Fig.
//!   5.9's grid; `watch`: the design stream); `inference`: the Open Inference Protocol handlers.
//!   Both validate every request before use and answer a malformed one with
//!   `INVALID_ARGUMENT` naming the field.
//! - `shared`: what every handler holds (the model source, [`ServeConfig`], the bounded pool of
//!   computations) and the checks of a design.
//! - `server`: [`serve`], one tonic server for both, with health per service and reflection
//!   (v1 and v1alpha), connections per peer limited as on the fleet's port, and every
//!   computation on a bounded pool of blocking threads ([`ServeConfig::max_concurrent`]) so
//!   that queries cannot starve the process that serves them.

mod design;
mod inference;
mod landscape;
mod live;
mod model;
mod optimize;
mod server;
mod shared;
mod watch;

pub use live::LiveSource;
pub use model::{DesignEvent, DesignModel, HistoryError, HistoryPage, HistoryRow, ModelSource, StaticSource};
pub use server::{DesignServer, ServeConfig, serve};

/// The remote address of an HTTP request served beside gRPC ([`ServeConfig::pages`]), from the
/// connection information the server attaches to every request (plaintext or TLS).
pub fn peer_ip(extensions: &axum::http::Extensions) -> Option<std::net::IpAddr> {
    use tonic::transport::server::{TcpConnectInfo, TlsConnectInfo};
    let plain = extensions.get::<TcpConnectInfo>().and_then(|i| i.remote_addr());
    plain.or_else(|| extensions.get::<TlsConnectInfo<TcpConnectInfo>>().and_then(|i| i.get_ref().remote_addr())).map(|a| a.ip())
}

/// The model name of the design critic in the Open Inference Protocol.
pub const MODEL_NAME: &str = "design-critic";
