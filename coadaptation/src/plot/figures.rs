//! Drawing the figures with plotters' SVG backend.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use coadapt_fleet::app::{AppError, Context};
use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;

use super::{DesignBest, EpisodeRow, LandscapeDesign, LandscapePoint, best_so_far};

pub(super) type Area<'a> = DrawingArea<SVGBackend<'a>, Shift>;

/// What drawing can fail with: plotters' own error (into a string: only a bug);
/// [`write_svg`] says which figure.
pub(super) type Drawn<T = ()> = Result<T, DrawingAreaErrorKind<std::io::Error>>;

/// Draws into an SVG string with `draw`; `what` names the figure in an error.
pub(super) fn svg_text(what: &str, size: (u32, u32), draw: impl FnOnce(&Area) -> Drawn) -> crate::Result<String> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, size).into_drawing_area();
        let drawn = root.fill(&WHITE).and_then(|()| draw(&root)).and_then(|()| root.present());
        drawn.map_err(|e| AppError::failed(e).context(format!("drawing {what}")))?;
    }
    Ok(svg)
}

/// Draws into an SVG string with `draw`, then writes it to `path`.
pub(super) fn write_svg(path: &Path, size: (u32, u32), draw: impl FnOnce(&Area) -> Drawn) -> crate::Result<()> {
    let svg = svg_text(&path.display().to_string(), size, draw)?;
    // Aside, then renamed over the old file: a reader (a browser, the operator page) sees the
    // old plot or the new one, never a part, also while the run redraws them.
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    std::fs::write(&tmp, svg).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("writing {}", path.display()))
}

/// The perceptually uniform viridis colour map at `t` in [0, 1] (5 stops, linear in between).
pub(super) fn viridis(t: f64) -> RGBColor {
    const STOPS: [(f64, f64, f64); 5] =
        [(68.0, 1.0, 84.0), (59.0, 82.0, 139.0), (33.0, 145.0, 140.0), (94.0, 201.0, 98.0), (253.0, 231.0, 37.0)];
    let t = if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.0 };
    let x = t * (STOPS.len() - 1) as f64;
    let i = (x.floor() as usize).min(STOPS.len() - 2);
    let f = x - i as f64;
    let (a, b) = (STOPS[i], STOPS[i + 1]);
    let mix = |p: f64, q: f64| (p + (q - p) * f).round().clamp(0.0, 255.0) as u8;
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

/// Distinct colours for categories (matplotlib's tab10).
fn category(i: usize) -> RGBColor {
    const TAB10: [RGBColor; 10] = [
        RGBColor(31, 119, 180),
        RGBColor(255, 127, 14),
        RGBColor(44, 160, 44),
        RGBColor(214, 39, 40),
        RGBColor(148, 103, 189),
        RGBColor(140, 86, 75),
        RGBColor(227, 119, 194),
        RGBColor(127, 127, 127),
        RGBColor(188, 189, 34),
        RGBColor(23, 190, 207),
    ];
    TAB10[i % TAB10.len()]
}

/// `[lo, hi]` of the finite values, widened to a non-empty range with 5% headroom.
fn range(values: impl IntoIterator<Item = f64>) -> Option<(f64, f64)> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.into_iter().filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if lo > hi {
        return None;
    }
    let pad = if hi > lo { 0.05 * (hi - lo) } else { 0.5 * lo.abs().max(1.0) };
    Some((lo - pad, hi + pad))
}

/// A tick label on an axis of whole numbers (design index, episode): no decimals where whole.
fn integer_label(v: &f64) -> String {
    if v.fract() == 0.0 { format!("{v:.0}") } else { format!("{v:.1}") }
}

/// A short number for a label.
pub(super) fn fmt_num(v: f64) -> String {
    if v != 0.0 && (v.abs() >= 1e5 || v.abs() < 1e-2) { format!("{v:.3e}") } else { format!("{v:.3}") }
}

