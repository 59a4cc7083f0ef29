//! Measured, not asserted beyond sanity: a 1 MiB weight publish + receive, fan-out to 4
//! readers, and experience throughput (`cargo test --release -p coadapt-shm --test timing --
//! --nocapture` prints them).

use std::time::{Duration, Instant};

use coadapt_shm::{ShmConfig, queue_receiver, queue_sender, topic_publisher, topic_subscriber};
use coadapt_transport::conformance::weights;
use coadapt_transport::{ExperienceChunk, Publisher, Receiver, Sender, Subscriber, Weights};

fn cfg(test: &str) -> ShmConfig {
    ShmConfig { fleet: format!("coadapt-test-{}-{test}", std::process::id()), ..ShmConfig::default() }
}

fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    v[v.len() / 2]
}

#[test]
fn weight_publish_and_receive_of_one_mib() {
    let cfg = cfg("timing-w");
    let mut p = topic_publisher::<Weights>(&cfg, "w").expect("publisher");
    let mut s = topic_subscriber::<Weights>(&cfg, "w").expect("subscriber");
    let mut readers: Vec<_> = (0..3).map(|_| topic_subscriber::<Weights>(&cfg, "w").expect("reader")).collect();
    let n = 1 << 18;
    let msgs: Vec<Weights> = (1..=21).map(|v| weights(v, n)).collect();
    let (mut publish, mut round) = (Vec::new(), Vec::new());
    for m in msgs {
        let v = m.version;
        let t = Instant::now();
        p.publish(m).expect("publish");
        publish.push(t.elapsed());
        let got = s.wait_for(v, Duration::from_secs(5)).expect("wait").expect("weights");
        round.push(t.elapsed());
        assert_eq!(got.policy.len(), n);
        for r in &mut readers {
            assert_eq!(r.wait_for(v, Duration::from_secs(5)).expect("wait").expect("weights").version, v);
        }
    }
    let (publish, round) = (median(publish), median(round));
    eprintln!("1 MiB weights: publish {publish:?}, publish + one reader's decode {round:?} (median of 21)");
    assert!(round < Duration::from_secs(1));
}

#[test]
fn experience_throughput() {
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
    let t = Instant::now();
    for i in 0..total {
        assert_eq!(rx.recv_timeout(Duration::from_secs(10)).expect("receive").expect("chunk").assignment, i);
    }
    let secs = t.elapsed().as_secs_f64();
    drop(producer.join().expect("producer"));
    eprintln!("experience: {:.0} chunks/s of 100 transitions ({:.0} transitions/s)", total as f64 / secs, total as f64 * 100.0 / secs);
}
