//! The service's edge: what a raw gRPC client sees for malformed and oversized messages, the
//! size limits on weights, health and reflection, and loopback throughput.

use crate::common;

use std::time::Duration;

use coadapt_grpc::{GrpcConfig, actor_links};
use coadapt_transport::conformance::{chunk, weights};
use coadapt_transport::{ExperienceChunk, TransportError, Weights};
use coadapt_wire::Wire;
use coadapt_wire::pb;
use coadapt_wire::pb::fleet_client::FleetClient;

const LONG: Duration = Duration::from_secs(10);

fn rt() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread().enable_all().build().expect("runtime")
}

/// Sends one experience frame from a plain tonic client (registered as an actor, naming its
/// session in the stream's metadata); returns the first answer.
fn push_raw(endpoint: &str, chunk: pb::ExperienceChunk) -> Result<pb::Ack, tonic::Status> {
    let endpoint = endpoint.to_string();
    rt().block_on(async move {
        let mut client = FleetClient::connect(endpoint).await.expect("connect").max_encoding_message_size(usize::MAX);
        let session = 0x5E55_1011;
        let hello = pb::Hello {
            fleet: GrpcConfig::default().fleet,
            protocol: coadapt_grpc::PROTOCOL,
            role: pb::Role::Actor as i32,
            actor_id: 99,
            session,
        };
        client.register(hello).await.expect("register");
        let frame = pb::ExperienceFrame { sender: 99, seq: 1, chunk: Some(chunk), fin: false };
        let mut req = tonic::Request::new(tokio_stream::iter(vec![frame]));
        req.metadata_mut().insert("coadapt-session", session.to_string().parse().expect("ascii"));
        let mut acks = client.push_experience(req).await?.into_inner();
        acks.message().await?.ok_or_else(|| tonic::Status::unknown("no answer"))
    })
}

#[test]
fn malformed_chunks_are_refused_naming_the_field() {
    let (mut learner, _server, endpoint) = common::learner();
    let mut nan = chunk(3).to_pb();
    let mut rewards = chunk(3).rewards;
    rewards[0] = f32::NAN;
    nan.rewards = coadapt_wire::f32_bytes(&rewards);
    let status = push_raw(&endpoint, nan).expect_err("a NaN reward");
    assert_eq!(status.code(), tonic::Code::InvalidArgument);
    assert!(status.message().contains("rewards"), "{}", status.message());

    let mut rows = chunk(3).to_pb();
    rows.rows = 2;
    let status = push_raw(&endpoint, rows).expect_err("two rows declared, one sent");
    assert_eq!(status.code(), tonic::Code::InvalidArgument);
    assert!(status.message().contains("rewards"), "{}", status.message());

    let mut obs = chunk(3).to_pb();
    obs.obs = coadapt_wire::f32_bytes(&[1.0, 2.0, 3.0, 4.0, 5.0]);
    let status = push_raw(&endpoint, obs).expect_err("obs that does not match next_obs");
    assert_eq!(status.code(), tonic::Code::InvalidArgument);
    assert!(status.message().contains("obs"), "{}", status.message());

    assert_eq!(learner.experience.recv_timeout(Duration::from_millis(200)).expect("recv"), None, "nothing malformed reached the learner");
    // A good frame from the same kind of client is accepted.
    assert_eq!(push_raw(&endpoint, chunk(4).to_pb()).expect("a good chunk").acked, 1);
    assert_eq!(learner.experience.recv_timeout(LONG).expect("recv"), Some(chunk(4)));
}

#[test]
fn declared_dimensions_are_checked_when_the_learner_gives_them() {
    let (mut learner, server, endpoint) = common::learner();
    server.expect_dims(coadapt_transport::messages::Dims { obs: 4, act: 2, design: 2 });
    // chunk() has 3-wide observations.
    let status = push_raw(&endpoint, chunk(1).to_pb()).expect_err("wrong observation width");
    assert_eq!(status.code(), tonic::Code::InvalidArgument);
    assert!(status.message().contains("obs"), "{}", status.message());
    assert_eq!(learner.experience.recv_timeout(Duration::from_millis(100)).expect("recv"), None);
}

#[test]
fn actors_refuse_to_send_malformed_chunks() {
    let (_learner, _server, endpoint) = common::learner();
    let mut actor = actor_links(&endpoint, 1, &common::cfg()).expect("actor");
    let mut bad = chunk(1);
    bad.obs[1] = f32::INFINITY;
    assert!(matches!(actor.experience.send(bad), Err(TransportError::Invalid(m)) if m.contains("obs")));
    actor.experience.send(chunk(2)).expect("a good chunk still goes");
}