/// A vertical colour bar in `area` (pixel coordinates) from `lo` (bottom) to `hi` (top).
pub(super) fn colour_bar(area: &Area, title: &str, lo: &str, hi: &str) -> Drawn {
    let h = area.dim_in_pixel().1;
    let (x0, x1) = (10i32, 34i32);
    let (top, bottom) = (60i32, h as i32 - 60);
    let font = ("sans-serif", 14).into_font();
    area.draw(&Text::new(title.to_string(), (4, 30), font.clone()))?;
    // 64 bands: smooth to the eye, a small file.
    let bands = 64;
    let height = f64::from((bottom - top).max(1));
    for k in 0..bands {
        let (a, b) = (f64::from(k) / f64::from(bands), f64::from(k + 1) / f64::from(bands));
        let (ya, yb) = (top + (a * height).round() as i32, top + (b * height).round() as i32);
        area.draw(&Rectangle::new([(x0, ya), (x1, yb)], viridis(1.0 - (a + b) / 2.0).filled()))?;
    }
    area.draw(&Rectangle::new([(x0, top), (x1, bottom)], BLACK.stroke_width(1)))?;
    area.draw(&Text::new(hi.to_string(), (x1 + 4, top - 6), font.clone()))?;
    area.draw(&Text::new(lo.to_string(), (x1 + 4, bottom - 6), font))?;
    Ok(())
}

