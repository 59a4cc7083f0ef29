//! Property tests of the fleet messages' byte encoding: arbitrary valid messages survive
//! encode -> decode unchanged (and validate against the dimensions they were built for),
//! arbitrary and corrupted bytes never panic a decoder, and a truncated encoding is refused or,
//! when cut exactly between two fields (protobuf has no end marker), decodes to a message that
//! is not the original.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_transport::messages::{
    Assignment, DesignKind, DesignReply, DesignRequest, Dims, EpisodeEnd, EpisodeMode, ExperienceChunk, Validate, Weights,
};
use coadapt_wire::{Limits, Wire, pb};
use proptest::collection::vec;
use proptest::prelude::*;
use prost::Message;

/// Finite f32 values of every class (normal, subnormal, zero; both signs).
fn finite() -> impl Strategy<Value = f32> {
    prop::num::f32::POSITIVE | prop::num::f32::NEGATIVE | prop::num::f32::NORMAL | prop::num::f32::SUBNORMAL | prop::num::f32::ZERO
}

fn floats(len: impl Into<prop::collection::SizeRange>) -> impl Strategy<Value = Vec<f32>> {
    vec(finite(), len)
}

fn weights() -> impl Strategy<Value = Weights> {
    (any::<u64>(), floats(1..64), 0..32usize, 0..3usize)
        .prop_flat_map(|(version, policy, k, h)| (Just(version), Just(policy), floats(k), floats(k), vec(floats(k), h)))
        .prop_map(|(version, policy, q1, q2, heads)| Weights { version, policy, q1, q2, heads })
}

fn assignment(design: usize) -> impl Strategy<Value = Assignment> {
    (any::<u64>(), any::<u32>(), floats(design), prop_oneof![Just(EpisodeMode::Train), Just(EpisodeMode::Eval)], any::<u64>(), any::<u64>())
        .prop_map(|(id, design_index, design, mode, seed, min_weights_version)| Assignment {
            id,
            design_index,
            design,
            mode,
            seed,
            min_weights_version,
        })
}

/// A chunk of `rows` transitions of a robot with observation width `obs` and action width `act`.
fn chunk(obs: usize, act: usize) -> impl Strategy<Value = ExperienceChunk> {
    (0..24usize)
        .prop_flat_map(move |rows| {
            (
                (any::<u64>(), any::<u64>(), any::<u32>(), any::<u64>(), any::<bool>()),
                (floats(rows * obs), floats(rows * act), floats(rows), floats(rows * obs), vec(any::<bool>(), rows)),
                proptest::option::of((finite(), any::<u64>())),
            )
        })
        .prop_map(|((actor, assignment, design_index, weights_version, first), (o, a, r, n, t), end)| ExperienceChunk {
            actor,
            assignment,
            design_index,
            weights_version,
            // A first chunk carries the start state: at least one row.
            first: first && !r.is_empty(),
            obs: o,
            actions: a,
            rewards: r,
            next_obs: n,
            terminated: t,
            end: end.map(|(episode_return, length)| EpisodeEnd { episode_return, length }),
        })
}

fn request(obs: usize, design: usize) -> impl Strategy<Value = DesignRequest> {
    (
        any::<u32>(),
        prop_oneof![Just(DesignKind::Exploit), Just(DesignKind::Explore)],
        any::<u64>(),
        (1..8usize).prop_flat_map(move |n| floats(n * obs)),
        (0..6usize).prop_flat_map(move |k| floats(k * design)),
        (0..6usize).prop_flat_map(move |k| floats(k * design)),
    )
        .prop_map(|(index, kind, weights_version, start_states, chosen, rejected)| DesignRequest {
            index,
            kind,
            weights_version,
            start_states,
            chosen,
            rejected,
        })
}

fn reply(design: usize) -> impl Strategy<Value = DesignReply> {
    // A method's name: 1 to 64 letters, digits, '-', '_', '.' or '+' (`DesignReply::validate`).
    (any::<u32>(), floats(design), "[A-Za-z0-9._+-]{1,64}", proptest::option::of(finite()), any::<u64>()).prop_map(
        |(index, design, method, predicted_objective, design_rollouts)| DesignReply {
            index,
            design,
            method,
            predicted_objective,
            design_rollouts,
        },
    )
}

