//! Every message survives encode -> decode unchanged, and malformed bytes are refused with the
//! offending field named, never a panic.

use coadapt_transport::conformance::{chunk, weights};
use coadapt_transport::messages::{Assignment, DesignKind, DesignReply, DesignRequest, EpisodeMode, ExperienceChunk, Weights};
use coadapt_wire::{Limits, Wire, WireError, pb};
use prost::Message;

fn roundtrip<T: Wire + PartialEq + std::fmt::Debug>(m: &T) {
    let bytes = m.encode();
    let back = T::decode(bytes.as_slice(), &Limits::default()).expect("decodes");
    assert_eq!(&back, m);
}

#[test]
fn messages_roundtrip() {
    roundtrip(&weights(3, 1000));
    roundtrip(&chunk(9));
    roundtrip(&Assignment { id: 4, design_index: 2, design: vec![1.0, 1.5], mode: EpisodeMode::Eval, seed: 77, min_weights_version: 5 });
    roundtrip(&DesignRequest {
        index: 6,
        kind: DesignKind::Explore,
        weights_version: 2,
        start_states: vec![0.5; 9],
        chosen: vec![1.0, 2.0],
        rejected: vec![1.5, 0.5],
    });
    roundtrip(&DesignReply {
        index: 6,
        design: vec![1.0, 1.2],
        method: "pso-q".into(),
        predicted_objective: Some(3.5),
        design_rollouts: 0,
    });
}

fn field_of<T: std::fmt::Debug>(r: Result<T, WireError>) -> &'static str {
    r.expect_err("must be refused").field
}

#[test]
fn malformed_messages_name_the_field() {
    let l = Limits::default();
    let mut w = weights(1, 8).to_pb();
    w.q1 = w.q1.slice(..5);
    assert_eq!(field_of(Weights::decode(w.encode_to_vec().as_slice(), &l)), "q1");
    let mut w = weights(1, 8).to_pb();
    w.policy = coadapt_wire::f32_bytes(&[1.0, f32::NAN]);
    assert_eq!(field_of(Weights::decode(w.encode_to_vec().as_slice(), &l)), "policy");

    let mut c = chunk(2).to_pb();
    c.rows = 2;
    assert_eq!(field_of(ExperienceChunk::decode(c.encode_to_vec().as_slice(), &l)), "rewards");
    let mut c = chunk(2).to_pb();
    c.terminated = vec![3u8].into();
    assert_eq!(field_of(ExperienceChunk::decode(c.encode_to_vec().as_slice(), &l)), "terminated");
    let mut c = chunk(2).to_pb();
    c.end = Some(pb::EpisodeEnd { episode_return: f32::INFINITY, length: 3 });
    assert_eq!(field_of(ExperienceChunk::decode(c.encode_to_vec().as_slice(), &l)), "end.episode_return");

    let a = pb::Assignment { mode: 9, ..Default::default() };
    assert_eq!(field_of(Assignment::decode(a.encode_to_vec().as_slice(), &l)), "mode");
    let r = pb::DesignRequest { kind: 1, rejected: vec![1.0, f32::NAN], ..Default::default() };
    assert_eq!(field_of(DesignRequest::decode(r.encode_to_vec().as_slice(), &l)), "rejected");
    let r = pb::DesignReply { predicted_objective: Some(f32::NAN), ..Default::default() };
    assert_eq!(field_of(DesignReply::decode(r.encode_to_vec().as_slice(), &l)), "predicted_objective");

    assert_eq!(field_of(Weights::decode(&[0xffu8, 0xff, 0xff][..], &l)), "message");
    let small = Limits { max_message_bytes: 100 };
    assert_eq!(field_of(Weights::decode(weights(1, 1000).encode().as_slice(), &small)), "message");
}
