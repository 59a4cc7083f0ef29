//! The toy networks, their values by plain forward passes, a server on port 0 and its clients.

pub use std::sync::Arc;

pub use coadapt_core::BoxSpace;
pub use coadapt_design_optimizer::objective::QMode;
pub use coadapt_design_service::{DesignModel, HistoryRow, LiveSource, ServeConfig, StaticSource, serve};
pub use coadapt_nn::Mlp;
pub use coadapt_wire::inference as oip;
pub use coadapt_wire::inference::grpc_inference_service_client::GrpcInferenceServiceClient;
pub use coadapt_wire::pb;
pub use coadapt_wire::pb::design_service_client::DesignServiceClient;
pub use rand::Rng;
pub use tonic::Code;
pub use tonic::transport::Channel;

pub const STATE: usize = 5;
pub const DIM: usize = 3;
pub const ACT: usize = 2;
pub const STATES: usize = 7;

pub struct Nets {
    pub policy: Mlp,
    pub phi: Vec<f32>,
    pub critic: Mlp,
    pub theta: Vec<f32>,
    /// A second critic (the twin), for the disagreement.
    pub theta2: Vec<f32>,
    pub starts: Vec<f32>,
}

pub fn nets() -> Nets {
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
pub fn reference(n: &Nets, design: &[f32]) -> (f32, f32) {
    let qs = q_per_state(n, &n.theta, design);
    let mu = qs.iter().sum::<f64>() / qs.len() as f64;
    let sd = (qs.iter().map(|q| (q - mu).powi(2)).sum::<f64>() / qs.len() as f64).sqrt();
    (mu as f32, sd as f32)
}

/// The twin critics' disagreement by plain forward passes: the mean over the start states of
/// |Q1 - Q2| / 2.
pub fn reference_disagreement(n: &Nets, design: &[f32]) -> f32 {
    let (q1, q2) = (q_per_state(n, &n.theta, design), q_per_state(n, &n.theta2, design));
    (q1.iter().zip(&q2).map(|(a, b)| (a - b).abs() / 2.0).sum::<f64>() / q1.len() as f64) as f32
}

/// Q of critic `theta` at each start state with `design` and the policy's squashed mean.
pub fn q_per_state(n: &Nets, theta: &[f32], design: &[f32]) -> Vec<f64> {
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

pub fn row(index: usize, prototype: &str) -> HistoryRow {
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

pub fn model(n: &Nets) -> DesignModel {
    model_with(n, &[&n.theta])
}

pub fn model_with(n: &Nets, thetas: &[&[f32]]) -> DesignModel {
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

pub fn server(cfg: ServeConfig) -> (coadapt_design_service::DesignServer, Nets) {
    let n = nets();
    let model = model(&n);
    let history = vec![row(0, ""), row(1, "rejected"), row(1, "confirmed"), row(2, "")];
    let s = serve("127.0.0.1:0".parse().unwrap(), cfg, Arc::new(StaticSource { model: Arc::new(model), history })).unwrap();
    (s, n)
}

pub fn rt() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap()
}

pub async fn channel(s: &coadapt_design_service::DesignServer) -> Channel {
    Channel::from_shared(format!("http://{}", s.local_addr())).unwrap().connect().await.unwrap()
}

pub fn designs(v: &[[f32; DIM]]) -> pb::ScoreRequest {
    pb::ScoreRequest { designs: v.iter().map(|d| pb::Design { values: d.to_vec() }).collect() }
}

#[track_caller]
pub fn invalid<T: std::fmt::Debug>(r: Result<tonic::Response<T>, tonic::Status>, field: &str) {
    let s = r.expect_err("accepted");
    assert_eq!(s.code(), Code::InvalidArgument, "{s:?}");
    assert!(s.message().starts_with(field), "{:?} does not name {field:?}", s.message());
}
