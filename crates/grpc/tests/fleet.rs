//! The queues from the learner (assignments, design requests), design replies, how clients
//! end (a learner that finishes vs one that crashes), reconnection, and the actors' status.

use crate::common;

use std::collections::HashSet;
use std::time::{Duration, Instant};

use coadapt_grpc::{actor_links, optimizer_links, serve_learner};
use coadapt_transport::conformance::{chunk, weights};
use coadapt_transport::{Assignment, DesignKind, DesignReply, DesignRequest, EpisodeMode, TransportError};

const LONG: Duration = Duration::from_secs(10);

fn assignment(id: u64) -> Assignment {
    Assignment { id, design_index: 0, design: vec![1.0, id as f32], mode: EpisodeMode::Train, seed: id, min_weights_version: 0 }
}

#[test]
fn assignments_arrive_in_order_and_time_out_when_none() {
    let (mut learner, _server, endpoint) = common::learner();
    let mut actor = actor_links(&endpoint, 1, &common::cfg()).expect("actor");
    for i in 0..50 {
        learner.assignments.send(assignment(i)).expect("send");
    }
    for i in 0..50 {
        assert_eq!(actor.assignments.recv_timeout(LONG).expect("recv"), Some(assignment(i)));
    }
    let t = Instant::now();
    assert_eq!(actor.assignments.recv_timeout(Duration::from_millis(100)).expect("recv"), None);
    let waited = t.elapsed();
    assert!(waited >= Duration::from_millis(90) && waited < Duration::from_secs(2), "waited {waited:?} for a 100 ms timeout");
}

#[test]
fn each_assignment_goes_to_exactly_one_actor() {
    let (mut learner, _server, endpoint) = common::learner();
    let n = 200;
    let actors: Vec<_> = (0..3)
        .map(|id| {
            let mut links = actor_links(&endpoint, id, &common::cfg()).expect("actor");
            std::thread::spawn(move || {
                let mut got = Vec::new();
                loop {
                    match links.assignments.recv_timeout(LONG) {
                        Ok(Some(a)) => got.push(a.id),
                        Err(TransportError::Closed) => return got,
                        other => panic!("actor {id}: {other:?}"),
                    }
                }
            })
        })
        .collect();
    for i in 0..n {
        learner.assignments.send(assignment(i)).expect("send");
    }
    drop(learner);
    let mut all = Vec::new();
    for a in actors {
        let got = a.join().expect("actor thread");
        assert!(got.windows(2).all(|w| w[0] < w[1]), "one actor's assignments out of order");
        all.extend(got);
    }
    let unique: HashSet<u64> = all.iter().copied().collect();
    assert_eq!(all.len(), n as usize, "an assignment was lost or delivered twice");
    assert_eq!(unique.len(), n as usize);
}

#[test]
fn a_learner_that_finishes_ends_its_actors() {
    let (mut learner, server, endpoint) = common::learner();
    let mut actor = actor_links(&endpoint, 1, &common::cfg()).expect("actor");
    learner.acting_weights.publish(weights(1, 10)).expect("publish");
    learner.assignments.send(assignment(1)).expect("send");
    // The learner ends normally before the actor asks: links first, then the server (which
    // waits until the actor's heartbeat has heard). Work nobody took ends with the learner.
    drop(learner);
    drop(server);
    assert!(matches!(actor.assignments.recv_timeout(LONG), Err(TransportError::Closed)), "the fleet finished");
    assert_eq!(actor.weights.wait_for(1, LONG).expect("the last weights").expect("weights").version, 1);
    assert!(matches!(actor.weights.wait_for(2, LONG), Err(TransportError::Closed)), "no newer weights will come");
    let t = Instant::now();
    loop {
        match actor.experience.send(chunk(1)) {
            Err(TransportError::Closed) => break,
            Ok(()) if t.elapsed() < LONG => std::thread::sleep(Duration::from_millis(20)),
            other => panic!("expected the experience sender to close, got {other:?}"),
        }
    }
}

#[test]
fn a_learner_that_crashes_leaves_its_actors_waiting() {
    let (learner, server, endpoint) = common::learner();
    let mut actor = actor_links(&endpoint, 1, &common::cfg()).expect("actor");
    drop(server);
    drop(learner);
    for _ in 0..3 {
        assert_eq!(actor.assignments.recv_timeout(Duration::from_millis(200)).expect("a soft failure"), None);
        assert!(actor.weights.wait_for(1, Duration::from_millis(200)).expect("a soft failure").is_none());
    }
}

#[test]
fn design_requests_and_replies_round_trip() {
    let (mut learner, _server, endpoint) = common::learner();
    let mut opt = optimizer_links(&endpoint, &common::cfg()).expect("optimizer");
    let req = DesignRequest {
        index: 3,
        kind: DesignKind::Exploit,
        weights_version: 2,
        start_states: vec![0.5; 6],
        chosen: vec![1.0, 2.0],
        rejected: vec![2.0, 1.0],
    };
    learner.design_requests.send(req.clone()).expect("send");
    assert_eq!(opt.requests.recv_timeout(LONG).expect("recv"), Some(req));
    let reply =
        DesignReply { index: 3, design: vec![1.5, 2.5], method: "pso-q".into(), predicted_objective: Some(4.0), design_rollouts: 0 };
    opt.replies.send(reply.clone()).expect("send");
    assert_eq!(learner.design_replies.recv_timeout(LONG).expect("recv"), Some(reply));
    // A reply the learner would refuse is refused at the optimiser already.
    let bad = DesignReply { index: 4, design: vec![f32::NAN, 1.0], method: "x".into(), predicted_objective: None, design_rollouts: 0 };
    assert!(matches!(opt.replies.send(bad), Err(TransportError::Invalid(m)) if m.contains("design")));
    drop(learner.design_requests);
    assert!(matches!(opt.requests.recv_timeout(LONG), Err(TransportError::Closed)));
    drop(opt);
    assert!(matches!(learner.design_replies.recv_timeout(LONG), Err(TransportError::Closed)), "the optimiser left cleanly");
}

