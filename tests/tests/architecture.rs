//! docs/ARCHITECTURE.md says which crate may import which; this test holds every crate's
//! `Cargo.toml` to it (a crate imports only crates on lower floors, and on its own floor only
//! those its row names), checks that every workspace member has a row, and that no file of
//! `cli/src` imports another in a loop (issue 30: the binary only parses and dispatches), and
//! that no test file is left out of a package's one test binary.

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

/// The files of `tests/` a test target reaches through `mod` declarations, from `entry`.
/// `#[path = "x.rs"]` is relative to the declaring file's directory; a plain `mod m;` is taken
/// as `m.rs` or `m/mod.rs` beside it, which is where rustc looks from a crate root, `main.rs` or
/// `mod.rs` (from any other file rustc looks one directory deeper, so a file this counts wrongly
/// as reached fails to build rather than being skipped).
fn reached(entry: &Path) -> BTreeSet<PathBuf> {
    let mut seen = BTreeSet::new();
    let mut todo = vec![entry.to_path_buf()];
    while let Some(file) = todo.pop() {
        let Ok(text) = std::fs::read_to_string(&file) else { continue };
        if !seen.insert(file.clone()) {
            continue;
        }
        let dir = file.parent().expect("a file's directory").to_path_buf();
        let mut path_attr: Option<String> = None;
        for line in text.lines().map(str::trim) {
            if let Some(p) = line.strip_prefix("#[path = \"").and_then(|r| r.strip_suffix("\"]")) {
                path_attr = Some(p.to_string());
            } else if let Some(m) = line.strip_prefix("mod ").or_else(|| line.strip_prefix("pub mod ")).and_then(|r| r.strip_suffix(';')) {
                match path_attr.take() {
                    Some(p) => todo.push(dir.join(p)),
                    None => {
                        todo.push(dir.join(format!("{m}.rs")));
                        todo.push(dir.join(m).join("mod.rs"));
                    }
                }
            } else if !line.starts_with("//") && !line.is_empty() {
                path_attr = None;
            }
        }
    }
    seen
}

/// The files directly under `tests/` (and `tests/*/main.rs`) of a package that its `[[test]]`
/// targets do not reach. With `autotests = false` (one test binary per package) such a file
/// would compile into nothing and its tests would silently never run.
fn unreached(package: &Path, targets: &[PathBuf]) -> Vec<PathBuf> {
    let mut seen = BTreeSet::new();
    for t in targets {
        seen.extend(reached(&package.join(t)));
    }
    let mut out = Vec::new();
    let Ok(entries) = std::fs::read_dir(package.join("tests")) else { return out };
    for e in entries.flatten() {
        let p = e.path();
        let candidate = if p.is_dir() { p.join("main.rs") } else { p };
        if candidate.extension().is_some_and(|x| x == "rs") && candidate.exists() && !seen.contains(&candidate) {
            out.push(candidate);
        }
    }
    out.sort();
    out
}

#[test]
fn every_test_file_is_in_its_packages_test_binary() {
    let root = root();
    let workspace: toml::Table = toml::from_str(&read(&root.join("Cargo.toml"))).expect("the workspace manifest");
    let mut checked = 0;
    let mut problems = Vec::new();
    for m in workspace["workspace"]["members"].as_array().expect("workspace.members") {
        let dir = root.join(m.as_str().expect("a member path"));
        let manifest: toml::Table = toml::from_str(&read(&dir.join("Cargo.toml"))).expect("a member manifest");
        if manifest["package"].get("autotests").and_then(toml::Value::as_bool) != Some(false) {
            continue;
        }
        let targets: Vec<PathBuf> = manifest
            .get("test")
            .and_then(|t| t.as_array())
            .map(|a| a.iter().filter_map(|t| t.get("path").and_then(|p| p.as_str()).map(PathBuf::from)).collect())
            .unwrap_or_default();
        assert!(!targets.is_empty(), "{}: autotests = false and no [[test]] target", dir.display());
        checked += 1;
        problems.extend(unreached(&dir, &targets).into_iter().map(|p| p.display().to_string()));
    }
    assert!(checked >= 5, "only {checked} packages with one test binary were found");
    assert!(problems.is_empty(), "test files no test target declares (add a `mod` line to tests/all.rs):\n{}", problems.join("\n"));
    // The checker can fail: a file beside the entry that nobody declares.
    let t = std::env::temp_dir().join(format!("coadapt-arch-tests-{}", std::process::id()));
    std::fs::create_dir_all(t.join("tests/sub")).expect("a scratch package");
    std::fs::write(t.join("tests/all.rs"), "mod a;\n#[path = \"sub/main.rs\"]\nmod sub;\n").expect("writing");
    for f in ["tests/a.rs", "tests/sub/main.rs", "tests/orphan.rs"] {
        std::fs::write(t.join(f), "").expect("writing");
    }
    assert_eq!(unreached(&t, &[PathBuf::from("tests/all.rs")]), vec![t.join("tests/orphan.rs")]);
    let _ = std::fs::remove_dir_all(&t);
}
