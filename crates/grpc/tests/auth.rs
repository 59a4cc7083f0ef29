//! The fleet's port with TLS and role tokens: a fleet whose peers present the right
//! credentials works; plaintext is refused where TLS is configured; a missing or unknown token
//! is UNAUTHENTICATED; a token of the wrong role is PERMISSION_DENIED (a client's on the
//! experience stream and the population weights, an actor's on the population weights and on
//! registering as an optimiser); mutual TLS refuses a client without a certificate. Refusals
//! are counted. The certificates are made here (coadapt_auth::Credentials), nothing by hand.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use crate::common;

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use coadapt_auth::{ClientAuth, ClientTls, Credentials, Role, ServerAuth, ServerTls, Token, TokenTable, new_token};
use coadapt_grpc::{GrpcConfig, PROTOCOL, actor_links, optimizer_links};
use coadapt_transport::conformance::{chunk, weights};
use coadapt_wire::pb;
use coadapt_wire::pb::fleet_client::FleetClient;
use tonic::Code;

const LONG: Duration = Duration::from_secs(10);

struct Setup {
    dir: PathBuf,
    actor: Token,
    optimizer: Token,
    client: Token,
    tokens: Arc<TokenTable>,
}

fn setup(name: &str) -> Setup {
    let dir = std::env::temp_dir().join(format!("coadapt-auth-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    Credentials::generate(&["localhost".into(), "127.0.0.1".into()], 1).expect("certificates").write(&dir).expect("write");
    let (actor, optimizer, client) = (new_token(), new_token(), new_token());
    let mut t = TokenTable::default();
    t.insert(&actor, Role::Actor);
    t.insert(&optimizer, Role::Optimizer);
    t.insert(&client, Role::Client);
    Setup { dir, actor, optimizer, client, tokens: Arc::new(t) }
}

impl Setup {
    fn server(&self, mutual: bool) -> GrpcConfig {
        let d = &self.dir;
        let tls = ServerTls::load(
            &d.join("server.pem"),
            &d.join("server-key.pem"),
            mutual.then(|| d.join("ca.pem")).as_deref(),
            ("c", "k", "ca"),
        )
        .expect("server tls");
        GrpcConfig { server_auth: ServerAuth { tls: Some(tls), tokens: Some(self.tokens.clone()) }, ..common::cfg() }
    }

    fn client(&self, token: Option<&Token>, certificate: bool) -> GrpcConfig {
        let d = &self.dir;
        let (c, k) = (d.join("client.pem"), d.join("client-key.pem"));
        let tls = ClientTls::load(&d.join("ca.pem"), "", certificate.then_some((c.as_path(), k.as_path())), ("ca", "c", "k"))
            .expect("client tls");
        GrpcConfig { client_auth: ClientAuth { tls: Some(tls), token: token.cloned() }, ..common::cfg() }
    }
}

fn rt() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap()
}

/// A raw Fleet client with `cfg`'s credentials, for calls our links never make.
async fn raw(endpoint: &str, cfg: &GrpcConfig) -> Result<FleetClient<coadapt_auth::AuthChannel>, tonic::transport::Error> {
    let channel = cfg.client_auth.endpoint(endpoint).expect("endpoint").connect_timeout(Duration::from_secs(2)).connect().await?;
    Ok(FleetClient::with_interceptor(channel, cfg.client_auth.bearer()))
}

fn hello(role: pb::Role) -> pb::Hello {
    pb::Hello { fleet: "coadapt".into(), protocol: PROTOCOL, role: role as i32, actor_id: 1, session: 77 }
}

#[test]
fn a_fleet_with_tls_and_tokens_moves_weights_and_experience() {
    let s = setup("fleet");
    let (mut learner, server, endpoint) = common::learner_with(&s.server(false));
    let mut actor = actor_links(&endpoint, 1, &s.client(Some(&s.actor), false)).expect("actor over TLS");
    let mut optimizer = optimizer_links(&endpoint, &s.client(Some(&s.optimizer), false)).expect("optimizer over TLS");
    learner.acting_weights.publish(weights(3, 50)).unwrap();
    learner.population_weights.publish(weights(4, 50)).unwrap();
    assert_eq!(actor.weights.wait_for(3, LONG).unwrap().expect("acting weights").version, 3);
    assert_eq!(optimizer.weights.wait_for(4, LONG).unwrap().expect("population weights").version, 4);
    learner
        .assignments
        .send(coadapt_transport::Assignment {
            id: 1,
            design_index: 0,
            design: vec![1.0],
            mode: coadapt_transport::EpisodeMode::Train,
            seed: 1,
            min_weights_version: 0,
        })
        .unwrap();
    let got = actor.assignments.recv_timeout(LONG).unwrap().expect("an assignment");
    actor.experience.send(chunk(got.id)).unwrap();
    let back = learner.experience.recv_timeout(LONG).unwrap().expect("experience over TLS");
    assert_eq!(back.assignment, 1);
    let r = server.refusals();
    assert_eq!((r.unauthenticated, r.permission_denied), (0, 0), "{r:?}");
}

#[test]
fn plaintext_is_refused_where_tls_is_configured() {
    let s = setup("plain");
    let (_learner, _server, endpoint) = common::learner_with(&s.server(false));
    // Our client without TLS settings: the connection never becomes a session.
    let plain = GrpcConfig { client_auth: ClientAuth { tls: None, token: Some(s.actor.clone()) }, ..common::cfg() };
    assert!(actor_links(&endpoint, 1, &plain).is_err(), "a plaintext actor was accepted");
    rt().block_on(async {
        let mut c = raw(&endpoint, &plain).await.expect("TCP connects");
        let r = tokio::time::timeout(LONG, c.register(hello(pb::Role::Actor))).await.expect("an answer");
        let st = r.expect_err("plaintext Register answered");
        assert_ne!(st.code(), Code::Ok);
        assert!(matches!(st.code(), Code::Unavailable | Code::Unknown | Code::Internal), "{st:?}");
    });
}

#[test]
fn a_missing_or_unknown_token_is_unauthenticated_and_counted() {
    let s = setup("token");
    let (_learner, server, endpoint) = common::learner_with(&s.server(false));
    rt().block_on(async {
        let mut none = raw(&endpoint, &s.client(None, false)).await.unwrap();
        let st = none.register(hello(pb::Role::Actor)).await.expect_err("no token accepted");
        assert_eq!(st.code(), Code::Unauthenticated, "{st:?}");
        assert!(st.message().contains("authorization: missing"), "{st:?}");
        let stranger = Token::new(new_token().expose()).unwrap();
        let mut wrong = raw(&endpoint, &s.client(Some(&stranger), false)).await.unwrap();
        let st = wrong.register(hello(pb::Role::Actor)).await.expect_err("an unknown token accepted");
        assert_eq!(st.code(), Code::Unauthenticated, "{st:?}");
        assert!(!st.message().contains(stranger.expose()), "the token echoed back: {st:?}");
        // Reflection wants a known token too; health answers probes without one.
        let channel = s.client(None, false).client_auth.endpoint(&endpoint).unwrap().connect().await.unwrap();
        let mut health = tonic_health::pb::health_client::HealthClient::new(channel);
        let h = health.check(tonic_health::pb::HealthCheckRequest { service: String::new() }).await.expect("health without a token");
        assert_eq!(h.into_inner().status, tonic_health::pb::health_check_response::ServingStatus::Serving as i32);
    });
    assert_eq!(server.refusals().unauthenticated, 2);
}

#[test]
fn a_token_of_the_wrong_role_is_permission_denied() {
    let s = setup("role");
    let (_learner, server, endpoint) = common::learner_with(&s.server(false));
    rt().block_on(async {
        let watch = |topic: pb::WeightsTopic| pb::WatchRequest { topic: topic as i32, min_version: 0, run_id: 0 };
        // A design client: nothing of the fleet, neither the experience stream nor weights.
        let mut client = raw(&endpoint, &s.client(Some(&s.client), false)).await.unwrap();
        let (tx, rx) = tokio::sync::mpsc::channel::<pb::ExperienceFrame>(1);
        drop(tx);
        let st = client.push_experience(tokio_stream::wrappers::ReceiverStream::new(rx)).await.expect_err("a client pushed experience");
        assert_eq!(st.code(), Code::PermissionDenied, "{st:?}");
        let st = client.watch_weights(watch(pb::WeightsTopic::Population)).await.expect_err("a client took the population");
        assert_eq!(st.code(), Code::PermissionDenied, "{st:?}");
        // An actor: its acting weights, not the population networks, and not an optimiser.
        let mut actor = raw(&endpoint, &s.client(Some(&s.actor), false)).await.unwrap();
        actor.watch_weights(watch(pb::WeightsTopic::Acting)).await.expect("an actor watches the acting weights");
        let st = actor.watch_weights(watch(pb::WeightsTopic::Population)).await.expect_err("an actor took the population");
        assert_eq!(st.code(), Code::PermissionDenied, "{st:?}");
        assert!(st.message().contains("population"), "{st:?}");
        let st = actor.register(hello(pb::Role::Optimizer)).await.expect_err("an actor registered as the optimiser");
        assert_eq!(st.code(), Code::PermissionDenied, "{st:?}");
        actor.register(hello(pb::Role::Actor)).await.expect("an actor registers as an actor");
    });
    assert_eq!(server.refusals().permission_denied, 4, "{:?}", server.refusals());
}

#[test]
fn mutual_tls_refuses_a_client_without_a_certificate() {
    let s = setup("mutual");
    let (mut learner, _server, endpoint) = common::learner_with(&s.server(true));
    rt().block_on(async {
        // The handshake (or the first call) fails without a client certificate.
        let failed = match raw(&endpoint, &s.client(Some(&s.actor), false)).await {
            Err(_) => true,
            Ok(mut c) => c.register(hello(pb::Role::Actor)).await.is_err(),
        };
        assert!(failed, "a client without a certificate got through mutual TLS");
    });
    let mut actor = actor_links(&endpoint, 1, &s.client(Some(&s.actor), true)).expect("an actor with its certificate");
    learner.acting_weights.publish(weights(1, 10)).unwrap();
    assert_eq!(actor.weights.wait_for(1, LONG).unwrap().expect("weights").version, 1);
}
