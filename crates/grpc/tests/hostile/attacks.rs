//! Attacks 1-10: others' work, invented sessions, poisoned sequence numbers, a flooded queue,
//! empty chunks, lying episode lengths; and an optimiser that crashed mid-search.

use super::support::*;

/// Attack 1: Experience for an assignment is accepted only from the session it was handed to.
#[test]
fn another_sessions_assignment_cannot_be_completed() {
    let (mut learner, server, endpoint) = common::learner();
    let holder = Peer::new(&endpoint, 0xA11CE, pb::Role::Actor, 1);
    let thief = Peer::new(&endpoint, 0xBAD, pb::Role::Actor, 2);
    learner.assignments.send(assignment(1, EpisodeMode::Train)).expect("send");
    let d = holder.next_assignment(1000, 0, false).expect("poll");
    assert_eq!(d.assignment.map(|a| a.id), Some(1));

    // A whole episode (start state, transitions, end) for assignment 1 from another session.
    let answer = thief.push(vec![frame(77, 1, transitions(1, 3, true, Some(3)))]);
    refused("the thief's episode", answer, DENIED, "assignment");
    assert!(drain(&mut learner, Duration::from_millis(300)).is_empty(), "the thief's chunk reached the learner");

    // The holder's own episode passes.
    let (acks, status) = holder.push(vec![frame(5, 1, transitions(1, 3, true, Some(3)))]);
    assert_eq!((acks, status.map(|s| s.code())), (vec![1], None));
    assert_eq!(drain(&mut learner, Duration::from_millis(300)).len(), 1);
    assert_eq!(server.refusals().foreign_assignment, 1);
}

/// Attack 2: Start states cannot be injected for an assignment one does not hold: not while it
/// waits to be handed out, nor by queueing chunks before the learner issues it.
#[test]
fn start_states_cannot_be_injected() {
    let (mut learner, server, endpoint) = common::learner();
    let thief = Peer::new(&endpoint, 0xBAD, pb::Role::Actor, 2);
    learner.assignments.send(assignment(1, EpisodeMode::Train)).expect("send");
    let answer = thief.push(vec![frame(77, 1, transitions(1, 1, true, None))]);
    refused("a start state for an assignment nobody holds yet", answer, DENIED, "assignment");

    // Sequential ids are guessable: chunks for the next one, queued before it is issued.
    let (acks, _) = thief.push(vec![frame(78, 1, transitions(2, 1, true, None))]);
    assert_eq!(acks, vec![1], "an assignment the learner never issued is the learner's to ignore");
    learner.assignments.send(assignment(2, EpisodeMode::Train)).expect("send");
    assert!(
        drain(&mut learner, Duration::from_millis(300)).iter().all(|c| c.assignment != 2),
        "a start state queued before assignment 2 was issued reached the learner after it was"
    );
    assert_eq!(server.refusals().purged, 1);
}

/// Attack 3: Work, heartbeats and queues need a registered session.
#[test]
fn sessions_that_never_registered_get_nothing() {
    let (mut learner, server, endpoint) = common::learner();
    learner.assignments.send(assignment(1, EpisodeMode::Train)).expect("send");
    let req = DesignRequest {
        index: 0,
        kind: DesignKind::Explore,
        weights_version: 0,
        start_states: vec![0.5; 3],
        chosen: Vec::new(),
        rejected: Vec::new(),
    };
    learner.design_requests.send(req).expect("send");

    let ghost = Peer::unregistered(&endpoint, 0x6057, pb::Role::Actor, 9);
    refused_call("an assignment for an invented session", ghost.next_assignment(300, 0, false), &[Code::FailedPrecondition], "register");
    refused_call(
        "a design request for an invented session",
        ghost.next_design_request(300, 0, false),
        &[Code::FailedPrecondition],
        "register",
    );
    refused_call("a heartbeat of an invented session", ghost.beat(pb::Role::Actor, false), &[Code::FailedPrecondition], "register");
    let answer = ghost.push(vec![frame(1, 1, transitions(9, 1, false, None))]);
    refused("experience of an invented session", answer, &[Code::FailedPrecondition], "register");
    let reply = pb::DesignReply { index: 0, design: vec![1.0, 2.0], method: "x".into(), predicted_objective: None, design_rollouts: 0 };
    let answer = ghost.push_replies(vec![pb::DesignReplyFrame { sender: 1, seq: 1, reply: Some(reply), fin: false }]);
    refused("a design reply of an invented session", answer, &[Code::FailedPrecondition], "register");
    assert!(drain(&mut learner, Duration::from_millis(200)).is_empty());
    assert!(server.clients().is_empty(), "a ghost is listed: {:?}", server.clients());

    // The work is still there for registered clients.
    let actor = Peer::new(&endpoint, 0xAC7, pb::Role::Actor, 1);
    assert_eq!(actor.next_assignment(1000, 0, false).expect("poll").assignment.map(|a| a.id), Some(1));
    let opt = Peer::new(&endpoint, 0x097, pb::Role::Optimizer, 0);
    assert_eq!(opt.next_design_request(1000, 0, false).expect("poll").request.map(|r| r.index), Some(0));
    assert!(server.refusals().unregistered >= 5);
}