fn big_weights(version: u64, bytes: usize) -> Weights {
    weights(version, bytes / 4)
}

#[test]
fn a_20_mib_weight_message_passes_and_one_above_the_limit_is_refused() {
    let cfg = GrpcConfig { max_message_bytes: 32 << 20, ..common::cfg() };
    let (mut learner, _server, endpoint) = common::learner_with(&cfg);
    let mut actor = actor_links(&endpoint, 1, &cfg).expect("actor");
    let w = big_weights(1, 20 << 20);
    learner.acting_weights.publish(w.clone()).expect("20 MiB is within the limit");
    assert_eq!(*actor.weights.wait_for(1, LONG).expect("wait").expect("weights"), w);
    match learner.acting_weights.publish(big_weights(2, 40 << 20)) {
        Err(TransportError::Invalid(m)) => assert!(m.contains("limit"), "{m}"),
        other => panic!("expected a refusal naming the limit, got {other:?}"),
    }
    // The refused version never replaced the good one.
    assert!(actor.weights.wait_for(2, Duration::from_millis(300)).expect("wait").is_none());
}

#[test]
fn a_client_with_a_smaller_limit_refuses_oversized_weights_clearly() {
    let (mut learner, _server, endpoint) = common::learner();
    let small = GrpcConfig { max_message_bytes: 8 << 20, ..common::cfg() };
    let mut actor = actor_links(&endpoint, 1, &small).expect("actor");
    learner.acting_weights.publish(big_weights(1, 20 << 20)).expect("publish");
    match actor.weights.wait_for(1, LONG) {
        Err(TransportError::Invalid(m)) => assert!(m.contains("too large"), "{m}"),
        other => panic!("expected a refusal, got {:?}", other.map(|w| w.map(|w| w.version))),
    }
}

#[test]
fn an_oversized_chunk_is_refused_by_the_learner() {
    let cfg = GrpcConfig { max_message_bytes: 1 << 20, ..common::cfg() };
    let (mut learner, _server, endpoint) = common::learner_with(&cfg);
    let rows = 100_000;
    let big = ExperienceChunk {
        obs: vec![0.5; rows],
        actions: vec![0.0; rows],
        rewards: vec![1.0; rows],
        next_obs: vec![0.5; rows],
        terminated: vec![false; rows],
        ..ExperienceChunk::default()
    };
    let status = push_raw(&endpoint, big.to_pb()).expect_err("above the 1 MiB limit");
    assert_eq!(status.code(), tonic::Code::OutOfRange, "{status:?}");
    assert!(status.message().contains("too large"), "{}", status.message());
    assert_eq!(learner.experience.recv_timeout(Duration::from_millis(100)).expect("recv"), None);
    // Our own client refuses it before sending.
    let mut actor = actor_links(&endpoint, 1, &cfg).expect("actor");
    assert!(matches!(actor.experience.send(big), Err(TransportError::Invalid(m)) if m.contains("limit")));
}

