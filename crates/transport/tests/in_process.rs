//! The conformance suite over the in-process transport.

use coadapt_transport::conformance as c;
use coadapt_transport::in_process::{queue, topic};

fn q() -> (
    Box<dyn coadapt_transport::Sender<coadapt_transport::ExperienceChunk>>,
    Box<dyn coadapt_transport::Receiver<coadapt_transport::ExperienceChunk>>,
) {
    let (tx, rx) = queue();
    (Box::new(tx), Box::new(rx))
}

fn t()
-> (Box<dyn coadapt_transport::Publisher<coadapt_transport::Weights>>, Box<dyn coadapt_transport::Subscriber<coadapt_transport::Weights>>) {
    let (p, s) = topic();
    (Box::new(p), Box::new(s))
}

#[test]
fn queue_is_ordered_and_lossless() {
    let (tx, rx) = q();
    c::queue_is_ordered_and_lossless(tx, rx);
}

#[test]
fn queue_receive_times_out() {
    let (tx, rx) = q();
    c::queue_receive_times_out(tx, rx);
}

#[test]
fn queue_drains_then_reports_closed() {
    let (tx, rx) = q();
    c::queue_drains_then_reports_closed(tx, rx);
}

#[test]
fn queue_survives_a_slow_reader() {
    let (tx, rx) = q();
    c::queue_survives_a_slow_reader(tx, rx);
}

#[test]
fn topic_delivers_newest() {
    let (p, s) = t();
    c::topic_delivers_newest(p, s);
}

#[test]
fn topic_wakes_a_waiting_reader() {
    let (p, s) = t();
    c::topic_wakes_a_waiting_reader(p, s);
}

#[test]
fn topic_serves_a_late_joiner() {
    let (p, s) = topic();
    c::topic_serves_a_late_joiner(Box::new(p), move || Box::new(s.clone()));
}

#[test]
fn topic_refuses_an_old_version() {
    let (p, s) = t();
    c::topic_refuses_an_old_version(p, s);
}

#[test]
fn topic_reports_a_vanished_publisher() {
    let (p, s) = t();
    c::topic_reports_a_vanished_publisher(p, s);
}

#[test]
fn messages_refuse_bad_dimensions_and_non_finite_values() {
    use coadapt_transport::messages::Dims;
    use coadapt_transport::{MessageError, Validate};
    let dims = Dims { obs: 3, act: 2, design: 2 };
    assert_eq!(c::chunk(3).validate(&dims), Ok(()));
    let mut bad = c::chunk(3);
    bad.obs.pop();
    assert!(matches!(bad.validate(&dims), Err(MessageError::Field { field: "obs", .. })));
    let mut nan = c::chunk(3);
    nan.rewards[0] = f32::NAN;
    assert!(matches!(nan.validate(&dims), Err(MessageError::Field { field: "rewards", .. })));
    let mut w = c::weights(1, 4);
    w.q1[2] = f32::INFINITY;
    assert!(matches!(w.validate(&dims), Err(MessageError::Field { field: "q1", .. })));
}
