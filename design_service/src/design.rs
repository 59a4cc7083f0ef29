//! `coadapt.v1.DesignService`: Info, Score, History (Optimize, Landscape and Watch have their
//! own modules).

use std::sync::Arc;

use coadapt_wire::pb;
use coadapt_wire::pb::design_service_server::DesignService;
use tonic::{Request, Response, Status};

use crate::model::HistoryRow;
use crate::shared::Shared;

#[derive(Debug)]
pub(crate) struct Design {
    pub(crate) shared: Arc<Shared>,
}

/// The designs of a Score request as one `n x dim` array, or `INVALID_ARGUMENT` naming the
/// first field that does not fit.
fn designs_of(req: &pb::ScoreRequest, model: &crate::DesignModel, max: usize) -> Result<Vec<f32>, Status> {
    let n = req.designs.len();
    if n == 0 {
        return Err(Status::invalid_argument("designs: empty; send at least one design"));
    }
    if n > max {
        return Err(Status::invalid_argument(format!("designs: {n} designs, at most {max} per call (the server's max-score-batch)")));
    }
    let dim = model.design_dim();
    let mut flat = Vec::with_capacity(n * dim);
    for (i, d) in req.designs.iter().enumerate() {
        crate::shared::check_design(&d.values, model, &format!("designs[{i}].values"))?;
        flat.extend_from_slice(&d.values);
    }
    Ok(flat)
}

pub(crate) fn record(r: HistoryRow) -> pb::DesignRecord {
    pb::DesignRecord {
        index: u32::try_from(r.index).unwrap_or(u32::MAX),
        kind: r.kind,
        design: Some(pb::Design { values: r.design }),
        episodes: u32::try_from(r.episodes).unwrap_or(u32::MAX),
        best_eval_return: r.best_eval_return,
        last_eval_return: r.last_eval_return,
        predicted_objective: r.predicted_objective,
        design_rollouts: r.design_rollouts,
        method: r.method,
        prototype: r.prototype,
    }
}

#[tonic::async_trait]
impl DesignService for Design {
    async fn info(&self, _: Request<pb::InfoRequest>) -> Result<Response<pb::InfoReply>, Status> {
        let m = self.shared.model()?;
        let dimensions = m
            .names
            .iter()
            .zip(m.bounds.low.iter().zip(&m.bounds.high))
            .map(|(name, (&low, &high))| pb::DesignDimension { name: name.clone(), unit: "x".into(), low, high })
            .collect();
        Ok(Response::new(pb::InfoReply {
            robot: m.robot.clone(),
            dimensions,
            weights_version: m.weights_version,
            start_states: u32::try_from(m.start_states()).unwrap_or(u32::MAX),
            max_score_batch: u32::try_from(self.shared.cfg.max_score_batch).unwrap_or(u32::MAX),
            max_optimize_evaluations: self.shared.cfg.max_optimize_evaluations,
            run_id: m.run_id.clone(),
        }))
    }

    async fn score(&self, req: Request<pb::ScoreRequest>) -> Result<Response<pb::ScoreReply>, Status> {
        let m = self.shared.model()?;
        let designs = designs_of(req.get_ref(), &m, self.shared.cfg.max_score_batch)?;
        let s = self.shared.score_with(m.clone(), designs, true).await?;
        let gap = |i: usize| s.disagreement.as_ref().map(|d| d[i]);
        Ok(Response::new(pb::ScoreReply {
            scores: (0..s.mean.len())
                .map(|i| pb::DesignScore { objective: s.mean[i], spread: s.spread[i], disagreement: gap(i) })
                .collect(),
            weights_version: m.weights_version,
            start_states: u32::try_from(m.start_states()).unwrap_or(u32::MAX),
        }))
    }

    type OptimizeStream = tokio_stream::wrappers::ReceiverStream<Result<pb::OptimizeProgress, Status>>;

    async fn optimize(&self, req: Request<pb::OptimizeRequest>) -> Result<Response<Self::OptimizeStream>, Status> {
        let m = self.shared.model()?;
        let search = crate::optimize::Search::of(req.get_ref(), &m, self.shared.cfg.max_optimize_evaluations)?;
        Ok(Response::new(crate::optimize::start(&self.shared, m, search).await?))
    }

    async fn history(&self, req: Request<pb::HistoryRequest>) -> Result<Response<pb::HistoryReply>, Status> {
        let r = req.into_inner();
        let page = self.shared.cfg.history_page;
        let max = if r.max_rows == 0 { page } else { (r.max_rows as usize).min(page) };
        let from = r.from_index as usize;
        let p = self.shared.source.history(from, max).map_err(|e| Status::internal(format!("reading the history: {e}")))?;
        let next = p.rows.last().map_or(from, |r| r.index + 1);
        Ok(Response::new(pb::HistoryReply {
            designs: p.rows.into_iter().map(record).collect(),
            next_index: u32::try_from(next).unwrap_or(u32::MAX),
            more: p.more,
        }))
    }

    async fn landscape(&self, req: Request<pb::LandscapeRequest>) -> Result<Response<pb::LandscapeReply>, Status> {
        let m = self.shared.model()?;
        Ok(Response::new(crate::landscape::landscape(&self.shared, m, req.get_ref()).await?))
    }

    type WatchStream = tokio_stream::wrappers::ReceiverStream<Result<pb::DesignEvent, Status>>;

    async fn watch(&self, req: Request<pb::WatchDesignsRequest>) -> Result<Response<Self::WatchStream>, Status> {
        Ok(Response::new(crate::watch::start(self.shared.clone(), req.get_ref().from_index as usize)))
    }
}
