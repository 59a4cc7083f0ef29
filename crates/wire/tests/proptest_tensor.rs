//! Property tests of the dm_env_rpc tensor readers: shapes from the network (huge, negative,
//! overflowing products) never panic, and whatever a reader accepts has the shape, the length
//! and the finiteness it promises.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_wire::dm_env_rpc::v1::tensor::{DoubleArray, FloatArray, Int32Array, Int64Array, Payload, Uint32Array, Uint64Array};
use coadapt_wire::dm_env_rpc::v1::tensor_spec::{Value, value};
use coadapt_wire::dm_env_rpc::v1::{DataType, Tensor, TensorSpec};
use coadapt_wire::tensor::{Accept, MAX_SPEC_ELEMENTS, read_f32, read_float_spec, read_u64, resolve_shape};
use proptest::collection::vec;
use proptest::prelude::*;
use prost::Message;

/// Dimensions as a peer may send them: small ones, and the extremes that overflow products.
fn dim() -> impl Strategy<Value = i32> {
    prop_oneof![
        4 => -2..8i32,
        1 => prop::sample::select(vec![i32::MAX, i32::MIN, -1, 1 << 16, 1 << 20, 1 << 30, 46_341, 65_536]),
        1 => any::<i32>(),
    ]
}

fn shape() -> impl Strategy<Value = Vec<i32>> {
    vec(dim(), 0..6)
}

fn count() -> impl Strategy<Value = usize> {
    prop_oneof![4 => 0..40usize, 1 => any::<usize>(), 1 => Just(usize::MAX)]
}

fn values() -> impl Strategy<Value = Vec<f32>> {
    vec(prop_oneof![8 => -10.0f32..10.0, 1 => Just(f32::NAN), 1 => Just(f32::INFINITY)], 0..40)
}

fn expected() -> impl Strategy<Value = Vec<usize>> {
    prop::sample::select(vec![vec![], vec![1], vec![2], vec![3], vec![6], vec![2, 3], vec![17], vec![0]])
}

fn payload() -> impl Strategy<Value = Option<Payload>> {
    prop_oneof![
        values().prop_map(|array| Some(Payload::Floats(FloatArray { array }))),
        values().prop_map(|v| Some(Payload::Doubles(DoubleArray { array: v.iter().map(|&x| f64::from(x)).collect() }))),
        vec(any::<f64>(), 0..4).prop_map(|array| Some(Payload::Doubles(DoubleArray { array }))),
        vec(any::<i32>(), 0..3).prop_map(|array| Some(Payload::Int32s(Int32Array { array }))),
        vec(any::<i64>(), 0..3).prop_map(|array| Some(Payload::Int64s(Int64Array { array }))),
        vec(any::<u32>(), 0..3).prop_map(|array| Some(Payload::Uint32s(Uint32Array { array }))),
        vec(any::<u64>(), 0..3).prop_map(|array| Some(Payload::Uint64s(Uint64Array { array }))),
        Just(None),
    ]
}

fn bound() -> impl Strategy<Value = Option<Value>> {
    prop_oneof![
        Just(None),
        values().prop_map(|array| Some(Value { payload: Some(value::Payload::Floats(FloatArray { array })) })),
        vec(any::<f64>(), 0..3).prop_map(|array| Some(Value { payload: Some(value::Payload::Doubles(DoubleArray { array })) })),
        vec(any::<i32>(), 0..3).prop_map(|array| Some(Value { payload: Some(value::Payload::Int32s(Int32Array { array })) })),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(8192))]

    #[test]
    fn proptest_tensor_shapes_with_overflow_never_panic(s in shape(), n in count()) {
        if let Ok(d) = resolve_shape("t", &s, n) {
            prop_assert_eq!(d.len(), s.len());
            let total = d.iter().try_fold(1usize, |p, &x| p.checked_mul(x));
            prop_assert!(total.is_some(), "resolved dimensions {:?} overflow", d);
            prop_assert!(total == Some(n) || n == 1, "{} elements resolved to {:?}", n, d);
            for (&given, &got) in s.iter().zip(&d) {
                prop_assert!(given < 0 || got == given as usize, "a fixed dimension changed: {:?} -> {:?}", s, d);
            }
        }
    }

    #[test]
    fn proptest_tensors_read_as_promised_or_are_refused(
        s in shape(), p in payload(), e in expected(), float_only: bool, fill in vec(-1.0f32..1.0, 0..5),
    ) {
        let t = Tensor { payload: p, shape: s };
        // Through the wire first: what a peer sends is a prost encoding.
        let t = Tensor::decode(t.encode_to_vec().as_slice()).unwrap();
        let accept = if float_only { Accept::FloatOnly } else { Accept::AnyFloat };
        let mut out = fill;
        match read_f32("observation", &t, &e, accept, &mut out) {
            Ok(()) => {
                prop_assert_eq!(out.len(), e.iter().product::<usize>());
                prop_assert!(out.iter().all(|v| v.is_finite()));
            }
            Err(err) => prop_assert!(err.to_string().starts_with("tensor `observation`: "), "{}", err),
        }
        match read_u64("seed", &t) {
            Ok(v) => prop_assert!(matches!(
                &t.payload,
                Some(Payload::Int32s(_) | Payload::Int64s(_) | Payload::Uint32s(_) | Payload::Uint64s(_))
            ), "{} from {:?}", v, t),
            Err(err) => prop_assert_eq!(err.tensor, "seed"),
        }
    }

    #[test]
    fn proptest_specs_with_any_shape_and_bounds_never_panic(
        s in shape(), dtype in -1..14i32, min in bound(), max in bound(), name in "[a-z]{0,8}",
    ) {
        let spec = TensorSpec { name: name.clone(), shape: s, dtype, min, max };
        match read_float_spec(&spec) {
            Ok(f) => {
                prop_assert!(spec.shape.iter().all(|&d| d >= 0));
                prop_assert!(matches!(DataType::try_from(dtype), Ok(DataType::Float | DataType::Double)));
                let n: usize = f.dims.iter().product();
                prop_assert!(n <= MAX_SPEC_ELEMENTS);
                if let Some((lo, hi)) = &f.bounds {
                    prop_assert_eq!((lo.len(), hi.len()), (n, n));
                    prop_assert!(lo.iter().zip(hi).all(|(l, h)| l.is_finite() && h.is_finite() && l <= h));
                }
            }
            Err(err) => prop_assert_eq!(err.tensor, name),
        }
    }
}
