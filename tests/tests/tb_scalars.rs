//! `scripts/tb_scalars.py` (the pure-Python reader that archives what a run logged only to
//! TensorBoard, such as the conservative term's gap and weight in EXPERIMENTS 5.13) reads back
//! exactly what our `EventWriter` wrote, keeps only the asked tags, and survives a file cut in
//! the middle of a record (a run killed while writing).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;

use coadapt_tensorboard::EventWriter;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("the workspace root").to_path_buf()
}

fn read(dir: &Path, tags: &str) -> (bool, String, String) {
    let o = Command::new("python3")
        .arg(root().join("scripts/tb_scalars.py"))
        .arg(dir)
        .arg(tags)
        .output()
        .expect("running python3 scripts/tb_scalars.py");
    (o.status.success(), String::from_utf8_lossy(&o.stdout).into(), String::from_utf8_lossy(&o.stderr).into())
}

#[test]
fn the_script_reads_back_what_the_writer_wrote() {
    let dir = std::env::temp_dir().join(format!("coadapt-tb-scalars-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    let mut w = EventWriter::create(&dir, "coadapt").expect("an event file");
    // Values exact in f32 (TensorBoard's simple_value), so the printed digits are known.
    w.scalars(7, &[("train/conservative_gap", -0.25), ("train/policy_loss", 3.0), ("train/conservative_weight", 1.5)]).expect("scalars");
    w.text("notes", 8, "not a scalar").expect("text");
    w.scalars(300, &[("train/conservative_gap", 12.125), ("eval/return", 150.5)]).expect("scalars");
    w.scalars(301, &[("train/conservative_weight", f64::NAN)]).expect("a skipped NaN");
    w.sync().expect("sync");
    let path = w.path().to_path_buf();
    drop(w);

    let want = "step,tag,value\n\
                7,train/conservative_gap,-0.25\n\
                7,train/conservative_weight,1.5\n\
                300,train/conservative_gap,12.125\n\
                300,eval/return,150.5\n";
    let (ok, out, err) = read(&dir, "conservative,eval/");
    assert!(ok, "the script failed: {err}");
    assert_eq!(out, want);

    // A record cut short at the end (its length says 40 bytes, 5 follow): the whole records
    // before it are read as before, and the cut is reported, not fatal.
    let mut f = std::fs::OpenOptions::new().append(true).open(&path).expect("reopening the file");
    f.write_all(&40u64.to_le_bytes()).and_then(|_| f.write_all(&[1, 2, 3, 4, 5, 6, 7, 8, 9])).expect("appending");
    drop(f);
    let (ok, out, err) = read(&dir, "conservative,eval/");
    assert!(ok, "a cut last record made the script fail: {err}");
    assert_eq!(out, want);
    assert!(err.contains("cut record"), "the cut was not reported: {err}");

    // No event files: a clear refusal.
    let empty = dir.join("empty");
    std::fs::create_dir_all(&empty).expect("empty dir");
    let (ok, _, err) = read(&empty, "x");
    assert!(!ok && err.contains("no event files"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}
