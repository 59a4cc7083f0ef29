//! A robot served across machines: dm_env_rpc over TLS with role tokens. An actor with the CA
//! and its token steps the robot as in process; a plaintext client, a client without a token
//! and a token of another role are refused at connect, each with the reason.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::sync::Arc;
use std::time::Duration;

use coadapt_auth::{ClientAuth, ClientTls, Credentials, Role, ServerAuth, ServerTls, Token, TokenTable, new_token};
use coadapt_core::Env;
use coadapt_core::conformance::trace;
use coadapt_env_rpc::{BackgroundServer, EnvFactory, RemoteEnv, RemoteOptions};

fn robot() -> EnvFactory {
    coadapt_env_rpc::plain(|| coadapt_robots::make("pendulum").map_err(|e| e.to_string()))
}

fn options(auth: ClientAuth) -> RemoteOptions {
    RemoteOptions {
        connect_timeout: Duration::from_secs(2),
        request_timeout: Duration::from_secs(2),
        reconnect_for: Duration::from_secs(1),
        max_backoff: Duration::from_millis(200),
        auth,
        ..RemoteOptions::default()
    }
}

#[test]
fn a_robot_over_tls_answers_only_actors_with_their_token() {
    let dir = std::env::temp_dir().join(format!("coadapt-env-auth-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    Credentials::generate(&["localhost".into(), "127.0.0.1".into()], 1).unwrap().write(&dir).unwrap();
    let (actor, client) = (new_token(), new_token());
    let mut table = TokenTable::default();
    table.insert(&actor, Role::Actor);
    table.insert(&client, Role::Client);
    let tls = ServerTls::load(&dir.join("server.pem"), &dir.join("server-key.pem"), None, ("c", "k", "ca")).unwrap();
    let server =
        BackgroundServer::start_with("127.0.0.1:0", robot(), ServerAuth { tls: Some(tls), tokens: Some(Arc::new(table)) }).unwrap();
    let ca = || Some(ClientTls::load(&dir.join("ca.pem"), "", None, ("ca", "c", "k")).unwrap());
    let with = |token: Option<&Token>| options(ClientAuth { tls: ca(), token: token.cloned() });

    // The actor: the same episode as in process.
    let mut remote = RemoteEnv::connect(&server.url(), with(Some(&actor))).expect("an actor over TLS");
    let mut local = coadapt_robots::make("pendulum").unwrap();
    let design = local.spec().default_design.clone();
    assert_eq!(trace(&mut remote, 3, &design, 3, 200).unwrap(), trace(&mut *local, 3, &design, 3, 200).unwrap());

    let refused = |o: RemoteOptions| match RemoteEnv::connect(&server.url(), o) {
        Ok(_) => panic!("connected"),
        Err(e) => e.to_string(),
    };
    let e = refused(options(ClientAuth { tls: None, token: Some(actor.clone()) }));
    assert!(e.contains("refused the stream") || e.contains("connect"), "plaintext: {e}");
    let e = refused(with(None));
    assert!(e.contains("Unauthenticated") && e.contains("authorization: missing"), "no token: {e}");
    let e = refused(with(Some(&client)));
    assert!(e.contains("PermissionDenied") && e.contains("role client"), "a client token: {e}");
    assert!(!e.contains(client.expose()), "the token is in the error: {e}");
}
