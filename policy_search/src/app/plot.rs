//! `coadapt search`'s plots: the learning curve (mean and spread over runs), and the synergies
//! (thesis Fig. 3.9-3.10 style).

use std::path::Path;

use super::config::SearchConfig;
use crate::{LinearPolicy, PlanarReaching, TimeFeatures};
use coadapt_fleet::app::AppError;

/// W and M after every iteration of one run (index 0: before the first).
#[derive(Debug, Default)]
pub(crate) struct History {
    pub w: Vec<Vec<f64>>,
    pub m: Vec<Vec<f64>>,
}

impl History {
    pub fn record(&mut self, w: &[f64], m: &[f64]) {
        self.w.push(w.to_vec());
        self.m.push(m.to_vec());
    }
}

/// Thesis Fig. 3.9: W (`d x k`) as a Hinton diagram after chosen iterations, a square per
/// entry whose area is its magnitude (relative to the largest entry of all panels shown), black
/// for positive, grey for negative.
pub(crate) fn synergies(path: &Path, h: &History, d: usize, k: usize) -> Result<(), AppError> {
    use plotters::prelude::*;
    let last = h.w.len().saturating_sub(1);
    let mut its: Vec<usize> = [1, 2, 4, 8, 16, 32, 64].into_iter().filter(|&i| i < last).collect();
    its.push(last);
    let max = its.iter().flat_map(|&i| h.w[i].iter()).fold(0.0f64, |a, v| a.max(v.abs())).max(1e-12);
    let cell = 22i32;
    let (pw, ph) = (k as i32 * cell + 20, d as i32 * cell + 40);
    let root = SVGBackend::new(path, ((pw * its.len() as i32 + 80) as u32, (ph + 70) as u32)).into_drawing_area();
    root.fill(&WHITE).map_err(AppError::failed)?;
    root.draw(&Text::new(
        format!("synergies W (joints x latent dimensions) over the iterations; largest |w| = {max:.1}"),
        (10, 10),
        ("sans-serif", 16),
    ))
    .map_err(AppError::failed)?;
    for (n, &it) in its.iter().enumerate() {
        let x0 = 70 + n as i32 * pw;
        let y0 = 60;
        root.draw(&Text::new(format!("iteration {it}"), (x0, y0 - 22), ("sans-serif", 13))).map_err(AppError::failed)?;
        for j in 0..d {
            if n == 0 {
                let name = if j < 6 { format!("L{}", j + 1) } else { format!("R{}", j - 5) };
                root.draw(&Text::new(name, (x0 - 30, y0 + j as i32 * cell + 5), ("sans-serif", 12))).map_err(AppError::failed)?;
            }
            for c in 0..k {
                let v = h.w[it].get(j * k + c).copied().unwrap_or(0.0);
                let half = ((v.abs() / max).sqrt() * f64::from(cell - 2) / 2.0).round() as i32;
                let (cx, cy) = (x0 + c as i32 * cell + cell / 2, y0 + j as i32 * cell + cell / 2);
                root.draw(&Rectangle::new(
                    [(x0 + c as i32 * cell, y0 + j as i32 * cell), (x0 + (c as i32 + 1) * cell, y0 + (j as i32 + 1) * cell)],
                    RGBColor(235, 235, 235),
                ))
                .map_err(AppError::failed)?;
                let colour = if v >= 0.0 { BLACK } else { RGBColor(150, 150, 150) };
                root.draw(&Rectangle::new([(cx - half, cy - half), (cx + half, cy + half)], colour.filled())).map_err(AppError::failed)?;
            }
        }
    }
    root.present().map_err(AppError::failed)?;
    Ok(())
}

/// The joint positions of one arm at joint angles `q` (degrees), base first.
fn arm(task: &PlanarReaching, q: &[f64]) -> Vec<(f64, f64)> {
    let (mut x, mut y, mut angle) = (0.0, 0.0, std::f64::consts::FRAC_PI_2);
    let mut pts = vec![(x, y)];
    for (l, qi) in task.geometry.links.iter().zip(q) {
        angle += (qi * task.geometry.unit_degrees).to_radians();
        x += l * angle.cos();
        y += l * angle.sin();
        pts.push((x, y));
    }
    pts
}

