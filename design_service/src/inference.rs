//! The Open Inference Protocol (KServe v2): the design critic as the model `design-critic`,
//! input `design` FP32 `[N, D]`, outputs FP32 `[N, 1]`: `value` (Eq. 5.6, as Score's
//! `objective`), `spread` (its standard deviation over the start states) and, when the served
//! networks have two critics or more, `disagreement` (the mean over the start states of the
//! critics' sd over their heads: `|Q1 - Q2| / 2` for the twin). A request that names no output gets them all, as the protocol says.

use std::sync::Arc;

use coadapt_wire::inference as oip;
use coadapt_wire::inference::grpc_inference_service_server::GrpcInferenceService;
use tonic::{Request, Response, Status};

use crate::MODEL_NAME;
use crate::shared::Shared;

#[derive(Debug)]
pub(crate) struct Inference {
    pub(crate) shared: Arc<Shared>,
}

const INPUT: &str = "design";

/// An output of the model.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Output {
    Value,
    Spread,
    Disagreement,
}

impl Output {
    fn name(self) -> &'static str {
        match self {
            Self::Value => "value",
            Self::Spread => "spread",
            Self::Disagreement => "disagreement",
        }
    }

    /// The outputs `m` has, in the order an unnamed request gets them.
    fn of(m: &crate::DesignModel) -> Vec<Self> {
        let mut all = vec![Self::Value, Self::Spread];
        if m.has_disagreement() {
            all.push(Self::Disagreement);
        }
        all
    }
}

/// The outputs `req` asks for (all when it names none), or `INVALID_ARGUMENT` naming the field.
fn outputs_of(req: &oip::ModelInferRequest, m: &crate::DesignModel) -> Result<Vec<Output>, Status> {
    let all = Output::of(m);
    if req.outputs.is_empty() {
        return Ok(all);
    }
    let names = all.iter().map(|o| format!("{:?}", o.name())).collect::<Vec<_>>().join(", ");
    let mut asked = Vec::new();
    for (i, o) in req.outputs.iter().enumerate() {
        let Some(&out) = all.iter().find(|x| x.name() == o.name) else {
            return Err(Status::invalid_argument(format!("outputs[{i}].name: {:?}; {MODEL_NAME} has the outputs {names}", o.name)));
        };
        if asked.contains(&out) {
            return Err(Status::invalid_argument(format!("outputs[{i}].name: {:?} is asked for twice", o.name)));
        }
        asked.push(out);
    }
    Ok(asked)
}

impl Inference {
    /// The model asked for, if it is ours (any version: empty or the current one).
    fn model_named(&self, name: &str, version: &str) -> Result<Arc<crate::DesignModel>, Status> {
        if name != MODEL_NAME {
            return Err(Status::not_found(format!("model_name: no model {name:?}; this server has {MODEL_NAME:?}")));
        }
        let m = self.shared.model()?;
        if !version.is_empty() && version != m.weights_version.to_string() {
            return Err(Status::not_found(format!(
                "model_version: {MODEL_NAME} has version {} (the population networks' version), not {version:?}",
                m.weights_version
            )));
        }
        Ok(m)
    }
}

/// The designs of `req` as one `n x dim` array, or `INVALID_ARGUMENT` naming the field.
fn designs_of(req: &oip::ModelInferRequest, m: &crate::DesignModel, max: usize) -> Result<(Vec<f32>, bool), Status> {
    let bad = |field: &str, why: String| Status::invalid_argument(format!("{field}: {why}"));
    let [input] = req.inputs.as_slice() else {
        return Err(bad("inputs", format!("{} inputs; {MODEL_NAME} takes one, {INPUT:?}", req.inputs.len())));
    };
    if input.name != INPUT {
        return Err(bad("inputs[0].name", format!("{:?}; {MODEL_NAME} takes {INPUT:?}", input.name)));
    }
    if input.datatype != "FP32" {
        return Err(bad("inputs[0].datatype", format!("{:?}; {INPUT} is FP32", input.datatype)));
    }
    let dim = m.design_dim();
    let (n, d) = match input.shape.as_slice() {
        &[n, d] => (n, d),
        s => return Err(bad("inputs[0].shape", format!("{s:?}; {INPUT} is [N, {dim}]"))),
    };
    if d != dim as i64 {
        return Err(bad("inputs[0].shape", format!("[{n}, {d}]; the design has {dim} dimensions: [N, {dim}]")));
    }
    if n < 1 || n > max as i64 {
        return Err(bad("inputs[0].shape", format!("[{n}, {d}]: N must be 1 to {max} (the server's max-score-batch)")));
    }
    let count = n as usize * dim;
    let given = input.contents.as_ref().is_some_and(|c| !c.fp32_contents.is_empty());
    let (values, raw) = if req.raw_input_contents.is_empty() {
        let c = input.contents.as_ref().map(|c| c.fp32_contents.as_slice()).unwrap_or_default();
        if c.len() != count {
            return Err(bad("inputs[0].contents.fp32_contents", format!("{} values for shape [{n}, {d}] ({count})", c.len())));
        }
        (c.to_vec(), false)
    } else {
        if given {
            return Err(bad("raw_input_contents", "given with inputs[0].contents; send the data in one of them".into()));
        }
        let [bytes] = req.raw_input_contents.as_slice() else {
            return Err(bad("raw_input_contents", format!("{} entries for one input", req.raw_input_contents.len())));
        };
        if bytes.len() != count * 4 {
            return Err(bad("raw_input_contents[0]", format!("{} bytes for FP32 [{n}, {d}] ({} bytes)", bytes.len(), count * 4)));
        }
        (bytes.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect(), true)
    };
    for (k, row) in values.chunks_exact(dim).enumerate() {
        crate::shared::check_design(row, m, &format!("inputs[0] row {k}"))?;
    }
    Ok((values, raw))
}