#[test]
fn the_learner_sees_its_actors_and_their_weights_version() {
    let (mut learner, server, endpoint) = common::learner();
    let mut a = actor_links(&endpoint, 11, &common::cfg()).expect("actor");
    let _b = actor_links(&endpoint, 12, &common::cfg()).expect("actor");
    learner.acting_weights.publish(weights(3, 10)).expect("publish");
    assert_eq!(a.weights.wait_for(3, LONG).expect("wait").expect("weights").version, 3);
    std::thread::sleep(Duration::from_millis(300));
    let actors = server.actors();
    assert_eq!(actors.iter().map(|s| s.id).collect::<Vec<_>>(), vec![11, 12]);
    assert!(actors.iter().all(|s| s.alive));
    assert_eq!(actors[0].weights_version, 3, "actor 11 acts with version 3");
    assert_eq!(actors[1].weights_version, 0, "actor 12 has not asked for weights");
    drop(a);
    std::thread::sleep(Duration::from_millis(100));
    assert!(!server.actors()[0].alive, "actor 11 left");
}

/// The server goes away and comes back for the same learner start (the same run id): clients
/// keep what they hold and resend what was not acknowledged. (A new start, with another run id,
/// is `run_id.rs`'s: there they drop it.)
#[test]
fn actors_reconnect_to_a_restarted_learner() {
    let cfg = coadapt_grpc::GrpcConfig { run_id: Some(0x5A3E_0001), ..common::cfg() };
    let (mut learner, server, endpoint) = common::learner_with(&cfg);
    let addr = server.local_addr();
    let mut actor = actor_links(&endpoint, 5, &cfg).expect("actor");
    learner.acting_weights.publish(weights(1, 100)).expect("publish");
    assert_eq!(actor.weights.wait_for(1, LONG).expect("wait").expect("weights").version, 1);
    for i in 0..10 {
        actor.experience.send(chunk(i)).expect("send");
    }
    for i in 0..10 {
        assert_eq!(learner.experience.recv_timeout(LONG).expect("recv"), Some(chunk(i)));
    }
    // Let the acknowledgements reach the actor: a learner that crashes between storing a
    // chunk and acknowledging it gets that chunk again from its successor.
    std::thread::sleep(Duration::from_millis(200));

    // The learner crashes (server first, so nothing tells the actor the fleet finished).
    drop(server);
    drop(learner);
    assert_eq!(actor.assignments.recv_timeout(Duration::from_millis(300)).expect("soft"), None);
    assert!(actor.weights.wait_for(2, Duration::from_millis(300)).expect("soft").is_none());
    for i in 10..15 {
        actor.experience.send(chunk(i)).expect("accepted into the window while the learner is away");
    }

    let (mut learner, server) = serve_learner(addr, &cfg).expect("the same learner start on the same port");
    for v in 2..=5 {
        learner.acting_weights.publish(weights(v, 100)).expect("publish");
    }
    assert_eq!(actor.weights.wait_for(2, LONG).expect("wait").expect("weights").version, 5, "the newest after the restart");
    for i in 10..15 {
        assert_eq!(learner.experience.recv_timeout(LONG).expect("recv"), Some(chunk(i)), "chunk {i} after the restart");
    }
    assert_eq!(learner.experience.recv_timeout(Duration::from_millis(200)).expect("recv"), None, "nothing twice");
    learner.assignments.send(assignment(9)).expect("send");
    assert_eq!(actor.assignments.recv_timeout(LONG).expect("recv"), Some(assignment(9)));
    std::thread::sleep(Duration::from_millis(300));
    assert_eq!(server.actors().iter().map(|s| s.id).collect::<Vec<_>>(), vec![5], "heartbeats registered the actor again");
}

#[test]
fn a_client_of_another_fleet_is_refused() {
    let (_learner, _server, endpoint) = common::learner();
    let other = coadapt_grpc::GrpcConfig { fleet: "another".into(), ..common::cfg() };
    match actor_links(&endpoint, 1, &other) {
        Err(TransportError::Invalid(m)) => assert!(m.contains("another"), "{m}"),
        Err(e) => panic!("expected Invalid, got {e:?}"),
        Ok(_) => panic!("expected Invalid, got links"),
    }
}

#[test]
fn an_unreachable_learner_fails_within_the_connect_timeout() {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    let addr = listener.local_addr().expect("addr");
    drop(listener);
    let cfg = coadapt_grpc::GrpcConfig { connect_timeout: Duration::from_millis(500), ..common::cfg() };
    let t = Instant::now();
    assert!(matches!(actor_links(&format!("http://{addr}"), 1, &cfg), Err(TransportError::Io(_))));
    assert!(t.elapsed() < Duration::from_secs(3), "took {:?}", t.elapsed());
}
