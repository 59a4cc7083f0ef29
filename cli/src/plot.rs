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

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::Args;
use plotters::coord::Shift;
use plotters::prelude::*;

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
    match args.compare {
        Some(out) => {
            let labels = match args.labels {
                Some(labels) => {
                    if labels.len() != args.runs.len() {
                        bail!("{} labels for {} run directories", labels.len(), args.runs.len());
                    }
                    labels
                }
                None => args.runs.iter().map(|r| dir_label(r)).collect(),
            };
            let runs: Vec<(String, PathBuf)> = labels.into_iter().zip(args.runs).collect();
            compare(&runs, &out)?;
            eprintln!("wrote {}", out.display());
        }
        None => {
            for dir in &args.runs {
                for path in draw_run(dir)? {
                    eprintln!("wrote {}", path.display());
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
pub fn draw_run(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
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
        None => eprintln!("skipping {}: no episodes.csv", out.display()),
        Some(eps) if !eps.iter().any(|e| e.ret.is_some()) => eprintln!("skipping {}: no episode returns yet", out.display()),
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
        eprintln!("skipping {}: no evaluation returns yet", out.display());
    }

    let out = plots.join("landscape.svg");
    match &landscape {
        None => eprintln!("skipping {}: no landscape.csv", out.display()),
        Some(points) if !points.iter().any(|p| p.objective.is_some()) => {
            eprintln!("skipping {}: landscape.csv has no objective values", out.display())
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
pub fn compare(runs: &[(String, PathBuf)], out: &Path) -> anyhow::Result<()> {
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
            eprintln!("leaving {label} ({}) out: no evaluation returns yet", dir.display());
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

// ---------------------------------------------------------------------------------------------
// Reading the CSV files.

/// A row of `designs.csv`.
#[derive(Clone, Debug, PartialEq)]
pub struct DesignRow {
    pub index: usize,
    pub kind: String,
    pub best_eval_return: Option<f64>,
}

/// A row of `episodes.csv`.
#[derive(Clone, Debug, PartialEq)]
pub struct EpisodeRow {
    pub design: usize,
    pub episode: usize,
    pub ret: Option<f64>,
    pub eval_return: Option<f64>,
}

/// A point of `landscape.csv`.
#[derive(Clone, Debug, PartialEq)]
pub struct LandscapePoint {
    pub pc: [f64; 2],
    pub objective: Option<f64>,
}

/// A row of `landscape_designs.csv`.
#[derive(Clone, Debug, PartialEq)]
pub struct LandscapeDesign {
    pub index: usize,
    pub kind: String,
    pub pc: [f64; 2],
}

/// `designs.csv`, or `None` when the file does not exist.
pub fn read_designs(path: &Path) -> anyhow::Result<Option<Vec<DesignRow>>> {
    let Some(t) = Table::read(path)? else { return Ok(None) };
    let (index, kind, best) = (t.col("index")?, t.opt_col("kind"), t.col("best_eval_return")?);
    let prototype = t.opt_col("prototype");
    let rows = t.rows(|r| {
        let row = DesignRow {
            index: r.int(index)?,
            kind: kind.map(|k| r.text(k).to_string()).unwrap_or_default(),
            best_eval_return: r.num(best)?,
        };
        Ok((row, prototype.is_some_and(|p| r.text(p) == "rejected")))
    })?;
    // A rejected proposal was never trained on; the design of that index is the next row.
    Ok(Some(rows.into_iter().filter(|(_, rejected)| !rejected).map(|(row, _)| row).collect()))
}

/// `episodes.csv`, or `None` when the file does not exist.
pub fn read_episodes(path: &Path) -> anyhow::Result<Option<Vec<EpisodeRow>>> {
    let Some(t) = Table::read(path)? else { return Ok(None) };
    let (design, episode, ret, eval) = (t.col("design")?, t.col("episode")?, t.col("return")?, t.opt_col("eval_return"));
    t.rows(|r| {
        Ok(EpisodeRow {
            design: r.int(design)?,
            episode: r.int(episode)?,
            ret: r.num(ret)?,
            eval_return: match eval {
                Some(c) => r.num(c)?,
                None => None,
            },
        })
    })
    .map(Some)
}

/// `landscape.csv`, or `None` when the file does not exist.
pub fn read_landscape(path: &Path) -> anyhow::Result<Option<Vec<LandscapePoint>>> {
    let Some(t) = Table::read(path)? else { return Ok(None) };
    let (pc1, pc2, obj) = (t.col("pc1")?, t.col("pc2")?, t.col("objective")?);
    t.rows(|r| Ok(LandscapePoint { pc: [r.req_num(pc1)?, r.req_num(pc2)?], objective: r.num(obj)? })).map(Some)
}

/// `landscape_designs.csv`, or `None` when the file does not exist.
pub fn read_landscape_designs(path: &Path) -> anyhow::Result<Option<Vec<LandscapeDesign>>> {
    let Some(t) = Table::read(path)? else { return Ok(None) };
    let (index, kind, pc1, pc2) = (t.col("index")?, t.opt_col("kind"), t.col("pc1")?, t.col("pc2")?);
    t.rows(|r| {
        Ok(LandscapeDesign {
            index: r.int(index)?,
            kind: kind.map(|k| r.text(k).to_string()).unwrap_or_default(),
            pc: [r.req_num(pc1)?, r.req_num(pc2)?],
        })
    })
    .map(Some)
}

/// A CSV file: its header and its data rows with their 1-based line numbers.
struct Table {
    path: PathBuf,
    header: Vec<String>,
    rows: Vec<(usize, Vec<String>)>,
    /// The last row had no final newline: it may have been cut short.
    last_unterminated: bool,
}

/// One data row being read, for error messages.
struct Row<'a> {
    table: &'a Table,
    line: usize,
    fields: &'a [String],
}

impl Table {
    fn read(path: &Path) -> anyhow::Result<Option<Self>> {
        let bytes = match std::fs::read(path) {
            Ok(b) => b,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(e).with_context(|| format!("reading {}", path.display())),
        };
        let text = String::from_utf8(bytes).with_context(|| format!("{} is not UTF-8 text", path.display()))?;
        let last_unterminated = !text.is_empty() && !text.ends_with('\n');
        let mut header = None;
        let mut rows = Vec::new();
        for (i, line) in text.split('\n').enumerate() {
            let line = line.strip_suffix('\r').unwrap_or(line);
            if line.trim().is_empty() {
                continue;
            }
            let fields = split_csv(line);
            if header.is_none() {
                header = Some(fields.into_iter().map(|f| f.to_ascii_lowercase()).collect());
            } else {
                rows.push((i + 1, fields));
            }
        }
        // A file cut inside its header row has no usable header: treat it as empty.
        let header = match header {
            Some(h) if !(last_unterminated && rows.is_empty()) => h,
            _ => Vec::new(),
        };
        Ok(Some(Self { path: path.to_path_buf(), header, rows, last_unterminated }))
    }

    fn name(&self) -> String {
        self.path.display().to_string()
    }

    fn col(&self, name: &str) -> anyhow::Result<usize> {
        match self.opt_col(name) {
            Some(c) => Ok(c),
            None if self.header.is_empty() => Ok(usize::MAX), // no header, hence no rows
            None => bail!("{}: line 1: no column `{name}` in the header ({})", self.name(), self.header.join(",")),
        }
    }

    fn opt_col(&self, name: &str) -> Option<usize> {
        self.header.iter().position(|h| h == name)
    }

    /// Parses every row with `f`; a failing last row without a final newline is dropped.
    fn rows<T>(&self, f: impl Fn(&Row) -> anyhow::Result<T>) -> anyhow::Result<Vec<T>> {
        let mut out = Vec::with_capacity(self.rows.len());
        let n = self.rows.len();
        for (k, (line, fields)) in self.rows.iter().enumerate() {
            let row = Row { table: self, line: *line, fields };
            let parsed = if fields.len() != self.header.len() {
                Err(anyhow::anyhow!("{}: line {line}: {} values for {} columns", self.name(), fields.len(), self.header.len()))
            } else {
                f(&row)
            };
            match parsed {
                Ok(v) => out.push(v),
                Err(e) if k + 1 == n && self.last_unterminated => {
                    eprintln!("note: ignoring the incomplete last line of {} ({e:#})", self.name());
                }
                Err(e) => return Err(e),
            }
        }
        Ok(out)
    }
}

impl Row<'_> {
    fn text(&self, col: usize) -> &str {
        self.fields.get(col).map(String::as_str).unwrap_or("")
    }

    fn err(&self, col: usize, what: &str) -> anyhow::Error {
        let name = self.table.header.get(col).map(String::as_str).unwrap_or("?");
        anyhow::anyhow!(
            "{}: line {}, column {} ({name}): cannot read {:?} as {what}",
            self.table.name(),
            self.line,
            col + 1,
            self.text(col)
        )
    }

    /// An optional number: empty or non-finite is `None`.
    fn num(&self, col: usize) -> anyhow::Result<Option<f64>> {
        let s = self.text(col);
        if s.is_empty() {
            return Ok(None);
        }
        let v: f64 = s.parse().map_err(|_| self.err(col, "a number"))?;
        Ok(v.is_finite().then_some(v))
    }

    /// A required finite number.
    fn req_num(&self, col: usize) -> anyhow::Result<f64> {
        match self.num(col)? {
            Some(v) => Ok(v),
            None => Err(self.err(col, "a finite number")),
        }
    }

    fn int(&self, col: usize) -> anyhow::Result<usize> {
        self.text(col).parse().map_err(|_| self.err(col, "a non-negative integer"))
    }
}

/// Splits one CSV line into trimmed fields; a field may be double-quoted, with `""` for a quote.
fn split_csv(line: &str) -> Vec<String> {
    let mut fields = Vec::new();
    let mut cur = String::new();
    let mut quoted = false;
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '"' if quoted && chars.peek() == Some(&'"') => {
                cur.push('"');
                chars.next();
            }
            '"' if quoted => quoted = false,
            '"' if cur.trim().is_empty() => {
                cur.clear();
                quoted = true;
            }
            ',' if !quoted => fields.push(std::mem::take(&mut cur).trim().to_string()),
            c => cur.push(c),
        }
    }
    fields.push(cur.trim().to_string());
    fields
}

// ---------------------------------------------------------------------------------------------
// What the plots show.

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

// ---------------------------------------------------------------------------------------------
// Drawing.

type Area<'a> = DrawingArea<SVGBackend<'a>, Shift>;

/// Draws into an SVG string with `draw`, then writes it to `path`.
fn write_svg(path: &Path, size: (u32, u32), draw: impl FnOnce(&Area) -> anyhow::Result<()>) -> anyhow::Result<()> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, size).into_drawing_area();
        root.fill(&WHITE)?;
        draw(&root).with_context(|| format!("drawing {}", path.display()))?;
        root.present()?;
    }
    std::fs::write(path, svg).with_context(|| format!("writing {}", path.display()))
}

