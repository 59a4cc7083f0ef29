//! The bimanual planar reaching benchmark (thesis ch. 2.4.1, Fig. 2.3) as an episodic task:
//! its kinematics and its robot live with the other robots ([`coadapt_robots::bimanual`]); here
//! a rollout's return (Eq. 2.31) and cost (the summed end-effector distance).

pub use coadapt_robots::bimanual::{ArmGeometry, PlanarReaching};

use crate::EpisodicTask;

impl EpisodicTask for PlanarReaching {
    fn steps(&self) -> usize {
        self.geometry.steps
    }

    fn action_dim(&self) -> usize {
        12
    }

    fn evaluate(&self, actions: &[f32]) -> (f64, f64) {
        self.distances(actions).iter().fold((0.0, 0.0), |(r, c), &(l, rr)| (r + (-l).exp() + (-rr).exp(), c + l + rr))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_kinematics_and_the_reward_by_hand() {
        let p = PlanarReaching::default();
        let e = p.end_effector(&[0.0; 6]);
        assert!(e[0].abs() < 1e-12 && (e[1] - 6.0).abs() < 1e-12, "{e:?}");
        // The first joint at +90 degrees: the whole arm points left.
        let e = p.end_effector(&[90.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        assert!((e[0] + 6.0).abs() < 1e-6 && e[1].abs() < 1e-6, "{e:?}");
        // Two links up, then a half turn: back down two, the rest up again: (0, 2).
        let e = p.end_effector(&[0.0, 0.0, 180.0, 0.0, 180.0, 0.0]);
        assert!(e[0].abs() < 1e-5 && (e[1] - 2.0).abs() < 1e-5, "{e:?}");
        assert_eq!(p.goals(0), ([-4.0, 2.0], [4.0, 2.0]));
        assert_eq!(p.goals(24), ([0.0, 4.0], [0.0, 4.0]));
        // Every step with both arms straight up: the distances to the goal paths, by hand.
        let actions = vec![0.0f32; 25 * 12];
        let (r, c) = p.evaluate(&actions);
        let mut want = (0.0, 0.0);
        for t in 0..25 {
            let s = t as f64 / 24.0;
            let d = ((-4.0 + 4.0 * s).powi(2) + (6.0 - (2.0 + 2.0 * s)).powi(2)).sqrt();
            want.0 += 2.0 * (-d).exp();
            want.1 += 2.0 * d;
        }
        assert!((r - want.0).abs() < 1e-9 && (c - want.1).abs() < 1e-9, "{r} {c} vs {want:?}");
        assert!(r > 0.0 && r < 50.0);
    }
}