/// Thesis Fig. 3.10: the mean policy's last pose after iteration `at`, moved along the two
/// strongest synergies (the columns of W with the largest norms), z in {-2, 0, 2} on each: a
/// 3 x 3 grid of both arms, the unmoved pose in the centre.
pub(crate) fn synergy_poses(
    path: &Path,
    h: &History,
    at: usize,
    d: usize,
    k: usize,
    phi: &TimeFeatures,
    task: &PlanarReaching,
) -> Result<(), AppError> {
    use plotters::prelude::*;
    let at = at.min(h.w.len().saturating_sub(1));
    let w = &h.w[at];
    let mut cols: Vec<(f64, usize)> = (0..k).map(|c| ((0..d).map(|j| w[j * k + c].powi(2)).sum::<f64>().sqrt(), c)).collect();
    cols.sort_by(|a, b| b.0.total_cmp(&a.0));
    let (s1, s2) = (cols.first().map_or(0, |c| c.1), cols.get(1).map_or(0, |c| c.1));
    let mut mean = Vec::new();
    LinearPolicy::actions_of(&h.m[at], d, phi, &mut mean);
    let t = phi.steps() - 1;
    // The synergies enter every step as W z phi; the features sum to 1 at each step.
    let base: Vec<f64> = mean[t * d..(t + 1) * d].iter().map(|&v| f64::from(v)).collect();
    let root = SVGBackend::new(path, (760, 800)).into_drawing_area();
    root.fill(&WHITE).map_err(AppError::failed)?;
    let (title, grid) = root.split_vertically(40);
    title
        .draw(&Text::new(
            format!("the last pose after iteration {at} moved along synergy {} (across, z = -2, 0, 2) and {} (down)", s1 + 1, s2 + 1),
            (10, 12),
            ("sans-serif", 14),
        ))
        .map_err(AppError::failed)?;
    let panels = grid.split_evenly((3, 3));
    let (gl, gr) = task.goals(t);
    for (n, panel) in panels.iter().enumerate() {
        let (z1, z2) = ((n % 3) as f64 * 2.0 - 2.0, (n / 3) as f64 * 2.0 - 2.0);
        let q: Vec<f64> = (0..d).map(|j| base[j] + w[j * k + s1] * z1 + w[j * k + s2] * z2).collect();
        let mut chart = ChartBuilder::on(panel)
            .margin(6)
            .caption(format!("z = ({z1:+.0}, {z2:+.0})"), ("sans-serif", 12))
            .build_cartesian_2d(-6.5f64..6.5, -3.0f64..6.5)
            .map_err(AppError::failed)?;
        chart.configure_mesh().disable_mesh().x_labels(3).y_labels(3).draw().map_err(AppError::failed)?;
        for (arm_q, colour) in [(&q[..6], BLUE), (&q[6..], RED)] {
            let pts = arm(task, arm_q);
            chart.draw_series(LineSeries::new(pts.clone(), colour.stroke_width(2))).map_err(AppError::failed)?;
            chart.draw_series(pts.iter().map(|&p| Circle::new(p, 2, colour.filled()))).map_err(AppError::failed)?;
        }
        chart.draw_series([gl, gr].iter().map(|g| Cross::new((g[0], g[1]), 5, BLACK.stroke_width(2)))).map_err(AppError::failed)?;
    }
    root.present().map_err(AppError::failed)?;
    Ok(())
}

/// Mean and standard deviation over runs of the mean policy's summed distance per iteration.
pub(crate) fn draw(path: &Path, cfg: &SearchConfig, curves: &[Vec<f64>]) -> Result<(), AppError> {
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
    root.fill(&WHITE).map_err(AppError::failed)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(format!("{} on the planar task, {} runs", cfg.method, curves.len()), ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0f64..(n.max(2) - 1) as f64, 0f64..top.max(1.0))
        .map_err(AppError::failed)?;
    chart.configure_mesh().x_desc("iteration").y_desc("summed end-effector distance").draw().map_err(AppError::failed)?;
    // The mean, and the mean plus and minus one standard deviation.
    chart.draw_series(LineSeries::new(stats.iter().enumerate().map(|(i, (m, _))| (i as f64, *m)), &BLUE)).map_err(AppError::failed)?;
    for sign in [1.0, -1.0] {
        chart
            .draw_series(LineSeries::new(stats.iter().enumerate().map(|(i, (m, s))| (i as f64, m + sign * s)), BLUE.mix(0.35)))
            .map_err(AppError::failed)?;
    }
    root.present().map_err(AppError::failed)?;
    Ok(())
}
