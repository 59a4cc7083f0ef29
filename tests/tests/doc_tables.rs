//! The tables of docs/EXPERIMENTS.md (and the README) that are generated from the archived runs
//! (docs/campaign/results) agree with the archive: `scripts/doc_tables.py` regenerates every
//! `<!-- generated: ... -->` block and fails on any difference (issue 28: evidence anyone can
//! check). A second test makes sure the checker can fail: a copy of the document with one digit
//! changed in a generated table is refused.

use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("the workspace root").to_path_buf()
}

fn check(doc: &Path) -> std::process::Output {
    Command::new("python3")
        .arg(root().join("scripts/doc_tables.py"))
        .arg(doc)
        .current_dir(root())
        .output()
        .expect("running python3 scripts/doc_tables.py")
}

/// `doc` (a path from the root) agrees with the archive.
fn agrees(doc: &str) {
    let o = check(&root().join(doc));
    let text = String::from_utf8_lossy(&o.stdout).to_string() + &String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{doc} disagrees with docs/campaign/results:\n{text}");
    assert!(text.contains("generated blocks agree"), "unexpected output:\n{text}");
}

#[test]
fn experiments_tables_agree_with_the_archive() {
    agrees("docs/EXPERIMENTS.md");
}

/// The README's calibration table (reading a score, issue 28 section 5) comes from the same
/// archive.
#[test]
fn readme_tables_agree_with_the_archive() {
    agrees("README.md");
}

#[test]
fn a_changed_digit_in_a_generated_table_is_caught() {
    let doc = std::fs::read_to_string(root().join("docs/EXPERIMENTS.md")).expect("reading EXPERIMENTS.md");
    let start = doc.find("<!-- generated: ").expect("EXPERIMENTS.md has a generated table");
    let body = start + doc[start..].find("-->\n").expect("the marker closes") + 4;
    // The first digit inside the block's table, changed.
    let at = body + doc[body..].find(|c: char| c.is_ascii_digit()).expect("a digit in the table");
    let old = doc.as_bytes()[at];
    let new = if old == b'9' { '0' } else { (old + 1) as char };
    let mut bad = doc.clone();
    bad.replace_range(at..at + 1, &new.to_string());
    let dir = std::env::temp_dir().join(format!("coadapt-doc-tables-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let copy = dir.join("EXPERIMENTS.md");
    std::fs::write(&copy, bad).expect("writing the copy");
    let o = check(&copy);
    let _ = std::fs::remove_dir_all(&dir);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(!o.status.success(), "a changed digit passed the check:\n{text}");
    assert!(text.contains("disagree with the archive"), "unexpected output:\n{text}");
}