pub(super) fn learning_curves(root: &Area, episodes: &[EpisodeRow]) -> Drawn {
    let mut by_design: BTreeMap<usize, Vec<&EpisodeRow>> = BTreeMap::new();
    for e in episodes {
        by_design.entry(e.design).or_default().push(e);
    }
    let x_max = episodes.iter().map(|e| e.episode).max().unwrap_or(0) as f64;
    let x_min = episodes.iter().map(|e| e.episode).min().unwrap_or(0) as f64;
    let (y0, y1) = range(episodes.iter().flat_map(|e| [e.ret, e.eval_return]).flatten()).unwrap_or((0.0, 1.0));
    let (left, right) = root.split_horizontally(root.dim_in_pixel().0.saturating_sub(120));
    let mut chart = ChartBuilder::on(&left)
        .caption("Training return per episode of each design", ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(x_min..x_max.max(x_min + 1.0), y0..y1)?;
    chart
        .configure_mesh()
        .label_style(("sans-serif", 14))
        .axis_desc_style(("sans-serif", 16))
        .x_desc("episode within the design")
        .x_label_formatter(&integer_label)
        .y_desc("return")
        .light_line_style(WHITE.mix(0.0))
        .draw()?;
    let designs: Vec<usize> = by_design.keys().copied().collect();
    let colour = |d: usize| {
        let pos = designs.iter().position(|&x| x == d).unwrap_or(0);
        viridis(if designs.len() > 1 { pos as f64 / (designs.len() - 1) as f64 } else { 0.0 })
    };
    let mut labelled = false;
    for (&d, eps) in &by_design {
        let c = colour(d);
        let mut line: Vec<(f64, f64)> = eps.iter().filter_map(|e| e.ret.map(|r| (e.episode as f64, r))).collect();
        line.sort_by(|a, b| a.0.total_cmp(&b.0));
        chart.draw_series(LineSeries::new(line, c.mix(0.8).stroke_width(1)))?;
        let evals: Vec<(f64, f64)> = eps.iter().filter_map(|e| e.eval_return.map(|r| (e.episode as f64, r))).collect();
        if evals.is_empty() {
            continue;
        }
        let drawn = chart.draw_series(evals.into_iter().map(|p| Circle::new(p, 3, c.filled())))?;
        if !labelled {
            drawn.label("evaluation return").legend(|(x, y)| Circle::new((x + 8, y), 3, BLACK.filled()));
            labelled = true;
        }
    }
    if labelled {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()?;
    }
    let (first, last) = (designs.first().copied().unwrap_or(0), designs.last().copied().unwrap_or(0));
    colour_bar(&right, "design", &first.to_string(), &last.to_string())
}

/// A chart with f64 axes on an SVG drawing area.
type XyChart<'a, 'b> = ChartContext<'a, SVGBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// A chart over design indices (integer x labels) with its caption, mesh and axis names.
fn design_index_chart<'a, 'b>(
    root: &'a Area<'b>,
    caption: &str,
    x: std::ops::Range<f64>,
    y: std::ops::Range<f64>,
    y_desc: &str,
) -> Drawn<XyChart<'a, 'b>> {
    let mut chart = ChartBuilder::on(root)
        .caption(caption, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(x, y)?;
    chart
        .configure_mesh()
        .label_style(("sans-serif", 14))
        .axis_desc_style(("sans-serif", 16))
        .x_desc("design index")
        .x_label_formatter(&integer_label)
        .y_desc(y_desc)
        .light_line_style(WHITE.mix(0.0))
        .draw()?;
    Ok(chart)
}

/// A step line through `steps`: each value holds until the next point's x.
fn step_path(steps: &[(f64, f64)]) -> Vec<(f64, f64)> {
    let mut path = Vec::with_capacity(2 * steps.len() + 1);
    for (k, &(x, y)) in steps.iter().enumerate() {
        if k > 0 {
            path.push((x, steps[k - 1].1));
        }
        path.push((x, y));
    }
    path
}

pub(super) fn best_return(root: &Area, best: &[DesignBest]) -> Drawn {
    let steps = best_so_far(best);
    let x_max = best.iter().map(|b| b.index).max().unwrap_or(0) as f64;
    let x_min = best.iter().map(|b| b.index).min().unwrap_or(0) as f64;
    let (y0, y1) = range(best.iter().filter_map(|b| b.best)).unwrap_or((0.0, 1.0));
    let mut chart =
        design_index_chart(root, "Best evaluation return over the designs", (x_min - 0.5)..(x_max + 0.5), y0..y1, "evaluation return")?;
    let mut path = step_path(&steps);
    if let Some(&(_, y)) = steps.last() {
        path.push((x_max, y));
    }
    chart
        .draw_series(LineSeries::new(path, BLACK.stroke_width(2)))?
        .label("best so far")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], BLACK.stroke_width(2)));
    let mut kinds: Vec<&str> = Vec::new();
    for b in best {
        if !kinds.contains(&b.kind.as_str()) {
            kinds.push(&b.kind);
        }
    }
    for (i, kind) in kinds.iter().enumerate() {
        let c = category(i);
        let label = if kind.is_empty() { "design" } else { kind };
        chart
            .draw_series(
                best.iter().filter(|b| b.kind == *kind).filter_map(|b| b.best.map(|y| Circle::new((b.index as f64, y), 4, c.filled()))),
            )?
            .label(label)
            .legend(move |(x, y)| Circle::new((x + 8, y), 4, c.filled()));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::LowerRight)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

/// The cell edges of sorted distinct grid coordinates: midpoints between neighbours, and half a
/// spacing beyond the ends (a unit cell for a single coordinate).
fn cell_edges(ticks: &[f64]) -> Vec<f64> {
    let n = ticks.len();
    if n == 0 {
        return Vec::new();
    }
    if n == 1 {
        return vec![ticks[0] - 0.5, ticks[0] + 0.5];
    }
    let mut edges = Vec::with_capacity(n + 1);
    edges.push(ticks[0] - 0.5 * (ticks[1] - ticks[0]));
    for w in ticks.windows(2) {
        edges.push(0.5 * (w[0] + w[1]));
    }
    edges.push(ticks[n - 1] + 0.5 * (ticks[n - 1] - ticks[n - 2]));
    edges
}

fn distinct(mut v: Vec<f64>) -> Vec<f64> {
    v.sort_by(f64::total_cmp);
    v.dedup();
    v
}