#[tonic::async_trait]
impl GrpcInferenceService for Inference {
    async fn server_live(&self, _: Request<oip::ServerLiveRequest>) -> Result<Response<oip::ServerLiveResponse>, Status> {
        Ok(Response::new(oip::ServerLiveResponse { live: true }))
    }

    async fn server_ready(&self, _: Request<oip::ServerReadyRequest>) -> Result<Response<oip::ServerReadyResponse>, Status> {
        Ok(Response::new(oip::ServerReadyResponse { ready: self.shared.source.model().is_some() }))
    }

    async fn model_ready(&self, req: Request<oip::ModelReadyRequest>) -> Result<Response<oip::ModelReadyResponse>, Status> {
        let r = req.into_inner();
        let ready = match self.model_named(&r.name, &r.version) {
            Ok(_) => true,
            Err(s) if s.code() == tonic::Code::Unavailable => false,
            Err(s) => return Err(s),
        };
        Ok(Response::new(oip::ModelReadyResponse { ready }))
    }

    async fn server_metadata(&self, _: Request<oip::ServerMetadataRequest>) -> Result<Response<oip::ServerMetadataResponse>, Status> {
        Ok(Response::new(oip::ServerMetadataResponse {
            name: "coadapt".into(),
            version: env!("CARGO_PKG_VERSION").into(),
            extensions: vec![],
        }))
    }

    async fn model_metadata(&self, req: Request<oip::ModelMetadataRequest>) -> Result<Response<oip::ModelMetadataResponse>, Status> {
        let r = req.into_inner();
        let m = self.model_named(&r.name, &r.version)?;
        let tensor = |name: &str, shape: Vec<i64>| oip::model_metadata_response::TensorMetadata {
            name: name.into(),
            datatype: "FP32".into(),
            shape,
        };
        Ok(Response::new(oip::ModelMetadataResponse {
            name: MODEL_NAME.into(),
            versions: vec![m.weights_version.to_string()],
            platform: "coadapt".into(),
            inputs: vec![tensor(INPUT, vec![-1, m.design_dim() as i64])],
            outputs: Output::of(&m).into_iter().map(|o| tensor(o.name(), vec![-1, 1])).collect(),
        }))
    }

    async fn model_infer(&self, req: Request<oip::ModelInferRequest>) -> Result<Response<oip::ModelInferResponse>, Status> {
        let r = req.into_inner();
        let m = self.model_named(&r.model_name, &r.model_version)?;
        let (designs, raw) = designs_of(&r, &m, self.shared.cfg.max_score_batch)?;
        let wanted = outputs_of(&r, &m)?;
        let n = designs.len() / m.design_dim();
        let s = self.shared.score_with(m.clone(), designs, wanted.contains(&Output::Disagreement)).await?;
        let (mut outputs, mut raw_output_contents) = (Vec::new(), Vec::new());
        for o in wanted {
            let values = match o {
                Output::Value => s.mean.clone(),
                Output::Spread => s.spread.clone(),
                Output::Disagreement => s.disagreement.clone().ok_or_else(|| Status::internal("the disagreement was not computed"))?,
            };
            let mut out = oip::model_infer_response::InferOutputTensor {
                name: o.name().into(),
                datatype: "FP32".into(),
                shape: vec![n as i64, 1],
                parameters: Default::default(),
                contents: None,
            };
            // Answer in kind: raw bytes to a raw request (what Triton's clients send), typed
            // contents otherwise.
            if raw {
                raw_output_contents.push(values.iter().flat_map(|v| v.to_le_bytes()).collect());
            } else {
                out.contents = Some(oip::InferTensorContents { fp32_contents: values, ..Default::default() });
            }
            outputs.push(out);
        }
        Ok(Response::new(oip::ModelInferResponse {
            model_name: MODEL_NAME.into(),
            model_version: m.weights_version.to_string(),
            id: r.id,
            parameters: Default::default(),
            outputs,
            raw_output_contents,
        }))
    }
}
