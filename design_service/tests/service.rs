//! The DesignService and the Open Inference Protocol over a real server on port 0: values
//! against a plain forward pass of the networks, ModelInfer equal to Score, every malformed
//! request answered INVALID_ARGUMENT naming its field, History paged on whole designs, health
//! and reflection.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::sync::Arc;

use coadapt_core::BoxSpace;
use coadapt_design_optimizer::objective::QMode;
use coadapt_design_service::{DesignModel, HistoryRow, LiveSource, ServeConfig, StaticSource, serve};
use coadapt_nn::Mlp;
use coadapt_wire::inference as oip;
use coadapt_wire::inference::grpc_inference_service_client::GrpcInferenceServiceClient;
use coadapt_wire::pb;
use coadapt_wire::pb::design_service_client::DesignServiceClient;
use rand::Rng;
use tonic::Code;
use tonic::transport::Channel;

const STATE: usize = 5;
const DIM: usize = 3;
const ACT: usize = 2;
const STATES: usize = 7;

struct Nets {
    policy: Mlp,
    phi: Vec<f32>,
    critic: Mlp,
    theta: Vec<f32>,
    /// A second critic (the twin), for the disagreement.
    theta2: Vec<f32>,
    starts: Vec<f32>,
}

fn nets() -> Nets {
    let mut rng = coadapt_core::rng(7, 0);
    let obs = STATE + DIM;
    let policy = Mlp::new(&[obs, 16, 16, 2 * ACT]).unwrap();
    let critic = Mlp::new(&[obs + ACT, 16, 16, 1]).unwrap();
    let (mut phi, mut theta) = (policy.zeros(), critic.zeros());
    // A last layer as large as the hidden ones: values far from zero, so a mistake shows.
    policy.init(&mut phi, 0.5, &mut rng);
    critic.init(&mut theta, 0.5, &mut rng);
    let starts = (0..STATES * obs).map(|_| rng.random_range(-1.0..1.0)).collect();
    let mut theta2 = critic.zeros();
    critic.init(&mut theta2, 0.5, &mut rng);
    Nets { policy, phi, critic, theta, theta2, starts }
}

/// Eq. 5.6 by plain forward passes: for each start state, the design put in its design
/// columns, the policy's mean squashed by tanh, Q1 of that; mean and standard deviation over
/// the states.
fn reference(n: &Nets, design: &[f32]) -> (f32, f32) {
    let qs = q_per_state(n, &n.theta, design);
    let mu = qs.iter().sum::<f64>() / qs.len() as f64;
    let sd = (qs.iter().map(|q| (q - mu).powi(2)).sum::<f64>() / qs.len() as f64).sqrt();
    (mu as f32, sd as f32)
}

/// The twin critics' disagreement by plain forward passes: the mean over the start states of
/// |Q1 - Q2| / 2.
fn reference_disagreement(n: &Nets, design: &[f32]) -> f32 {
    let (q1, q2) = (q_per_state(n, &n.theta, design), q_per_state(n, &n.theta2, design));
    (q1.iter().zip(&q2).map(|(a, b)| (a - b).abs() / 2.0).sum::<f64>() / q1.len() as f64) as f32
}

/// Q of critic `theta` at each start state with `design` and the policy's squashed mean.
fn q_per_state(n: &Nets, theta: &[f32], design: &[f32]) -> Vec<f64> {
    let obs = STATE + DIM;
    let mut qs = Vec::new();
    for s in n.starts.chunks_exact(obs) {
        let mut x = s.to_vec();
        x[STATE..].copy_from_slice(design);
        let mut act = n.policy.activations(1);
        let out = n.policy.forward(&n.phi, &x, 1, &mut act);
        let a: Vec<f32> = out[..ACT].iter().map(|m| m.tanh()).collect();
        let xa: Vec<f32> = x.iter().chain(&a).copied().collect();
        let mut act = n.critic.activations(1);
        qs.push(f64::from(n.critic.forward(theta, &xa, 1, &mut act)[0]));
    }
    qs
}

