//! Untrusted bytes through every decoder of crates/wire: the fleet messages (`Wire::decode`,
//! then `Validate` against fixed dimensions), the gRPC frames and deliveries that carry them
//! (decoded as the fleet service does: prost, then `from_pb` of the payload), and the
//! dm_env_rpc tensors and specs of `coadapt_wire::tensor`.
//!
//! Input: the first byte picks the decoder, the second (where one is needed) the expected
//! dimensions; the rest are the bytes on the wire. Besides "never panics", each accepted
//! message must survive encode -> decode unchanged, and each accepted tensor must have the
//! shape and finiteness the reader promised.

#![no_main]

use coadapt_transport::messages::{Assignment, DesignReply, DesignRequest, Dims, ExperienceChunk, Validate, Weights};
use coadapt_wire::dm_env_rpc::v1::{Tensor, TensorSpec};
use coadapt_wire::tensor::{self, Accept};
use coadapt_wire::{Limits, Wire, pb};
use libfuzzer_sys::fuzz_target;
use prost::Message;

/// Receivers' dimensions: a small robot, HalfCheetah (obs 17 + design 6, act 6, design 6), and
/// a degenerate one with no design.
const DIMS: [Dims; 3] = [Dims { obs: 3, act: 2, design: 2 }, Dims { obs: 23, act: 6, design: 6 }, Dims { obs: 1, act: 1, design: 0 }];

/// Shapes a reader of a tensor may expect.
const SHAPES: [&[usize]; 6] = [&[], &[1], &[2], &[6], &[2, 3], &[17]];

/// Small limits too, so the size check is exercised.
const LIMITS: [Limits; 2] = [Limits { max_message_bytes: 64 << 20 }, Limits { max_message_bytes: 64 }];

fn message<T: Wire + Validate + PartialEq + std::fmt::Debug>(bytes: &[u8], dims: &Dims, limits: &Limits) {
    if let Ok(m) = T::decode(bytes, limits) {
        accepted(&m, dims);
    }
}

/// What every accepted message must satisfy.
fn accepted<T: Wire + Validate + PartialEq + std::fmt::Debug>(m: &T, dims: &Dims) {
    let again = m.encode();
    let back = T::decode(again.as_slice(), &Limits::default()).expect("an accepted message re-encodes to an accepted one");
    assert_eq!(&back, m, "encode -> decode changed the message");
    // Whatever `validate` says, it must say it without panicking.
    let _ = m.validate(dims);
}

/// The fleet service's receipt of one frame payload (`check` in crates/grpc/src/server).
fn payload<T: Wire + Validate + PartialEq + std::fmt::Debug>(pb: Option<T::Pb>, dims: &Dims) {
    if let Some(pb) = pb
        && let Ok(m) = T::from_pb(pb)
    {
        accepted(&m, dims);
    }
}

fn read_tensor(bytes: &[u8], expected: &[usize]) {
    let Ok(t) = Tensor::decode(bytes) else { return };
    for accept in [Accept::FloatOnly, Accept::AnyFloat] {
        let mut out = vec![7.0; 3];
        if tensor::read_f32("t", &t, expected, accept, &mut out).is_ok() {
            assert_eq!(out.len(), expected.iter().product::<usize>(), "read_f32 filled the expected shape");
            assert!(out.iter().all(|v| v.is_finite()), "read_f32 refuses non-finite values");
        }
    }
    let _ = tensor::read_u64("t", &t);
}

fn read_spec(bytes: &[u8]) {
    let Ok(s) = TensorSpec::decode(bytes) else { return };
    if let Ok(f) = tensor::read_float_spec(&s) {
        let n: usize = f.dims.iter().product();
        assert!(n <= tensor::MAX_SPEC_ELEMENTS);
        if let Some((lo, hi)) = &f.bounds {
            assert_eq!((lo.len(), hi.len()), (n, n), "one bound per element");
            assert!(lo.iter().zip(hi).all(|(l, h)| l <= h && l.is_finite() && h.is_finite()));
        }
    }
}

/// `resolve_shape` on a raw shape: little-endian i32 dimensions after a u32 element count.
fn shape(bytes: &[u8]) {
    let Some((n, dims)) = bytes.split_first_chunk::<4>() else { return };
    let n = u32::from_le_bytes(*n) as usize;
    let shape: Vec<i32> = dims.chunks_exact(4).map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
    if let Ok(d) = tensor::resolve_shape("t", &shape, n) {
        assert_eq!(d.len(), shape.len());
        let total = d.iter().try_fold(1usize, |p, &x| p.checked_mul(x)).expect("resolved dimensions do not overflow");
        assert!(n == total || n == 1, "{n} elements resolved to {d:?}");
    }
}

fuzz_target!(|data: &[u8]| {
    let [which, pick, bytes @ ..] = data else { return };
    let dims = &DIMS[usize::from(*pick) % DIMS.len()];
    let limits = &LIMITS[usize::from(*pick >> 4) % LIMITS.len()];
    match which % 15 {
        0 => message::<Weights>(bytes, dims, limits),
        1 => message::<Assignment>(bytes, dims, limits),
        2 => message::<ExperienceChunk>(bytes, dims, limits),
        3 => message::<DesignRequest>(bytes, dims, limits),
        4 => message::<DesignReply>(bytes, dims, limits),
        5 => {
            if let Ok(f) = pb::ExperienceFrame::decode(bytes) {
                payload::<ExperienceChunk>(f.chunk, dims);
            }
        }
        6 => {
            if let Ok(f) = pb::DesignReplyFrame::decode(bytes) {
                payload::<DesignReply>(f.reply, dims);
            }
        }
        7 => {
            if let Ok(u) = pb::WeightsUpdate::decode(bytes) {
                payload::<Weights>(u.weights, dims);
            }
        }
        8 => {
            if let Ok(d) = pb::AssignmentDelivery::decode(bytes) {
                payload::<Assignment>(d.assignment, dims);
            }
        }
        9 => {
            if let Ok(d) = pb::DesignRequestDelivery::decode(bytes) {
                payload::<DesignRequest>(d.request, dims);
            }
        }
        10 => read_tensor(bytes, SHAPES[usize::from(*pick) % SHAPES.len()]),
        11 => read_spec(bytes),
        12 => shape(bytes),
        // Weights accepted by the decoder are valid weights: the two checks agree.
        13 => {
            if let Ok(w) = Weights::decode(bytes, limits) {
                w.validate(dims).expect("decoded weights validate");
            }
        }
        // A chunk accepted by the decoder with rows that fit `dims` validates.
        _ => {
            if let Ok(c) = ExperienceChunk::decode(bytes, limits)
                && c.obs.len() == c.len() * dims.obs
                && c.actions.len() == c.len() * dims.act
            {
                c.validate(dims).expect("a decoded chunk of the right widths validates");
            }
        }
    }
});
