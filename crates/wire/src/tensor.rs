//! dm_env_rpc tensors and tensor specs to and from f32 vectors.
//!
//! A dm_env_rpc [`Tensor`] is a typed payload plus a shape: one element fills the whole shape
//! (broadcast) and at most one dimension may be negative (its size follows from the payload).
//! Readers here resolve both, insist on the expected shape, and refuse non-finite values,
//! naming the tensor and the element, because these tensors come from other processes and,
//! behind them, from robot hardware.

use crate::dm_env_rpc::v1::tensor::{DoubleArray, FloatArray, Payload, Uint64Array};
use crate::dm_env_rpc::v1::tensor_spec::{Value, value};
use crate::dm_env_rpc::v1::{DataType, Tensor, TensorSpec};

/// A tensor that could not be accepted, with the tensor's name.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("tensor `{tensor}`: {why}")]
pub struct TensorError {
    pub tensor: String,
    pub why: String,
}

fn err(tensor: &str, why: impl Into<String>) -> TensorError {
    TensorError { tensor: tensor.to_string(), why: why.into() }
}

/// A `FLOAT` tensor holding `values` with dimensions `shape`.
pub fn floats(values: &[f32], shape: &[usize]) -> Tensor {
    Tensor { payload: Some(Payload::Floats(FloatArray { array: values.to_vec() })), shape: shape.iter().map(|&d| d as i32).collect() }
}

/// A `FLOAT` scalar (shape `[]`).
pub fn scalar(v: f32) -> Tensor {
    Tensor { payload: Some(Payload::Floats(FloatArray { array: vec![v] })), shape: vec![] }
}

/// A `UINT64` scalar (shape `[]`).
pub fn scalar_u64(v: u64) -> Tensor {
    Tensor { payload: Some(Payload::Uint64s(Uint64Array { array: vec![v] })), shape: vec![] }
}

/// The dimensions of a tensor whose payload has `n` elements, as the specification defines
/// them: one negative dimension takes what is left, one element broadcasts.
pub fn resolve_shape(name: &str, shape: &[i32], n: usize) -> Result<Vec<usize>, TensorError> {
    let negative = shape.iter().filter(|&&d| d < 0).count();
    if negative > 1 {
        return Err(err(name, format!("shape {shape:?} has more than one negative dimension")));
    }
    // Shapes come from the network: a product that overflows is refused, never a panic.
    let too_big = || err(name, format!("shape {shape:?} has more elements than memory"));
    let known = shape.iter().filter(|&&d| d >= 0).try_fold(1usize, |p, &d| p.checked_mul(d as usize)).ok_or_else(too_big)?;
    let mut dims: Vec<usize> = shape.iter().map(|&d| d.max(0) as usize).collect();
    if let Some(i) = shape.iter().position(|&d| d < 0) {
        // With one element the unknown dimension is 1 (broadcast of a scalar).
        let fill = if known == 0 {
            0
        } else if n == 1 {
            1
        } else {
            n / known
        };
        if n != 1 && fill * known != n {
            return Err(err(name, format!("{n} elements do not fill shape {shape:?}")));
        }
        dims[i] = fill;
    }
    let total = dims.iter().try_fold(1usize, |p, &d| p.checked_mul(d)).ok_or_else(too_big)?;
    if n != total && n != 1 {
        return Err(err(name, format!("{n} elements for shape {shape:?} ({total} expected)")));
    }
    Ok(dims)
}

/// Which payload types a reader accepts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Accept {
    /// `floats` only: what a `FLOAT` spec promises (the compliance suites send doubles to a
    /// float action and expect a refusal).
    FloatOnly,
    /// `floats` or `doubles` (settings and observations from other implementations).
    AnyFloat,
}

/// Reads tensor `t` named `name`, which must have dimensions `expected`, into `out` (cleared
/// first), broadcasting one element; refuses other payload types, other shapes and non-finite
/// values.
pub fn read_f32(name: &str, t: &Tensor, expected: &[usize], accept: Accept, out: &mut Vec<f32>) -> Result<(), TensorError> {
    out.clear();
    let n = match (&t.payload, accept) {
        (Some(Payload::Floats(a)), _) => {
            out.extend_from_slice(&a.array);
            a.array.len()
        }
        (Some(Payload::Doubles(a)), Accept::AnyFloat) => {
            out.extend(a.array.iter().map(|&v| v as f32));
            a.array.len()
        }
        (None, _) => return Err(err(name, "has no payload")),
        (Some(p), _) => {
            let want = if accept == Accept::FloatOnly { "floats" } else { "floats or doubles" };
            return Err(err(name, format!("has {} values, {want} expected", payload_name(p))));
        }
    };
    let dims = resolve_shape(name, &t.shape, n)?;
    if dims != expected {
        return Err(err(name, format!("has shape {dims:?}, {expected:?} expected")));
    }
    let total: usize = expected.iter().product();
    if n == 1 && total != 1 {
        let v = out[0];
        out.resize(total, v);
    }
    if let Some(i) = out.iter().position(|v| !v.is_finite()) {
        return Err(err(name, format!("element {i} is {}", out[i])));
    }
    Ok(())
}

