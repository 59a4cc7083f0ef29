use super::*;
use crate::{PlanarReaching, TimeFeatures};

fn random_samples(n: usize, t: usize, d: usize, k: usize, seed: u64) -> Vec<Sample> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    (0..n)
        .map(|_| Sample {
            actions: (0..t * d).map(|_| StandardNormal.sample(&mut rng)).collect(),
            z: (0..t * k).map(|_| StandardNormal.sample(&mut rng)).collect(),
            ret: 1.0,
            cost: 0.0,
        })
        .collect()
}

#[test]
fn without_latent_factors_the_m_update_is_reward_weighted_least_squares() {
    let phi = TimeFeatures::thesis(25);
    let (d, p) = (3, phi.len());
    let cfg = GroupsConfig { latent: 0, sigma2: 1e12, ..GroupsConfig::default() };
    let mut g = Groups::new(cfg, vec![vec![0, 1, 2]], d, p, 1).unwrap_or_else(|e| panic!("{e}"));
    let samples = random_samples(3, 25, d, 0, 2);
    let weights = [0.5, 0.3, 0.2];
    g.update(&samples, &weights, &phi);
    // The normal equations of min sum_i w_i sum_t (a_itj - m_j' phi_t)^2 / s_t, checked
    // directly: the gradient at the update's M is zero.
    for j in 0..d {
        let mj = &g.m[j * p..(j + 1) * p];
        let mut grad = vec![0.0; p];
        let mut scale = 0.0f64;
        for (x, w) in samples.iter().zip(weights) {
            for t in 0..25 {
                let f = phi.at(t);
                let s = dot(f, f);
                let r = x.actions[t * d + j] - dot(mj, f);
                grad.iter_mut().zip(f).for_each(|(gr, fi)| *gr += w * r * fi / s);
                scale = scale.max((w * x.actions[t * d + j] / s).abs());
            }
        }
        assert!(grad.iter().all(|v| v.abs() < 1e-6 * scale.max(1.0)), "action {j}: gradient {grad:?}");
    }
}

#[test]
fn with_zero_data_weight_the_synergies_are_the_prior_w_hat() {
    let phi = TimeFeatures::thesis(15);
    let (d, p, k) = (4, phi.len(), 2);
    let mut g = Groups::new(GroupsConfig { latent: k, inner: 3, ..GroupsConfig::default() }, vec![vec![0, 1], vec![2, 3]], d, p, 3)
        .unwrap_or_else(|e| panic!("{e}"));
    g.w_hat = (0..d * k).map(|i| i as f64 * 0.25 - 1.0).collect();
    let samples = random_samples(2, 15, d, k, 4);
    g.update(&samples, &[0.0, 0.0], &phi);
    for (a, b) in g.w.iter().zip(&g.w_hat) {
        assert!((a - b).abs() < 1e-12, "{:?} vs {:?}", g.w, g.w_hat);
    }
}

#[test]
fn the_log_linear_alpha_is_fitted_in_the_loop() {
    let phi = TimeFeatures::thesis(15);
    let (d, p, k) = (6, phi.len(), 3);
    let cfg = GroupsConfig { latent: k, inner: 2, alpha_rank: 1, ..GroupsConfig::default() };
    let mut g = Groups::new(cfg, vec![vec![0, 1, 2], vec![3, 4], vec![5]], d, p, 5).unwrap_or_else(|e| panic!("{e}"));
    let samples = random_samples(4, 15, d, k, 6);
    g.update(&samples, &[0.4, 0.3, 0.2, 0.1], &phi);
    let model = g.alpha_model.as_ref().unwrap_or_else(|| panic!("no model"));
    let l = model.log_alpha(&model.params);
    for (m, row) in g.alpha.iter().enumerate() {
        for (c, a) in row.iter().enumerate() {
            assert!((a - l[m * k + c].exp()).abs() < 1e-12 * a.max(1.0), "alpha[{m}][{c}] = {a}, exp(L) = {}", l[m * k + c].exp());
        }
    }
    // Rank 1: alpha's log is U V' plus the two means, not a free matrix.
    assert!(g.alpha.iter().flatten().all(|a| a.is_finite() && *a > 0.0));
}

#[test]
fn groups_must_partition_the_actions() {
    let e = Groups::new(GroupsConfig::default(), vec![vec![0, 1], vec![1]], 3, 11, 0).err();
    assert_eq!(e, Some(GroupsError::NotAPartition { action: 1, groups: 2 }));
    assert_eq!(e.map(|e| e.to_string()).as_deref(), Some("action 1 is in 2 groups; every action belongs to exactly one"));
    let e = Groups::new(GroupsConfig::default(), vec![vec![0, 5]], 3, 11, 0).err();
    assert_eq!(e.map(|e| e.to_string()).as_deref(), Some("group action 5 is beyond the 3 actions"));
}

#[test]
fn groups_with_four_groups_brings_the_arms_nearer_their_goal_paths() {
    use crate::EpisodicTask;
    let phi = TimeFeatures::thesis(25);
    let task = PlanarReaching::default();
    // Eq. 2.32: joints 1-4 and 5-6 of each arm.
    let groups = vec![vec![0, 1, 2, 3], vec![4, 5], vec![6, 7, 8, 9], vec![10, 11]];
    let mut g = Groups::new(GroupsConfig::default(), groups, 12, phi.len(), 1).unwrap_or_else(|e| panic!("{e}"));
    let mut a = Vec::new();
    let cost = |g: &Groups, a: &mut Vec<f32>| {
        crate::LinearPolicy::actions_of(&g.m, 12, &phi, a);
        task.evaluate(a).1
    };
    let before = cost(&g, &mut a);
    let mut costs = Vec::new();
    for _ in 0..25 {
        g.iterate(&task, &phi).unwrap();
        costs.push(cost(&g, &mut a));
    }
    coadapt_log::logln!("GrouPS (4 groups) on the planar task, summed distance of M: {before:.1} -> {costs:.1?}");
    // Measured (seed 1): 184 -> 132, down at every iteration. Slower than PoWER over these 25
    // (124): whether the thesis's ordering holds is the experiment's question, not this
    // test's.
    assert!(costs[24] < 0.8 * before && costs[24] < costs[12] && costs[12] < costs[0], "{before} -> {costs:?}");
}
