//! Saving and loading a trained embedding: one safetensors file with the encoder's and the
//! decoder's parameters as two flat F32 tensors (`encoder`, `decoder`, in [`Embedding`]'s
//! layer order, each layer PyTorch's layout) and the shape in the metadata (`image`,
//! `in-channels`, `channels`, `latent`, `margin`). Loading validates everything it reads: a
//! corrupt or mismatched file is an error naming what is wrong, never a panic.

use std::collections::HashMap;
use std::path::Path;

use safetensors::{Dtype, SafeTensors, tensor::TensorView};

use crate::{Embedding, EmbeddingConfig};

/// Why an embedding file could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum EmbeddingFileError {
    #[error("embedding file {path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("embedding file {path} is not a coadapt embedding: {why}")]
    Corrupt { path: String, why: String },
}

/// An embedding that cannot be written to a full disk cannot be written after a restart either.
impl coadapt_fleet::supervise::exit::ExitCode for EmbeddingFileError {
    fn exit_code(&self) -> Option<u8> {
        match self {
            Self::Io { source, .. } => source.exit_code(),
            Self::Corrupt { .. } => None,
        }
    }
}

/// Writes `emb`'s shape and parameters to `path` (atomically: a temporary file renamed).
pub fn save_embedding(path: &Path, emb: &Embedding, enc: &[f32], dec: &[f32]) -> Result<(), EmbeddingFileError> {
    let p = path.display().to_string();
    let io = |source| EmbeddingFileError::Io { path: p.clone(), source };
    assert_eq!((enc.len(), dec.len()), (emb.encoder_params(), emb.decoder_params()), "parameters do not match the embedding");
    let c = emb.cfg;
    let meta: HashMap<String, String> = [
        ("image", c.image.to_string()),
        ("in-channels", c.in_channels.to_string()),
        ("channels", c.channels.map(|v| v.to_string()).join(",")),
        ("latent", c.latent.to_string()),
        ("margin", c.margin.to_string()),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v))
    .collect();
    let (eb, db) = (le_bytes(enc), le_bytes(dec));
    let views = [("encoder", &eb, enc.len()), ("decoder", &db, dec.len())]
        .into_iter()
        .map(|(k, b, n)| TensorView::new(Dtype::F32, vec![n], b).map(|v| (k.to_string(), v)))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| io(std::io::Error::other(e.to_string())))?;
    let buf = safetensors::serialize(views, Some(meta)).map_err(|e| io(std::io::Error::other(e.to_string())))?;
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(io)?;
    }
    let tmp = path.with_extension("safetensors.tmp");
    std::fs::write(&tmp, &buf).map_err(io)?;
    std::fs::rename(&tmp, path).map_err(io)
}

/// Reads an embedding written by [`save_embedding`]: its networks, encoder and decoder
/// parameters.
pub fn load_embedding(path: &Path) -> Result<(Embedding, Vec<f32>, Vec<f32>), EmbeddingFileError> {
    let p = path.display().to_string();
    let corrupt = |why: String| EmbeddingFileError::Corrupt { path: p.clone(), why };
    let buf = std::fs::read(path).map_err(|source| EmbeddingFileError::Io { path: p.clone(), source })?;
    let (_, metadata) = SafeTensors::read_metadata(&buf).map_err(|e| corrupt(e.to_string()))?;
    let meta = metadata.metadata().clone().unwrap_or_default();
    let get = |k: &str| meta.get(k).ok_or_else(|| corrupt(format!("no `{k}` in the metadata")));
    let int = |k: &str| -> Result<usize, EmbeddingFileError> {
        let v = get(k)?;
        v.trim().parse().map_err(|e| corrupt(format!("`{k}` = {v:?}: {e}")))
    };
    let ch: Vec<usize> = get("channels")?
        .split(',')
        .map(|s| s.trim().parse::<usize>())
        .collect::<Result<_, _>>()
        .map_err(|e| corrupt(format!("`channels`: {e}")))?;
    let channels: [usize; 3] = ch.try_into().map_err(|c| corrupt(format!("`channels` = {c:?}: three values")))?;
    let margin: f32 = get("margin")?.trim().parse().map_err(|e| corrupt(format!("`margin`: {e}")))?;
    let cfg = EmbeddingConfig { image: int("image")?, in_channels: int("in-channels")?, channels, latent: int("latent")?, margin };
    let emb = Embedding::new(cfg).map_err(|e| corrupt(format!("shape {cfg:?}: {e}")))?;
    let st = SafeTensors::deserialize(&buf).map_err(|e| corrupt(e.to_string()))?;
    let read = |name: &str, n: usize| -> Result<Vec<f32>, EmbeddingFileError> {
        let t = st.tensor(name).map_err(|e| corrupt(format!("tensor `{name}`: {e}")))?;
        if t.dtype() != Dtype::F32 || t.shape() != [n] {
            return Err(corrupt(format!("tensor `{name}` is {:?} {:?}, expected F32 [{n}]", t.dtype(), t.shape())));
        }
        let v: Vec<f32> = t.data().chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
        if let Some(bad) = v.iter().position(|x| !x.is_finite()) {
            return Err(corrupt(format!("tensor `{name}` has a non-finite value at index {bad}")));
        }
        Ok(v)
    };
    let enc = read("encoder", emb.encoder_params())?;
    let dec = read("decoder", emb.decoder_params())?;
    Ok((emb, enc, dec))
}

fn le_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}