#[test]
fn health_and_reflection_answer() {
    use tonic_health::pb::health_check_response::ServingStatus;
    use tonic_health::pb::{HealthCheckRequest, health_client::HealthClient};
    use tonic_reflection::pb::v1::ServerReflectionRequest;
    use tonic_reflection::pb::v1::server_reflection_client::ServerReflectionClient;
    use tonic_reflection::pb::v1::server_reflection_request::MessageRequest;
    use tonic_reflection::pb::v1::server_reflection_response::MessageResponse;
    use tonic_reflection::pb::v1alpha::server_reflection_client::ServerReflectionClient as AlphaClient;

    let (_learner, _server, endpoint) = common::learner();
    rt().block_on(async move {
        let channel = tonic::transport::Channel::from_shared(endpoint).expect("endpoint").connect().await.expect("connect");
        let mut health = HealthClient::new(channel.clone());
        for service in ["", "coadapt.v1.Fleet"] {
            let status = health.check(HealthCheckRequest { service: service.into() }).await.expect("health check").into_inner().status;
            assert_eq!(status, ServingStatus::Serving as i32, "service {service:?}");
        }

        let mut reflection = ServerReflectionClient::new(channel.clone());
        let req = ServerReflectionRequest { host: String::new(), message_request: Some(MessageRequest::ListServices(String::new())) };
        let mut answers = reflection.server_reflection_info(tokio_stream::iter(vec![req])).await.expect("reflection").into_inner();
        let Some(MessageResponse::ListServicesResponse(list)) = answers.message().await.expect("answer").expect("one").message_response
        else {
            panic!("not a service list")
        };
        let names: Vec<_> = list.service.into_iter().map(|s| s.name).collect();
        for want in ["coadapt.v1.Fleet", "grpc.health.v1.Health", "grpc.reflection.v1.ServerReflection"] {
            assert!(names.iter().any(|n| n == want), "{want} missing from {names:?}");
        }
        // The message types resolve too (what grpcurl needs to call the service).
        let req = ServerReflectionRequest {
            host: String::new(),
            message_request: Some(MessageRequest::FileContainingSymbol("coadapt.v1.Fleet".into())),
        };
        let mut answers = reflection.server_reflection_info(tokio_stream::iter(vec![req])).await.expect("reflection").into_inner();
        assert!(matches!(
            answers.message().await.expect("answer").expect("one").message_response,
            Some(MessageResponse::FileDescriptorResponse(_))
        ));

        let mut alpha = AlphaClient::new(channel);
        use tonic_reflection::pb::v1alpha as a;
        let req = a::ServerReflectionRequest {
            host: String::new(),
            message_request: Some(a::server_reflection_request::MessageRequest::ListServices(String::new())),
        };
        let mut answers = alpha.server_reflection_info(tokio_stream::iter(vec![req])).await.expect("v1alpha reflection").into_inner();
        assert!(answers.message().await.expect("answer").is_some());
    });
}

/// Both large flows at volume: 8 x 20 MiB of weights, each arriving whole, and 600
/// 1000-row chunks in order. Their speed is `coadapt bench transport`'s business.
#[test]
fn large_weights_and_many_chunks_cross_loopback() {
    let (mut learner, _server, endpoint) = common::learner();
    let mut actor = actor_links(&endpoint, 1, &common::cfg()).expect("actor");

    let size = 20 << 20;
    let rounds = 8;
    for v in 1..=rounds {
        let w = big_weights(v, size);
        let expected = w.policy.len();
        learner.acting_weights.publish(w).expect("publish");
        let got = actor.weights.wait_for(v, LONG).expect("wait").expect("weights");
        assert_eq!((got.version, got.policy.len()), (v, expected));
    }

    // HalfCheetah-sized rows (obs 23 with the design, act 6), 1000 rows a chunk.
    let rows = 1000;
    let c = ExperienceChunk {
        actor: 1,
        obs: vec![0.25; rows * 23],
        actions: vec![0.5; rows * 6],
        rewards: vec![1.0; rows],
        next_obs: vec![0.25; rows * 23],
        terminated: vec![false; rows],
        ..ExperienceChunk::default()
    };
    let n = 600;
    let producer = std::thread::spawn(move || {
        let mut tx = actor.experience;
        for i in 0..n {
            let mut c = c.clone();
            c.assignment = i;
            tx.send(c).expect("send");
        }
        tx
    });
    for i in 0..n {
        let got = learner.experience.recv_timeout(LONG).expect("recv").expect("chunk");
        assert_eq!((got.assignment, got.len()), (i, rows));
    }
    drop(producer.join().expect("producer"));
}

#[test]
fn the_health_switch_turns_the_learner_not_serving_and_back() {
    use tonic_health::pb::health_check_response::ServingStatus;
    use tonic_health::pb::{HealthCheckRequest, health_client::HealthClient};

    let (_learner, server, endpoint) = common::learner();
    let switch = server.health();
    let check = |want: ServingStatus| {
        let endpoint = endpoint.clone();
        rt().block_on(async move {
            let channel = tonic::transport::Channel::from_shared(endpoint).expect("endpoint").connect().await.expect("connect");
            let mut health = HealthClient::new(channel);
            for service in ["", "coadapt.v1.Fleet"] {
                let status = health.check(HealthCheckRequest { service: service.into() }).await.expect("health check").into_inner().status;
                assert_eq!(status, want as i32, "service {service:?}");
            }
        })
    };
    check(ServingStatus::Serving);
    switch.set_serving(false);
    check(ServingStatus::NotServing);
    switch.set_serving(true);
    check(ServingStatus::Serving);
}