fn row(index: usize, prototype: &str) -> HistoryRow {
    HistoryRow {
        index,
        kind: if index == 0 { "initial" } else { "exploit" }.into(),
        design: vec![1.0, 1.0 + index as f32 / 10.0, 1.0],
        episodes: if prototype == "rejected" { 0 } else { 3 },
        best_eval_return: (prototype != "rejected").then_some(10.0 + index as f32),
        last_eval_return: None,
        predicted_objective: (index > 0).then_some(5.5),
        design_rollouts: 0,
        method: if index == 0 { "fixed" } else { "pso-q" }.into(),
        prototype: prototype.into(),
    }
}

fn model(n: &Nets) -> DesignModel {
    model_with(n, &[&n.theta])
}

fn model_with(n: &Nets, thetas: &[&[f32]]) -> DesignModel {
    DesignModel::new(
        "toy".into(),
        vec!["thigh".into(), "shin".into(), "foot".into()],
        BoxSpace::new(vec![0.5; DIM], vec![2.0; DIM]).unwrap(),
        42,
        "run-1".into(),
        (&n.policy, &n.phi, &n.critic, thetas),
        &n.starts,
        STATE,
        QMode::First,
    )
    .unwrap()
}

fn server(cfg: ServeConfig) -> (coadapt_design_service::DesignServer, Nets) {
    let n = nets();
    let model = model(&n);
    let history = vec![row(0, ""), row(1, "rejected"), row(1, "confirmed"), row(2, "")];
    let s = serve("127.0.0.1:0".parse().unwrap(), cfg, Arc::new(StaticSource { model: Arc::new(model), history })).unwrap();
    (s, n)
}

fn rt() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap()
}

async fn channel(s: &coadapt_design_service::DesignServer) -> Channel {
    Channel::from_shared(format!("http://{}", s.local_addr())).unwrap().connect().await.unwrap()
}

fn designs(v: &[[f32; DIM]]) -> pb::ScoreRequest {
    pb::ScoreRequest { designs: v.iter().map(|d| pb::Design { values: d.to_vec() }).collect() }
}

#[track_caller]
fn invalid<T: std::fmt::Debug>(r: Result<tonic::Response<T>, tonic::Status>, field: &str) {
    let s = r.expect_err("accepted");
    assert_eq!(s.code(), Code::InvalidArgument, "{s:?}");
    assert!(s.message().starts_with(field), "{:?} does not name {field:?}", s.message());
}

