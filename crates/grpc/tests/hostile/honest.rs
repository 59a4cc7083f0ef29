//! What honest actors do passes every check, a refused chunk does not end an honest sender, and
//! our clients register again with a restarted learner.

use super::support::*;

/// What honest actors do (our client, as `actors::role` drives it) passes every check: a
/// training episode restarted from its first step, and an evaluation episode that sends empty
/// chunks for liveness, then its end.
#[test]
fn honest_actors_pass_every_check() {
    let (mut learner, server, endpoint) = common::learner();
    let mut actor = coadapt_grpc::actor_links(&endpoint, 1, &common::cfg()).expect("actor");
    learner.assignments.send(assignment(1, EpisodeMode::Train)).expect("send");
    learner.assignments.send(assignment(2, EpisodeMode::Eval)).expect("send");
    let long = Duration::from_secs(10);
    let chunk =
        |a: u64, rows: usize, first: bool, end: Option<u64>| ExperienceChunk::from_pb(transitions(a, rows, first, end)).expect("chunk");
    assert_eq!(actor.assignments.recv_timeout(long).expect("recv").map(|a| a.id), Some(1));
    // A failed attempt, then the whole episode again from its start.
    actor.experience.send(chunk(1, 4, true, None)).expect("send");
    actor.experience.send(chunk(1, 3, true, None)).expect("send");
    actor.experience.send(chunk(1, 2, false, None)).expect("send");
    actor.experience.send(chunk(1, 0, false, Some(5))).expect("send");
    assert_eq!(actor.assignments.recv_timeout(long).expect("recv").map(|a| a.id), Some(2));
    for _ in 0..5 {
        actor.experience.send(chunk(2, 0, false, None)).expect("send");
    }
    actor.experience.send(chunk(2, 0, false, Some(40))).expect("send");
    let mut got = Vec::new();
    while got.iter().filter(|c: &&ExperienceChunk| c.end.is_some()).count() < 2 {
        got.push(learner.experience.recv_timeout(long).expect("recv").expect("a chunk"));
    }
    let train: Vec<usize> = got.iter().filter(|c| c.assignment == 1).map(|c| c.len()).collect();
    assert_eq!(train, vec![4, 3, 2, 0]);
    assert!(got.iter().filter(|c| c.assignment == 2).count() >= 2, "liveness and the end of the evaluation");
    let r = server.refusals();
    assert_eq!(coadapt_grpc::Refusals { empty_dropped: r.empty_dropped, ..Default::default() }, r, "an honest actor was refused");
}

/// A chunk of an assignment the learner gave to someone else (a late chunk of a predecessor
/// learner's episode whose id was issued again) is refused; our client drops that chunk and
/// its sender goes on working.
#[test]
fn a_refused_chunk_does_not_end_an_honest_sender() {
    let (mut learner, server, endpoint) = common::learner();
    let other = Peer::new(&endpoint, 0x07E, pb::Role::Actor, 2);
    learner.assignments.send(assignment(1, EpisodeMode::Train)).expect("send");
    assert_eq!(other.next_assignment(1000, 0, false).expect("poll").assignment.map(|a| a.id), Some(1));
    let mut actor = coadapt_grpc::actor_links(&endpoint, 1, &common::cfg()).expect("actor");
    let chunk = |a: u64| ExperienceChunk::from_pb(transitions(a, 1, false, None)).expect("chunk");
    actor.experience.send(chunk(1)).expect("queued");
    actor.experience.send(chunk(50)).expect("queued");
    let got = learner.experience.recv_timeout(Duration::from_secs(10)).expect("recv").expect("a chunk");
    assert_eq!(got.assignment, 50, "the refused chunk was delivered, or the next one lost");
    actor.experience.send(chunk(51)).expect("the sender still works");
    assert_eq!(learner.experience.recv_timeout(Duration::from_secs(10)).expect("recv").map(|c| c.assignment), Some(51));
    assert_eq!(server.refusals().foreign_assignment, 1);
}

/// A restarted learner knows no session: our clients register again (same session) and go on,
/// the optimiser's replies included (those sent once it knows the new start: what it sent for
/// the old start is dropped, see run_id.rs).
#[test]
fn clients_register_again_with_a_restarted_learner() {
    let cfg = common::cfg();
    let (learner, server, endpoint) = common::learner();
    let addr = server.local_addr();
    let mut opt = coadapt_grpc::optimizer_links(&endpoint, &cfg).expect("optimizer");
    drop(server);
    drop(learner);
    let (mut learner, server) = coadapt_grpc::serve_learner(addr, &cfg).expect("a new learner on the same port");
    let t = Instant::now();
    while !server.clients().iter().any(|c| c.role == coadapt_grpc::ClientRole::Optimizer) {
        assert!(t.elapsed() < Duration::from_secs(10), "the optimiser did not register again");
        std::thread::sleep(Duration::from_millis(20));
    }
    // Its heartbeat has read the answer (and so the new run id).
    std::thread::sleep(Duration::from_millis(300));
    let reply = coadapt_transport::DesignReply {
        index: 0,
        design: vec![1.0, 2.0],
        method: "pso-q".into(),
        predicted_objective: None,
        design_rollouts: 0,
    };
    opt.replies.send(reply.clone()).expect("send");
    assert_eq!(learner.design_replies.recv_timeout(Duration::from_secs(10)).expect("recv"), Some(reply));
    assert!(server.clients().iter().any(|c| c.role == coadapt_grpc::ClientRole::Optimizer), "the optimiser registered again");
    // Whether a call reached the new learner under the old session first (refused as
    // unregistered) or the client registered as soon as its connection broke is a race; both
    // are right, so `refusals().unregistered` is not asserted (it made this test fail 1 run in 7).
}
