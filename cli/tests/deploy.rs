//! The deploy/ checks that need tools this machine may lack: the Kubernetes manifests
//! (`deploy/k8s/validate.sh`: kustomize builds and schema checks), the systemd units
//! (`deploy/multi-host/verify-units.sh`: systemd-analyze verify) and shellcheck over every
//! script. A script that lacks its tool exits 77 and the skip is reported on stderr.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::path::{Path, PathBuf};
use std::process::Command;

fn deploy() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy")
}

fn run_check(script: &str) {
    let o = Command::new("bash").arg(deploy().join(script)).output().unwrap();
    let out = format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    match o.status.code() {
        Some(0) => {}
        Some(77) => eprintln!("SKIPPED {script}: {out}"),
        c => panic!("{script} failed ({c:?}):\n{out}"),
    }
}

#[test]
fn kubernetes_manifests_validate() {
    run_check("k8s/validate.sh");
}

#[test]
fn systemd_units_verify() {
    run_check("multi-host/verify-units.sh");
}

#[test]
fn scripts_pass_shellcheck() {
    let Ok(v) = Command::new("shellcheck").arg("--version").output() else {
        eprintln!("SKIPPED: shellcheck is not installed (apt-get install shellcheck)");
        return;
    };
    assert!(v.status.success());
    let mut scripts = Vec::new();
    let mut dirs = vec![deploy()];
    while let Some(d) = dirs.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() && !p.ends_with(".venv") {
                dirs.push(p);
            } else if p.extension().is_some_and(|x| x == "sh" || x == "sbatch") {
                scripts.push(p);
            }
        }
    }
    assert!(scripts.len() >= 5, "{scripts:?}");
    let o = Command::new("shellcheck").args(&scripts).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stdout));
}
