//! Work sharing of assignments and a whole fleet (learner, four actors, optimiser) in threads.

use std::collections::HashSet;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use coadapt_shm::{ShmConfig, actor_links, assignment_receiver, assignment_sender, learner_links, optimizer_links};
use coadapt_transport::conformance::{chunk, weights};
use coadapt_transport::{Assignment, DesignKind, DesignReply, DesignRequest, EpisodeMode, Receiver, Sender, TransportError};

const LONG: Duration = Duration::from_secs(20);

fn cfg(test: &str) -> ShmConfig {
    ShmConfig { fleet: format!("coadapt-test-{}-{test}", std::process::id()), ..ShmConfig::default() }
}

fn assignment(id: u64) -> Assignment {
    Assignment { id, design_index: 0, design: vec![1.0, 2.0], mode: EpisodeMode::Train, seed: id, min_weights_version: 1 }
}

/// Takes assignments until the learner has gone; every one it took goes to `got`.
fn drain_until_closed(mut rx: impl Receiver<Assignment>, actor: u64, got: mpsc::Sender<(u64, u64)>) -> usize {
    let start = Instant::now();
    let mut n = 0;
    loop {
        match rx.recv_timeout(Duration::from_millis(100)) {
            Ok(Some(a)) => {
                n += 1;
                got.send((actor, a.id)).expect("collector");
                std::thread::sleep(Duration::from_millis(1));
            }
            Ok(None) => assert!(start.elapsed() < LONG * 2, "actor {actor} never learned the learner had gone"),
            Err(TransportError::Closed) => return n,
            Err(e) => panic!("actor {actor}: {e}"),
        }
    }
}

#[test]
fn each_assignment_goes_to_exactly_one_of_three_actors() {
    let cfg = cfg("work");
    let mut tx = assignment_sender(&cfg, "asg").expect("sender");
    let (got_tx, got_rx) = mpsc::channel();
    let actors: Vec<_> = (1..=3)
        .map(|id| {
            let rx = assignment_receiver(&cfg, "asg", id).expect("receiver");
            let got = got_tx.clone();
            std::thread::spawn(move || drain_until_closed(rx, id, got))
        })
        .collect();
    drop(got_tx);
    for i in 0..300 {
        tx.send(assignment(i)).expect("send");
    }
    let mut seen = HashSet::new();
    let mut per_actor = [0usize; 4];
    for _ in 0..300 {
        let (actor, id) = got_rx.recv_timeout(LONG).expect("all 300 assignments arrive");
        assert!(seen.insert(id), "assignment {id} delivered twice");
        per_actor[actor as usize] += 1;
    }
    drop(tx);
    let counts: Vec<usize> = actors.into_iter().map(|h| h.join().expect("actor thread")).collect();
    assert_eq!(counts.iter().sum::<usize>(), 300, "no assignment arrived after the 300");
    assert!(got_rx.try_recv().is_err());
    eprintln!("assignments per actor: {:?}", &per_actor[1..]);
    assert!(per_actor[1..].iter().filter(|&&n| n > 0).count() >= 2, "work was not shared: {per_actor:?}");
}

#[test]
fn a_second_actor_with_the_same_id_is_refused() {
    let cfg = cfg("sameid");
    let _first = assignment_receiver(&cfg, "asg", 5).expect("first");
    assert!(assignment_receiver(&cfg, "asg", 5).is_err());
}

#[test]
fn a_fleet_exchanges_every_kind_of_message() {
    let cfg = cfg("fleet");
    let mut learner = learner_links(&cfg).expect("learner links");
    let actors: Vec<_> = (0..4u64)
        .map(|id| {
            let mut links = actor_links(&cfg, id).expect("actor links");
            std::thread::spawn(move || {
                let mut episodes = 0;
                loop {
                    match links.assignments.recv_timeout(Duration::from_millis(100)) {
                        Ok(Some(a)) => {
                            let w = links.weights.wait_for(a.min_weights_version, LONG).expect("weights").expect("in time");
                            assert_eq!(w.policy.len(), 1000);
                            let mut c = chunk(a.id);
                            c.actor = id;
                            c.weights_version = w.version;
                            links.experience.send(c).expect("experience");
                            episodes += 1;
                        }
                        Ok(None) => {}
                        Err(TransportError::Closed) => return episodes,
                        Err(e) => panic!("actor {id}: {e}"),
                    }
                }
            })
        })
        .collect();
    let optimizer = {
        let mut links = optimizer_links(&cfg).expect("optimizer links");
        std::thread::spawn(move || {
            let mut answered = 0;
            loop {
                match links.requests.recv_timeout(Duration::from_millis(100)) {
                    Ok(Some(r)) => {
                        let w = links.weights.wait_for(r.weights_version, LONG).expect("weights").expect("in time");
                        assert_eq!(w.q1.len(), 4);
                        let reply = DesignReply {
                            index: r.index,
                            design: vec![w.version as f32, 0.5],
                            method: "exploit".into(),
                            predicted_objective: Some(1.5),
                            design_rollouts: 0,
                        };
                        links.replies.send(reply).expect("reply");
                        answered += 1;
                    }
                    Ok(None) => {}
                    Err(TransportError::Closed) => return answered,
                    Err(e) => panic!("optimizer: {e}"),
                }
            }
        })
    };

    learner.acting_weights.publish(weights(1, 1000)).expect("acting weights");
    learner.population_weights.publish(weights(1, 500)).expect("population weights");
    for i in 0..12 {
        learner.assignments.send(assignment(i)).expect("assignment");
    }
    let mut ids = HashSet::new();
    for _ in 0..12 {
        let c = learner.experience.recv_timeout(LONG).expect("experience").expect("in time");
        assert!(c.actor < 4 && c.weights_version == 1);
        assert!(ids.insert(c.assignment), "assignment {} ran twice", c.assignment);
    }
    for index in 0..3 {
        learner.population_weights.publish(weights(2 + u64::from(index), 500)).expect("population weights");
        let req = DesignRequest {
            index,
            kind: DesignKind::Exploit,
            weights_version: 2 + u64::from(index),
            start_states: vec![0.0; 6],
            chosen: vec![],
            rejected: vec![1.0; 2 * usize::from(index as u8)],
        };
        learner.design_requests.send(req).expect("design request");
        let reply = learner.design_replies.recv_timeout(LONG).expect("reply").expect("in time");
        assert_eq!((reply.index, reply.design[0]), (index, 2.0 + f32::from(index as u8)));
    }
    drop(learner);
    let episodes: usize = actors.into_iter().map(|h| h.join().expect("actor")).sum();
    assert_eq!(episodes, 12);
    assert_eq!(optimizer.join().expect("optimizer"), 3);
}
