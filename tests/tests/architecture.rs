//! docs/ARCHITECTURE.md says which crate may import which; this test holds every crate's
//! `Cargo.toml` to it (a crate imports only crates on lower floors, and on its own floor only
//! those its row names), checks that every workspace member has a row, and that no file of
//! `cli/src` imports another in a loop (issue 30: the binary only parses and dispatches).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("the workspace root").to_path_buf()
}

#[derive(Debug)]
struct Row {
    floor: u32,
    dir: String,
    same_floor: BTreeSet<String>,
}

/// The import table of docs/ARCHITECTURE.md: crate -> row.
fn table(doc: &str) -> BTreeMap<String, Row> {
    let mut rows = BTreeMap::new();
    for line in doc.lines() {
        let cells: Vec<&str> = line.trim().trim_matches('|').split('|').map(str::trim).collect();
        if cells.len() != 4 {
            continue;
        }
        let Ok(floor) = cells[0].parse::<u32>() else { continue };
        let same_floor = cells[3].split(',').map(str::trim).filter(|s| !s.is_empty()).map(String::from).collect();
        rows.insert(cells[1].to_string(), Row { floor, dir: cells[2].to_string(), same_floor });
    }
    rows
}

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("reading {}: {e}", path.display()))
}

/// The `coadapt-*` crates a manifest's `[dependencies]` name (dev-dependencies are free).
fn imports(manifest: &toml::Table) -> BTreeSet<String> {
    manifest
        .get("dependencies")
        .and_then(|d| d.as_table())
        .map_or_else(BTreeSet::new, |d| d.keys().filter(|k| k.starts_with("coadapt")).cloned().collect())
}

/// What is wrong with `crates` (name, directory, imports) against the table `rows`.
fn problems(rows: &BTreeMap<String, Row>, crates: &[(String, String, BTreeSet<String>)]) -> Vec<String> {
    let mut problems = Vec::new();
    for (name, dir, deps) in crates {
        let Some(row) = rows.get(name) else {
            problems.push(format!("{name} ({dir}) has no row in docs/ARCHITECTURE.md"));
            continue;
        };
        if &row.dir != dir {
            problems.push(format!("{name}: the table says {}, the workspace {dir}", row.dir));
        }
        for dep in deps {
            if dep == "coadapt-test-support" {
                problems.push(format!("{name} imports coadapt-test-support outside its tests"));
                continue;
            }
            let Some(d) = rows.get(dep) else {
                problems.push(format!("{name} imports {dep}, which has no row"));
                continue;
            };
            let allowed = d.floor < row.floor || d.floor == row.floor && row.same_floor.contains(dep);
            if !allowed {
                problems.push(format!(
                    "{name} (floor {}) imports {dep} (floor {}), which stands above it or beside it unlisted",
                    row.floor, d.floor
                ));
            }
        }
    }
    for name in rows.keys().filter(|n| !crates.iter().any(|c| &c.0 == *n)) {
        problems.push(format!("{name} has a row but is not a workspace member"));
    }
    problems
}

#[test]
fn every_crate_imports_only_what_the_architecture_allows() {
    let root = root();
    let rows = table(&read(&root.join("docs/ARCHITECTURE.md")));
    assert!(rows.len() > 10, "the import table of docs/ARCHITECTURE.md was not found");
    let workspace: toml::Table = toml::from_str(&read(&root.join("Cargo.toml"))).expect("the workspace manifest");
    let crates: Vec<(String, String, BTreeSet<String>)> = workspace["workspace"]["members"]
        .as_array()
        .expect("workspace.members")
        .iter()
        .map(|m| {
            let dir = m.as_str().expect("a member path").to_string();
            let manifest: toml::Table = toml::from_str(&read(&root.join(&dir).join("Cargo.toml"))).expect("a member manifest");
            let name = manifest["package"]["name"].as_str().expect("package.name").to_string();
            (name, dir, imports(&manifest))
        })
        .collect();
    let p = problems(&rows, &crates);
    assert!(p.is_empty(), "docs/ARCHITECTURE.md and the manifests disagree:\n{}", p.join("\n"));
}

