//! Two processes writing `logln!` lines to one stderr (a fleet's roles share the supervisor's)
//! never cut into each other's lines.

use std::process::{Command, Stdio};

const LINES: usize = 3000;

/// The writer: this test binary started again with `COADAPT_LOG_WRITER` set to its id.
#[test]
fn writer() {
    let Ok(id) = std::env::var("COADAPT_LOG_WRITER") else { return };
    for i in 0..LINES {
        // Many formatted pieces: one `write` each when stderr is written piece by piece.
        coadapt_log::logln!("w{id} {i} {} {} {} {} {} {} end", "a", 1, "b", 2.5, "c", id);
    }
}

#[test]
fn lines_from_two_processes_sharing_stderr_stay_whole() {
    if std::env::var("COADAPT_LOG_WRITER").is_ok() {
        return;
    }
    let dir = std::env::temp_dir().join(format!("coadapt-log-whole-lines-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a temp dir");
    let path = dir.join("stderr.txt");
    // One open file shared by both, as a pipe or a log file is shared by a fleet's processes.
    let file = std::fs::OpenOptions::new().create(true).truncate(true).write(true).open(&path).expect("the shared stderr");
    let exe = std::env::current_exe().expect("this test binary");
    let children: Vec<_> = ["0", "1"]
        .iter()
        .map(|id| {
            Command::new(&exe)
                .args(["--exact", "writer", "--nocapture", "--test-threads", "1"])
                .env("COADAPT_LOG_WRITER", id)
                .stdout(Stdio::null())
                .stderr(file.try_clone().expect("a second handle"))
                .spawn()
                .expect("a writer")
        })
        .collect();
    for mut c in children {
        assert!(c.wait().expect("a writer's end").success());
    }
    let text = std::fs::read_to_string(&path).expect("the shared stderr");
    let mut seen = [0usize; 2];
    for line in text.lines().filter(|l| l.starts_with('w') || l.contains(" end")) {
        let id: usize = line[1..2].parse().unwrap_or(9);
        let whole = id < 2 && line.ends_with(&format!("a 1 b 2.5 c {id} end")) && line.matches(" end").count() == 1;
        assert!(whole, "a line cut by another process's: {line:?}");
        seen[id] += 1;
    }
    assert_eq!(seen, [LINES, LINES], "lines lost");
    let _ = std::fs::remove_dir_all(&dir);
}
