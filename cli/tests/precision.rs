//! `--precision` through the binary (issue 34): `coadapt run --precision bf16|f32` sets
//! learner.sac.precision and records it in config.toml; the reference protocol
//! (`configs/half-cheetah-reference.toml`) asks for bf16; a bad value is refused by name. On a CPU with the
//! bf16 kernel the two precisions give different episodes (the products really changed); on
//! one without it bf16 means f32 products, bit for bit. The summary names the kernel.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::process::{Command, Output};

const TINY: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/half-cheetah-tiny.toml");
const REFERENCE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/half-cheetah-reference.toml");

fn coadapt(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_coadapt")).args(args).output().unwrap()
}

fn precision_of(run: &std::path::Path) -> String {
    let cfg: toml::Value = toml::from_str(&std::fs::read_to_string(run.join("config.toml")).unwrap()).unwrap();
    cfg["learner"]["sac"]["precision"].as_str().unwrap().to_owned()
}

#[test]
fn precision_is_chosen_by_flag_and_recorded() {
    let dir = coadapt_test_support::scratch("cli", "precision");
    let mut episodes = Vec::new();
    for p in ["f32", "bf16"] {
        let out = dir.join(p);
        let o = coadapt(&[
            "run",
            "--config",
            TINY,
            "--designs",
            "1",
            "--transport",
            "in-process",
            "--precision",
            p,
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        assert_eq!(precision_of(&out), p);
        // The summary (stdout's JSON line) names the kernel the bf16 products ran on (absent
        // in f32).
        let stdout = String::from_utf8_lossy(&o.stdout);
        let line = stdout.lines().rev().find(|l| l.starts_with('{')).expect("the summary line on stdout");
        let summary: serde_json::Value = serde_json::from_str(line).unwrap();
        let want = (p == "bf16").then(coadapt_nn::bf16::bf16_kernel);
        assert_eq!(summary.get("products").and_then(|v| v.as_str()), want, "{summary}");
        let text = std::fs::read_to_string(out.join("episodes.csv")).unwrap();
        // Every column but the wall time (the 8th).
        episodes.push(
            text.lines()
                .map(|l| l.split(',').enumerate().filter(|(i, _)| *i != 7).map(|(_, v)| v).collect::<Vec<_>>().join(","))
                .collect::<Vec<_>>(),
        );
    }
    if coadapt_nn::bf16::bf16_available() {
        assert_ne!(episodes[0], episodes[1], "bf16 products gave the f32 run's episodes");
    } else {
        eprintln!("no AVX-512 BF16 here: bf16 means f32 products");
        assert_eq!(episodes[0], episodes[1], "without the bf16 kernel the run must be the f32 run");
    }

    // The reference protocol (too long to run here) asks for bf16; the flag above overrides
    // whatever a config says.
    let reference: toml::Value = toml::from_str(&std::fs::read_to_string(REFERENCE).unwrap()).unwrap();
    assert_eq!(reference["learner"]["sac"]["precision"].as_str(), Some("bf16"));

    let bad = dir.join("bad");
    let o = coadapt(&["run", "--config", TINY, "--precision", "f16", "--out", bad.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("f16"), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(!bad.exists(), "a refused run wrote its directory");
}
