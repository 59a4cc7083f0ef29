//! The transport conformance suite over shared-memory queues and topics. Each test has its own
//! fleet name, so they run in parallel without meeting.

use coadapt_shm::{ShmConfig, queue_receiver, queue_sender, topic_publisher, topic_subscriber};
use coadapt_transport::conformance as c;
use coadapt_transport::{ExperienceChunk, Publisher, Receiver, Sender, Subscriber, Weights};

fn cfg(test: &str) -> ShmConfig {
    ShmConfig { fleet: format!("coadapt-test-{}-{test}", std::process::id()), ..ShmConfig::default() }
}

fn q(test: &str) -> (Box<dyn Sender<ExperienceChunk>>, Box<dyn Receiver<ExperienceChunk>>) {
    let cfg = cfg(test);
    let rx = queue_receiver(&cfg, "q").expect("receiver");
    let tx = queue_sender(&cfg, "q").expect("sender");
    (Box::new(tx), Box::new(rx))
}

fn t(test: &str) -> (Box<dyn Publisher<Weights>>, Box<dyn Subscriber<Weights>>) {
    let cfg = cfg(test);
    let p = topic_publisher(&cfg, "w").expect("publisher");
    let s = topic_subscriber(&cfg, "w").expect("subscriber");
    (Box::new(p), Box::new(s))
}

#[test]
fn queue_is_ordered_and_lossless() {
    let (tx, rx) = q("ordered");
    c::queue_is_ordered_and_lossless(tx, rx);
}

#[test]
fn queue_receive_times_out() {
    let (tx, rx) = q("timeout");
    c::queue_receive_times_out(tx, rx);
}

#[test]
fn queue_drains_then_reports_closed() {
    let (tx, rx) = q("drains");
    c::queue_drains_then_reports_closed(tx, rx);
}

#[test]
fn queue_survives_a_slow_reader() {
    let (tx, rx) = q("slow");
    c::queue_survives_a_slow_reader(tx, rx);
}

/// The slow-reader test again with a buffer far smaller than the traffic, so the sender really
/// blocks on a full buffer and is woken by the reader.
#[test]
fn queue_survives_a_slow_reader_with_a_tiny_buffer() {
    let cfg = ShmConfig { queue_depth: 4, ..cfg("tiny") };
    let rx = queue_receiver(&cfg, "q").expect("receiver");
    let tx = queue_sender(&cfg, "q").expect("sender");
    c::queue_survives_a_slow_reader(Box::new(tx), Box::new(rx));
}

#[test]
fn topic_delivers_newest() {
    let (p, s) = t("newest");
    c::topic_delivers_newest(p, s);
}

#[test]
fn topic_wakes_a_waiting_reader() {
    let (p, s) = t("wakes");
    c::topic_wakes_a_waiting_reader(p, s);
}

#[test]
fn topic_serves_a_late_joiner() {
    let cfg = cfg("late");
    let p = topic_publisher(&cfg, "w").expect("publisher");
    c::topic_serves_a_late_joiner(Box::new(p), move || Box::new(topic_subscriber::<Weights>(&cfg, "w").expect("late subscriber")));
}

#[test]
fn topic_refuses_an_old_version() {
    let (p, s) = t("old");
    c::topic_refuses_an_old_version(p, s);
}

#[test]
fn topic_reports_a_vanished_publisher() {
    let (p, s) = t("vanished");
    c::topic_reports_a_vanished_publisher(p, s);
}

/// A sender with no receiver reports `Closed` after the connect timeout instead of losing the
/// message.
#[test]
fn a_sender_without_receiver_reports_closed() {
    let cfg = ShmConfig { connect_timeout: std::time::Duration::from_millis(200), ..cfg("noreceiver") };
    let mut tx = queue_sender::<ExperienceChunk>(&cfg, "q").expect("sender");
    let t = std::time::Instant::now();
    assert!(matches!(tx.send(c::chunk(0)), Err(coadapt_transport::TransportError::Closed)));
    assert!(t.elapsed() >= std::time::Duration::from_millis(190));
}