/// Attack 4: A sender id belongs to the session that used it first: another session's frame
/// with seq u64::MAX does not turn the owner's next frames into "duplicates".
#[test]
fn a_sender_cannot_be_poisoned_by_another_session() {
    let (mut learner, server, endpoint) = common::learner();
    let owner = Peer::new(&endpoint, 0x0111, pb::Role::Actor, 1);
    let thief = Peer::new(&endpoint, 0xBAD, pb::Role::Actor, 2);
    assert_eq!(owner.push(vec![frame(42, 1, transitions(100, 1, false, None))]).0, vec![1]);
    refused(
        "a frame under another session's sender id",
        thief.push(vec![frame(42, u64::MAX, transitions(101, 1, false, None))]),
        DENIED,
        "sender",
    );
    assert_eq!(owner.push(vec![frame(42, 2, transitions(102, 1, false, None))]).0, vec![2]);
    let got: Vec<u64> = drain(&mut learner, Duration::from_millis(300)).iter().map(|c| c.assignment).collect();
    assert_eq!(got, vec![100, 102], "the owner's second frame was lost");
    assert_eq!(server.refusals().foreign_sender, 1);
}

/// Attack 4: A sequence number far beyond the send window is refused, naming `seq`.
#[test]
fn sequence_jumps_beyond_the_window_are_refused() {
    let cfg = common::cfg();
    let (mut learner, server, endpoint) = common::learner_with(&cfg);
    let actor = Peer::new(&endpoint, 0x0111, pb::Role::Actor, 1);
    assert_eq!(actor.push(vec![frame(43, 1, transitions(100, 1, false, None))]).0, vec![1]);
    let jump = 1 + cfg.send_window as u64 + 1;
    refused("a jump past the window", actor.push(vec![frame(43, jump, transitions(101, 1, false, None))]), &[Code::InvalidArgument], "seq");
    assert_eq!(actor.push(vec![frame(43, 2, transitions(102, 1, false, None))]).0, vec![2]);
    let got: Vec<u64> = drain(&mut learner, Duration::from_millis(300)).iter().map(|c| c.assignment).collect();
    assert_eq!(got, vec![100, 102]);
    assert_eq!(server.refusals().seq_jump, 1);
}

/// Attack 5: Leaving is for the session itself: an unregistered session, or a session presented
/// with the other role, neither leaves nor hands back work.
#[test]
fn only_a_session_itself_can_leave() {
    let (mut learner, server, endpoint) = common::learner();
    let actor = Peer::new(&endpoint, 0xAC7, pb::Role::Actor, 1);
    learner.assignments.send(assignment(1, EpisodeMode::Train)).expect("send");
    assert_eq!(actor.next_assignment(1000, 0, false).expect("poll").assignment.map(|a| a.id), Some(1));
    actor.beat(pb::Role::Actor, false).expect("beat");

    let ghost = Peer::unregistered(&endpoint, 0x6057, pb::Role::Actor, 1);
    refused_call("Poll{leaving} of an invented session", ghost.next_assignment(0, 0, true), &[Code::FailedPrecondition], "register");
    refused_call("Beat{leaving} of an invented session", ghost.beat(pb::Role::Actor, true), &[Code::FailedPrecondition], "register");
    // The actor's session with the optimiser's role.
    let imposter = Peer::unregistered(&endpoint, 0xAC7, pb::Role::Optimizer, 1);
    refused_call("Beat{leaving} with the wrong role", imposter.beat(pb::Role::Optimizer, true), DENIED, "role");
    refused_call("a design request poll of an actor's session", imposter.next_design_request(0, 0, true), DENIED, "role");

    assert!(server.actors().iter().all(|a| a.alive), "the actor was made to leave: {:?}", server.actors());
    let other = Peer::new(&endpoint, 0x07E, pb::Role::Actor, 2);
    assert_eq!(other.next_assignment(300, 0, false).expect("poll").assignment, None, "the actor's assignment was handed back");
    assert!(server.refusals().wrong_role >= 2);
}