/// The perceptually uniform viridis colour map at `t` in [0, 1] (5 stops, linear in between).
fn viridis(t: f64) -> RGBColor {
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
fn fmt_num(v: f64) -> String {
    if v != 0.0 && (v.abs() >= 1e5 || v.abs() < 1e-2) { format!("{v:.3e}") } else { format!("{v:.3}") }
}

/// A vertical colour bar in `area` (pixel coordinates) from `lo` (bottom) to `hi` (top).
fn colour_bar(area: &Area, title: &str, lo: &str, hi: &str) -> anyhow::Result<()> {
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

fn learning_curves(root: &Area, episodes: &[EpisodeRow]) -> anyhow::Result<()> {
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

fn best_return(root: &Area, best: &[DesignBest]) -> anyhow::Result<()> {
    let steps = best_so_far(best);
    let x_max = best.iter().map(|b| b.index).max().unwrap_or(0) as f64;
    let x_min = best.iter().map(|b| b.index).min().unwrap_or(0) as f64;
    let (y0, y1) = range(best.iter().filter_map(|b| b.best)).unwrap_or((0.0, 1.0));
    let mut chart = ChartBuilder::on(root)
        .caption("Best evaluation return over the designs", ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d((x_min - 0.5)..(x_max + 0.5), y0..y1)?;
    chart
        .configure_mesh()
        .label_style(("sans-serif", 14))
        .axis_desc_style(("sans-serif", 16))
        .x_desc("design index")
        .x_label_formatter(&integer_label)
        .y_desc("evaluation return")
        .light_line_style(WHITE.mix(0.0))
        .draw()?;
    // Step line: the best so far holds until the next design with a value.
    let mut path = Vec::with_capacity(2 * steps.len() + 1);
    for (k, &(x, y)) in steps.iter().enumerate() {
        if k > 0 {
            path.push((x, steps[k - 1].1));
        }
        path.push((x, y));
    }
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

fn landscape_plot(root: &Area, points: &[LandscapePoint], tried: &[LandscapeDesign]) -> anyhow::Result<()> {
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
fn bounds(values: impl IntoIterator<Item = f64>) -> (f64, f64) {
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

fn compare_plot(root: &Area, curves: &[(String, Vec<(f64, f64)>)]) -> anyhow::Result<()> {
    let (x0, x1) = bounds(curves.iter().flat_map(|(_, c)| c.iter().map(|p| p.0)));
    let (y0, y1) = range(curves.iter().flat_map(|(_, c)| c.iter().map(|p| p.1))).unwrap_or((0.0, 1.0));
    let mut chart = ChartBuilder::on(root)
        .caption("Best evaluation return so far", ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d((x0 - 0.5)..(x1 + 0.5), y0..y1)?;
    chart
        .configure_mesh()
        .label_style(("sans-serif", 14))
        .axis_desc_style(("sans-serif", 16))
        .x_desc("design index")
        .x_label_formatter(&integer_label)
        .y_desc("best evaluation return")
        .light_line_style(WHITE.mix(0.0))
        .draw()?;
    for (i, (label, steps)) in curves.iter().enumerate() {
        let c = category(i);
        let mut path = Vec::with_capacity(2 * steps.len());
        for (k, &(x, y)) in steps.iter().enumerate() {
            if k > 0 {
                path.push((x, steps[k - 1].1));
            }
            path.push((x, y));
        }
        chart
            .draw_series(LineSeries::new(path, c.stroke_width(2)))?
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
    fn csv_fields_split_with_quotes() {
        assert_eq!(split_csv("1, a ,\"b,c\",\"say \"\"hi\"\"\","), vec!["1", "a", "b,c", "say \"hi\"", ""]);
    }

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

    #[test]
    fn viridis_ends() {
        assert_eq!(viridis(0.0), RGBColor(68, 1, 84));
        assert_eq!(viridis(1.0), RGBColor(253, 231, 37));
        assert_eq!(viridis(f64::NAN), RGBColor(68, 1, 84));
    }
}