#[test]
fn score_and_model_infer_give_eq_5_6_of_the_networks() {
    let (s, n) = server(ServeConfig::default());
    rt().block_on(async {
        let ch = channel(&s).await;
        let mut d = DesignServiceClient::new(ch.clone());
        let info = d.info(pb::InfoRequest {}).await.unwrap().into_inner();
        assert_eq!((info.robot.as_str(), info.weights_version, info.start_states, info.max_score_batch), ("toy", 42, 7, 10_000));
        assert_eq!(
            info.dimensions.iter().map(|x| (x.name.as_str(), x.low, x.high)).collect::<Vec<_>>(),
            [("thigh", 0.5, 2.0), ("shin", 0.5, 2.0), ("foot", 0.5, 2.0)]
        );
        let batch = [[1.0, 1.0, 1.0], [0.5, 2.0, 1.3], [2.0, 0.5, 0.7], [1.7, 1.1, 2.0]];
        let got = d.score(designs(&batch)).await.unwrap().into_inner();
        assert_eq!((got.weights_version, got.start_states, got.scores.len()), (42, 7, 4));
        let mut distinct = Vec::new();
        for (x, sc) in batch.iter().zip(&got.scores) {
            let (mu, sd) = reference(&n, x);
            assert!((sc.objective - mu).abs() <= 1e-4 * (1.0 + mu.abs()), "objective {} vs {mu} for {x:?}", sc.objective);
            assert!((sc.spread - sd).abs() <= 1e-4 * (1.0 + sd.abs()), "spread {} vs {sd} for {x:?}", sc.spread);
            assert_eq!(sc.disagreement, None, "one critic: no disagreement to report");
            distinct.push(sc.objective);
        }
        distinct.dedup();
        assert_eq!(distinct.len(), 4, "the designs score alike: {distinct:?}");

        // The same values through the Open Inference Protocol, typed and raw.
        let mut i = GrpcInferenceServiceClient::new(ch);
        let flat: Vec<f32> = batch.iter().flatten().copied().collect();
        let input = |contents| oip::model_infer_request::InferInputTensor {
            name: "design".into(),
            datatype: "FP32".into(),
            shape: vec![4, DIM as i64],
            parameters: Default::default(),
            contents,
        };
        let typed = oip::ModelInferRequest {
            model_name: "design-critic".into(),
            id: "q1".into(),
            inputs: vec![input(Some(oip::InferTensorContents { fp32_contents: flat.clone(), ..Default::default() }))],
            ..Default::default()
        };
        let r = i.model_infer(typed.clone()).await.unwrap().into_inner();
        assert_eq!((r.id.as_str(), r.model_version.as_str(), r.outputs[0].shape.as_slice()), ("q1", "42", &[4, 1][..]));
        let values = &r.outputs[0].contents.as_ref().unwrap().fp32_contents;
        assert_eq!(values, &got.scores.iter().map(|s| s.objective).collect::<Vec<_>>());
        let names: Vec<&str> = r.outputs.iter().map(|o| o.name.as_str()).collect();
        assert_eq!(names, ["value", "spread"], "no output named: all of the model's");
        let spread = &r.outputs[1].contents.as_ref().unwrap().fp32_contents;
        assert_eq!(spread, &got.scores.iter().map(|s| s.spread).collect::<Vec<_>>());
        let raw = oip::ModelInferRequest {
            inputs: vec![input(None)],
            raw_input_contents: vec![flat.iter().flat_map(|v| v.to_le_bytes()).collect()],
            ..typed.clone()
        };
        let r = i.model_infer(raw).await.unwrap().into_inner();
        let back: Vec<f32> = r.raw_output_contents[0].chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect();
        assert_eq!(&back, values);

        let meta = i
            .model_metadata(oip::ModelMetadataRequest { name: "design-critic".into(), version: String::new() })
            .await
            .unwrap()
            .into_inner();
        assert_eq!((meta.inputs[0].name.as_str(), meta.inputs[0].shape.as_slice()), ("design", &[-1, 3][..]));
        assert_eq!((meta.outputs[0].name.as_str(), meta.outputs[0].shape.as_slice()), ("value", &[-1, 1][..]));
        assert_eq!(meta.outputs.iter().map(|o| o.name.as_str()).collect::<Vec<_>>(), ["value", "spread"]);
        assert!(i.server_live(oip::ServerLiveRequest {}).await.unwrap().into_inner().live);
        assert!(i.server_ready(oip::ServerReadyRequest {}).await.unwrap().into_inner().ready);
        assert!(
            i.model_ready(oip::ModelReadyRequest { name: "design-critic".into(), version: "42".into() }).await.unwrap().into_inner().ready
        );
        let e = i.model_ready(oip::ModelReadyRequest { name: "nope".into(), version: String::new() }).await.unwrap_err();
        assert_eq!(e.code(), Code::NotFound);
    });
}