fn dims() -> impl Strategy<Value = Dims> {
    (1..6usize, 1..5usize, 1..7usize).prop_map(|(obs, act, design)| Dims { obs, act, design })
}

/// Dimensions and one valid message of each kind built for them.
type Messages = (Dims, Weights, Assignment, ExperienceChunk, DesignRequest, DesignReply);

fn messages() -> impl Strategy<Value = Messages> {
    dims().prop_flat_map(|d| (Just(d), weights(), assignment(d.design), chunk(d.obs, d.act), request(d.obs, d.design), reply(d.design)))
}

fn roundtrip<T: Wire + Validate + PartialEq + std::fmt::Debug>(m: &T, dims: &Dims) -> Result<(), TestCaseError> {
    m.validate(dims).map_err(|e| TestCaseError::fail(format!("the generated message is invalid: {e}")))?;
    let bytes = m.encode();
    let back = T::decode(bytes.as_slice(), &Limits::default()).map_err(|e| TestCaseError::fail(format!("{e}")))?;
    prop_assert_eq!(&back, m);
    prop_assert!(back.validate(dims).is_ok());
    Ok(())
}

/// Offsets in a protobuf encoding where one field ends and the next begins (and 0).
fn field_boundaries(bytes: &[u8]) -> Vec<usize> {
    fn varint(b: &[u8], at: &mut usize) -> u64 {
        let mut v = 0u64;
        for shift in (0..64).step_by(7) {
            let byte = b[*at];
            *at += 1;
            v |= u64::from(byte & 0x7f) << shift;
            if byte < 0x80 {
                break;
            }
        }
        v
    }
    let mut out = vec![0];
    let mut at = 0;
    while at < bytes.len() {
        let key = varint(bytes, &mut at);
        match key & 7 {
            0 => {
                varint(bytes, &mut at);
            }
            1 => at += 8,
            2 => at += varint(bytes, &mut at) as usize,
            5 => at += 4,
            w => panic!("wire type {w} in an encoding prost wrote"),
        }
        out.push(at);
    }
    out
}

/// Every proper prefix of `m`'s encoding is refused, or is a message (cut between fields) other
/// than `m`; none panics.
fn truncations<T: Wire + PartialEq + std::fmt::Debug>(m: &T) -> Result<(), TestCaseError> {
    let bytes = m.encode();
    let boundaries = field_boundaries(&bytes);
    for cut in 0..bytes.len() {
        match T::decode(&bytes[..cut], &Limits::default()) {
            Err(_) => {}
            Ok(back) => {
                prop_assert!(boundaries.contains(&cut), "a cut inside a field at {cut} of {} bytes was accepted", bytes.len());
                prop_assert_ne!(&back, m, "a cut at {} lost a field silently", cut);
            }
        }
    }
    Ok(())
}

const CASES: u32 = 2048;

