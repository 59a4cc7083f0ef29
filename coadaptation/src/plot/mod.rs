//! `coadapt plot`: SVG figures of a co-adaptation run directory, and the method comparison.
//!
//! [`draw_run`] reads the CSV files of a run directory and writes `plots/learning_curves.svg`,
//! `plots/best_return.svg` and `plots/landscape.svg` (thesis Fig. 5.9); [`compare`] draws the
//! best evaluation return so far of several runs in one figure. The figures are SVG drawn by
//! plotters' SVG backend, which writes text as `<text>` elements: no font files are needed.
//!
//! # Input files
//! Every file is CSV with a header row. Columns are found by their header name, in any order;
//! columns not listed here are ignored; values may be quoted (`"..."`) and are trimmed. A number
//! may be empty where it is optional (unknown), and a non-finite one (`nan`, `inf`) is treated as
//! unknown too.
//! - `designs.csv`: `index` (integer), `kind` (free text, optional column) and `best_eval_return`
//!   (optional number) of each design, and `prototype` (optional column): a row whose
//!   `prototype` is `rejected` (a proposal the operator would not build) is left out; the run
//!   also writes `design`, `episodes`, `last_eval_return`, `predicted_objective`,
//!   `design_rollouts` and `method`, which no plot needs.
//! - `episodes.csv`: `design` (integer index), `episode` (integer, within the design), `return`
//!   (number) and, if the column exists, `eval_return` (optional number).
//! - `landscape.csv` (optional): `pc1`, `pc2`, `objective` (optional number) of the points of a
//!   grid, in any order; the grid is the distinct `pc1` and `pc2` values.
//! - `landscape_designs.csv` (optional): `index` (integer), `pc1`, `pc2` of the designs tried,
//!   with `kind` optional.
//!
//! A run may have been interrupted: a file may stop anywhere, so a last line without a final
//! newline that does not parse is dropped with a note, and a missing file skips the plots that
//! need it with a note. Any other malformed row is an error naming the file, the line and the
//! column.
//!
//! The best evaluation return of a design is `best_eval_return` from `designs.csv`; a design
//! without one there (not yet written when the run stopped) takes the largest `eval_return` of
//! its episodes in `episodes.csv`.
//!
//! # Layout
//! `csv` reads the files, this module turns them into what the plots show, `figures` draws.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crate::error::{Context, bail};

pub mod action_space;
mod csv;
mod figures;

pub use csv::{
    DesignRow, EpisodeRow, LandscapeDesign, LandscapePoint, read_designs, read_episodes, read_landscape, read_landscape_designs,
};
use figures::{best_return, compare_plot, landscape_plot, learning_curves, svg_text, write_svg};

/// The run's figures by name, as the operator page asks for them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Figure {
    LearningCurves,
    BestReturn,
    Landscape,
}

impl Figure {
    pub const ALL: [Figure; 3] = [Figure::LearningCurves, Figure::BestReturn, Figure::Landscape];

    /// The file name under `plots/` (without `.svg`).
    pub fn name(self) -> &'static str {
        match self {
            Figure::LearningCurves => "learning_curves",
            Figure::BestReturn => "best_return",
            Figure::Landscape => "landscape",
        }
    }
}

/// `figure` of the run in `dir` drawn now from its files, as SVG text (what `coadapt plot`
/// writes under `plots/`); `None` while the run has no data for it.
pub fn figure_svg(dir: &Path, figure: Figure) -> crate::Result<Option<String>> {
    match figure {
        Figure::LearningCurves => {
            let Some(eps) = read_episodes(&dir.join("episodes.csv"))? else { return Ok(None) };
            if !eps.iter().any(|e| e.ret.is_some()) {
                return Ok(None);
            }
            svg_text("learning_curves", (900, 560), |root| learning_curves(root, &eps)).map(Some)
        }
        Figure::BestReturn => {
            let designs = read_designs(&dir.join("designs.csv"))?.unwrap_or_default();
            let eps = read_episodes(&dir.join("episodes.csv"))?.unwrap_or_default();
            let best = best_per_design(&designs, &eps);
            if !best.iter().any(|b| b.best.is_some()) {
                return Ok(None);
            }
            svg_text("best_return", (900, 560), |root| best_return(root, &best)).map(Some)
        }
        Figure::Landscape => {
            let Some(points) = read_landscape(&dir.join("landscape.csv"))? else { return Ok(None) };
            let tried = read_landscape_designs(&dir.join("landscape_designs.csv"))?.unwrap_or_default();
            landscape_svg(&points, &tried)
        }
    }
}