#[test]
fn with_the_twin_critics_a_score_says_how_far_they_disagree() {
    let n = nets();
    let model = model_with(&n, &[&n.theta, &n.theta2]);
    let s =
        serve("127.0.0.1:0".parse().unwrap(), ServeConfig::default(), Arc::new(StaticSource { model: Arc::new(model), history: vec![] }))
            .unwrap();
    rt().block_on(async {
        let ch = channel(&s).await;
        let batch = [[1.0, 1.0, 1.0], [0.5, 2.0, 1.3], [2.0, 0.5, 0.7]];
        let got = DesignServiceClient::new(ch.clone()).score(designs(&batch)).await.unwrap().into_inner();
        for (x, sc) in batch.iter().zip(&got.scores) {
            let (mu, _) = reference(&n, x);
            assert!((sc.objective - mu).abs() <= 1e-4 * (1.0 + mu.abs()), "Q1 still scores: {} vs {mu}", sc.objective);
            let want = reference_disagreement(&n, x);
            let d = sc.disagreement.expect("two critics: a disagreement");
            assert!(want > 1e-3, "the critics differ here: {want}");
            assert!((d - want).abs() <= 1e-4 * (1.0 + want), "disagreement {d} vs {want} for {x:?}");
        }

        let mut i = GrpcInferenceServiceClient::new(ch);
        let flat: Vec<f32> = batch.iter().flatten().copied().collect();
        let out = |name: &str| oip::model_infer_request::InferRequestedOutputTensor { name: name.into(), parameters: Default::default() };
        let req = oip::ModelInferRequest {
            model_name: "design-critic".into(),
            inputs: vec![oip::model_infer_request::InferInputTensor {
                name: "design".into(),
                datatype: "FP32".into(),
                shape: vec![3, DIM as i64],
                parameters: Default::default(),
                contents: None,
            }],
            raw_input_contents: vec![flat.iter().flat_map(|v| v.to_le_bytes()).collect()],
            outputs: vec![out("disagreement"), out("value")],
            ..Default::default()
        };
        let r = i.model_infer(req.clone()).await.unwrap().into_inner();
        assert_eq!(r.outputs.iter().map(|o| o.name.as_str()).collect::<Vec<_>>(), ["disagreement", "value"], "in the order asked");
        let raw: Vec<Vec<f32>> =
            r.raw_output_contents.iter().map(|b| b.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect()).collect();
        assert_eq!(raw[0], got.scores.iter().map(|s| s.disagreement.unwrap()).collect::<Vec<_>>());
        assert_eq!(raw[1], got.scores.iter().map(|s| s.objective).collect::<Vec<_>>());
        let meta = i
            .model_metadata(oip::ModelMetadataRequest { name: "design-critic".into(), version: String::new() })
            .await
            .unwrap()
            .into_inner();
        assert_eq!(meta.outputs.iter().map(|o| o.name.as_str()).collect::<Vec<_>>(), ["value", "spread", "disagreement"]);
        let twice = oip::ModelInferRequest { outputs: vec![out("value"), out("value")], ..req };
        invalid(i.model_infer(twice).await, "outputs[1].name");
    });
}

#[test]
fn malformed_requests_are_refused_naming_the_field() {
    let (s, _) = server(ServeConfig { max_score_batch: 5, ..ServeConfig::default() });
    rt().block_on(async {
        let ch = channel(&s).await;
        let mut d = DesignServiceClient::new(ch.clone());
        invalid(d.score(designs(&[])).await, "designs: empty");
        invalid(d.score(designs(&[[1.0; DIM]; 6])).await, "designs: 6 designs, at most 5");
        let short = pb::ScoreRequest { designs: vec![pb::Design { values: vec![1.0; DIM] }, pb::Design { values: vec![1.0; 2] }] };
        invalid(d.score(short).await, "designs[1].values: 2 values");
        invalid(d.score(designs(&[[1.0, 1.0, 2.5]])).await, "designs[0].values[2] (foot): 2.5 is outside the design box");
        invalid(d.score(designs(&[[f32::NAN, 1.0, 1.0]])).await, "designs[0].values[0] (thigh)");

        let mut i = GrpcInferenceServiceClient::new(ch);
        let req = |shape: Vec<i64>, n: usize| oip::ModelInferRequest {
            model_name: "design-critic".into(),
            inputs: vec![oip::model_infer_request::InferInputTensor {
                name: "design".into(),
                datatype: "FP32".into(),
                shape,
                parameters: Default::default(),
                contents: Some(oip::InferTensorContents { fp32_contents: vec![1.0; n], ..Default::default() }),
            }],
            ..Default::default()
        };
        invalid(i.model_infer(req(vec![2, 4], 8)).await, "inputs[0].shape");
        invalid(i.model_infer(req(vec![6, 3], 18)).await, "inputs[0].shape: [6, 3]: N must be 1 to 5");
        invalid(i.model_infer(req(vec![2, 3], 5)).await, "inputs[0].contents.fp32_contents: 5 values");
        let mut r = req(vec![1, 3], 0);
        r.inputs[0].contents = None;
        r.raw_input_contents = vec![vec![0; 11]];
        invalid(i.model_infer(r).await, "raw_input_contents[0]: 11 bytes");
        let mut r = req(vec![1, 3], 3);
        r.inputs[0].datatype = "FP64".into();
        invalid(i.model_infer(r).await, "inputs[0].datatype");
        let mut r = req(vec![1, 3], 3);
        r.outputs = vec![oip::model_infer_request::InferRequestedOutputTensor { name: "q".into(), parameters: Default::default() }];
        invalid(i.model_infer(r).await, "outputs[0].name");
        let mut r = req(vec![1, 3], 3);
        r.model_name = "other".into();
        assert_eq!(i.model_infer(r).await.unwrap_err().code(), Code::NotFound);
        let mut r = req(vec![1, 3], 3);
        r.model_version = "41".into();
        assert_eq!(i.model_infer(r).await.unwrap_err().code(), Code::NotFound);
    });
}

