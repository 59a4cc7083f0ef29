//! Optimize and Landscape: the best design within bounds, refusals, cancellation, the grid.

use crate::support::*;

#[test]
fn optimize_streams_the_best_design_within_bounds_and_fixed_coordinates() {
    let (s, _) = server(ServeConfig::default());
    rt().block_on(async {
        let mut d = DesignServiceClient::new(channel(&s).await);
        let req = pb::OptimizeRequest {
            method: "pso".into(),
            particles: 40,
            iterations: 15,
            low: vec![0.5, 0.8, 0.5],
            high: vec![2.0, 1.6, 2.0],
            fixed: vec![pb::FixedCoordinate { dimension: 2, value: 1.25 }],
            seed: 3,
        };
        let msgs = optimize_all(&mut d, req.clone()).await;
        assert_eq!(msgs.len(), 16, "15 iterations and the answer");
        assert!(msgs[..15].iter().all(|m| !m.done) && msgs[15].done);
        for w in msgs[..15].windows(2) {
            assert!(w[1].best_objective >= w[0].best_objective, "the best so far went down");
            assert_eq!(w[1].evaluations, w[0].evaluations + 40);
        }
        let last = &msgs[15];
        let best = last.best.as_ref().unwrap().values.clone();
        assert_eq!(best[2], 1.25, "the fixed coordinate moved");
        assert!((0.8..=1.6).contains(&best[1]) && (0.5..=2.0).contains(&best[0]), "{best:?}");
        assert_eq!(last.best_objective, msgs[14].best_objective);
        // The answer is what Score says of it, beats the box's centre, and comes within 1 % of
        // its best corner (this critic peaks on a corner, which the periodic rule rarely hits
        // exactly).
        let sc = d.score(pb::ScoreRequest { designs: vec![pb::Design { values: best.clone() }] }).await.unwrap().into_inner();
        assert_eq!((sc.scores[0].objective, sc.scores[0].spread), (last.best_objective, last.best_spread));
        let others = [[1.25, 1.2, 1.25], [0.5, 0.8, 1.25], [2.0, 1.6, 1.25], [0.5, 1.6, 1.25], [2.0, 0.8, 1.25]];
        let sc = d.score(designs(&others)).await.unwrap().into_inner();
        let top = sc.scores.iter().map(|o| o.objective).fold(f32::NEG_INFINITY, f32::max);
        assert!(last.best_objective > sc.scores[0].objective, "no better than the centre: {:?} vs {}", sc.scores, last.best_objective);
        assert!(last.best_objective >= top - 0.01 * top.abs(), "{:?} vs {}", sc.scores, last.best_objective);
        // The same request and seed: the same answer.
        assert_eq!(optimize_all(&mut d, req).await.last().unwrap().best, last.best);
        // CMA-ES.
        let req = pb::OptimizeRequest { method: "cmaes".into(), iterations: 20, seed: 1, ..Default::default() };
        let msgs = optimize_all(&mut d, req).await;
        assert!(msgs.last().unwrap().done && msgs.len() >= 2, "{}", msgs.len());
    });
}

