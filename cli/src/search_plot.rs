//! `coadapt search`'s plots: the learning curve (mean and spread over runs), and the synergies
//! (thesis Fig. 3.9-3.10 style).

use std::path::Path;

use crate::search::SearchConfig;

/// Mean and standard deviation over runs of the mean policy's summed distance per iteration.
pub(crate) fn draw(path: &Path, cfg: &SearchConfig, curves: &[Vec<f64>]) -> anyhow::Result<()> {
    use plotters::prelude::*;
    let n = curves.iter().map(Vec::len).min().unwrap_or(0);
    let stats: Vec<(f64, f64)> = (0..n)
        .map(|i| {
            let v: Vec<f64> = curves.iter().map(|c| c[i]).collect();
            let m = v.iter().sum::<f64>() / v.len() as f64;
            let sd = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt();
            (m, sd)
        })
        .collect();
    let top = stats.iter().map(|(m, s)| m + s).fold(0.0, f64::max) * 1.05;
    let root = SVGBackend::new(path, (800, 500)).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(format!("{} on the planar task, {} runs", cfg.method, curves.len()), ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0f64..(n.max(2) - 1) as f64, 0f64..top.max(1.0))?;
    chart.configure_mesh().x_desc("iteration").y_desc("summed end-effector distance").draw()?;
    // The mean, and the mean plus and minus one standard deviation.
    chart.draw_series(LineSeries::new(stats.iter().enumerate().map(|(i, (m, _))| (i as f64, *m)), &BLUE))?;
    for sign in [1.0, -1.0] {
        chart.draw_series(LineSeries::new(stats.iter().enumerate().map(|(i, (m, s))| (i as f64, m + sign * s)), BLUE.mix(0.35)))?;
    }
    root.present()?;
    Ok(())
}