pub(super) fn landscape_plot(root: &Area, points: &[LandscapePoint], tried: &[LandscapeDesign]) -> Drawn {
    let t1 = distinct(points.iter().map(|p| p.pc[0]).collect());
    let t2 = distinct(points.iter().map(|p| p.pc[1]).collect());
    let (e1, e2) = (cell_edges(&t1), cell_edges(&t2));
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in points.iter().filter_map(|p| p.objective) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    let span = if hi > lo { hi - lo } else { 1.0 };
    let xs = e1.iter().copied().chain(tried.iter().map(|d| d.pc[0]));
    let ys = e2.iter().copied().chain(tried.iter().map(|d| d.pc[1]));
    let (x0, x1) = bounds(xs);
    let (y0, y1) = bounds(ys);
    let (left, right) = root.split_horizontally(root.dim_in_pixel().0.saturating_sub(140));
    let mut chart = ChartBuilder::on(&left)
        .caption("Design objective over the first two principal components", ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(x0..x1, y0..y1)?;
    chart
        .configure_mesh()
        .label_style(("sans-serif", 14))
        .axis_desc_style(("sans-serif", 16))
        .x_desc("PC 1")
        .y_desc("PC 2")
        .disable_mesh()
        .draw()?;
    let index = |ticks: &[f64], v: f64| ticks.binary_search_by(|t| t.total_cmp(&v)).ok();
    chart.draw_series(points.iter().filter_map(|p| {
        let (i, j, v) = (index(&t1, p.pc[0])?, index(&t2, p.pc[1])?, p.objective?);
        Some(Rectangle::new([(e1[i], e2[j]), (e1[i + 1], e2[j + 1])], viridis((v - lo) / span).filled()))
    }))?;
    let mut order: Vec<&LandscapeDesign> = tried.iter().collect();
    order.sort_by_key(|d| d.index);
    chart.draw_series(LineSeries::new(order.iter().map(|d| (d.pc[0], d.pc[1])), WHITE.stroke_width(1)))?;
    // White labels with a dark shadow: readable on both ends of the colour map.
    let (font, shadow) = (("sans-serif", 14).into_font().color(&WHITE), ("sans-serif", 14).into_font().color(&BLACK));
    chart.draw_series(order.iter().map(|d| {
        EmptyElement::at((d.pc[0], d.pc[1]))
            + Circle::new((0, 0), 4, RED.filled())
            + Circle::new((0, 0), 4, WHITE.stroke_width(1))
            + Text::new(d.index.to_string(), (6, -15), shadow.clone())
            + Text::new(d.index.to_string(), (5, -16), font.clone())
    }))?;
    colour_bar(&right, "objective", &fmt_num(lo), &fmt_num(hi))
}

/// The range of finite coordinates, made non-empty.
pub(super) fn bounds(values: impl IntoIterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.into_iter().filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if lo > hi {
        (0.0, 1.0)
    } else if hi > lo {
        (lo, hi)
    } else {
        (lo - 0.5, hi + 0.5)
    }
}

pub(super) fn compare_plot(root: &Area, curves: &[(String, Vec<(f64, f64)>)]) -> Drawn {
    let (x0, x1) = bounds(curves.iter().flat_map(|(_, c)| c.iter().map(|p| p.0)));
    let (y0, y1) = range(curves.iter().flat_map(|(_, c)| c.iter().map(|p| p.1))).unwrap_or((0.0, 1.0));
    let mut chart = design_index_chart(root, "Best evaluation return so far", (x0 - 0.5)..(x1 + 0.5), y0..y1, "best evaluation return")?;
    for (i, (label, steps)) in curves.iter().enumerate() {
        let c = category(i);
        chart
            .draw_series(LineSeries::new(step_path(steps), c.stroke_width(2)))?
            .label(label.as_str())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], c.stroke_width(2)));
        chart.draw_series(steps.iter().map(|&(x, y)| Circle::new((x, y), 3, c.filled())))?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::LowerRight)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn viridis_ends() {
        assert_eq!(viridis(0.0), RGBColor(68, 1, 84));
        assert_eq!(viridis(1.0), RGBColor(253, 231, 37));
        assert_eq!(viridis(f64::NAN), RGBColor(68, 1, 84));
    }
}
