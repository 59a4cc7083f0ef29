//! `Landscape`: thesis Fig. 5.9 on request, the objective over the principal plane of the
//! designs tried.

use std::sync::Arc;

use coadapt_design_optimizer::landscape::{Pca2, grid};
use coadapt_wire::pb;
use tonic::Status;

use crate::model::DesignModel;
use crate::shared::Shared;

/// Grid points per side when the request says 0.
pub(crate) const DEFAULT_GRID: usize = 21;

pub(crate) async fn landscape(shared: &Shared, m: Arc<DesignModel>, req: &pb::LandscapeRequest) -> Result<pb::LandscapeReply, Status> {
    let n = if req.grid == 0 { DEFAULT_GRID } else { req.grid as usize };
    let max = shared.cfg.max_score_batch;
    if n.checked_mul(n).is_none_or(|nn| nn > max) {
        return Err(Status::invalid_argument(format!(
            "grid: {n} x {n} points is more than the {max} designs one call may score (the server's max-score-batch)"
        )));
    }
    // The designs tried: every row but the proposals the operator would not build.
    let mut rows = Vec::new();
    let mut from = 0;
    loop {
        let p = shared.source.history(from, shared.cfg.history_page).map_err(|e| Status::internal(format!("reading the history: {e}")))?;
        let Some(last) = p.rows.last() else { break };
        from = last.index + 1;
        rows.extend(p.rows.into_iter().filter(|r| r.prototype != "rejected" && r.design.len() == m.design_dim()));
        if !p.more {
            break;
        }
    }
    if rows.is_empty() {
        return Err(Status::failed_precondition("the run has no designs yet: nothing to lay a plane through"));
    }
    let dim = m.design_dim();
    let designs: Vec<f32> = rows.iter().flat_map(|r| r.design.iter().copied()).collect();
    let bad = |e: coadapt_design_optimizer::landscape::LandscapeError| Status::internal(format!("the principal plane of the designs: {e}"));
    let pca = Pca2::fit(&designs, dim).map_err(bad)?;
    let g = grid(&pca, &designs, &m.bounds, n).map_err(bad)?;
    let (objective, _) = shared.score(m.clone(), g.designs).await?;
    let ticks = |j: usize| -> Vec<f32> {
        match j {
            0 => g.pc.iter().take(n).map(|p| p[0]).collect(),
            _ => g.pc.iter().step_by(n.max(1)).map(|p| p[1]).collect(),
        }
    };
    Ok(pb::LandscapeReply {
        mean: Some(pb::Design { values: pca.mean.clone() }),
        axis1: Some(pb::Design { values: pca.axes[0].clone() }),
        axis2: Some(pb::Design { values: pca.axes[1].clone() }),
        explained1: pca.explained[0],
        explained2: pca.explained[1],
        pc1: ticks(0),
        pc2: ticks(1),
        objective,
        designs: rows
            .iter()
            .map(|r| {
                let p = pca.project(&r.design);
                pb::ProjectedDesign { index: u32::try_from(r.index).unwrap_or(u32::MAX), kind: r.kind.clone(), pc1: p[0], pc2: p[1] }
            })
            .collect(),
        weights_version: m.weights_version,
    })
}
