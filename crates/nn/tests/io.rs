#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::path::PathBuf;

use coadapt_nn::{Mlp, NamedNetwork, NnError, load_networks, save_networks};
use rand::SeedableRng;

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("coadapt-nn-io-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn net() -> (Mlp, Vec<f32>) {
    let mlp = Mlp::new(&[3, 5, 2]).unwrap();
    let mut p = mlp.zeros();
    mlp.init(&mut p, 0.1, &mut rand_pcg::Pcg64Mcg::seed_from_u64(1));
    (mlp, p)
}

#[test]
fn save_then_load_round_trips_every_network_exactly() {
    let (mlp, p) = net();
    let big = Mlp::new(&[4, 8, 8, 1]).unwrap();
    let q: Vec<f32> = (0..big.n_params()).map(|i| i as f32 * 0.25).collect();
    let path = tmp("roundtrip.safetensors");
    save_networks(&path, &[("policy", &mlp, &p), ("q1", &big, &q)]).unwrap();
    let nets = load_networks(&path).unwrap();
    assert_eq!(nets.len(), 2);
    let pol = NamedNetwork::find(&nets, &path, "policy", &[3, 5, 2]).unwrap();
    assert_eq!(pol.params, p);
    assert_eq!(NamedNetwork::find(&nets, &path, "q1", &[4, 8, 8, 1]).unwrap().params, q);
    assert!(matches!(NamedNetwork::find(&nets, &path, "q2", &[4, 8, 8, 1]), Err(NnError::MissingNetwork { .. })));
    assert!(matches!(NamedNetwork::find(&nets, &path, "q1", &[4, 8, 1]), Err(NnError::ShapeMismatch { .. })));
    assert!(!path.with_extension("safetensors.tmp").exists(), "temporary file left behind");
}

#[test]
fn missing_truncated_or_corrupt_files_are_clear_errors() {
    let missing = tmp("does-not-exist.safetensors");
    let e = load_networks(&missing).unwrap_err();
    assert!(matches!(e, NnError::Read { .. }), "{e}");
    assert!(e.to_string().contains("does-not-exist.safetensors"));

    let (mlp, p) = net();
    let good = tmp("good.safetensors");
    save_networks(&good, &[("policy", &mlp, &p)]).unwrap();
    let bytes = std::fs::read(&good).unwrap();

    let truncated = tmp("truncated.safetensors");
    std::fs::write(&truncated, &bytes[..bytes.len() - 7]).unwrap();
    assert!(matches!(load_networks(&truncated), Err(NnError::Corrupt { .. })));

    let garbage = tmp("garbage.safetensors");
    std::fs::write(&garbage, b"\xff\xff\xff\xff\xff\xff\xff\x7fnot a safetensors file").unwrap();
    assert!(matches!(load_networks(&garbage), Err(NnError::Corrupt { .. })));

    let empty = tmp("empty.safetensors");
    std::fs::write(&empty, b"").unwrap();
    assert!(matches!(load_networks(&empty), Err(NnError::Corrupt { .. })));

    // A NaN weight is refused rather than loaded.
    let mut bad = p.clone();
    bad[3] = f32::NAN;
    let nan = tmp("nan.safetensors");
    save_networks(&nan, &[("policy", &mlp, &bad)]).unwrap();
    let e = load_networks(&nan).unwrap_err();
    assert!(e.to_string().contains("non-finite"), "{e}");
}
