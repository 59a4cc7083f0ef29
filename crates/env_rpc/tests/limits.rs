//! A robot server's limits against a peer that opens worlds or connections in a loop: what is
//! beyond them is refused and counted, and what was accepted goes on.

use std::io::Read;
use std::net::TcpStream;
use std::time::{Duration, Instant};

use coadapt_core::Env;
use coadapt_env_rpc::{BackgroundServer, EnvFactory, RemoteEnv, RemoteOptions, ServerLimits};

fn pendulum() -> EnvFactory {
    coadapt_env_rpc::plain(|| coadapt_robots::make("pendulum").map_err(|e| e.to_string()))
}

fn quick() -> RemoteOptions {
    RemoteOptions {
        connect_timeout: Duration::from_millis(500),
        request_timeout: Duration::from_millis(500),
        reconnect_for: Duration::from_millis(300),
        max_backoff: Duration::from_millis(100),
        ..RemoteOptions::default()
    }
}

fn one_step(env: &mut RemoteEnv) {
    let design = env.spec().default_design.clone();
    env.reset(1, &design).expect("reset of an accepted world");
    let action = vec![0.0; env.spec().action.dim()];
    env.step(&action).expect("step of an accepted world");
}

#[test]
fn worlds_beyond_max_worlds_are_refused_and_the_accepted_ones_go_on() {
    let limits = ServerLimits { max_worlds: 2, ..ServerLimits::default() };
    let server = BackgroundServer::start_limited("127.0.0.1:0", pendulum(), Default::default(), limits).unwrap();
    let mut a = RemoteEnv::connect(&server.url(), quick()).unwrap();
    let mut b = RemoteEnv::connect(&server.url(), quick()).unwrap();
    let err = RemoteEnv::connect(&server.url(), quick()).expect_err("a third world on a server of two");
    let msg = err.to_string();
    assert!(msg.contains("max-worlds"), "the refusal names the limit: {msg}");
    assert!(server.refusals().worlds >= 1, "{:?}", server.refusals());
    assert_eq!(server.world_count(), 2);
    one_step(&mut a);
    one_step(&mut b);
    // A client that goes away frees its world for the next.
    drop(a);
    let t = Instant::now();
    let mut c = loop {
        match RemoteEnv::connect(&server.url(), quick()) {
            Ok(c) => break c,
            Err(e) => assert!(t.elapsed() < Duration::from_secs(5), "the closed client's world was not freed: {e}"),
        }
    };
    one_step(&mut c);
    one_step(&mut b);
}

/// True when the server closed `s` (EOF or a reset) within `within`; false when it stays open.
fn closed_by_server(s: &mut TcpStream, within: Duration) -> bool {
    if s.set_read_timeout(Some(within)).is_err() {
        return true;
    }
    let mut buf = [0u8; 64];
    loop {
        match s.read(&mut buf) {
            Ok(0) => return true,
            // An HTTP/2 server speaks first (its SETTINGS frame): keep reading.
            Ok(_) => continue,
            Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => return false,
            Err(_) => return true,
        }
    }
}

#[test]
fn connections_beyond_the_per_peer_limit_are_closed_as_accepted_and_counted() {
    let limits = ServerLimits { max_connections_per_peer: 2, ..ServerLimits::default() };
    let server = BackgroundServer::start_limited("127.0.0.1:0", pendulum(), Default::default(), limits).unwrap();
    let mut first = TcpStream::connect(server.addr).unwrap();
    let mut second = TcpStream::connect(server.addr).unwrap();
    let mut third = TcpStream::connect(server.addr).unwrap();
    assert!(closed_by_server(&mut third, Duration::from_secs(5)), "a third connection from one host was kept");
    assert!(!closed_by_server(&mut first, Duration::from_millis(300)), "the first connection was closed");
    assert!(!closed_by_server(&mut second, Duration::from_millis(300)), "the second connection was closed");
    assert_eq!(server.refusals().connections_per_peer, 1, "{:?}", server.refusals());
    // Closing one makes room again (here for a real client).
    drop(first);
    let t = Instant::now();
    let mut env = loop {
        match RemoteEnv::connect(&server.url(), quick()) {
            Ok(e) => break e,
            Err(e) => assert!(t.elapsed() < Duration::from_secs(5), "no room after a connection closed: {e}"),
        }
    };
    one_step(&mut env);
}
