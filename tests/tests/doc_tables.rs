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

/// Runs `python3 scripts/NAME ARGS...` from the root; its stdout and stderr, asserting it succeeded.
fn script(name: &str, args: &[&std::ffi::OsStr]) -> String {
    let o = Command::new("python3")
        .arg(root().join("scripts").join(name))
        .args(args)
        .current_dir(root())
        .output()
        .unwrap_or_else(|e| panic!("running python3 scripts/{name}: {e}"));
    let text = String::from_utf8_lossy(&o.stdout).to_string() + &String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{name} failed:\n{text}");
    text
}

/// Writes a finished benchmark run (designs.csv with the given best evaluation returns after two
/// initial designs, summary.json, one episode row) under `root/name`, every design the same.
fn synthetic_run(root: &Path, name: &str, kinds: &[&str], best: &[f64]) {
    synthetic_run_with(root, name, kinds, &vec!["1;1;1;1;1;1"; kinds.len()], best);
}

/// `synthetic_run` with a design vector (`;`-separated) per row.
fn synthetic_run_with(root: &Path, name: &str, kinds: &[&str], designs: &[&str], best: &[f64]) {
    let dir = root.join(name);
    std::fs::create_dir_all(&dir).expect("run dir");
    let mut csv =
        String::from("index,kind,design,episodes,best_eval_return,last_eval_return,predicted_objective,design_rollouts,method,prototype\n");
    for (i, ((k, d), b)) in kinds.iter().zip(designs).zip(best).enumerate() {
        csv += &format!("{i},{k},{d},16,{b},{b},,0,x,\n");
    }
    std::fs::write(dir.join("designs.csv"), csv).expect("designs.csv");
    std::fs::write(dir.join("summary.json"), "{}").expect("summary.json");
    std::fs::write(dir.join("episodes.csv"), "design,episode,seconds\n0,0,10.0\n").expect("episodes.csv");
}

