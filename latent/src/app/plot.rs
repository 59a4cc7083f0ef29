//! `coadapt latent`'s plot: `plots/returns.svg`, both returns per episode over the runs.

use std::path::Path;

use coadapt_fleet::app::AppError;

/// Mean and standard deviation per episode over runs.
fn stats(curves: &[Vec<f64>]) -> Vec<(f64, f64)> {
    let n = curves.iter().map(Vec::len).min().unwrap_or(0);
    (0..n)
        .map(|i| {
            let v: Vec<f64> = curves.iter().map(|c| c[i]).collect();
            let m = v.iter().sum::<f64>() / v.len() as f64;
            (m, (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt())
        })
        .collect()
}

/// `plots/returns.svg`: training (exploring) and evaluation (deterministic) returns per episode,
/// mean and mean +- one standard deviation over runs.
pub(crate) fn draw(path: &Path, method: &str, robot: &str, train: &[Vec<f64>], eval: &[Vec<f64>]) -> Result<(), AppError> {
    use plotters::prelude::*;
    let (ts, es) = (stats(train), stats(eval));
    let n = ts.len().max(es.len()).max(2);
    let all = ts.iter().chain(&es).flat_map(|(m, s)| [m - s, m + s]);
    let (lo, hi) = all.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
    let (lo, hi) = if lo.is_finite() && hi > lo { (lo - 0.05 * (hi - lo), hi + 0.05 * (hi - lo)) } else { (-1.0, 1.0) };
    let root = SVGBackend::new(path, (800, 500)).into_drawing_area();
    root.fill(&WHITE).map_err(AppError::failed)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(format!("{method} on the pixel {robot}, {} runs (mean, +- 1 sd)", train.len()), ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0f64..(n - 1) as f64, lo..hi)
        .map_err(AppError::failed)?;
    chart.configure_mesh().x_desc("episode").y_desc("episode return").draw().map_err(AppError::failed)?;
    for (st, colour, name) in [(&ts, BLUE, "training (exploring)"), (&es, RED, "evaluation (deterministic actor)")] {
        chart
            .draw_series(LineSeries::new(st.iter().enumerate().map(|(i, (m, _))| (i as f64, *m)), colour.stroke_width(2)))
            .map_err(AppError::failed)?
            .label(name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2)));
        for sign in [1.0, -1.0] {
            chart
                .draw_series(LineSeries::new(st.iter().enumerate().map(|(i, (m, s))| (i as f64, m + sign * s)), colour.mix(0.35)))
                .map_err(AppError::failed)?;
        }
    }
    chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw().map_err(AppError::failed)?;
    root.present().map_err(AppError::failed)?;
    Ok(())
}
