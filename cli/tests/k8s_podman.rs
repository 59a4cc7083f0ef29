//! The Kubernetes manifests run in a real container runtime (issue 33): the image built
//! without a registry (a Debian root filesystem from mmdebstrap), learner, optimiser and actors
//! played from `kubectl kustomize deploy/k8s` by `podman kube play`, the probes' endpoint
//! answering, the learner pod deleted mid-run and resumed from its volume, and the rows equal to
//! an undisturbed lock-step run's (`deploy/k8s/podman-test.sh`). Where root, podman or Debian
//! bookworm cannot be had the script says why and exits 77, and this test reports the skip.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::process::Command;

#[test]
fn the_kubernetes_manifests_run_a_co_adaptation_in_podman_and_a_deleted_learner_pod_resumes() {
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/k8s/podman-test.sh");
    let o = Command::new("bash").arg(&script).arg(env!("CARGO_BIN_EXE_coadapt")).output().unwrap();
    let (stdout, stderr) = (String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    match o.status.code() {
        Some(0) => {
            assert!(stderr.contains("PASS"), "{stderr}");
            assert!(stderr.contains("probe: GET /healthz on the metrics port: 200"), "{stderr}");
            assert!(stderr.contains("the new learner pod resumed"), "{stderr}");
            assert!(stderr.contains("designs.csv: 40 rows, equal to the undisturbed run's"), "{stderr}");
            assert!(stderr.contains("episodes.csv") && stderr.contains("equal to the undisturbed run's"), "{stderr}");
        }
        Some(77) => eprintln!("SKIPPED: the manifests cannot run in podman here:\n{stderr}"),
        c => panic!("Kubernetes-in-podman test failed ({c:?}):\n{stdout}\n{stderr}"),
    }
}