/// Not an attack, a crash (issue 29): an optimiser killed while it searches holds the design
/// request unconfirmed. The optimiser restarted in its place (a new session) gets that request
/// at its first poll, not after the learner's resend deadline nor after the dead session is
/// forgotten; and it gets it once.
#[test]
fn a_new_optimiser_gets_the_request_a_dead_one_had_taken() {
    let (mut learner, _server, endpoint) = common::learner();
    let req = DesignRequest {
        index: 5,
        kind: DesignKind::Exploit,
        weights_version: 3,
        start_states: vec![0.5; 3],
        chosen: vec![1.0; 3],
        rejected: Vec::new(),
    };
    learner.design_requests.send(req).expect("send");
    let dead = Peer::new(&endpoint, 0x0DEAD, pb::Role::Optimizer, 0);
    let got = dead.next_design_request(1000, 0, false).expect("poll");
    assert_eq!(got.request.as_ref().map(|r| r.index), Some(5));
    // It never polls again (killed mid-search); its successor registers and asks.
    let t = Instant::now();
    let next = Peer::new(&endpoint, 0x0A11CE, pb::Role::Optimizer, 0);
    let got = next.next_design_request(5000, 0, false).expect("poll");
    assert_eq!(got.request.as_ref().map(|r| (r.index, r.weights_version)), Some((5, 3)), "{got:?}");
    assert!(t.elapsed() < Duration::from_secs(2), "waited {:?} for the request", t.elapsed());
    // Confirmed by the new one (it asks for the next): the copy was one item, not two.
    assert_eq!(next.next_design_request(300, got.seq, false).expect("poll").request, None);
}

/// Attack 6: Empty chunks (no transition, no end) reach the learner at most once per heartbeat
/// per episode, so they cannot be used to flood it; the episode's end still passes.
#[test]
fn empty_chunks_pass_at_most_once_per_heartbeat() {
    let cfg = common::cfg();
    let (mut learner, server, endpoint) = common::learner_with(&cfg);
    let actor = Peer::new(&endpoint, 0xAC7, pb::Role::Actor, 1);
    learner.assignments.send(assignment(1, EpisodeMode::Eval)).expect("send");
    assert_eq!(actor.next_assignment(1000, 0, false).expect("poll").assignment.map(|a| a.id), Some(1));
    let n = 50;
    let t = Instant::now();
    let (acks, status) = actor.push((1..=n).map(|seq| frame(7, seq, transitions(1, 0, false, None))).collect());
    let took = t.elapsed();
    assert_eq!((acks.len(), status.map(|s| s.code())), (n as usize, None), "empty chunks are acknowledged");
    let passed = drain(&mut learner, Duration::from_millis(200)).len();
    let allowed = 2 + (took.as_secs_f64() / cfg.heartbeat.as_secs_f64()) as usize;
    assert!(passed <= allowed, "{passed} of {n} empty chunks reached the learner in {took:?} (at most {allowed})");
    let (acks, _) = actor.push(vec![frame(7, n + 1, transitions(1, 0, false, Some(1000)))]);
    assert_eq!(acks, vec![n + 1]);
    let end = drain(&mut learner, Duration::from_millis(300));
    assert!(end.iter().any(|c| c.end.is_some()), "the episode's end did not pass");
    assert!(server.refusals().empty_dropped >= n - allowed as u64);
}

/// Attack 7: The learner's queue holds at most `inbox_max_bytes` of experience: beyond it,
/// frames wait unacknowledged until the learner takes some.
#[test]
fn the_inbox_holds_at_most_its_byte_cap() {
    let cfg = GrpcConfig { inbox_max_bytes: 64 << 10, ..common::cfg() };
    let (mut learner, _server, endpoint) = common::learner_with(&cfg);
    let actor = Peer::new(&endpoint, 0xAC7, pb::Role::Actor, 1);
    let rows = 1000; // about 37 kB a chunk
    let n = 20u64;
    let (tx, rx) = tokio::sync::mpsc::channel(n as usize);
    for seq in 1..=n {
        tx.try_send(frame(8, seq, transitions(1000 + seq, rows, false, None))).expect("queue");
    }
    let req = actor.with_session(tokio_stream::wrappers::ReceiverStream::new(rx));
    let mut c = actor.client.clone();
    let mut acks = rt().block_on(async move { c.push_experience(req).await }).expect("open").into_inner();
    let read_acks = |acks: &mut tonic::Streaming<pb::Ack>, for_: Duration| {
        rt().block_on(async {
            let mut top = 0;
            let until = tokio::time::Instant::now() + for_;
            while let Ok(Ok(Some(a))) = tokio::time::timeout_at(until, acks.message()).await {
                top = top.max(a.acked);
            }
            top
        })
    };
    let held = read_acks(&mut acks, Duration::from_millis(800));
    assert!(held <= 3, "the learner's queue took {held} chunks of about 37 kB with a 64 KiB cap");
    for i in 1..=n {
        let c = learner.experience.recv_timeout(Duration::from_secs(10)).expect("recv").expect("a chunk");
        assert_eq!(c.assignment, 1000 + i);
    }
    assert_eq!(read_acks(&mut acks, Duration::from_millis(500)), n, "every chunk acknowledged once taken");
    drop(tx);
}

