#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::ops::ControlFlow;

use coadapt_actors::{Actor, ActorError, PolicyKind};
use coadapt_core::ReplayBuffer;
use coadapt_learner::{Sac, SacConfig};

#[test]
fn actor_acts_as_the_learners_policy_and_refuses_bad_weights() {
    let env = coadapt_robots::make("pendulum").unwrap();
    let mut sac = Sac::new(5, 1, SacConfig { hidden: vec![32, 32], policy_final_init: 0.3, ..SacConfig::default() }, 1).unwrap();
    let mut actor = Actor::new(env, sac.policy().clone(), PolicyKind::SquashedGaussian, 2).unwrap();
    actor.set_weights(7, sac.policy_params()).unwrap();

    let mut replay = ReplayBuffer::new(5, 1, 1000);
    let mut mismatches = 0;
    let stats = actor
        .run_episode(11, &[1.0, 1.0], false, &mut |t| {
            let mut a = [0.0];
            sac.act(t.obs, true, &mut a);
            if a != [t.action[0]] {
                mismatches += 1;
            }
            replay.push(t).unwrap();
            ControlFlow::Continue(())
        })
        .unwrap();
    assert_eq!(mismatches, 0, "the actor's deterministic action is the learner's");
    assert_eq!(stats.length, 200);
    assert_eq!(stats.weights_version, 7);
    assert_eq!(replay.len(), 200);
    let sum: f32 = (0..200).map(|i| replay.get(i).reward).sum();
    assert!((sum - stats.episode_return).abs() < 1e-2);

    let n = sac.policy_params().len();
    assert!(matches!(actor.set_weights(8, &vec![0.0; n - 1]), Err(ActorError::WeightsLen { .. })));
    let mut bad = sac.policy_params().to_vec();
    bad[5] = f32::INFINITY;
    assert!(matches!(actor.set_weights(8, &bad), Err(ActorError::WeightsNonFinite { index: 5 })));
    assert_eq!(actor.weights_version(), 7, "refused weights leave the old ones in force");

    // The sink can cut an episode short.
    let stats = actor.run_episode(12, &[1.0, 1.0], true, &mut |_| ControlFlow::Break(())).unwrap();
    assert_eq!(stats.length, 1);
}
