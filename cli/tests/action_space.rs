//! `coadapt action-space` and `coadapt train --latent-exploration` through the binary: an
//! autoencoder learned from a finished run's experience, its files and figures, and SAC
//! exploring through it on a body the run never trained; refusals named, exit 78.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::process::{Command, Output};

const TINY: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/half-cheetah-tiny.toml");

fn coadapt(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_coadapt")).args(args).output().unwrap()
}

fn last_json(o: &Output) -> serde_json::Value {
    serde_json::from_str(String::from_utf8_lossy(&o.stdout).lines().last().unwrap()).unwrap()
}

#[test]
fn an_action_space_learned_from_a_run_drives_sacs_exploration_on_a_new_body() {
    let dir = coadapt_test_support::scratch("cli", "action-space");
    let run = dir.join("run");
    let o = coadapt(&["run", "--config", TINY, "--transport", "in-process", "--out", run.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    let out = dir.join("ae");
    let o = coadapt(&["action-space", run.to_str().unwrap(), "--out", out.to_str().unwrap(), "--updates", "600", "--hidden", "32,32"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = last_json(&o);
    assert_eq!(s["latent_dim"], 2, "{s}");
    assert_eq!(s["transitions"], 10_000, "the population replay holds the run's 10 training episodes: {s}");
    assert!(s["weighted_transitions"].as_u64().unwrap() > 0, "{s}");
    assert_eq!(s["grid_dims"], serde_json::json!([2, 4]), "{s}");
    assert_eq!(s["grid_spread"].as_array().unwrap().len(), 2, "{s}");
    for f in ["action_space.safetensors", "loss.csv", "latent_plane.svg", "decoded_grid.svg", "summary.json"] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let loss: Vec<f64> = std::fs::read_to_string(out.join("loss.csv"))
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(1).unwrap().parse().unwrap())
        .collect();
    assert_eq!(loss.len(), 6);
    assert!(loss[5] < loss[0], "Eq. 6.1's loss did not fall: {loss:?}");

    // SAC on a body the run never trained, exploring through the decoder, against its own.
    let ae = out.join("action_space.safetensors");
    let train = |name: &str, extra: &[&str]| {
        let d = dir.join(name);
        let mut args = vec![
            "train",
            "--env",
            "half-cheetah",
            "--design",
            "1.3,0.9,1.1,1.5,1.2,0.8",
            "--steps",
            "3000",
            "--learning-starts",
            "1000",
            "--hidden",
            "32,32",
            "--quiet",
            "--out",
            d.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        let o = coadapt(&args);
        assert!(o.status.success(), "{name}: {}", String::from_utf8_lossy(&o.stderr));
        std::fs::read_to_string(d.join("episodes.csv")).unwrap()
    };
    let own = train("own", &[]);
    let latent = train("latent", &["--latent-exploration", ae.to_str().unwrap(), "--latent-beta", "0.8"]);
    // The first episode is uniform random in both (learning starts at step 1000); the second
    // explores, each its own way.
    let ret = |csv: &str, k: usize| csv.lines().nth(k).unwrap().split(',').nth(2).unwrap().to_string();
    assert_eq!(ret(&own, 1), ret(&latent, 1));
    assert_ne!(ret(&own, 2), ret(&latent, 2));

    // Refusals, exit 78, naming what is wrong.
    for (args, needle) in [
        (
            vec!["train", "--env", "pendulum", "--steps", "100", "--latent-exploration", ae.to_str().unwrap()],
            "latent-exploration.action-space",
        ),
        (
            vec!["train", "--env", "half-cheetah", "--algo", "ddpg", "--steps", "100", "--latent-exploration", ae.to_str().unwrap()],
            "latent-exploration",
        ),
        (
            vec!["train", "--env", "half-cheetah", "--steps", "100", "--latent-exploration", ae.to_str().unwrap(), "--latent-beta=-1"],
            "latent-exploration.beta",
        ),
        (vec!["action-space", dir.join("nope").to_str().unwrap()], "nope"),
    ] {
        let o = coadapt(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?} succeeded");
        assert!(err.contains(needle), "{args:?}: `{err}` does not name {needle}");
        if args[0] == "train" {
            assert_eq!(o.status.code(), Some(78), "{args:?}: {err}");
        }
    }
}
