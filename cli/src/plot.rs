//! `coadapt plot`: its flags, over the co-adaptation's plots ([`coadapt_coadaptation::plot`]).

use std::path::PathBuf;

use clap::Args;

/// Draw the figures of a co-adaptation run, or compare runs.
///
/// `coadapt plot RUN_DIR` writes RUN_DIR/plots/learning_curves.svg (the training return of each
/// episode within each design, one line per design coloured by design order, evaluation returns
/// as dots), RUN_DIR/plots/best_return.svg (the best evaluation return so far over the design
/// index, with each design's best as a dot coloured by how it was chosen) and
/// RUN_DIR/plots/landscape.svg (the design objective over the first two principal components of
/// the designs tried, with the designs in order: thesis Fig. 5.9).
///
/// Inputs, all CSV with a header row (columns found by name, others ignored):
/// designs.csv (index, kind, best_eval_return), episodes.csv (design, episode, return,
/// eval_return), landscape.csv (pc1, pc2, objective) and landscape_designs.csv (index, pc1, pc2).
/// Empty numbers are unknown. A missing file skips its plots; a file cut short by an interrupted
/// run is plotted as far as it goes; a malformed value is an error naming file, line and column.
///
/// `coadapt plot --compare OUT.svg RUN_DIR RUN_DIR... [--labels a,b,...]` instead draws the best
/// evaluation return so far over the design index of every run in one figure.
#[derive(Debug, Args)]
pub struct PlotArgs {
    /// Run directories (each written by `coadapt run`).
    #[arg(required = true, value_name = "RUN_DIR")]
    pub runs: Vec<PathBuf>,
    /// Draw one comparison figure of all the runs into this SVG file instead of each run's plots.
    #[arg(long, value_name = "OUT.svg")]
    pub compare: Option<PathBuf>,
    /// Legend labels of the compared runs, comma-separated, one per RUN_DIR (default: the
    /// directory names). Only with --compare.
    #[arg(long, value_delimiter = ',', requires = "compare")]
    pub labels: Option<Vec<String>>,
}

/// Runs `coadapt plot`.
pub fn run(args: PlotArgs) -> anyhow::Result<()> {
    Ok(coadapt_coadaptation::plot::plot(args.runs, args.compare, args.labels)?)
}
