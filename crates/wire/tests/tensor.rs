//! dm_env_rpc tensors: broadcast, variable dimensions, types, shapes and finiteness, with the
//! tensor named in every refusal.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_wire::dm_env_rpc::v1::Tensor;
use coadapt_wire::dm_env_rpc::v1::tensor::{DoubleArray, Int64Array, Payload};
use coadapt_wire::tensor::{Accept, float_spec, floats, read_f32, read_float_spec, read_u64, resolve_shape, scalar_u64};

fn read(t: &Tensor, expected: &[usize], accept: Accept) -> Result<Vec<f32>, String> {
    let mut out = vec![7.0; 9];
    read_f32("observation", t, expected, accept, &mut out).map(|()| out).map_err(|e| e.to_string())
}

#[test]
fn shapes_broadcast_and_variable_dimensions_resolve_as_the_spec_says() {
    assert_eq!(resolve_shape("x", &[2, 3], 6).unwrap(), [2, 3]);
    assert_eq!(resolve_shape("x", &[-1, 3], 6).unwrap(), [2, 3]);
    assert_eq!(resolve_shape("x", &[4], 1).unwrap(), [4], "one element fills the shape");
    assert_eq!(resolve_shape("x", &[], 1).unwrap(), Vec::<usize>::new());
    assert!(resolve_shape("x", &[-1, -1], 4).unwrap_err().to_string().contains("more than one negative"));
    assert!(resolve_shape("x", &[-1, 3], 7).unwrap_err().to_string().contains("do not fill"));
    assert!(resolve_shape("x", &[3], 2).unwrap_err().to_string().contains("2 elements for shape [3]"));
    let huge = [i32::MAX, i32::MAX, i32::MAX, 8];
    assert!(resolve_shape("x", &huge, 1).unwrap_err().to_string().contains("more elements than memory"), "no overflow panic");
    assert_eq!(read(&floats(&[1.5], &[3]), &[3], Accept::FloatOnly).unwrap(), [1.5; 3]);
    assert_eq!(read(&Tensor { payload: floats(&[1.0, 2.0], &[2]).payload, shape: vec![-1] }, &[2], Accept::FloatOnly).unwrap(), [1.0, 2.0]);
}

#[test]
fn wrong_shapes_types_and_non_finite_values_are_refused_naming_the_tensor() {
    let e = read(&floats(&[0.0; 4], &[4]), &[3], Accept::AnyFloat).unwrap_err();
    assert_eq!(e, "tensor `observation`: has shape [4], [3] expected");
    let e = read(&floats(&[0.0; 3], &[3, 1]), &[3], Accept::AnyFloat).unwrap_err();
    assert!(e.contains("shape [3, 1]"), "{e}");
    let e = read(&floats(&[0.0, f32::NAN, 1.0], &[3]), &[3], Accept::AnyFloat).unwrap_err();
    assert_eq!(e, "tensor `observation`: element 1 is NaN");
    let e = read(&floats(&[f32::INFINITY], &[]), &[], Accept::AnyFloat).unwrap_err();
    assert!(e.contains("element 0 is inf"), "{e}");
    let doubles = Tensor { payload: Some(Payload::Doubles(DoubleArray { array: vec![0.5, 0.25] })), shape: vec![2] };
    assert_eq!(read(&doubles, &[2], Accept::AnyFloat).unwrap(), [0.5, 0.25]);
    assert!(read(&doubles, &[2], Accept::FloatOnly).unwrap_err().contains("double values, floats expected"));
    assert!(read(&Tensor::default(), &[2], Accept::AnyFloat).unwrap_err().contains("no payload"));
    assert_eq!(read_u64("seed", &scalar_u64(42)).unwrap(), 42);
    let negative = Tensor { payload: Some(Payload::Int64s(Int64Array { array: vec![-3] })), shape: vec![] };
    assert!(read_u64("seed", &negative).unwrap_err().to_string().contains("tensor `seed`: -3 is negative"));
    assert!(read_u64("seed", &floats(&[1.0], &[])).unwrap_err().to_string().contains("an integer expected"));
}

#[test]
fn specs_round_trip_and_bad_bounds_are_refused() {
    let s = float_spec("action", &[2], Some((&[-1.0, -2.0], &[1.0, 2.0])));
    let f = read_float_spec(&s).unwrap();
    assert_eq!(f.dims, [2]);
    assert_eq!(f.bounds, Some((vec![-1.0, -2.0], vec![1.0, 2.0])));
    let upside_down = float_spec("action", &[1], Some((&[1.0], &[-1.0])));
    assert!(read_float_spec(&upside_down).unwrap_err().to_string().contains("min[0] 1 exceeds max[0] -1"));
    let infinite = float_spec("action", &[1], Some((&[f32::NEG_INFINITY], &[1.0])));
    assert!(read_float_spec(&infinite).unwrap_err().to_string().contains("spec min[0] is -inf"));
    let huge = float_spec("action", &[1 << 16, 1 << 16], Some((&[0.0], &[1.0])));
    assert!(read_float_spec(&huge).unwrap_err().to_string().contains("more than 1048576 elements"));
    let mut variable = float_spec("observation", &[3], None);
    variable.shape = vec![-1];
    assert!(read_float_spec(&variable).unwrap_err().to_string().contains("variable"));
}
