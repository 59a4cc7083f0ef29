//! The figures of thesis section 6.2 from a trained action autoencoder: Fig. 6.1, the latent
//! plane at one start state coloured by the critic's value of each decoded action; Fig. 6.2, a
//! grid of latent codes decoded for two designs, drawn in two action dimensions.

use std::path::Path;

use plotters::prelude::*;

use super::figures::{Area, Drawn, bounds, colour_bar, fmt_num, viridis, write_svg};

/// Fig. 6.1: `values[j * n + i]` is Q at the latent code `(zs[i], zs[j])` (a square grid).
pub fn latent_plane(path: &Path, zs: &[f64], values: &[f64], title: &str) -> crate::Result<()> {
    write_svg(path, (820, 700), |root| latent_plane_on(root, zs, values, title))
}

fn latent_plane_on(root: &Area, zs: &[f64], values: &[f64], title: &str) -> Drawn {
    let n = zs.len();
    let half = if n > 1 { 0.5 * (zs[1] - zs[0]) } else { 0.5 };
    let (lo, hi) = bounds(values.iter().copied());
    let span = if hi > lo { hi - lo } else { 1.0 };
    let (left, right) = root.split_horizontally(root.dim_in_pixel().0.saturating_sub(140));
    let (a, b) = (zs[0] - half, zs[n - 1] + half);
    let mut chart = ChartBuilder::on(&left)
        .caption(title, ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(a..b, a..b)?;
    chart.configure_mesh().disable_mesh().x_desc("z1").y_desc("z2").label_style(("sans-serif", 14)).draw()?;
    chart.draw_series((0..n * n).map(|k| {
        let (i, j) = (k % n, k / n);
        let c = viridis((values[k] - lo) / span);
        Rectangle::new([(zs[i] - half, zs[j] - half), (zs[i] + half, zs[j] + half)], c.filled())
    }))?;
    colour_bar(&right, "Q(s0, d(z))", &fmt_num(lo), &fmt_num(hi))
}

/// Fig. 6.2: for each design (its label and the decoded actions of a `k x k` latent grid, row
/// by row, each `(x, y)` in the two chosen action dimensions), the grid's points joined to their
/// neighbours.
pub fn decoded_grids(path: &Path, grids: &[(String, Vec<(f64, f64)>)], k: usize, dims: (usize, usize)) -> crate::Result<()> {
    write_svg(path, (760, 700), |root| decoded_grids_on(root, grids, k, dims))
}

fn decoded_grids_on(root: &Area, grids: &[(String, Vec<(f64, f64)>)], k: usize, dims: (usize, usize)) -> Drawn {
    let (x0, x1) = bounds(grids.iter().flat_map(|(_, g)| g.iter().map(|p| p.0)));
    let (y0, y1) = bounds(grids.iter().flat_map(|(_, g)| g.iter().map(|p| p.1)));
    let pad = |a: f64, b: f64| (a - 0.05 * (b - a), b + 0.05 * (b - a));
    let ((x0, x1), (y0, y1)) = (pad(x0, x1), pad(y0, y1));
    let mut chart = ChartBuilder::on(root)
        .caption("A latent grid decoded for two designs", ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(x0..x1, y0..y1)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc(format!("action dimension {}", dims.0 + 1))
        .y_desc(format!("action dimension {}", dims.1 + 1))
        .label_style(("sans-serif", 14))
        .draw()?;
    let colours = [RGBColor(31, 119, 180), RGBColor(214, 39, 40)];
    for (g, (label, points)) in grids.iter().enumerate() {
        let c = colours[g % colours.len()];
        for r in 0..k {
            let row: Vec<(f64, f64)> = (0..k).map(|i| points[r * k + i]).collect();
            let col: Vec<(f64, f64)> = (0..k).map(|i| points[i * k + r]).collect();
            chart.draw_series(LineSeries::new(row, c.stroke_width(1)))?;
            chart.draw_series(LineSeries::new(col, c.stroke_width(1)))?;
        }
        chart
            .draw_series(points.iter().map(|&p| Circle::new(p, 2, c.filled())))?
            .label(label.clone())
            .legend(move |(x, y)| Circle::new((x, y), 4, c.filled()));
    }
    chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw()?;
    Ok(())
}
