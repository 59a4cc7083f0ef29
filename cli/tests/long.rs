//! The tests that take minutes (a Slurm job's time limit, Kubernetes pods, a partitioned
//! network, the Python bridge's learning run, fleets killed and resumed), started first: see
//! `all.rs`.

#[path = "env_rpc.rs"]
mod env_rpc;
#[path = "k8s_podman.rs"]
mod k8s_podman;
#[path = "netns.rs"]
mod netns;
#[path = "resume/main.rs"]
mod resume;
#[path = "slurm.rs"]
mod slurm;
