//! The bytes in a shared-memory sample: coadapt-wire's protobuf encoding, written straight
//! into the loaned slice, and decoded (and validated) by [`Wire::decode`].

use coadapt_transport::TransportError;
use coadapt_transport::messages::{Assignment, DesignReply, DesignRequest, ExperienceChunk, Weights};
use coadapt_wire::{Limits, Wire, WireError};
use prost::Message;

/// A message that can travel through shared memory. Implemented for every coadapt message.
pub trait Codec: Sized + Send + 'static {
    /// Encodes `self` into the slice `loan(len)` returns (a loaned sample of exactly `len`
    /// bytes), so the message is written once, in place.
    fn write_with<'a>(&self, loan: impl FnOnce(usize) -> Result<&'a mut [u8], TransportError>) -> Result<(), TransportError>;

    /// Decodes and validates untrusted bytes.
    fn decode_from(bytes: &[u8], limits: &Limits) -> Result<Self, WireError>;
}

fn write_pb<'a, M: Message>(pb: &M, loan: impl FnOnce(usize) -> Result<&'a mut [u8], TransportError>) -> Result<(), TransportError> {
    let mut out = loan(pb.encoded_len())?;
    pb.encode(&mut out).map_err(|e| TransportError::Io(format!("encoding into shared memory: {e}")))
}

macro_rules! via_prost {
    ($($t:ty),*) => {$(
        impl Codec for $t {
            fn write_with<'a>(&self, loan: impl FnOnce(usize) -> Result<&'a mut [u8], TransportError>) -> Result<(), TransportError> {
                write_pb(&self.to_pb(), loan)
            }

            fn decode_from(bytes: &[u8], limits: &Limits) -> Result<Self, WireError> {
                <$t as Wire>::decode(bytes, limits)
            }
        }
    )*};
}
via_prost!(Assignment, ExperienceChunk, DesignRequest, DesignReply);

// Weights are the big message: `Wire::to_pb` would copy every f32 into a `Bytes` first, so they
// are written field by field in prost's layout instead (a test checks it byte for byte).
const VERSION_TAG: u8 = 1 << 3; // field 1, varint
const POLICY_TAG: u8 = (2 << 3) | 2; // field 2, length-delimited
const Q1_TAG: u8 = (3 << 3) | 2;
const Q2_TAG: u8 = (4 << 3) | 2;
const HEAD_TAG: u8 = (5 << 3) | 2; // repeated: one field per head

fn varint_len(v: u64) -> usize {
    (64 - (v | 1).leading_zeros() as usize).div_ceil(7)
}

fn put_varint(out: &mut [u8], mut at: usize, mut v: u64) -> usize {
    while v >= 0x80 {
        out[at] = (v as u8) | 0x80;
        v >>= 7;
        at += 1;
    }
    out[at] = v as u8;
    at + 1
}

fn field_len(values: &[f32]) -> usize {
    let n = values.len() * 4;
    if n == 0 { 0 } else { 1 + varint_len(n as u64) + n }
}

/// A repeated field's element is written even when empty (prost keeps empty elements).
fn element_len(values: &[f32]) -> usize {
    let n = values.len() * 4;
    1 + varint_len(n as u64) + n
}

fn put_f32s(out: &mut [u8], at: usize, tag: u8, values: &[f32]) -> usize {
    if values.is_empty() {
        return at;
    }
    put_element(out, at, tag, values)
}

fn put_element(out: &mut [u8], at: usize, tag: u8, values: &[f32]) -> usize {
    out[at] = tag;
    let at = put_varint(out, at + 1, values.len() as u64 * 4);
    let end = at + values.len() * 4;
    for (dst, x) in out[at..end].chunks_exact_mut(4).zip(values) {
        dst.copy_from_slice(&x.to_le_bytes());
    }
    end
}

impl Codec for Weights {
    fn write_with<'a>(&self, loan: impl FnOnce(usize) -> Result<&'a mut [u8], TransportError>) -> Result<(), TransportError> {
        let version_len = if self.version == 0 { 0 } else { 1 + varint_len(self.version) };
        let heads_len: usize = self.heads.iter().map(|h| element_len(h)).sum();
        let len = version_len + field_len(&self.policy) + field_len(&self.q1) + field_len(&self.q2) + heads_len;
        let out = loan(len)?;
        let mut at = 0;
        if self.version != 0 {
            out[0] = VERSION_TAG;
            at = put_varint(out, 1, self.version);
        }
        at = put_f32s(out, at, POLICY_TAG, &self.policy);
        at = put_f32s(out, at, Q1_TAG, &self.q1);
        at = put_f32s(out, at, Q2_TAG, &self.q2);
        for h in &self.heads {
            at = put_element(out, at, HEAD_TAG, h);
        }
        Ok(())
    }

    fn decode_from(bytes: &[u8], limits: &Limits) -> Result<Self, WireError> {
        <Weights as Wire>::decode(bytes, limits)
    }
}

/// "Actor `0` is ready for one assignment": the credit of the work-sharing assignment queue.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Credit(pub u64);

impl Codec for Credit {
    fn write_with<'a>(&self, loan: impl FnOnce(usize) -> Result<&'a mut [u8], TransportError>) -> Result<(), TransportError> {
        loan(8)?.copy_from_slice(&self.0.to_le_bytes());
        Ok(())
    }

    fn decode_from(bytes: &[u8], _: &Limits) -> Result<Self, WireError> {
        match <[u8; 8]>::try_from(bytes) {
            Ok(b) => Ok(Credit(u64::from_le_bytes(b))),
            Err(_) => Err(WireError { field: "credit", why: format!("{} bytes, expected 8", bytes.len()) }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn encode<T: Codec>(m: &T) -> Vec<u8> {
        let mut buf = Vec::new();
        let mut slot: Option<&mut Vec<u8>> = Some(&mut buf);
        m.write_with(|n| {
            let b = slot.take().ok_or(TransportError::Closed)?;
            b.resize(n, 0);
            Ok(b.as_mut_slice())
        })
        .expect("encode");
        buf
    }

    #[test]
    fn weights_are_written_exactly_as_prost_writes_them() {
        for w in [
            Weights { version: 0, policy: vec![1.0], q1: vec![], q2: vec![], heads: vec![] },
            Weights { version: 1, policy: vec![0.5; 3], q1: vec![2.0; 40], q2: vec![-1.0; 40], heads: vec![] },
            Weights { version: u64::MAX, policy: (0..70_000).map(|i| i as f32 * 1e-3).collect(), q1: vec![], q2: vec![], heads: vec![] },
            Weights { version: 7, policy: vec![0.5; 3], q1: vec![2.0; 40], q2: vec![-1.0; 40], heads: vec![vec![3.0; 40], vec![-4.5; 40]] },
            // An empty head is still an element of the repeated field.
            Weights { version: 8, policy: vec![0.5; 3], q1: vec![], q2: vec![], heads: vec![vec![]] },
        ] {
            let ours = encode(&w);
            assert_eq!(ours, w.encode(), "version {}", w.version);
            assert_eq!(Weights::decode_from(&ours, &Limits::default()).expect("decodes"), w);
        }
    }

    #[test]
    fn prost_messages_and_credits_round_trip() {
        let c = coadapt_transport::conformance::chunk(9);
        assert_eq!(ExperienceChunk::decode_from(&encode(&c), &Limits::default()), Ok(c));
        assert_eq!(Credit::decode_from(&encode(&Credit(42)), &Limits::default()), Ok(Credit(42)));
        assert!(Credit::decode_from(&[1, 2, 3], &Limits::default()).is_err());
    }
}
