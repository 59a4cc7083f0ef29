//! The transport conformance suite over gRPC: experience from an actor to the learner's
//! queue, weights from the learner's topic to actors.

use crate::common;

use coadapt_grpc::actor_links;
use coadapt_transport::conformance as c;
use coadapt_transport::{ExperienceChunk, Publisher, Receiver, Sender, Subscriber, Weights};

struct Queue {
    tx: Box<dyn Sender<ExperienceChunk>>,
    rx: Box<dyn Receiver<ExperienceChunk>>,
    _server: coadapt_grpc::LearnerServer,
}

fn queue() -> Queue {
    let (learner, server, endpoint) = common::learner();
    let actor = actor_links(&endpoint, 7, &common::cfg()).expect("actor links");
    Queue { tx: actor.experience, rx: learner.experience, _server: server }
}

struct Topic {
    publisher: Box<dyn Publisher<Weights>>,
    sub: Box<dyn Subscriber<Weights>>,
    endpoint: String,
    _server: coadapt_grpc::LearnerServer,
}

fn topic() -> Topic {
    let (learner, server, endpoint) = common::learner();
    let actor = actor_links(&endpoint, 1, &common::cfg()).expect("actor links");
    Topic { publisher: learner.acting_weights, sub: actor.weights, endpoint, _server: server }
}

#[test]
fn queue_is_ordered_and_lossless() {
    let q = queue();
    c::queue_is_ordered_and_lossless(q.tx, q.rx);
}

#[test]
fn queue_receive_times_out() {
    let q = queue();
    c::queue_receive_times_out(q.tx, q.rx);
}

#[test]
fn queue_drains_then_reports_closed() {
    let q = queue();
    c::queue_drains_then_reports_closed(q.tx, q.rx);
}

#[test]
fn queue_survives_a_slow_reader() {
    let q = queue();
    c::queue_survives_a_slow_reader(q.tx, q.rx);
}

#[test]
fn topic_delivers_newest() {
    let t = topic();
    c::topic_delivers_newest(t.publisher, t.sub);
}

#[test]
fn topic_wakes_a_waiting_reader() {
    let t = topic();
    c::topic_wakes_a_waiting_reader(t.publisher, t.sub);
}

#[test]
fn topic_serves_a_late_joiner() {
    let t = topic();
    let endpoint = t.endpoint.clone();
    c::topic_serves_a_late_joiner(t.publisher, move || actor_links(&endpoint, 2, &common::cfg()).expect("late actor").weights);
}

#[test]
fn topic_refuses_an_old_version() {
    let t = topic();
    c::topic_refuses_an_old_version(t.publisher, t.sub);
}

#[test]
fn topic_reports_a_vanished_publisher() {
    let t = topic();
    c::topic_reports_a_vanished_publisher(t.publisher, t.sub);
}

#[test]
fn population_topic_reaches_the_optimizer() {
    let (learner, _server, endpoint) = common::learner();
    let opt = coadapt_grpc::optimizer_links(&endpoint, &common::cfg()).expect("optimizer links");
    c::topic_delivers_newest(learner.population_weights, opt.weights);
}
