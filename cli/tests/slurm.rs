//! `deploy/slurm/coadapt.sbatch` on a real Slurm (issue 33): Debian's slurmctld, slurmd and
//! munge (installed by `deploy/slurm/local-cluster.sh` when missing), a controller and three
//! nodes in network namespaces. The time limit requeues the job at least once, an actor node
//! crashes in a later allocation, and the run's rows must equal an undisturbed lock-step run's
//! (`deploy/slurm/slurm-test.sh`). Where root, namespaces or the packages cannot be had the
//! script says why and exits 77, and this test reports the skip on stderr.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::process::Command;

#[test]
fn a_slurm_job_requeued_by_its_time_limit_and_hit_by_a_node_crash_completes_the_run_exactly() {
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/slurm/slurm-test.sh");
    let o = Command::new("bash").arg(&script).arg(env!("CARGO_BIN_EXE_coadapt")).output().unwrap();
    let (stdout, stderr) = (String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    match o.status.code() {
        Some(0) => {
            assert!(stderr.contains("PASS"), "{stderr}");
            assert!(stderr.contains("requeueing job"), "the job requeued itself: {stderr}");
            assert!(stderr.contains("node n3 crashed"), "{stderr}");
            assert!(stderr.contains("designs.csv:") && stderr.contains("rows, equal to the undisturbed run's"), "{stderr}");
            assert!(stderr.contains("episodes.csv") && stderr.contains("equal to the undisturbed run's"), "{stderr}");
        }
        Some(77) => eprintln!("SKIPPED: Slurm cannot run here (root, network namespaces, or its packages):\n{stderr}"),
        c => panic!("Slurm test failed ({c:?}):\n{stdout}\n{stderr}"),
    }
}