/// Attack 8: At most `max_sessions` sessions; silent ones are forgotten and make room.
#[test]
fn sessions_are_capped_and_silent_ones_forgotten() {
    let cfg = GrpcConfig { max_sessions: 8, session_idle_timeout: Duration::from_millis(300), ..common::cfg() };
    let (_learner, server, endpoint) = common::learner_with(&cfg);
    let peers: Vec<Peer> = (0..8).map(|i| Peer::new(&endpoint, 0x5E55 + i, pb::Role::Actor, i)).collect();
    peers[0].register().expect("registering again is not a new session");
    let late = Peer::unregistered(&endpoint, 0x1A7E, pb::Role::Actor, 100);
    refused_call("a session beyond the cap", late.register(), &[Code::ResourceExhausted], "sessions");
    assert_eq!(server.clients().len(), 8);
    std::thread::sleep(Duration::from_millis(900));
    assert!(server.clients().is_empty(), "silent sessions kept: {}", server.clients().len());
    refused_call("a forgotten session", peers[1].next_assignment(0, 0, false), &[Code::FailedPrecondition], "register");
    late.register().expect("room again");
    assert_eq!(server.refusals().sessions_full, 1);
}

/// Attack 9: A connection has at most `max_concurrent_streams` calls open at once.
#[test]
fn streams_per_connection_are_limited() {
    let cfg = GrpcConfig { max_concurrent_streams: 4, rpc_timeout: Duration::from_secs(3), ..common::cfg() };
    let (_learner, _server, endpoint) = common::learner_with(&cfg);
    let actor = Peer::new(&endpoint, 0xAC7, pb::Role::Actor, 1);
    let polls: Vec<_> = (0..4)
        .map(|_| {
            let mut c = actor.client.clone();
            let poll = actor.poll(1500, 0, false);
            rt().spawn(async move { c.next_assignment(poll).await.map(|r| r.into_inner()) })
        })
        .collect();
    std::thread::sleep(Duration::from_millis(300));
    let mut c = actor.client.clone();
    let beat =
        pb::Beat { session: actor.session, role: pb::Role::Actor as i32, actor_id: 1, weights_version: 0, leaving: false, run_id: 0 };
    let fifth = rt().block_on(async move { tokio::time::timeout(Duration::from_millis(400), c.heartbeat(beat)).await });
    assert!(fifth.is_err(), "a fifth call ran beside four open ones on one connection: {fifth:?}");
    for p in polls {
        rt().block_on(p).expect("join").expect("the long polls end normally");
    }
    actor.beat(pb::Role::Actor, false).expect("room again");
}

/// Attack 10: `EpisodeEnd.length` must match what was streamed, and stay below the longest
/// episode.
#[test]
fn episode_lengths_are_checked() {
    let (mut learner, server, endpoint) = common::learner();
    let actor = Peer::new(&endpoint, 0xAC7, pb::Role::Actor, 1);
    learner.assignments.send(assignment(1, EpisodeMode::Train)).expect("send");
    assert_eq!(actor.next_assignment(1000, 0, false).expect("poll").assignment.map(|a| a.id), Some(1));
    assert_eq!(actor.push(vec![frame(9, 1, transitions(1, 2, true, None))]).0, vec![1]);
    refused(
        "length u64::MAX",
        actor.push(vec![frame(9, 2, transitions(1, 1, false, Some(u64::MAX)))]),
        &[Code::InvalidArgument],
        "end.length",
    );
    refused(
        "length 7 for 3 transitions",
        actor.push(vec![frame(9, 2, transitions(1, 1, false, Some(7)))]),
        &[Code::InvalidArgument],
        "end.length",
    );
    assert_eq!(actor.push(vec![frame(9, 2, transitions(1, 1, false, Some(3)))]).0, vec![2]);
    let got = drain(&mut learner, Duration::from_millis(300));
    assert_eq!(got.iter().map(|c| c.len()).collect::<Vec<_>>(), vec![2, 1]);
    assert_eq!(got[1].end.map(|e| e.length), Some(3));
    // An assignment this learner never issued: still no more than the longest episode.
    let too_long = GrpcConfig::default().max_episode_steps + 1;
    refused(
        "an endless episode",
        actor.push(vec![frame(9, 3, transitions(500, 1, false, Some(too_long)))]),
        &[Code::InvalidArgument],
        "end.length",
    );
    assert_eq!(server.refusals().bad_length, 3);
}
