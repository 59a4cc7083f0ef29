//! Reading the run directory's CSV files (the format is in the parent module's doc).

use std::path::{Path, PathBuf};

use crate::AppError;
use crate::error::{Context, bail};

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
pub fn read_designs(path: &Path) -> crate::Result<Option<Vec<DesignRow>>> {
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
pub fn read_episodes(path: &Path) -> crate::Result<Option<Vec<EpisodeRow>>> {
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
pub fn read_landscape(path: &Path) -> crate::Result<Option<Vec<LandscapePoint>>> {
    let Some(t) = Table::read(path)? else { return Ok(None) };
    let (pc1, pc2, obj) = (t.col("pc1")?, t.col("pc2")?, t.col("objective")?);
    t.rows(|r| Ok(LandscapePoint { pc: [r.req_num(pc1)?, r.req_num(pc2)?], objective: r.num(obj)? })).map(Some)
}

/// `landscape_designs.csv`, or `None` when the file does not exist.
pub fn read_landscape_designs(path: &Path) -> crate::Result<Option<Vec<LandscapeDesign>>> {
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
    fn read(path: &Path) -> crate::Result<Option<Self>> {
        let bytes = match std::fs::read(path) {
            Ok(b) => b,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(e).with_context(|| format!("reading {}", path.display())),
        };
        let text = String::from_utf8(bytes).map_err(AppError::library).with_context(|| format!("{} is not UTF-8 text", path.display()))?;
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

    fn col(&self, name: &str) -> crate::Result<usize> {
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
    fn rows<T>(&self, f: impl Fn(&Row) -> crate::Result<T>) -> crate::Result<Vec<T>> {
        let mut out = Vec::with_capacity(self.rows.len());
        let n = self.rows.len();
        for (k, (line, fields)) in self.rows.iter().enumerate() {
            let row = Row { table: self, line: *line, fields };
            let parsed = if fields.len() != self.header.len() {
                Err(crate::error::failed!("{}: line {line}: {} values for {} columns", self.name(), fields.len(), self.header.len()))
            } else {
                f(&row)
            };
            match parsed {
                Ok(v) => out.push(v),
                Err(e) if k + 1 == n && self.last_unterminated => {
                    coadapt_log::logln!("note: ignoring the incomplete last line of {} ({e:#})", self.name());
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

    fn err(&self, col: usize, what: &str) -> crate::AppError {
        let name = self.table.header.get(col).map(String::as_str).unwrap_or("?");
        crate::error::failed!(
            "{}: line {}, column {} ({name}): cannot read {:?} as {what}",
            self.table.name(),
            self.line,
            col + 1,
            self.text(col)
        )
    }

    /// An optional number: empty or non-finite is `None`.
    fn num(&self, col: usize) -> crate::Result<Option<f64>> {
        let s = self.text(col);
        if s.is_empty() {
            return Ok(None);
        }
        let v: f64 = s.parse().map_err(|_| self.err(col, "a number"))?;
        Ok(v.is_finite().then_some(v))
    }

    /// A required finite number.
    fn req_num(&self, col: usize) -> crate::Result<f64> {
        match self.num(col)? {
            Some(v) => Ok(v),
            None => Err(self.err(col, "a finite number")),
        }
    }

    fn int(&self, col: usize) -> crate::Result<usize> {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_fields_split_with_quotes() {
        assert_eq!(split_csv("1, a ,\"b,c\",\"say \"\"hi\"\"\","), vec!["1", "a", "b,c", "say \"hi\"", ""]);
    }
}
