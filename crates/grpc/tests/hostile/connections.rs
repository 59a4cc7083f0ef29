//! Attack 13: connections per peer and in all are limited.

use super::support::*;

/// Attack 13: One host opens connections until the learner runs out of descriptors (tonic has
/// no limit of its own): beyond `max_connections_per_peer` from one address, and beyond
/// `max_connections` in all, a connection is closed as it is accepted and counted; a closed
/// connection gives its place back.
#[test]
fn connections_per_peer_and_in_all_are_limited() {
    let cfg = GrpcConfig { max_connections_per_peer: 3, ..common::cfg() };
    let (_learner, server, endpoint) = common::learner_with(&cfg);
    let mut held: Vec<Peer> = (0..3).map(|i| try_connect_and_register(&endpoint, 0x100 + i).expect("within the limit")).collect();
    let fourth = try_connect_and_register(&endpoint, 0x200);
    assert!(fourth.is_err(), "a fourth connection from one host was served");
    assert!(server.refusals().connections_per_peer >= 1, "{:?}", server.refusals());
    // The three already accepted still work.
    for p in &held {
        p.beat(pb::Role::Actor, false).expect("an accepted connection keeps working");
    }
    drop(held.pop());
    let deadline = Instant::now() + Duration::from_secs(5);
    let again = loop {
        match try_connect_and_register(&endpoint, 0x300) {
            Ok(p) => break p,
            Err(e) if Instant::now() > deadline => panic!("no room after a connection closed: {e}"),
            Err(_) => std::thread::sleep(Duration::from_millis(100)),
        }
    };
    again.beat(pb::Role::Actor, false).expect("works");

    let cfg = GrpcConfig { max_connections: 2, ..common::cfg() };
    let (_learner, server, endpoint) = common::learner_with(&cfg);
    let _two: Vec<Peer> = (0..2).map(|i| try_connect_and_register(&endpoint, 0x400 + i).expect("within the limit")).collect();
    assert!(try_connect_and_register(&endpoint, 0x500).is_err(), "a third connection was served with max_connections = 2");
    assert!(server.refusals().connections_total >= 1, "{:?}", server.refusals());
}