#[test]
fn history_pages_end_on_whole_designs() {
    let (s, _) = server(ServeConfig::default());
    rt().block_on(async {
        let mut d = DesignServiceClient::new(channel(&s).await);
        let p = d.history(pb::HistoryRequest { from_index: 0, max_rows: 2 }).await.unwrap().into_inner();
        // Rows 0 and 1 (rejected) fit the page; design 1's final row comes with them.
        assert_eq!(
            p.designs.iter().map(|r| (r.index, r.prototype.as_str())).collect::<Vec<_>>(),
            [(0, ""), (1, "rejected"), (1, "confirmed")]
        );
        assert_eq!((p.next_index, p.more), (2, true));
        assert_eq!(p.designs[0].design.as_ref().unwrap().values, [1.0, 1.0, 1.0]);
        assert_eq!(
            (p.designs[2].best_eval_return, p.designs[2].predicted_objective, p.designs[0].predicted_objective),
            (Some(11.0), Some(5.5), None)
        );
        let p = d.history(pb::HistoryRequest { from_index: p.next_index, max_rows: 0 }).await.unwrap().into_inner();
        assert_eq!((p.designs.len(), p.designs[0].index, p.more), (1, 2, false));
    });
}

#[test]
fn health_and_reflection_name_both_services() {
    use tonic_health::pb::health_check_response::ServingStatus;
    use tonic_health::pb::{HealthCheckRequest, health_client::HealthClient};
    use tonic_reflection::pb::v1::ServerReflectionRequest;
    use tonic_reflection::pb::v1::server_reflection_client::ServerReflectionClient;
    use tonic_reflection::pb::v1::server_reflection_request::MessageRequest;
    use tonic_reflection::pb::v1::server_reflection_response::MessageResponse;
    let (s, _) = server(ServeConfig::default());
    rt().block_on(async {
        let ch = channel(&s).await;
        let mut health = HealthClient::new(ch.clone());
        for service in ["", "coadapt.v1.DesignService", "inference.GRPCInferenceService"] {
            let st = health.check(HealthCheckRequest { service: service.into() }).await.unwrap().into_inner().status;
            assert_eq!(st, ServingStatus::Serving as i32, "{service:?}");
        }
        let mut reflection = ServerReflectionClient::new(ch);
        let req = ServerReflectionRequest { host: String::new(), message_request: Some(MessageRequest::ListServices(String::new())) };
        let mut answers = reflection.server_reflection_info(tokio_stream::iter(vec![req])).await.unwrap().into_inner();
        let Some(MessageResponse::ListServicesResponse(list)) = answers.message().await.unwrap().unwrap().message_response else {
            panic!("not a service list")
        };
        let names: Vec<_> = list.service.into_iter().map(|s| s.name).collect();
        for want in ["coadapt.v1.DesignService", "inference.GRPCInferenceService", "grpc.health.v1.Health"] {
            assert!(names.iter().any(|n| n == want), "{want} missing from {names:?}");
        }
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

async fn next(w: &mut tonic::Streaming<pb::DesignEvent>) -> Option<pb::DesignEvent> {
    tokio::time::timeout(std::time::Duration::from_secs(5), w.message()).await.expect("no event in 5 s").unwrap()
}

#[test]
fn watch_streams_the_history_then_each_change_until_the_run_ends() {
    let n = nets();
    // A resumed run's rows: design 1 is the open one.
    let live = Arc::new(LiveSource::new(vec![row(0, ""), row(1, "rejected")]));
    // Streams outlive the server's deadline for a call.
    let cfg = ServeConfig { rpc_timeout: std::time::Duration::from_millis(300), ..ServeConfig::default() };
    let s = serve("127.0.0.1:0".parse().unwrap(), cfg, live.clone()).unwrap();
    rt().block_on(async {
        let mut d = DesignServiceClient::new(channel(&s).await);
        // No networks yet: UNAVAILABLE, but the history is there.
        assert_eq!(d.info(pb::InfoRequest {}).await.unwrap_err().code(), Code::Unavailable);
        let h = d.history(pb::HistoryRequest { from_index: 0, max_rows: 0 }).await.unwrap().into_inner();
        assert_eq!(h.designs.len(), 2);
        let mut w = d.watch(pb::WatchDesignsRequest { from_index: 1 }).await.unwrap().into_inner();
        let first = next(&mut w).await.unwrap().design.unwrap();
        assert_eq!((first.index, first.prototype.as_str()), (1, "rejected"));
        tokio::time::sleep(std::time::Duration::from_millis(600)).await;
        // Design 1 chosen again and confirmed, then trained; design 2 chosen.
        let mut chosen = row(1, "confirmed");
        chosen.episodes = 0;
        live.upsert(chosen);
        live.upsert(row(1, "confirmed"));
        live.set_model(model(&n));
        live.upsert(row(2, ""));
        let got: Vec<(u32, u32, String)> = {
            let mut v = Vec::new();
            for _ in 0..3 {
                let r = next(&mut w).await.unwrap().design.unwrap();
                v.push((r.index, r.episodes, r.prototype));
            }
            v
        };
        assert_eq!(got, vec![(1, 0, "confirmed".into()), (1, 3, "confirmed".into()), (2, 3, String::new())]);
        // The history keeps the rejected proposal and the confirmed row, and the new design.
        let h = d.history(pb::HistoryRequest { from_index: 1, max_rows: 1 }).await.unwrap().into_inner();
        assert_eq!(
            h.designs.iter().map(|r| (r.index, r.prototype.clone())).collect::<Vec<_>>(),
            vec![(1, "rejected".to_string()), (1, "confirmed".to_string())]
        );
        assert!(h.more);
        assert_eq!(d.info(pb::InfoRequest {}).await.unwrap().into_inner().weights_version, 42);
        live.end();
        assert!(next(&mut w).await.is_none(), "the stream ends with the run");
        // A Watch after the end: the rows, then the end.
        let mut w = d.watch(pb::WatchDesignsRequest { from_index: 0 }).await.unwrap().into_inner();
        let mut rows = 0;
        while next(&mut w).await.is_some() {
            rows += 1;
        }
        assert_eq!(rows, 4);
    });
}

#[test]
fn a_server_stops_within_its_grace_whatever_its_clients_do() {
    let (s, _) = server(ServeConfig::default());
    let rt = rt();
    // A client that made a call and then went quiet without closing its connection (its
    // runtime is not polled again: as a frozen or hostile peer would).
    let mut d = rt.block_on(async { DesignServiceClient::new(channel(&s).await) });
    rt.block_on(d.info(pb::InfoRequest {})).unwrap();
    let t = std::time::Instant::now();
    drop(s);
    let took = t.elapsed();
    assert!(took < std::time::Duration::from_secs(3), "the server took {took:?} to stop");
    drop(d);
}