/// The landscape figure (thesis Fig. 5.9) of `points` with the designs `tried` marked; `None`
/// when no point has an objective.
pub fn landscape_svg(points: &[LandscapePoint], tried: &[LandscapeDesign]) -> crate::Result<Option<String>> {
    if !points.iter().any(|p| p.objective.is_some()) {
        return Ok(None);
    }
    svg_text("landscape", (900, 700), |root| landscape_plot(root, points, tried)).map(Some)
}

/// Draws each run's plots (`into: None`), or one figure comparing the best evaluation
/// return so far of all `runs` into the SVG file `into` (legend: `labels`, default the directory names).
pub fn plot(runs: Vec<PathBuf>, into: Option<PathBuf>, labels: Option<Vec<String>>) -> crate::Result<()> {
    match into {
        Some(out) => {
            let labels = match labels {
                Some(labels) => {
                    if labels.len() != runs.len() {
                        bail!("{} labels for {} run directories", labels.len(), runs.len());
                    }
                    labels
                }
                None => runs.iter().map(|r| dir_label(r)).collect(),
            };
            let runs: Vec<(String, PathBuf)> = labels.into_iter().zip(runs).collect();
            compare(&runs, &out)?;
            coadapt_log::logln!("wrote {}", out.display());
        }
        None => {
            for dir in &runs {
                for path in draw_run(dir)? {
                    coadapt_log::logln!("wrote {}", path.display());
                }
            }
        }
    }
    Ok(())
}

/// A run directory's name, for a legend.
fn dir_label(dir: &Path) -> String {
    dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| dir.display().to_string())
}

/// Draws the plots of the run in `dir` into `dir/plots/` and returns the files written. A plot
/// whose input is missing or empty is skipped with a note on stderr; errors for an unreadable or
/// malformed file, or when no plot could be drawn at all.
pub fn draw_run(dir: &Path) -> crate::Result<Vec<PathBuf>> {
    draw(dir, true)
}

/// [`draw_run`] while the run goes on (each design's end): the same files, each replaced
/// whole (written aside and renamed, so a reader never sees half of one), without a line for
/// each plot that has no data yet.
pub fn redraw_live(dir: &Path) -> crate::Result<Vec<PathBuf>> {
    draw(dir, false)
}

fn draw(dir: &Path, say_skips: bool) -> crate::Result<Vec<PathBuf>> {
    let skip = |what: std::fmt::Arguments<'_>| {
        if say_skips {
            coadapt_log::logln!("{what}");
        }
    };
    let designs = read_designs(&dir.join("designs.csv"))?;
    let episodes = read_episodes(&dir.join("episodes.csv"))?;
    let landscape = read_landscape(&dir.join("landscape.csv"))?;
    let landscape_designs = read_landscape_designs(&dir.join("landscape_designs.csv"))?;
    if designs.is_none() && episodes.is_none() {
        bail!("{} has neither designs.csv nor episodes.csv: not a run directory", dir.display());
    }
    let plots = dir.join("plots");
    std::fs::create_dir_all(&plots).with_context(|| format!("creating {}", plots.display()))?;
    let mut written = Vec::new();

    let out = plots.join("learning_curves.svg");
    match &episodes {
        None => skip(format_args!("skipping {}: no episodes.csv", out.display())),
        Some(eps) if !eps.iter().any(|e| e.ret.is_some()) => skip(format_args!("skipping {}: no episode returns yet", out.display())),
        Some(eps) => {
            write_svg(&out, (900, 560), |root| learning_curves(root, eps))?;
            written.push(out);
        }
    }

    let out = plots.join("best_return.svg");
    let best = best_per_design(designs.as_deref().unwrap_or(&[]), episodes.as_deref().unwrap_or(&[]));
    if best.iter().any(|b| b.best.is_some()) {
        write_svg(&out, (900, 560), |root| best_return(root, &best))?;
        written.push(out);
    } else {
        skip(format_args!("skipping {}: no evaluation returns yet", out.display()));
    }

    let out = plots.join("landscape.svg");
    match &landscape {
        None => skip(format_args!("skipping {}: no landscape.csv", out.display())),
        Some(points) if !points.iter().any(|p| p.objective.is_some()) => {
            skip(format_args!("skipping {}: landscape.csv has no objective values", out.display()))
        }
        Some(points) => {
            let tried = landscape_designs.as_deref().unwrap_or(&[]);
            write_svg(&out, (900, 700), |root| landscape_plot(root, points, tried))?;
            written.push(out);
        }
    }
    if written.is_empty() {
        bail!("nothing to plot in {} yet", dir.display());
    }
    Ok(written)
}

