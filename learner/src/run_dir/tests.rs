use super::*;

fn row(index: usize, episodes: usize, prototype: &str) -> DesignRow {
    DesignRow {
        index,
        kind: "exploit".into(),
        design: vec![0.1 * index as f32 + 1.0 / 3.0, f32::MIN_POSITIVE, 7.0],
        episodes,
        best_eval_return: (episodes > 0).then_some(-1.0 / 7.0),
        last_eval_return: None,
        predicted_objective: Some(123.456_79),
        design_rollouts: 3,
        method: "pso-q, \"odd\"\nmethod".into(),
        prototype: prototype.into(),
    }
}

fn tempdir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("coadapt-run-dir-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// What `designs.csv` must hold: the header and `rows`.
fn whole(rows: &[DesignRow]) -> String {
    format!("{DESIGNS_HEADER}\n{}", String::from_utf8(design_lines(rows).unwrap()).unwrap())
}

#[test]
fn designs_csv_is_appended_and_the_open_rows_replaced() {
    let dir = tempdir("append");
    let mut w = RunWriter::create(&dir).unwrap();
    let path = dir.join("designs.csv");
    assert_eq!(std::fs::read_to_string(&path).unwrap(), whole(&[]));
    w.design(&row(0, 3, "")).unwrap();
    // Design 1: awaiting, rejected; the next proposal awaiting, then confirmed and trained.
    w.design(&row(1, 0, PROTOTYPE_AWAITING)).unwrap();
    w.design(&row(1, 0, PROTOTYPE_REJECTED)).unwrap();
    w.design(&row(1, 0, PROTOTYPE_AWAITING)).unwrap();
    assert_eq!(
        std::fs::read_to_string(&path).unwrap(),
        whole(&[row(0, 3, ""), row(1, 0, PROTOTYPE_REJECTED), row(1, 0, PROTOTYPE_AWAITING)])
    );
    w.design(&row(1, 2, PROTOTYPE_CONFIRMED)).unwrap();
    w.design(&row(2, 2, "")).unwrap();
    let all = [row(0, 3, ""), row(1, 0, PROTOTYPE_REJECTED), row(1, 2, PROTOTYPE_CONFIRMED), row(2, 2, "")];
    assert_eq!(std::fs::read_to_string(&path).unwrap(), whole(&all));
    // Read back exactly, quoted text and every f32 bit included.
    assert_eq!(w.read_designs().unwrap(), all);
    let at = w.written_so_far();
    assert_eq!(at.designs_open, [row(2, 2, "")]);
    // Rows written after a snapshot are cut off by a resume from it.
    w.design(&row(3, 1, "")).unwrap();
    drop(w);
    let w = RunWriter::resume(&dir, at).unwrap();
    assert_eq!(std::fs::read_to_string(&path).unwrap(), whole(&all));
    assert_eq!(w.read_designs().unwrap(), all);
}

#[test]
fn a_damaged_designs_csv_is_named_not_a_panic() {
    let dir = tempdir("damaged");
    let mut w = RunWriter::create(&dir).unwrap();
    w.design(&row(0, 3, "")).unwrap();
    w.design(&row(1, 3, "")).unwrap();
    w.design(&row(2, 3, "")).unwrap();
    let at = w.written_so_far();
    let path = dir.join("designs.csv");
    let text = std::fs::read_to_string(&path).unwrap().replacen(";7", ";seven", 1);
    std::fs::write(&path, &text).unwrap();
    let e = read_designs(&path, at.designs_closed + 4).unwrap_err().to_string();
    assert!(e.contains("line 2: column design"), "{e}");
    std::fs::write(&path, &text[..20]).unwrap();
    let e = RunWriter::resume(&dir, at).unwrap_err().to_string();
    assert!(e.contains("fewer than the"), "{e}");
}
