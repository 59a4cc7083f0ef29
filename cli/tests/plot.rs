#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

//! `coadapt plot` on small synthetic run directories.

use std::fs;
use std::path::{Path, PathBuf};

use coadapt_coadaptation::plot;

fn tmpdir(name: &str) -> PathBuf {
    coadapt_test_support::scratch_dir("plot", name)
}

const DESIGNS: &str = "index,kind,design,episodes,best_eval_return,last_eval_return,predicted_objective,design_rollouts
0,initial,1;1;1,3,-50.5,-60,,3
1,exploit,1.2;0.9;1.1,3,12.25,10,33.1,3
2,explore,0.7;1.4;0.95,3,,,,3
3,exploit,1.3;0.8;1.2,3,40,38.5,41.0,3
";

fn episodes_csv() -> String {
    let mut s = String::from("design,episode,global_episode,steps,return,eval_return,weights_version,seconds\n");
    let mut g = 0;
    for d in 0..4 {
        for e in 0..3 {
            let eval = if e == 2 { format!("{}", 10.0 * d as f64 - 5.0) } else { String::new() };
            s += &format!("{d},{e},{g},1000,{},{eval},{},{}.5\n", -100.0 + 30.0 * d as f64 + 7.0 * e as f64, g * 5, g);
            g += 1;
        }
    }
    s
}

fn landscape_csv(n: usize) -> String {
    let mut s = String::from("pc1,pc2,objective\n");
    for j in 0..n {
        for i in 0..n {
            let (x, y) = (-1.0 + 2.0 * i as f64 / (n - 1) as f64, -0.5 + j as f64 / (n - 1) as f64);
            s += &format!("{x},{y},{}\n", 10.0 - x * x - 3.0 * y * y);
        }
    }
    s
}

const LANDSCAPE_DESIGNS: &str = "index,kind,pc1,pc2\n0,initial,0,0\n1,exploit,0.5,0.1\n2,explore,-0.8,-0.3\n3,exploit,0.6,0.2\n";

fn write_run(dir: &Path, landscape: bool) {
    fs::write(dir.join("designs.csv"), DESIGNS).unwrap();
    fs::write(dir.join("episodes.csv"), episodes_csv()).unwrap();
    if landscape {
        fs::write(dir.join("landscape.csv"), landscape_csv(6)).unwrap();
        fs::write(dir.join("landscape_designs.csv"), LANDSCAPE_DESIGNS).unwrap();
    }
}

/// The contents of the SVG's `<text>` elements, trimmed.
fn texts(svg: &str) -> Vec<String> {
    svg.split("<text").skip(1).filter_map(|t| Some(t[t.find('>')? + 1..t.find("</text>")?].trim().to_string())).collect()
}

fn assert_svg(path: &Path) -> String {
    let svg = fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert!(svg.contains("<svg") && svg.contains("</svg>"), "{} is not an SVG", path.display());
    svg
}