/// Draws the best evaluation return so far over the design index of each `(label, run_dir)` in
/// one figure at `out` (SVG). A run without any evaluation return yet is left out with a note;
/// errors when none has one, or for a malformed file.
pub fn compare(runs: &[(String, PathBuf)], out: &Path) -> crate::Result<()> {
    let mut curves = Vec::new();
    for (label, dir) in runs {
        let designs = read_designs(&dir.join("designs.csv"))?;
        let episodes = read_episodes(&dir.join("episodes.csv"))?;
        if designs.is_none() && episodes.is_none() {
            bail!("{} has neither designs.csv nor episodes.csv: not a run directory", dir.display());
        }
        let best = best_per_design(designs.as_deref().unwrap_or(&[]), episodes.as_deref().unwrap_or(&[]));
        let steps = best_so_far(&best);
        if steps.is_empty() {
            coadapt_log::logln!("leaving {label} ({}) out: no evaluation returns yet", dir.display());
        } else {
            curves.push((label.clone(), steps));
        }
    }
    if curves.is_empty() {
        bail!("none of the runs has an evaluation return yet");
    }
    if let Some(parent) = out.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).with_context(|| format!("creating {}", parent.display()))?;
    }
    write_svg(out, (900, 560), |root| compare_plot(root, &curves))
}

/// A design's best evaluation return (see the module doc for where it comes from).
#[derive(Clone, Debug, PartialEq)]
pub struct DesignBest {
    pub index: usize,
    pub kind: String,
    pub best: Option<f64>,
}

/// Every design named in either file, by index, with its best evaluation return.
pub fn best_per_design(designs: &[DesignRow], episodes: &[EpisodeRow]) -> Vec<DesignBest> {
    let mut by_index: BTreeMap<usize, DesignBest> = BTreeMap::new();
    for d in designs {
        let e = by_index.entry(d.index).or_insert(DesignBest { index: d.index, kind: String::new(), best: None });
        e.kind.clone_from(&d.kind);
        e.best = max_opt(e.best, d.best_eval_return);
    }
    let mut from_episodes: BTreeMap<usize, Option<f64>> = BTreeMap::new();
    for ep in episodes {
        let b = from_episodes.entry(ep.design).or_insert(None);
        *b = max_opt(*b, ep.eval_return);
    }
    for (index, best) in from_episodes {
        let e = by_index.entry(index).or_insert(DesignBest { index, kind: String::new(), best: None });
        if e.best.is_none() {
            e.best = best;
        }
    }
    by_index.into_values().collect()
}

/// The best evaluation return so far at each design with a known value: `(index, best so far)`.
pub fn best_so_far(best: &[DesignBest]) -> Vec<(f64, f64)> {
    let mut top = None;
    best.iter()
        .filter_map(|b| {
            top = max_opt(top, b.best);
            b.best.and(top).map(|t| (b.index as f64, t))
        })
        .collect()
}

fn max_opt(a: Option<f64>, b: Option<f64>) -> Option<f64> {
    match (a, b) {
        (Some(x), Some(y)) => Some(x.max(y)),
        (x, None) => x,
        (None, y) => y,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn best_so_far_is_a_running_max_over_known_values() {
        let best = [
            DesignBest { index: 0, kind: String::new(), best: Some(1.0) },
            DesignBest { index: 1, kind: String::new(), best: None },
            DesignBest { index: 2, kind: String::new(), best: Some(0.5) },
            DesignBest { index: 3, kind: String::new(), best: Some(3.0) },
        ];
        assert_eq!(best_so_far(&best), vec![(0.0, 1.0), (2.0, 1.0), (3.0, 3.0)]);
    }

    #[test]
    fn designs_without_a_best_take_their_episodes_eval_returns() {
        let designs = [DesignRow { index: 0, kind: "initial".into(), best_eval_return: Some(2.0) }];
        let eps = [
            EpisodeRow { design: 0, episode: 0, ret: Some(1.0), eval_return: Some(5.0) },
            EpisodeRow { design: 1, episode: 0, ret: Some(1.0), eval_return: Some(4.0) },
            EpisodeRow { design: 1, episode: 1, ret: Some(1.0), eval_return: Some(6.0) },
        ];
        let b = best_per_design(&designs, &eps);
        assert_eq!(b.len(), 2);
        assert_eq!((b[0].best, b[0].kind.as_str()), (Some(2.0), "initial"));
        assert_eq!(b[1].best, Some(6.0));
    }
}
