//! Larger volumes than the conformance suite: 1 MiB weights fanned out to four readers, 5,000
//! HalfCheetah-sized chunks in order from another thread. Speed is `coadapt bench transport`'s
//! business (BENCHMARKS.md).

use std::time::Duration;

use coadapt_shm::{ShmConfig, queue_receiver, queue_sender, topic_publisher, topic_subscriber};
use coadapt_transport::conformance::weights;
use coadapt_transport::{ExperienceChunk, Publisher, Receiver, Sender, Subscriber, Weights};

fn cfg(test: &str) -> ShmConfig {
    ShmConfig { fleet: format!("coadapt-test-{}-{test}", std::process::id()), ..ShmConfig::default() }
}

#[test]
fn one_mib_of_weights_reaches_every_reader() {
    let cfg = cfg("timing-w");
    let mut p = topic_publisher::<Weights>(&cfg, "w").expect("publisher");
    let mut s = topic_subscriber::<Weights>(&cfg, "w").expect("subscriber");
    let mut readers: Vec<_> = (0..3).map(|_| topic_subscriber::<Weights>(&cfg, "w").expect("reader")).collect();
    let n = 1 << 18;
    let msgs: Vec<Weights> = (1..=21).map(|v| weights(v, n)).collect();
    for m in msgs {
        let v = m.version;
        let expected = m.clone();
        p.publish(m).expect("publish");
        let got = s.wait_for(v, Duration::from_secs(5)).expect("wait").expect("weights");
        assert_eq!(*got, expected, "every value of a 1 MiB publish arrives intact");
        for r in &mut readers {
            assert_eq!(r.wait_for(v, Duration::from_secs(5)).expect("wait").expect("weights").version, v);
        }
    }
}

#[test]
fn five_thousand_chunks_arrive_in_order_from_another_thread() {
    let cfg = cfg("timing-q");
    let mut rx = queue_receiver::<ExperienceChunk>(&cfg, "q").expect("receiver");
    let mut tx = queue_sender::<ExperienceChunk>(&cfg, "q").expect("sender");
    // 100 transitions of HalfCheetah with its 6-wide design: obs 23, act 6.
    let chunk = ExperienceChunk {
        obs: vec![0.5; 2300],
        next_obs: vec![0.5; 2300],
        actions: vec![0.1; 600],
        rewards: vec![1.0; 100],
        terminated: vec![false; 100],
        ..ExperienceChunk::default()
    };
    let total = 5000;
    let producer = std::thread::spawn(move || {
        for i in 0..total {
            tx.send(ExperienceChunk { assignment: i, ..chunk.clone() }).expect("send");
        }
        tx
    });
    for i in 0..total {
        assert_eq!(rx.recv_timeout(Duration::from_secs(10)).expect("receive").expect("chunk").assignment, i);
    }
    drop(producer.join().expect("producer"));
}