proptest! {
    #![proptest_config(ProptestConfig::with_cases(CASES))]

    #[test]
    fn proptest_valid_messages_roundtrip_unchanged((d, w, a, c, req, rep) in messages()) {
        roundtrip(&w, &d)?;
        roundtrip(&a, &d)?;
        roundtrip(&c, &d)?;
        roundtrip(&req, &d)?;
        roundtrip(&rep, &d)?;
    }

    /// The gRPC frames and deliveries around the messages carry them unchanged.
    #[test]
    fn proptest_frames_carry_messages_unchanged((_, w, a, c, req, rep) in messages(), sender: u64, seq: u64) {
        let frame = pb::ExperienceFrame { sender, seq, chunk: Some(c.to_pb()), fin: false }.encode_to_vec();
        let f = pb::ExperienceFrame::decode(frame.as_slice()).unwrap();
        prop_assert_eq!((f.sender, f.seq), (sender, seq));
        prop_assert_eq!(ExperienceChunk::from_pb(f.chunk.unwrap()).unwrap(), c);
        let frame = pb::DesignReplyFrame { sender, seq, reply: Some(rep.to_pb()), fin: false }.encode_to_vec();
        prop_assert_eq!(DesignReply::from_pb(pb::DesignReplyFrame::decode(frame.as_slice()).unwrap().reply.unwrap()).unwrap(), rep);
        let u = pb::WeightsUpdate { weights: Some(w.to_pb()), publisher_closed: false }.encode_to_vec();
        prop_assert_eq!(Weights::from_pb(pb::WeightsUpdate::decode(u.as_slice()).unwrap().weights.unwrap()).unwrap(), w);
        let d = pb::AssignmentDelivery { assignment: Some(a.to_pb()), seq, finished: false }.encode_to_vec();
        prop_assert_eq!(Assignment::from_pb(pb::AssignmentDelivery::decode(d.as_slice()).unwrap().assignment.unwrap()).unwrap(), a);
        let d = pb::DesignRequestDelivery { request: Some(req.to_pb()), seq, finished: false }.encode_to_vec();
        prop_assert_eq!(DesignRequest::from_pb(pb::DesignRequestDelivery::decode(d.as_slice()).unwrap().request.unwrap()).unwrap(), req);
    }

    #[test]
    fn proptest_arbitrary_bytes_never_panic_a_decoder(bytes in vec(any::<u8>(), 0..512), d in dims(), small in any::<bool>()) {
        let limits = if small { Limits { max_message_bytes: 64 } } else { Limits::default() };
        decode_everything(&bytes, &d, &limits);
    }

    /// Valid encodings with a few bytes overwritten: these get past the first field, so they
    /// reach the checks of every field.
    #[test]
    fn proptest_corrupted_messages_never_panic_a_decoder(
        (d, w, a, c, req, rep) in messages(),
        edits in vec((any::<prop::sample::Index>(), any::<u8>()), 1..6),
    ) {
        for mut bytes in [w.encode(), a.encode(), c.encode(), req.encode(), rep.encode()] {
            if bytes.is_empty() {
                continue;
            }
            for (i, b) in &edits {
                let i = i.index(bytes.len());
                bytes[i] = *b;
            }
            decode_everything(&bytes, &d, &Limits::default());
        }
    }

    #[test]
    fn proptest_truncated_messages_are_refused_not_a_panic((_, w, a, c, req, rep) in messages()) {
        truncations(&w)?;
        truncations(&a)?;
        truncations(&c)?;
        truncations(&req)?;
        truncations(&rep)?;
    }
}

/// Every decoder of a fleet message on `bytes`, then `Validate` on what is accepted.
fn decode_everything(bytes: &[u8], d: &Dims, limits: &Limits) {
    fn one<T: Wire + Validate + PartialEq + std::fmt::Debug>(bytes: &[u8], d: &Dims, limits: &Limits) {
        if let Ok(m) = T::decode(bytes, limits) {
            let _ = m.validate(d);
            assert_eq!(T::decode(m.encode().as_slice(), &Limits::default()).as_ref(), Ok(&m), "accepted messages re-encode");
        }
    }
    one::<Weights>(bytes, d, limits);
    one::<Assignment>(bytes, d, limits);
    one::<ExperienceChunk>(bytes, d, limits);
    one::<DesignRequest>(bytes, d, limits);
    one::<DesignReply>(bytes, d, limits);
    if let Ok(f) = pb::ExperienceFrame::decode(bytes)
        && let Some(c) = f.chunk
        && let Ok(c) = ExperienceChunk::from_pb(c)
    {
        let _ = c.validate(d);
    }
    if let Ok(f) = pb::DesignReplyFrame::decode(bytes)
        && let Some(r) = f.reply
        && let Ok(r) = DesignReply::from_pb(r)
    {
        let _ = r.validate(d);
    }
}

/// The cut that the property above allows: a population `Weights` cut just before its critics
/// is a valid acting `Weights` (policy only). The transports carry each message's length (gRPC's
/// length prefix, the shared-memory sample's size), so a cut message never reaches a decoder.
#[test]
fn a_cut_between_fields_is_a_different_message_not_the_original() {
    let w = Weights { version: 3, policy: vec![1.0, 2.0], q1: vec![0.5], q2: vec![0.25], heads: vec![] };
    let bytes = w.encode();
    let policy_end = field_boundaries(&bytes)[2];
    let cut = Weights::decode(&bytes[..policy_end], &Limits::default()).unwrap();
    assert_eq!(cut, Weights { q1: vec![], q2: vec![], ..w.clone() });
    assert!(Weights::decode(&bytes[..policy_end + 1], &Limits::default()).is_err(), "a cut inside q1 is refused");
}