#[test]
fn draw_run_writes_the_three_plots() {
    let dir = tmpdir("full");
    write_run(&dir, true);
    let written = plot::draw_run(&dir).unwrap();
    let names: Vec<String> = written.iter().map(|p| p.file_name().unwrap().to_string_lossy().into_owned()).collect();
    assert_eq!(names, ["learning_curves.svg", "best_return.svg", "landscape.svg"]);
    for p in &written {
        assert_eq!(p.parent().unwrap(), dir.join("plots"));
        assert_svg(p);
    }
    // The landscape: 36 cells, the design indices as labels, the colour scale's ends.
    let svg = assert_svg(&dir.join("plots/landscape.svg"));
    assert!(svg.matches("<rect").count() >= 36, "heat map cells");
    let labels = texts(&svg);
    for i in ["0", "1", "2", "3", "9.930", "8.250", "objective", "PC 1", "PC 2"] {
        assert!(labels.iter().any(|t| t == i), "no text {i:?} in {labels:?}");
    }
    let best = texts(&assert_svg(&dir.join("plots/best_return.svg")));
    for kind in ["initial", "exploit", "explore", "best so far"] {
        assert!(best.iter().any(|t| t == kind), "legend of how designs were chosen: no {kind:?} in {best:?}");
    }
    fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_missing_landscape_skips_only_that_plot() {
    let dir = tmpdir("nolandscape");
    write_run(&dir, false);
    let written = plot::draw_run(&dir).unwrap();
    assert_eq!(written.len(), 2);
    assert!(dir.join("plots/learning_curves.svg").exists() && dir.join("plots/best_return.svg").exists());
    assert!(!dir.join("plots/landscape.svg").exists());
    fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_malformed_number_names_file_line_and_column() {
    let dir = tmpdir("malformed");
    write_run(&dir, true);
    let bad = DESIGNS.replace("12.25", "12.2.5");
    fs::write(dir.join("designs.csv"), bad).unwrap();
    let err = format!("{:#}", plot::draw_run(&dir).unwrap_err());
    assert!(err.contains("designs.csv") && err.contains("line 3") && err.contains("best_eval_return") && err.contains("12.2.5"), "{err}");

    // Too few values in a middle row is an error too.
    write_run(&dir, true);
    let mut eps = episodes_csv();
    eps = eps.replacen("0,1,1,1000", "0,1,1", 1);
    fs::write(dir.join("episodes.csv"), eps).unwrap();
    let err = format!("{:#}", plot::draw_run(&dir).unwrap_err());
    assert!(err.contains("episodes.csv") && err.contains("line 3"), "{err}");
    fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn an_interrupted_run_is_plotted_as_far_as_it_goes() {
    let dir = tmpdir("partial");
    // designs.csv has only the header so far; episodes.csv stops in the middle of a row.
    fs::write(dir.join("designs.csv"), DESIGNS.lines().next().unwrap().to_string() + "\n").unwrap();
    let eps = episodes_csv();
    let cut = eps.len() - 9;
    fs::write(dir.join("episodes.csv"), &eps[..cut]).unwrap();
    let written = plot::draw_run(&dir).unwrap();
    assert_eq!(written.len(), 2, "{written:?}");
    // The best returns come from the episodes' evaluation returns.
    assert_svg(&dir.join("plots/best_return.svg"));

    // A run with nothing yet is an error, not a panic.
    let empty = tmpdir("empty");
    assert!(plot::draw_run(&empty).is_err());
    fs::write(empty.join("episodes.csv"), "design,episode,global_episode,steps,return,eval_return,weights_version,seconds\n").unwrap();
    let err = format!("{:#}", plot::draw_run(&empty).unwrap_err());
    assert!(err.contains("nothing to plot"), "{err}");
    fs::remove_dir_all(&dir).unwrap();
    fs::remove_dir_all(&empty).unwrap();
}

#[test]
fn compare_draws_several_runs_in_one_figure() {
    let a = tmpdir("cmp-a");
    let b = tmpdir("cmp-b");
    write_run(&a, false);
    fs::write(b.join("designs.csv"), DESIGNS.replace("40,38.5", "80,70")).unwrap();
    let out = tmpdir("cmp-out").join("compare.svg");
    plot::compare(&[("FEAR".into(), a.clone()), ("PSO on sim".into(), b.clone())], &out).unwrap();
    let svg = assert_svg(&out);
    let labels = texts(&svg);
    assert!(labels.iter().any(|t| t == "FEAR") && labels.iter().any(|t| t == "PSO on sim"), "legend: {labels:?}");
    // Through the clap front end, with labels.
    let args = <PlotArgsCli as clap::Parser>::try_parse_from([
        "plot",
        "--compare",
        out.to_str().unwrap(),
        a.to_str().unwrap(),
        b.to_str().unwrap(),
        "--labels",
        "one,two",
    ])
    .unwrap();
    coadapt_cli::plot::run(args.args).unwrap();
    assert!(texts(&assert_svg(&out)).iter().any(|t| t == "two"));
    let wrong =
        <PlotArgsCli as clap::Parser>::try_parse_from(["plot", "--compare", out.to_str().unwrap(), a.to_str().unwrap(), "--labels", "x,y"])
            .unwrap();
    assert!(coadapt_cli::plot::run(wrong.args).is_err(), "label count must match");
    for d in [a, b, out.parent().unwrap().to_path_buf()] {
        fs::remove_dir_all(d).unwrap();
    }
}

#[derive(clap::Parser)]
struct PlotArgsCli {
    #[command(flatten)]
    args: coadapt_cli::plot::PlotArgs,
}

#[test]
fn one_of_everything_is_drawn_without_panicking() {
    let dir = tmpdir("single");
    fs::write(dir.join("designs.csv"), "index,kind,best_eval_return\n0,initial,5\n").unwrap();
    fs::write(dir.join("episodes.csv"), "design,episode,return,eval_return\n0,0,-3,5").unwrap();
    fs::write(dir.join("landscape.csv"), "pc1,pc2,objective\n0,0,1.5\n").unwrap();
    fs::write(dir.join("landscape_designs.csv"), "index,pc1,pc2\n0,0,0\n").unwrap();
    assert_eq!(plot::draw_run(&dir).unwrap().len(), 3);
    // Unknown objectives (empty, nan) are blank cells; all of them unknown skips the plot.
    fs::write(dir.join("landscape.csv"), "pc1,pc2,objective\n0,0,\n1,0,nan\n").unwrap();
    assert_eq!(plot::draw_run(&dir).unwrap().len(), 2);
    fs::remove_dir_all(&dir).unwrap();
}

/// With the prototype step a design may have been rejected (a row of its own, no episodes,
/// followed by the row of the design built instead) or still await its prototype (no episodes,
/// no returns): the plots leave the rejected one out and draw the rest.
#[test]
fn rejected_and_awaiting_prototypes_leave_the_plots_intact() {
    let dir = tmpdir("prototype");
    let designs = "index,kind,design,episodes,best_eval_return,last_eval_return,predicted_objective,design_rollouts,method,prototype
0,initial,1;1;1,2,-50.5,-60,,0,fixed,confirmed
1,exploit,1.2;0.9;1.1,0,,,33.1,0,pso-q,rejected
1,exploit,1.3;0.9;1.1,2,12.25,10,30,0,pso-q,as-built (requested 1.25;0.9;1.1)
2,explore,0.7;1.4;0.95,0,,,,0,novelty,awaiting
";
    fs::write(dir.join("designs.csv"), designs).unwrap();
    fs::write(dir.join("episodes.csv"), "design,episode,return,eval_return\n0,0,-70,\n0,1,-60,-50.5\n1,0,5,\n1,1,10,12.25\n").unwrap();
    let rows = plot::read_designs(&dir.join("designs.csv")).unwrap().unwrap();
    assert_eq!(rows.iter().map(|r| (r.index, r.best_eval_return)).collect::<Vec<_>>(), [(0, Some(-50.5)), (1, Some(12.25)), (2, None)]);
    let best = plot::best_per_design(&rows, &plot::read_episodes(&dir.join("episodes.csv")).unwrap().unwrap());
    assert_eq!(
        best.iter().map(|b| (b.index, b.kind.as_str(), b.best)).collect::<Vec<_>>(),
        [(0, "initial", Some(-50.5)), (1, "exploit", Some(12.25)), (2, "explore", None)]
    );
    assert_eq!(plot::draw_run(&dir).unwrap().len(), 2, "learning curves and best return; no landscape yet");
    fs::remove_dir_all(&dir).unwrap();
}