#[test]
fn the_checker_refuses_an_import_from_above_or_beside() {
    let rows = table("| 0 | a | x | |\n| 3 | b | y | |\n| 3 | c | z | b |\n");
    let set = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<BTreeSet<_>>();
    let ok = [("a".into(), "x".into(), set(&[])), ("b".into(), "y".into(), set(&["a"])), ("c".into(), "z".into(), set(&["a", "b"]))];
    assert!(problems(&rows, &ok).is_empty(), "{:?}", problems(&rows, &ok));
    let up = [("a".into(), "x".into(), set(&["b"])), ("b".into(), "y".into(), set(&[])), ("c".into(), "z".into(), set(&[]))];
    assert_eq!(problems(&rows, &up).len(), 1, "a ground-floor crate importing one above");
    let beside = [("a".into(), "x".into(), set(&[])), ("b".into(), "y".into(), set(&["c"])), ("c".into(), "z".into(), set(&[]))];
    assert_eq!(problems(&rows, &beside).len(), 1, "an unlisted import on the same floor");
    let support =
        [("a".into(), "x".into(), set(&["coadapt-test-support"])), ("b".into(), "y".into(), set(&[])), ("c".into(), "z".into(), set(&[]))];
    assert_eq!(problems(&rows, &support).len(), 1, "the test support in a library");
}

/// The modules of `cli/src` each file names with `crate::<module>`.
fn cli_imports(src: &Path) -> BTreeMap<String, BTreeSet<String>> {
    let mut graph = BTreeMap::new();
    let mut files = Vec::new();
    let mut dirs = vec![src.to_path_buf()];
    while let Some(d) = dirs.pop() {
        for e in std::fs::read_dir(&d).expect("cli/src").flatten() {
            let p = e.path();
            if p.is_dir() {
                dirs.push(p);
            } else if p.extension().is_some_and(|x| x == "rs") {
                files.push(p);
            }
        }
    }
    for f in files {
        let rel = f.strip_prefix(src).expect("under cli/src");
        // A file's module is its first path component (`plot/figures.rs` belongs to `plot`).
        let module = rel.components().next().expect("a file").as_os_str().to_string_lossy().trim_end_matches(".rs").to_string();
        if module == "lib" || module == "main" {
            continue;
        }
        let text = read(&f);
        let uses: BTreeSet<String> = text
            .match_indices("crate::")
            .filter_map(|(i, _)| {
                let rest = &text[i + 7..];
                let end = rest.find(|c: char| !(c.is_ascii_alphanumeric() || c == '_')).unwrap_or(rest.len());
                let m = &rest[..end];
                (!m.is_empty() && m != module && m.chars().next().is_some_and(|c| c.is_ascii_lowercase())).then(|| m.to_string())
            })
            .collect();
        graph.entry(module).or_insert_with(BTreeSet::new).extend(uses);
    }
    graph
}

fn find_cycle(graph: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(n: &str, g: &BTreeMap<String, BTreeSet<String>>, stack: &mut Vec<String>, done: &mut BTreeSet<String>) -> Option<Vec<String>> {
        if let Some(i) = stack.iter().position(|s| s == n) {
            let mut c = stack[i..].to_vec();
            c.push(n.to_string());
            return Some(c);
        }
        if done.contains(n) {
            return None;
        }
        stack.push(n.to_string());
        for m in g.get(n).into_iter().flatten() {
            if let Some(c) = visit(m, g, stack, done) {
                return Some(c);
            }
        }
        stack.pop();
        done.insert(n.to_string());
        None
    }
    let mut done = BTreeSet::new();
    graph.keys().find_map(|n| visit(n, graph, &mut Vec::new(), &mut done))
}

#[test]
fn no_file_of_the_binary_imports_another_in_a_loop() {
    let graph = cli_imports(&root().join("cli/src"));
    assert!(graph.len() > 5, "cli/src was not read: {graph:?}");
    if let Some(c) = find_cycle(&graph) {
        panic!("cli/src imports in a loop: {}", c.join(" -> "));
    }
    // The checker can fail.
    let mut looped = graph.clone();
    looped.entry("a".into()).or_default().insert("b".into());
    looped.entry("b".into()).or_default().insert("a".into());
    assert!(find_cycle(&looped).is_some());
}