/// The benchmark's `trend` table adds back, pair by pair, what training one body later is worth
/// in the random-designs run of the same seed at the same slots (issue 28: the within-run pairs'
/// time trend). Two initial designs, then FEAR's exploit/explore pairs at slots (2, 3) and (4, 5):
/// FEAR's pairs are 100 - 130 = -30 and 90 - 150 = -60; the random run's later minus earlier
/// bodies at those slots are 140 - 100 = +40 and 160 - 110 = +50, so the adjusted differences
/// are +10 and -10 (mean 0.0, sd 14.1), the trend +45.0 ± 7.1, one win in two (exact p 1.00).
#[test]
fn the_trend_table_removes_the_random_runs_time_trend_pair_by_pair() {
    let dir = std::env::temp_dir().join(format!("coadapt-trend-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let k = ["initial", "initial", "exploit", "explore", "exploit", "explore"];
    synthetic_run(&dir, "hc-fear-seed1", &k, &[50.0, 60.0, 100.0, 130.0, 90.0, 150.0]);
    synthetic_run(
        &dir,
        "hc-random-seed1",
        &["initial", "initial", "exploit", "exploit", "exploit", "exploit"],
        &[50.0, 60.0, 100.0, 140.0, 110.0, 160.0],
    );
    let text = script(
        "design_bench_report.py",
        &[dir.as_os_str(), "--robots".as_ref(), "hc".as_ref(), "--tables".as_ref(), "within,trend".as_ref()],
    );
    let _ = std::fs::remove_dir_all(&dir);
    // The plain within-run row, then the adjusted one.
    assert!(text.contains("| fear | 1 | 2 | -45.0 ± 21.2 | 0/2 |"), "within row:\n{text}");
    // The trend row; then the chosen design at slot 4 against the mean of its random
    // neighbours, 90 - (130 + 150) / 2 = -50 (the one at slot 2 has an initial design before it).
    assert!(text.contains("| fear | 1 | +45.0 ± 7.1 (2) | +0.0 ± 14.1 | 1/2 | 1.00 | -50.0 (1) | 0/1 | 1.00 |"), "trend row:\n{text}");
}

/// Section 3's rule (`--tables verdict`): a method becomes the default only if it beats FEAR on 3
/// of the 4 robots, each with 3 seeds paired with FEAR's, without losing on HalfCheetah. `alt`
/// beats FEAR by 10 on every seed of HalfCheetah, Walker and Hopper (+10.0 ± 0.0, exact p 0.25
/// with 3 pairs): yes. `bad` beats it by 20 on Walker and Hopper and loses 10 on HalfCheetah: no.
/// `thin` has one HalfCheetah seed: open, naming the seeds each robot lacks.
#[test]
fn the_verdict_applies_section_3s_rule_robot_by_robot() {
    let dir = std::env::temp_dir().join(format!("coadapt-verdict-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let k = ["initial", "initial", "exploit", "explore"];
    for robot in ["hc", "walker-bench", "hopper-bench"] {
        for seed in 1..=3 {
            synthetic_run(&dir, &format!("{robot}-fear-seed{seed}"), &k, &[50.0, 60.0, 100.0, 80.0]);
            synthetic_run(&dir, &format!("{robot}-alt-seed{seed}"), &k, &[50.0, 60.0, 110.0, 80.0]);
            let bad = if robot == "hc" { 90.0 } else { 120.0 };
            synthetic_run(&dir, &format!("{robot}-bad-seed{seed}"), &k, &[50.0, 60.0, bad, 80.0]);
        }
    }
    synthetic_run(&dir, "hc-thin-seed1", &k, &[50.0, 60.0, 130.0, 80.0]);
    let text = script("design_bench_report.py", &[dir.as_os_str(), "--tables".as_ref(), "verdict".as_ref()]);
    let _ = std::fs::remove_dir_all(&dir);
    assert!(!text.contains("#### HalfCheetah"), "per-robot tables were not asked for:\n{text}");
    assert!(
        text.contains("| alt | +10.0 ± 0.0 (3, 0.25) | +10.0 ± 0.0 (3, 0.25) | +10.0 ± 0.0 (3, 0.25) | - | yes (beats FEAR on 3) |"),
        "alt row:\n{text}"
    );
    assert!(
        text.contains("| bad | -10.0 ± 0.0 (3, 0.25) | +20.0 ± 0.0 (3, 0.25) | +20.0 ± 0.0 (3, 0.25) | - | no (loses on HalfCheetah) |"),
        "bad row:\n{text}"
    );
    assert!(
        text.contains("| thin | +30.0 (1, 1.00) | - | - | - | open: seeds HalfCheetah 1/3, Walker 0/3, Hopper 0/3, Daisy 0/3 |"),
        "thin row:\n{text}"
    );
}

/// The reference run's tables (`scripts/reference_report.py`, EXPERIMENTS 5.13) on a run with two
/// initial designs (50, 70: mean 60.0, sd 14.1) and two exploit/explore pairs, 100 - 130 = -30
/// and 160 - 90 = +70 (mean +20.0, sd 70.7, one win in two, exact p 1.00); chosen designs'
/// mean (100 + 130 + 160 + 90) / 4 = 120.0, exploitation designs' 130.0, the best design 4.
#[test]
fn the_reference_report_summarises_a_run_design_by_design() {
    let dir = std::env::temp_dir().join(format!("coadapt-reference-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let k = ["initial", "initial", "exploit", "explore", "exploit", "explore"];
    synthetic_run(&dir, "hc-reference-seed1", &k, &[50.0, 70.0, 100.0, 130.0, 160.0, 90.0]);
    let run = dir.join("hc-reference-seed1");
    let text = script(
        "reference_report.py",
        &[run.as_os_str(), "--initial".as_ref(), "2".as_ref(), "--tables".as_ref(), "designs,summary".as_ref()],
    );
    let _ = std::fs::remove_dir_all(&dir);
    assert!(text.contains("| 4 | exploit | 1.00 1.00 1.00 1.00 1.00 1.00 | 16 | 160.0 | - | 0/6 |"), "designs row:\n{text}");
    assert!(
        text.contains(
            "| 6 | 96 | 60.0 ± 14.1 (n = 2) | 120.0 (n = 4) | 130.0 (n = 2) | +20.0 ± 70.7 (1/2, p = 1.00) | 160.0 (design 4, exploit) |"
        ),
        "summary row:\n{text}"
    );
}

/// The bar (`--tables everywhere`): a method's chosen designs beat the random design
/// trained after them on every robot, pooled over the grid's seeds (HalfCheetah 5, the others
/// 3), exact p <= 0.05. `good` wins both pairs of every run by 10: 10 pairs on HalfCheetah (p =
/// 2/1024, 0.002) and 6 elsewhere (2/64 = 0.031, printed 0.03): yes. `weak` has the same runs but loses by 10 on
/// Walker: no, naming Walker. `thin` wins on one HalfCheetah seed only: open.
#[test]
fn the_everywhere_table_asks_for_every_robot_at_the_grids_seeds() {
    let dir = std::env::temp_dir().join(format!("coadapt-everywhere-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let k = ["initial", "initial", "exploit", "explore", "exploit", "explore"];
    for robot in ["hc", "walker-bench", "hopper-bench", "daisy-bench", "mujoco-bench"] {
        for seed in 1..=(if robot == "hc" { 5 } else { 3 }) {
            synthetic_run(&dir, &format!("{robot}-good-seed{seed}"), &k, &[50.0, 60.0, 110.0, 100.0, 130.0, 120.0]);
            let w = if robot == "walker-bench" { [90.0, 100.0, 110.0, 120.0] } else { [110.0, 100.0, 130.0, 120.0] };
            synthetic_run(&dir, &format!("{robot}-weak-seed{seed}"), &k, &[50.0, 60.0, w[0], w[1], w[2], w[3]]);
        }
    }
    synthetic_run(&dir, "hc-thin-seed1", &k, &[50.0, 60.0, 110.0, 100.0, 130.0, 120.0]);
    let text = script("design_bench_report.py", &[dir.as_os_str(), "--tables".as_ref(), "everywhere".as_ref()]);
    // The README's brief form of the same table: the same decisions, cell by cell.
    let brief = script("design_bench_report.py", &[dir.as_os_str(), "--tables".as_ref(), "brief".as_ref()]);
    let _ = std::fs::remove_dir_all(&dir);
    let beats = "**beats**: +10.0 ± 0.0, n = 6, p 0.03 (3/3 seeds)";
    let good = format!("| good | **beats**: +10.0 ± 0.0, n = 10, p 0.002 (5/5 seeds) | {beats} | {beats} | {beats} | {beats} |");
    assert!(brief.contains(&good), "brief good row:\n{brief}");
    let weak =
        format!("| weak | **beats**: +10.0 ± 0.0, n = 10, p 0.002 (5/5 seeds) | loses: -10.0 ± 0.0, n = 6, p 0.03 (3/3 seeds) | {beats} |");
    assert!(brief.contains(&weak), "brief weak row:\n{brief}");
    assert!(brief.contains("| thin | open: +10.0 ± 0.0, n = 2, p 0.50 (1/5 seeds) | - | - | - | - |"), "brief thin row:\n{brief}");
    let good = "| good | +10.0 ± 0.0 (5, 10, 0.002) | +10.0 ± 0.0 (3, 6, 0.03) | +10.0 ± 0.0 (3, 6, 0.03) | \
                +10.0 ± 0.0 (3, 6, 0.03) | +10.0 ± 0.0 (3, 6, 0.03) | yes |";
    assert!(text.contains(good), "good row:\n{text}");
    assert!(text.contains("| -10.0 ± 0.0 (3, 6, 0.03) |") && text.contains("| no (not shown on Walker) |"), "weak row:\n{text}");
    assert!(
        text.contains(
            "| thin | +10.0 ± 0.0 (1, 2, 0.50) | - | - | - | - | open: seeds HalfCheetah 1/5, Walker 0/3, Hopper 0/3, Daisy 0/3, MuJoCo HalfCheetah (bridge) 0/3 |"
        ),
        "thin row:\n{text}"
    );
}

/// `--tables edges`: every within-run pair of a robot, pooled over methods, grouped by how many
/// coordinates of the chosen design sit within 2 % of a bound (HalfCheetah's box: 0.8-2.0, so
/// 0.024). FEAR's chosen bodies: three coordinates at 2.0 (then -30 against the random body
/// after it) and one at 0.8 (-60); trust's: none at an edge (+20) and one at 1.99 (+40). So
/// the group of 0 is +20 (1 pair), of 1 is -60 and +40 (-10.0 ± 70.7, 2 pairs of 2 methods), of
/// 3 or more -30; no design has exactly 2.
#[test]
fn the_edges_table_groups_pairs_by_coordinates_at_a_bound() {
    let dir = std::env::temp_dir().join(format!("coadapt-edges-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let k = ["initial", "initial", "exploit", "explore", "exploit", "explore"];
    let run = |name: &str, designs: [&str; 6], best: [f64; 6]| synthetic_run_with(&dir, name, &k, &designs, &best);
    let mid = "1;1;1;1;1;1";
    run("hc-fear-seed1", [mid, mid, "2.0;2.0;2.0;1;1;1", mid, "0.8;1;1;1;1;1", mid], [50.0, 60.0, 100.0, 130.0, 90.0, 150.0]);
    run("hc-trust-seed1", [mid, mid, mid, mid, "1.99;1;1;1;1;1", mid], [50.0, 60.0, 120.0, 100.0, 140.0, 100.0]);
    let text =
        script("design_bench_report.py", &[dir.as_os_str(), "--robots".as_ref(), "hc".as_ref(), "--tables".as_ref(), "edges".as_ref()]);
    let _ = std::fs::remove_dir_all(&dir);
    assert!(text.contains("| 0 | 1 (1) | +20.0 | 1/1 | 1.00 |"), "group 0:\n{text}");
    assert!(text.contains("| 1 | 2 (2) | -10.0 ± 70.7 | 1/2 | 1.00 |"), "group 1:\n{text}");
    assert!(text.contains("| 3 or more | 1 (1) | -30.0 | 0/1 | 1.00 |"), "group 3+:\n{text}");
    assert!(!text.contains("| 2 |"), "a group of 2 from nowhere:\n{text}");
}

/// `--tables samebody`: the random-designs run trains some of the very bodies FEAR's run trained
/// as exploration designs, a few slots earlier. FEAR's run: bodies B (slot 3, 130) and D (slot 5,
/// 150) as exploration designs; the random run: B at slot 2 (100), D at 3 (110), then E (120) and
/// F (130), a trend of +10 per slot. So B is +30 one slot later and D +40 two slots later
/// (+35.0 ± 7.1, 1.5 slots, 2 of 2, exact p 0.50); less the trend x slots, +20 and +20. A body
/// FEAR's run chose (A, an exploitation design) that the random run also drew does not count.
#[test]
fn the_samebody_table_compares_one_body_trained_in_two_histories() {
    let dir = std::env::temp_dir().join(format!("coadapt-samebody-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let (a, b, c, d, e, f) = ("1;1;1;1;1;2", "1;1;1;1;2;1", "1;1;1;2;1;1", "1;1;2;1;1;1", "1;2;1;1;1;1", "2;1;1;1;1;1");
    let init = "1;1;1;1;1;1";
    let k = ["initial", "initial", "exploit", "explore", "exploit", "explore"];
    synthetic_run_with(&dir, "hc-fear-seed1", &k, &[init, init, a, b, c, d], &[50.0, 60.0, 100.0, 130.0, 90.0, 150.0]);
    let r = ["initial", "initial", "exploit", "exploit", "exploit", "exploit", "exploit"];
    synthetic_run_with(&dir, "hc-random-seed1", &r, &[init, init, b, d, e, f, a], &[50.0, 60.0, 100.0, 110.0, 120.0, 130.0, 140.0]);
    let text = script("design_bench_report.py", &[dir.as_os_str(), "--tables".as_ref(), "samebody".as_ref()]);
    let _ = std::fs::remove_dir_all(&dir);
    assert!(!text.contains("#### HalfCheetah (`hc-*`)"), "per-robot tables were not asked for:\n{text}");
    assert!(text.contains("| HalfCheetah | 1 | 2 | 1.5 | +35.0 ± 7.1 | 2/2 | 0.50 | +10.0 | +20.0 ± 0.0 | 2/2 | 0.50 |"), "row:\n{text}");
    assert!(!text.contains("| all robots |"), "one robot, no pooled row:\n{text}");
}

/// The calibration counts quoted in words where a user reads a score (`coadapt serve --help`,
/// and the README's reading under its calibration table) are the generated table's: "A of B
/// (times) on ROBOT" must be ROBOT's "predicted order right" for the chosen body against the next
/// random one. The table itself is checked against the archive above.
#[test]
fn quoted_calibration_matches_the_table() {
    let readme = std::fs::read_to_string(root().join("README.md")).expect("reading README.md");
    let start = readme.find("calibration_report.py docs/campaign/results --methods").expect("the README's calibration table");
    let end = start + readme[start..].find("<!-- end generated -->").expect("the table's end");
    let table: std::collections::HashMap<&str, &str> = readme[start..end]
        .lines()
        .filter_map(|l| {
            let cells: Vec<&str> = l.split('|').map(str::trim).collect();
            (cells.len() > 4 && cells[1].ends_with("-fear")).then(|| (cells[1], cells[4]))
        })
        .collect();
    let robots = [
        ("HalfCheetah", "hc-fear"),
        ("Walker", "walker-bench-fear"),
        ("Hopper", "hopper-bench-fear"),
        ("Daisy", "daisy-bench-fear"),
        ("MuJoCo's cheetah", "mujoco-bench-fear"),
    ];
    // The paragraphs that quote it, whitespace and doc-comment markers folded.
    let serve = std::fs::read_to_string(root().join("cli/src/serve.rs")).expect("reading cli/src/serve.rs");
    let fold = |s: &str| s.lines().map(|l| l.trim().trim_start_matches("///").trim()).collect::<Vec<_>>().join(" ");
    let from = serve.find("How far to trust").expect("serve's paragraph");
    let help = fold(&serve[from..from + serve[from..].find("#[derive").expect("the paragraph's end")]);
    let reading = fold(&readme[end..][..readme[end..].find("as a guess.").expect("the README's reading")]);
    for (what, text) in [("coadapt serve --help", help.as_str()), ("the README's reading", reading.as_str())] {
        for (robot, method) in robots {
            let want = table.get(method).unwrap_or_else(|| panic!("no row {method} in the README's table"));
            // The first "on ROBOT" with "A of B" (or "A of B times") before it.
            let quoted = text
                .match_indices(&format!(" on {robot}"))
                .find_map(|(at, _)| {
                    let words: Vec<&str> = text[..at].split_whitespace().collect();
                    let words = words.strip_suffix(&["times"]).unwrap_or(&words);
                    let n = words.len();
                    (n >= 3 && words[n - 2] == "of").then(|| format!("{}/{}", words[n - 3], words[n - 1]))
                })
                .unwrap_or_else(|| panic!("{what} quotes no 'A of B on {robot}': {text}"));
            assert_eq!(&quoted, want, "{what} quotes {quoted} on {robot}; the table says {want}");
        }
    }
}
