//! Networks as safetensors files that PyTorch loads.
//!
//! Network `name` with layers `0..k` is stored as tensors `name.{2i}.weight` (`[out, in]`) and
//! `name.{2i}.bias` (`[out]`), the keys of `nn.Sequential(Linear, ReLU, Linear, ...)`'s
//! `state_dict()` behind a prefix; the metadata entry `name.sizes` records the layer widths. So
//! `seq.load_state_dict({k[len(name)+1:]: v for k, v in load_file(path).items() if k.startswith(name + ".")})`
//! loads our weights into PyTorch. Files are written to a temporary name and renamed, so a crash
//! never leaves a half-written file under the real name.

use std::collections::HashMap;
use std::path::Path;

use safetensors::{Dtype, SafeTensors, tensor::TensorView};

use crate::{Mlp, NnError};

/// A network and its flat parameters, as saved or loaded.
#[derive(Clone, Debug, PartialEq)]
pub struct NamedNetwork {
    pub name: String,
    pub mlp: Mlp,
    pub params: Vec<f32>,
}

impl NamedNetwork {
    /// The network `name` among `nets`, checked to have the `expected` layer sizes.
    pub fn find<'a>(nets: &'a [NamedNetwork], path: &Path, name: &str, expected: &[usize]) -> Result<&'a NamedNetwork, NnError> {
        let net = nets.iter().find(|n| n.name == name).ok_or_else(|| NnError::MissingNetwork {
            path: path.display().to_string(),
            name: name.to_string(),
            available: nets.iter().map(|n| n.name.as_str()).collect::<Vec<_>>().join(", "),
        })?;
        if net.mlp.sizes() != expected {
            return Err(NnError::ShapeMismatch {
                path: path.display().to_string(),
                name: name.to_string(),
                found: net.mlp.sizes().to_vec(),
                expected: expected.to_vec(),
            });
        }
        Ok(net)
    }
}

/// Writes the networks `(name, shape, params)` to one safetensors file at `path`.
pub fn save_networks(path: &Path, nets: &[(&str, &Mlp, &[f32])]) -> Result<(), NnError> {
    let werr = |cause| NnError::Write { path: path.display().to_string(), cause };
    let mut bytes: Vec<(String, Vec<usize>, Vec<u8>)> = Vec::new();
    let mut meta = HashMap::new();
    for (name, mlp, params) in nets {
        assert_eq!(params.len(), mlp.n_params(), "parameters of `{name}` do not match its shape");
        let sizes: Vec<String> = mlp.sizes().iter().map(|s| s.to_string()).collect();
        meta.insert(format!("{name}.sizes"), sizes.join(","));
        for (i, l) in mlp.layers().iter().enumerate() {
            bytes.push((format!("{name}.{}.weight", 2 * i), vec![l.n_out, l.n_in], le_bytes(&params[l.w..l.b])));
            bytes.push((format!("{name}.{}.bias", 2 * i), vec![l.n_out], le_bytes(&params[l.b..l.b + l.n_out])));
        }
    }
    let views = bytes
        .iter()
        .map(|(k, shape, data)| TensorView::new(Dtype::F32, shape.clone(), data).map(|v| (k.clone(), v)))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| werr(std::io::Error::other(e.to_string())))?;
    let buf = safetensors::serialize(views, Some(meta)).map_err(|e| werr(std::io::Error::other(e.to_string())))?;
    let tmp = path.with_extension("safetensors.tmp");
    std::fs::write(&tmp, &buf).map_err(werr)?;
    std::fs::rename(&tmp, path).map_err(werr)
}

/// Reads every network of a file written by [`save_networks`] (or by PyTorch with the same
/// naming and metadata), validating dtypes, shapes and that each layer chains to the next.
pub fn load_networks(path: &Path) -> Result<Vec<NamedNetwork>, NnError> {
    let p = path.display().to_string();
    let corrupt = |why: String| NnError::Corrupt { path: p.clone(), why };
    let buf = std::fs::read(path).map_err(|cause| NnError::Read { path: p.clone(), cause })?;
    let (_, metadata) = SafeTensors::read_metadata(&buf).map_err(|e| corrupt(e.to_string()))?;
    let st = SafeTensors::deserialize(&buf).map_err(|e| corrupt(e.to_string()))?;
    let meta = metadata.metadata().clone().unwrap_or_default();
    let mut names: Vec<&String> = meta.keys().filter(|k| k.ends_with(".sizes")).collect();
    names.sort();
    if names.is_empty() {
        return Err(corrupt("no `<name>.sizes` metadata: not a coadapt network file".into()));
    }
    let mut out = Vec::new();
    for key in names {
        let name = key.trim_end_matches(".sizes");
        let sizes = meta[key]
            .split(',')
            .map(|s| s.trim().parse::<usize>())
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| corrupt(format!("metadata `{key}` = `{}`: {e}", meta[key])))?;
        let mlp = Mlp::new(&sizes).map_err(|e| corrupt(e.to_string()))?;
        let mut params = mlp.zeros();
        for (i, l) in mlp.layers().iter().enumerate() {
            for (suffix, shape, range) in [("weight", vec![l.n_out, l.n_in], l.w..l.b), ("bias", vec![l.n_out], l.b..l.b + l.n_out)] {
                let tname = format!("{name}.{}.{suffix}", 2 * i);
                let t = st.tensor(&tname).map_err(|e| corrupt(format!("tensor `{tname}`: {e}")))?;
                if t.dtype() != Dtype::F32 {
                    return Err(corrupt(format!("tensor `{tname}` is {:?}, expected F32", t.dtype())));
                }
                if t.shape() != shape.as_slice() {
                    return Err(corrupt(format!("tensor `{tname}` has shape {:?}, expected {shape:?}", t.shape())));
                }
                for (dst, src) in params[range].iter_mut().zip(t.data().chunks_exact(4)) {
                    *dst = f32::from_le_bytes([src[0], src[1], src[2], src[3]]);
                }
            }
        }
        if let Some(bad) = params.iter().position(|v| !v.is_finite()) {
            return Err(corrupt(format!("network `{name}` has a non-finite parameter at index {bad}")));
        }
        out.push(NamedNetwork { name: name.to_string(), mlp, params });
    }
    Ok(out)
}

fn le_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}
