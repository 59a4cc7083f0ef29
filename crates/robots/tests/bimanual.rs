//! The bimanual planar reaching robot (policy search's, ch. 2) under the Env conformance suite,
//! and its observation and reward against the benchmark's kinematics.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_core::Env;
use coadapt_core::conformance::check_env;
use coadapt_robots::bimanual::{PlanarEnv, PlanarReaching};

#[test]
fn the_planar_robot_passes_the_env_conformance_suite() {
    check_env(&mut PlanarEnv::default(), 25);
}

#[test]
fn each_step_observes_the_distances_and_earns_eq_2_31() {
    let task = PlanarReaching::default();
    let mut env = PlanarEnv::default();
    env.reset(0, &[]).unwrap();
    let actions: Vec<f32> = (0..25 * 12).map(|i| ((i * 7) % 31) as f32 - 15.0).collect();
    let d = task.distances(&actions);
    for (t, a) in actions.chunks_exact(12).enumerate() {
        let s = env.step(a).unwrap();
        let (l, r) = d[t];
        assert!((f64::from(s.observation[1]) - l).abs() < 1e-4 && (f64::from(s.observation[2]) - r).abs() < 1e-4, "step {t}");
        assert!((f64::from(s.reward) - ((-l).exp() + (-r).exp())).abs() < 1e-5, "step {t}");
        assert_eq!(s.truncated, t == 24);
    }
}
