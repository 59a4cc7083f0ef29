//! The router: `coadapt.v1.Fleet` beside grpc.health.v1 and reflection, behind the role gate,
//! with TLS and the server's bounds on connections and streams.

use std::sync::Arc;

use coadapt_auth::Role;
use coadapt_wire::pb::fleet_server::FleetServer;
use tonic::service::interceptor::InterceptedService;

use super::Hub;
use super::service::FleetService;
use crate::{CONNECTION_WINDOW, STREAM_WINDOW};

/// Fleet, grpc.health.v1 and reflection (v1 and v1alpha, which know the health service too),
/// with the message-size limit on both directions.
pub(super) fn router(
    hub: Arc<Hub>,
    rt: &tokio::runtime::Runtime,
) -> Result<(tonic::transport::server::Router, tonic_health::server::HealthReporter), String> {
    let cfg = hub.cfg.clone();
    let gate = |roles| cfg.server_auth.gate(roles).counting(hub.gate_counts.clone()).server("fleet");
    let fleet = FleetServer::new(FleetService::new(hub.clone()))
        .max_decoding_message_size(cfg.max_message_bytes)
        .max_encoding_message_size(cfg.max_message_bytes);
    // Actors and optimisers (each call then checked against the caller's role); health
    // answers anyone (probes), reflection any known token.
    let fleet = InterceptedService::new(fleet, gate(&[Role::Actor, Role::Optimizer]));
    let (health_reporter, health) = tonic_health::server::health_reporter();
    let reporter = health_reporter.clone();
    // Serving before the first client can ask.
    let (set, is_set) = std::sync::mpsc::sync_channel(1);
    rt.spawn(async move {
        health_reporter.set_serving::<FleetServer<FleetService>>().await;
        let _ = set.send(());
    });
    let _ = is_set.recv();
    let reflection = || {
        tonic_reflection::server::Builder::configure()
            .register_encoded_file_descriptor_set(coadapt_wire::FILE_DESCRIPTOR_SET)
            .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
    };
    let mut builder = tonic::transport::Server::builder();
    if let Some(tls) = &cfg.server_auth.tls {
        builder = builder.tls_config(tls.config()).map_err(|e| format!("TLS: {e}"))?;
    }
    let any = gate(&Role::ALL);
    let v1 = InterceptedService::new(reflection().build_v1().map_err(|e| e.to_string())?, any.clone());
    let v1alpha = InterceptedService::new(reflection().build_v1alpha().map_err(|e| e.to_string())?, any);
    let router = builder
        .initial_stream_window_size(STREAM_WINDOW)
        .initial_connection_window_size(CONNECTION_WINDOW)
        .http2_keepalive_interval(Some(cfg.heartbeat))
        .http2_keepalive_timeout(Some(cfg.rpc_timeout))
        // Bounds on what one connection may hold open or throw at us.
        .max_concurrent_streams(cfg.max_concurrent_streams.max(1))
        .http2_max_header_list_size(cfg.max_header_list_bytes)
        .http2_max_pending_accept_reset_streams(Some(cfg.max_pending_reset_streams))
        .tcp_nodelay(true)
        .add_service(fleet)
        .add_service(health)
        .add_service(v1)
        .add_service(v1alpha);
    Ok((router, reporter))
}