#[test]
fn optimize_refuses_what_does_not_fit_and_stops_when_cancelled() {
    let (s, _) = server(ServeConfig { max_optimize_evaluations: 100_000_000, ..ServeConfig::default() });
    rt().block_on(async {
        let mut d = DesignServiceClient::new(channel(&s).await);
        let r = |f: &dyn Fn(&mut pb::OptimizeRequest)| {
            let mut r = pb::OptimizeRequest { particles: 10, iterations: 2, ..Default::default() };
            f(&mut r);
            r
        };
        invalid(d.optimize(r(&|r| r.method = "bfgs".into())).await, "method: \"bfgs\"");
        invalid(d.optimize(r(&|r| r.particles = 60_000_000)).await, "particles x iterations: 60000000 x 2");
        invalid(d.optimize(r(&|r| r.low = vec![0.5, 0.5])).await, "low: 2 values");
        invalid(d.optimize(r(&|r| r.high = vec![2.0, 2.5, 2.0])).await, "high[1] (shin): 2.5 is outside");
        let crossed = |r: &mut pb::OptimizeRequest| {
            r.low = vec![1.5, 0.5, 0.5];
            r.high = vec![1.0, 2.0, 2.0];
        };
        invalid(d.optimize(r(&crossed)).await, "low[0] (thigh): 1.5 is above high 1");
        invalid(d.optimize(r(&|r| r.fixed = vec![pb::FixedCoordinate { dimension: 3, value: 1.0 }])).await, "fixed[0].dimension: 3");
        invalid(d.optimize(r(&|r| r.fixed = vec![pb::FixedCoordinate { dimension: 0, value: 9.0 }])).await, "fixed[0].value: 9");
        let all = (0..3).map(|j| pb::FixedCoordinate { dimension: j, value: 1.0 }).collect::<Vec<_>>();
        invalid(d.optimize(r(&|r| r.fixed = all.clone())).await, "fixed: every coordinate is fixed");

        // A search of 10,000 x 1,000 designs (minutes), cancelled after its first message: the
        // server's one scoring place is free again at once.
        let mut stream =
            d.optimize(pb::OptimizeRequest { particles: 10_000, iterations: 1_000, ..Default::default() }).await.unwrap().into_inner();
        assert!(!stream.message().await.unwrap().unwrap().done);
        drop(stream);
        let t = std::time::Instant::now();
        let sc = tokio::time::timeout(std::time::Duration::from_secs(10), d.score(designs(&[[1.0; DIM]]))).await;
        assert!(sc.is_ok_and(|r| r.is_ok()), "Score waited behind a cancelled search");
        assert!(t.elapsed() < std::time::Duration::from_secs(5), "the cancelled search held the pool for {:?}", t.elapsed());
    });
}

#[test]
fn landscape_lays_the_grid_over_the_designs_tried_and_refuses_a_grid_too_large() {
    let (s, n) = server(ServeConfig { max_score_batch: 100, ..ServeConfig::default() });
    rt().block_on(async {
        let mut d = DesignServiceClient::new(channel(&s).await);
        let l = d.landscape(pb::LandscapeRequest { grid: 4 }).await.unwrap().into_inner();
        assert_eq!((l.pc1.len(), l.pc2.len(), l.objective.len()), (4, 4, 16));
        // The rejected proposal is not a design tried.
        assert_eq!(l.designs.iter().map(|p| p.index).collect::<Vec<_>>(), vec![0, 1, 2]);
        // Each grid value is Eq. 5.6 at mean + pc1 axis1 + pc2 axis2, clipped to the box.
        let (mean, a1, a2) = (l.mean.unwrap().values, l.axis1.unwrap().values, l.axis2.unwrap().values);
        for (j, &p2) in l.pc2.iter().enumerate() {
            for (i, &p1) in l.pc1.iter().enumerate() {
                let x: Vec<f32> = (0..DIM).map(|k| (mean[k] + p1 * a1[k] + p2 * a2[k]).clamp(0.5, 2.0)).collect();
                let (want, _) = reference(&n, &x);
                let got = l.objective[j * 4 + i];
                assert!((got - want).abs() <= 1e-4 * want.abs().max(1.0), "({i}, {j}): {got} vs {want}");
            }
        }
        // The designs differ only in the second coordinate: all the variance on one axis.
        assert!((l.explained1 - 1.0).abs() < 1e-5, "{}", l.explained1);
        invalid(d.landscape(pb::LandscapeRequest { grid: 11 }).await, "grid: 11 x 11 points");
    });
}

async fn optimize_all(d: &mut DesignServiceClient<Channel>, r: pb::OptimizeRequest) -> Vec<pb::OptimizeProgress> {
    let mut s = d.optimize(r).await.unwrap().into_inner();
    let mut out = Vec::new();
    while let Some(m) = s.message().await.unwrap() {
        out.push(m);
    }
    out
}
