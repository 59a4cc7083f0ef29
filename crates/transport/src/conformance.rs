//! What every transport must do, as functions over boxed channel ends; each implementation's
//! test file calls every one of them with its own channels. They panic (assert) on a
//! violation, like any test.

use std::time::{Duration, Instant};

use crate::messages::{EpisodeEnd, ExperienceChunk, Weights};
use crate::traits::{Publisher, Receiver, Sender, Subscriber, TransportError};

const SHORT: Duration = Duration::from_millis(50);
const LONG: Duration = Duration::from_secs(10);

/// A one-transition chunk tagged `i` (obs 3, act 2).
pub fn chunk(i: u64) -> ExperienceChunk {
    let x = i as f32;
    ExperienceChunk {
        actor: 7,
        assignment: i,
        design_index: 0,
        weights_version: i,
        first: i == 0,
        obs: vec![x, x + 0.5, -x],
        actions: vec![0.25, -0.25],
        rewards: vec![x * 0.1],
        next_obs: vec![x + 1.0, x, 0.0],
        terminated: vec![false],
        end: (i % 10 == 9).then_some(EpisodeEnd { episode_return: x, length: 10 }),
    }
}

/// Weights of `version`, `n` values.
pub fn weights(version: u64, n: usize) -> Weights {
    let v = version as f32;
    Weights { version, policy: (0..n).map(|i| v + i as f32 * 1e-3).collect(), q1: vec![v; 4], q2: vec![-v; 4], heads: vec![] }
}

/// Every accepted chunk arrives, once, in order, intact.
pub fn queue_is_ordered_and_lossless(mut tx: Box<dyn Sender<ExperienceChunk>>, mut rx: Box<dyn Receiver<ExperienceChunk>>) {
    let n = 1000;
    for i in 0..n {
        tx.send(chunk(i)).expect("send accepted");
    }
    for i in 0..n {
        let got = rx.recv_timeout(LONG).expect("receive").expect("a chunk within the timeout");
        assert_eq!(got, chunk(i), "chunk {i} arrived out of order or changed");
    }
    assert!(rx.recv_timeout(SHORT).expect("receive").is_none(), "a chunk arrived twice");
}

/// An empty queue times out after about the timeout, neither at once nor never.
pub fn queue_receive_times_out(_tx: Box<dyn Sender<ExperienceChunk>>, mut rx: Box<dyn Receiver<ExperienceChunk>>) {
    let t = Instant::now();
    assert!(rx.recv_timeout(Duration::from_millis(100)).expect("receive").is_none());
    let waited = t.elapsed();
    assert!(waited >= Duration::from_millis(90) && waited < Duration::from_secs(5), "waited {waited:?} for a 100 ms timeout");
}

/// When the sender is gone, what it sent is still delivered, then the receiver learns the
/// channel is closed.
pub fn queue_drains_then_reports_closed(mut tx: Box<dyn Sender<ExperienceChunk>>, mut rx: Box<dyn Receiver<ExperienceChunk>>) {
    tx.send(chunk(1)).expect("send");
    tx.send(chunk(2)).expect("send");
    drop(tx);
    assert_eq!(rx.recv_timeout(LONG).expect("receive"), Some(chunk(1)));
    assert_eq!(rx.recv_timeout(LONG).expect("receive"), Some(chunk(2)));
    let t = Instant::now();
    loop {
        match rx.recv_timeout(SHORT) {
            Err(TransportError::Closed) => break,
            Ok(None) if t.elapsed() < LONG => continue,
            other => panic!("expected Closed after the sender left, got {other:?}"),
        }
    }
}

/// A producer on another thread while the consumer is slow: nothing lost, order kept.
pub fn queue_survives_a_slow_reader(tx: Box<dyn Sender<ExperienceChunk>>, mut rx: Box<dyn Receiver<ExperienceChunk>>) {
    let n = 200;
    let producer = std::thread::spawn(move || {
        let mut tx = tx;
        for i in 0..n {
            tx.send(chunk(i)).expect("send");
        }
        tx
    });
    for i in 0..n {
        if i % 50 == 0 {
            std::thread::sleep(Duration::from_millis(20));
        }
        let got = rx.recv_timeout(LONG).expect("receive").expect("chunk");
        assert_eq!(got.assignment, i);
    }
    drop(producer.join().expect("producer thread"));
}

/// A reader sees the newest version, never an older one, and a slow reader skips versions.
pub fn topic_delivers_newest(mut publisher: Box<dyn Publisher<Weights>>, mut sub: Box<dyn Subscriber<Weights>>) {
    for v in 1..=5 {
        publisher.publish(weights(v, 1000)).expect("publish");
    }
    let got = sub.wait_for(1, LONG).expect("wait").expect("weights");
    assert_eq!(*got, weights(5, 1000), "a reader arriving after five publishes sees the fifth");
    assert!(sub.wait_for(6, SHORT).expect("wait").is_none(), "no version 6 yet");
    publisher.publish(weights(6, 1000)).expect("publish");
    assert_eq!(sub.wait_for(6, LONG).expect("wait").expect("weights").version, 6);
}

/// A reader waiting for a version is woken when it is published from another thread.
pub fn topic_wakes_a_waiting_reader(publisher: Box<dyn Publisher<Weights>>, mut sub: Box<dyn Subscriber<Weights>>) {
    let t = std::thread::spawn(move || {
        let mut p = publisher;
        std::thread::sleep(Duration::from_millis(100));
        p.publish(weights(3, 10)).expect("publish");
        p
    });
    let got = sub.wait_for(3, LONG).expect("wait").expect("woken with the new version");
    assert_eq!(got.version, 3);
    drop(t.join().expect("publisher thread"));
}

/// A reader that joins after the publish still gets the newest value.
pub fn topic_serves_a_late_joiner(mut publisher: Box<dyn Publisher<Weights>>, late: impl FnOnce() -> Box<dyn Subscriber<Weights>>) {
    publisher.publish(weights(7, 100)).expect("publish");
    let mut sub = late();
    assert_eq!(sub.wait_for(0, LONG).expect("wait").expect("weights").version, 7);
}

/// Versions only move forward.
pub fn topic_refuses_an_old_version(mut publisher: Box<dyn Publisher<Weights>>, mut sub: Box<dyn Subscriber<Weights>>) {
    publisher.publish(weights(4, 10)).expect("publish");
    assert!(publisher.publish(weights(4, 10)).is_err(), "republishing a version must fail");
    assert!(publisher.publish(weights(2, 10)).is_err(), "an older version must fail");
    assert_eq!(sub.wait_for(0, LONG).expect("wait").expect("weights").version, 4);
}

/// When the publisher disappears, a reader waiting for a newer version learns it.
pub fn topic_reports_a_vanished_publisher(publisher: Box<dyn Publisher<Weights>>, mut sub: Box<dyn Subscriber<Weights>>) {
    drop(publisher);
    let t = Instant::now();
    loop {
        match sub.wait_for(1, SHORT) {
            Err(TransportError::Closed) => break,
            Ok(None) if t.elapsed() < LONG => continue,
            other => panic!("expected Closed after the publisher left, got {other:?}"),
        }
    }
}