/// Reads a non-negative integer scalar (shape `[]` or `[1]`) of any integer type.
pub fn read_u64(name: &str, t: &Tensor) -> Result<u64, TensorError> {
    let values: Vec<i128> = match &t.payload {
        Some(Payload::Int32s(a)) => a.array.iter().map(|&v| v as i128).collect(),
        Some(Payload::Int64s(a)) => a.array.iter().map(|&v| v as i128).collect(),
        Some(Payload::Uint32s(a)) => a.array.iter().map(|&v| v as i128).collect(),
        Some(Payload::Uint64s(a)) => a.array.iter().map(|&v| v as i128).collect(),
        Some(p) => return Err(err(name, format!("has {} values, an integer expected", payload_name(p)))),
        None => return Err(err(name, "has no payload")),
    };
    let dims = resolve_shape(name, &t.shape, values.len())?;
    if dims.iter().product::<usize>() != 1 || values.len() != 1 {
        return Err(err(name, format!("has shape {dims:?}, a scalar expected")));
    }
    u64::try_from(values[0]).map_err(|_| err(name, format!("{} is negative", values[0])))
}

fn payload_name(p: &Payload) -> &'static str {
    match p {
        Payload::Floats(_) => "float",
        Payload::Doubles(_) => "double",
        Payload::Int8s(_) => "int8",
        Payload::Int32s(_) => "int32",
        Payload::Int64s(_) => "int64",
        Payload::Uint8s(_) => "uint8",
        Payload::Uint32s(_) => "uint32",
        Payload::Uint64s(_) => "uint64",
        Payload::Bools(_) => "bool",
        Payload::Strings(_) => "string",
        Payload::Protos(_) => "proto",
    }
}

/// A `FLOAT` spec named `name` with dimensions `shape` and, optionally, inclusive bounds.
pub fn float_spec(name: &str, shape: &[usize], bounds: Option<(&[f32], &[f32])>) -> TensorSpec {
    let value = |v: &[f32]| Value { payload: Some(value::Payload::Floats(FloatArray { array: v.to_vec() })) };
    TensorSpec {
        name: name.to_string(),
        shape: shape.iter().map(|&d| d as i32).collect(),
        dtype: DataType::Float as i32,
        min: bounds.map(|(lo, _)| value(lo)),
        max: bounds.map(|(_, hi)| value(hi)),
    }
}

/// What a client needs of a numeric spec: its dimensions and its bounds, if any, one per
/// element.
#[derive(Clone, Debug, PartialEq)]
pub struct FloatSpec {
    pub dims: Vec<usize>,
    pub bounds: Option<(Vec<f32>, Vec<f32>)>,
}

/// The most elements a spec may declare (a robot's action, state or design is far smaller).
pub const MAX_SPEC_ELEMENTS: usize = 1 << 20;

/// Reads a numeric spec: fixed dimensions (no negative ones), a float type, bounds given as one
/// value or one per element, finite, `min <= max`.
pub fn read_float_spec(spec: &TensorSpec) -> Result<FloatSpec, TensorError> {
    let name = spec.name.as_str();
    if spec.shape.iter().any(|&d| d < 0) {
        return Err(err(name, format!("spec shape {:?} is variable; coadapt needs fixed shapes", spec.shape)));
    }
    let dtype = DataType::try_from(spec.dtype).unwrap_or(DataType::InvalidDataType);
    if !matches!(dtype, DataType::Float | DataType::Double) {
        return Err(err(name, format!("spec type {dtype:?}, FLOAT or DOUBLE expected")));
    }
    let dims: Vec<usize> = spec.shape.iter().map(|&d| d as usize).collect();
    // A spec's bounds are expanded to one value per element: refuse absurd sizes from the wire.
    let n = dims
        .iter()
        .try_fold(1usize, |p, &d| p.checked_mul(d))
        .filter(|&n| n <= MAX_SPEC_ELEMENTS)
        .ok_or_else(|| err(name, format!("spec shape {:?} has more than {MAX_SPEC_ELEMENTS} elements", spec.shape)))?;
    let read = |which: &str, v: &Option<Value>| -> Result<Option<Vec<f32>>, TensorError> {
        let values: Vec<f32> = match v.as_ref().and_then(|v| v.payload.as_ref()) {
            None => return Ok(None),
            Some(value::Payload::Floats(a)) => a.array.clone(),
            Some(value::Payload::Doubles(DoubleArray { array })) => array.iter().map(|&x| x as f32).collect(),
            Some(_) => return Err(err(name, format!("spec {which} is not a float"))),
        };
        let values = match values.len() {
            1 => vec![values[0]; n],
            l if l == n => values,
            l => return Err(err(name, format!("spec {which} has {l} values for {n} elements"))),
        };
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            return Err(err(name, format!("spec {which}[{i}] is {}", values[i])));
        }
        Ok(Some(values))
    };
    let bounds = match (read("min", &spec.min)?, read("max", &spec.max)?) {
        (Some(lo), Some(hi)) => {
            if let Some(i) = lo.iter().zip(&hi).position(|(l, h)| l > h) {
                return Err(err(name, format!("spec min[{i}] {} exceeds max[{i}] {}", lo[i], hi[i])));
            }
            Some((lo, hi))
        }
        (None, None) => None,
        _ => return Err(err(name, "spec has only one of min and max")),
    };
    Ok(FloatSpec { dims, bounds })
}
