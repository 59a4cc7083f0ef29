//! A trained embedding saved and loaded: the same codes after the round trip; broken files are
//! errors that say what is wrong.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_latent::{Embedding, EmbeddingConfig, EmbeddingWork, load_embedding, save_embedding};
use rand::SeedableRng;

#[test]
fn an_embedding_survives_a_round_trip_and_broken_files_are_refused() {
    let cfg = EmbeddingConfig { image: 16, in_channels: 3, channels: [4, 5, 6], latent: 3, margin: 0.7 };
    let emb = Embedding::new(cfg).unwrap();
    let mut rng = rand::rngs::StdRng::seed_from_u64(3);
    let (mut enc, mut dec) = (vec![0.0; emb.encoder_params()], vec![0.0; emb.decoder_params()]);
    emb.init(&mut enc, &mut dec, &mut rng);
    let dir = std::env::temp_dir().join(format!("coadapt-emb-io-{}", std::process::id()));
    let path = dir.join("sub/embedding.safetensors");
    save_embedding(&path, &emb, &enc, &dec).unwrap();
    let (back, enc2, dec2) = load_embedding(&path).unwrap();
    assert_eq!(back.cfg, cfg);
    assert_eq!((enc2.as_slice(), dec2.as_slice()), (enc.as_slice(), dec.as_slice()));
    let x: Vec<f32> = (0..2 * emb.image_len()).map(|i| ((i as f32) * 0.37).sin().abs()).collect();
    let (mut w1, mut w2) = (EmbeddingWork::default(), EmbeddingWork::default());
    assert_eq!(emb.encode(&enc, &x, 2, &mut w1), back.encode(&enc2, &x, 2, &mut w2));
    // Broken files: missing, truncated, not an embedding.
    let err = load_embedding(&dir.join("missing.safetensors")).unwrap_err().to_string();
    assert!(err.contains("missing.safetensors"), "{err}");
    let bytes = std::fs::read(&path).unwrap();
    let cut = dir.join("cut.safetensors");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let err = load_embedding(&cut).unwrap_err().to_string();
    assert!(err.contains("not a coadapt embedding"), "{err}");
    let other = dir.join("mlp.safetensors");
    let mlp = coadapt_nn::Mlp::new(&[2, 3]).unwrap();
    coadapt_nn::save_networks(&other, &[("net", &mlp, &mlp.zeros())]).unwrap();
    let err = load_embedding(&other).unwrap_err().to_string();
    assert!(err.contains("not a coadapt embedding") && err.contains("in the metadata"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}
