//! Rollouts through a fleet of actor threads over the in-process transport: the same returns
//! and costs as in process, the same first update, and a silent actor's rollouts taken over.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use coadapt_core::Env;
use coadapt_core::conformance::check_env;
use coadapt_policy_search::{
    EpisodicTask, FleetRunner, Groups, GroupsConfig, PlanarEnv, PlanarReaching, RolloutRunner, TimeFeatures, run_actor,
};

fn groups(seed: u64) -> Groups {
    let g = vec![vec![0, 1, 2, 3], vec![4, 5], vec![6, 7, 8, 9], vec![10, 11]];
    Groups::new(GroupsConfig::default(), g, 12, TimeFeatures::thesis(25).len(), seed).unwrap()
}

#[test]
fn the_planar_robot_passes_the_env_conformance_suite() {
    let mut env = PlanarEnv::default();
    check_env(&mut env, 25);
}

#[test]
fn the_planar_robot_steps_to_the_tasks_return_and_cost() {
    let task = PlanarReaching::default();
    let actions: Vec<f32> = (0..25 * 12).map(|i| ((i * 37 % 91) as f32) - 45.0).collect();
    let (ret, cost) = task.evaluate(&actions);
    let mut env = PlanarEnv::default();
    env.reset(0, &[]).unwrap();
    let (mut r, mut c) = (0.0f64, 0.0f64);
    for t in 0..25 {
        let s = env.step(&actions[t * 12..(t + 1) * 12]).unwrap();
        r += f64::from(s.reward);
        c += PlanarEnv::step_cost(s.observation);
        assert_eq!(s.truncated, t == 24);
    }
    assert!((r - ret).abs() < 1e-5 * ret.max(1.0) && (c - cost).abs() < 1e-4 * cost, "{r} {c} vs {ret} {cost}");
}

#[test]
fn groups_through_a_fleet_of_actor_threads_sees_what_it_sees_in_process() {
    let (learner, actors, _optimizer) = coadapt_transport::in_process::fleet(3);
    let stop = Arc::new(AtomicBool::new(false));
    let threads: Vec<_> = actors
        .into_iter()
        .enumerate()
        .map(|(i, mut links)| {
            let stop = stop.clone();
            std::thread::spawn(move || run_actor(&mut PlanarEnv::default(), 25, i as u64, &mut links, &stop))
        })
        .collect();
    let runner = FleetRunner::new(learner, 25, 12, 3, PlanarEnv::step_cost);
    let task = PlanarReaching::default();
    let phi = TimeFeatures::thesis(25);
    let (mut by_fleet, mut in_process) = (groups(5), groups(5));
    for it in 0..3 {
        let a = by_fleet.iterate(&runner, &phi).unwrap();
        let b = in_process.iterate(&task, &phi).unwrap();
        assert_eq!(a.len(), 30);
        if it == 0 {
            // The same draws: the same rollouts, to the f32 rewards' precision.
            for (x, y) in a.iter().zip(&b) {
                assert!((x.ret - y.ret).abs() < 1e-5 * y.ret.max(1.0), "return {} vs {}", x.ret, y.ret);
                assert!((x.cost - y.cost).abs() < 1e-4 * y.cost, "cost {} vs {}", x.cost, y.cost);
            }
            let dm = by_fleet.m.iter().zip(&in_process.m).map(|(p, q)| (p - q).abs()).fold(0.0, f64::max);
            assert!(dm < 1e-3, "M after the first update differs by {dm}");
        }
    }
    // The queue closes when the runner goes: every actor ends by itself.
    drop(runner);
    let ran: u64 = threads.into_iter().map(|t| t.join().unwrap().unwrap()).sum();
    assert_eq!(ran, 90, "each rollout ran exactly once");
    assert!(!stop.load(Ordering::Relaxed));
}

#[test]
fn a_rollout_whose_actor_went_silent_goes_to_another_after_the_lease() {
    let (learner, mut actors, _optimizer) = coadapt_transport::in_process::fleet(2);
    // Actor 0 takes assignments and never answers (a robot that hung); actor 1 works.
    let mut hung = actors.remove(0);
    let stop = Arc::new(AtomicBool::new(false));
    // The working actor starts only once the hung one holds a rollout (else it may take them
    // all first: CI saw that).
    let (took, first_taken) = std::sync::mpsc::channel::<()>();
    let hung_thread = {
        let stop = stop.clone();
        std::thread::spawn(move || {
            let mut taken = 0;
            while !stop.load(Ordering::Relaxed) {
                if let Ok(Some(_)) = hung.assignments.recv_timeout(Duration::from_millis(20)) {
                    taken += 1;
                    let _ = took.send(());
                }
            }
            taken
        })
    };
    let mut good = actors.remove(0);
    let stop2 = stop.clone();
    let worker = std::thread::spawn(move || {
        first_taken.recv_timeout(Duration::from_secs(30)).expect("the hung actor took a rollout");
        run_actor(&mut PlanarEnv::default(), 25, 1, &mut good, &stop2)
    });
    let mut runner = FleetRunner::new(learner, 25, 12, 3, PlanarEnv::step_cost);
    runner.set_lease(Duration::from_millis(300));
    let rollouts: Vec<Vec<f32>> = (0..6).map(|k| vec![k as f32; 25 * 12]).collect();
    let got = runner.run(&rollouts).unwrap();
    let task = PlanarReaching::default();
    for (a, (ret, cost)) in rollouts.iter().zip(&got) {
        let (r, c) = task.evaluate(a);
        assert!((ret - r).abs() < 1e-5 * r.max(1.0) && (cost - c).abs() < 1e-4 * c, "{ret} {cost} vs {r} {c}");
    }
    stop.store(true, Ordering::Relaxed);
    let taken = hung_thread.join().unwrap();
    assert!(taken >= 1, "the hung actor took no rollout: the test did not test the lease");
    drop(runner);
    worker.join().unwrap().unwrap();
}
