//! `scripts/campaign.sh` with the real binary on the tiny protocol (tests/tests/campaign_script.rs
//! drives it with a fake): a run of the conservative design head is archived with its term's
//! scalars (`conservative.csv`, from TensorBoard); then, its run directory gone as on a new
//! machine, a fork of it has the source's first designs run again, matched row for row against
//! the archive, forked and continued to the archived schedule. This keeps the script and the
//! binary's command line (`--designs`, `--resume`, the summary) in step.

use std::path::{Path, PathBuf};
use std::process::Command;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("the workspace root").to_path_buf()
}

fn campaign(root: &Path, queue: &str) -> String {
    let o = Command::new("bash")
        .arg(root.join("scripts/campaign.sh"))
        .args(["-j", "1", queue])
        .current_dir(root)
        .env("BIN", env!("CARGO_BIN_EXE_coadapt"))
        .output()
        .expect("running campaign.sh");
    let text = format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success(), "campaign.sh {queue} failed:\n{text}");
    text
}

fn rows(path: &Path) -> Vec<String> {
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())).lines().map(String::from).collect()
}

#[test]
fn a_real_run_is_archived_with_its_scalars_and_forked_after_its_directory_is_gone() {
    let base = std::env::temp_dir().join(format!("coadapt-campaign-e2e-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&base);
    let root = base.join("checkout");
    std::fs::create_dir_all(root.join("scripts")).expect("temp tree");
    std::fs::create_dir_all(root.join("configs")).expect("temp tree");
    for s in ["campaign.sh", "campaign_lines.sh", "fork_run.sh", "config_with.py", "tb_scalars.py"] {
        std::fs::copy(repo().join("scripts").join(s), root.join("scripts").join(s)).expect("copying the scripts");
    }
    std::fs::copy(repo().join("configs/half-cheetah-tiny.toml"), root.join("configs/half-cheetah-tiny.toml")).expect("the tiny config");
    let head = "configs/half-cheetah-tiny.toml+learner.population-critics=3+learner.conservative.weight=1.0+optimizer.q=\"heads\"";
    std::fs::write(root.join("a.queue"), format!("head {head} 1\n")).expect("queue");
    campaign(&root, "a.queue");
    let arch = root.join("docs/campaign/results/head-seed1");
    let scalars = rows(&arch.join("conservative.csv"));
    assert_eq!(scalars[0], "step,tag,value");
    assert!(scalars.iter().any(|l| l.contains(",train/conservative_weight,")), "{scalars:?}");
    assert!(scalars.iter().any(|l| l.contains(",train/conservative_gap,")), "{scalars:?}");

    // A new machine: the run directory is gone, the archive is there. The fork at the first
    // chosen design (2, after the tiny protocol's two initial designs) needs the source's
    // snapshot there: the campaign runs designs 0-1 again and checks them.
    std::fs::remove_dir_all(root.join("runs/campaign/head-seed1")).expect("removing the run directory");
    std::fs::write(root.join("b.queue"), "fork fork:head:2+optimizer.exploit=\"random\" 1\n").expect("queue");
    let out = campaign(&root, "b.queue");
    assert!(out.contains("its first 2 designs again, row for row the archived ones"), "{out}");
    let fork = rows(&root.join("docs/campaign/results/fork-seed1/designs.csv"));
    let source = rows(&arch.join("designs.csv"));
    assert_eq!(fork.len(), source.len(), "the fork did not run the archived schedule:\n{fork:?}");
    // The initial designs are the archived ones to the digit (columns up to the returns); the
    // chosen ones differ (random, not the head's choice).
    let cut = |l: &String| l.split(',').take(6).collect::<Vec<_>>().join(",");
    assert_eq!(fork[..3].iter().map(cut).collect::<Vec<_>>(), source[..3].iter().map(cut).collect::<Vec<_>>());
    let method = |l: &String| l.split(',').nth(8).unwrap_or_default().to_string();
    assert_eq!((method(&source[3]), method(&fork[3])), ("pso-q".to_string(), "random".to_string()), "design 2's method");
    let _ = std::fs::remove_dir_all(&base);
}
