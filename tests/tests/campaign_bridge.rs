//! The MuJoCo bridge moved from 127.0.0.1:50061 (the port `coadapt serve` and a run's design
//! service take by default: serving a MuJoCo run's designs beside its bridge failed with
//! "address already in use") to 127.0.0.1:50071. The runs archived before name the old address;
//! what `scripts/campaign.sh` runs again from them (a fork's prefix, the forks, the bodies
//! retrained) talks to the bridge where it is now, and the archive stays as it ran.

use crate::campaign_tree;

use campaign_tree::*;
use std::process::Command;

const OLD: &str = "dm-env-rpc://127.0.0.1:50061";

#[test]
fn runs_from_a_config_archived_before_the_bridge_moved_talk_to_the_bridge_where_it_is() {
    let t = Tree::new("bridge");
    t.archive_source(3);
    let arch = t.path("docs/campaign/results/src-seed1");
    let config = format!("env = \"{OLD}\"\n\n[schedule]\ndesigns = 3\n");
    std::fs::write(arch.join("config.toml"), &config).expect("the archived config");
    let designs = "index,kind,design,best_eval_return\n0,initial,1;1,5\n1,exploit,1.5;1,9\n2,explore,0.9;1.2,7\n";
    std::fs::write(arch.join("designs.csv"), designs).expect("the archived designs");
    std::fs::write(t.path("q.queue"), "frk fork:src:2 1\nbody retrain:src:exploit 1\n").expect("queue");

    // mujoco_lane.sh names the bridge it started (MUJOCO_BRIDGE) for the queue it runs.
    let done = t.campaign(&["-j", "1", "q.queue"]).env("MUJOCO_BRIDGE", "127.0.0.1:59999").output().expect("campaign.sh");
    let log = text(&done);
    assert!(done.status.success(), "{log}");
    assert!(log.contains("row for row the archived ones"), "{log}");
    let now = "dm-env-rpc://127.0.0.1:59999";
    for f in [
        "runs/campaign/configs/src-seed1.prefix.toml",              // the prefix's --config
        "runs/campaign/src-seed1/config.toml",                      // the source the forks copy
        "runs/campaign/frk-seed1/config.toml",                      // a fork, resumed from its own config
        "docs/campaign/results/frk-seed1/config.toml",              // and archived as it ran
        "docs/campaign/results/body-seed1/train-seed1/config.toml", // a body retrained: `train --env`
        "docs/campaign/results/body-seed1/train-seed2/config.toml",
    ] {
        let c = std::fs::read_to_string(t.path(f)).unwrap_or_else(|e| panic!("{f}: {e}\n{log}"));
        assert!(c.contains(now) && !c.contains(OLD), "{f} talks to the bridge's old address:\n{c}\n{log}");
    }
    // The fork keeps the rest of the archived config, and the archive what ran.
    let fork = std::fs::read_to_string(t.path("runs/campaign/frk-seed1/config.toml")).expect("the fork's config");
    assert!(fork.contains("designs = 3"), "{fork}");
    assert_eq!(std::fs::read_to_string(arch.join("config.toml")).expect("the archived config"), config);
    let body = std::fs::read_to_string(t.path("docs/campaign/results/body-seed1/summary.json")).expect("the body's summary");
    assert!(body.contains("[1.5, 1.0]"), "not the exploitation design: {body}");

    // Without MUJOCO_BRIDGE (a queue run by hand, the bridge started as the README says): 50071.
    // Another env is left alone.
    let here = |env: &str| {
        let o = Command::new("bash")
            .args(["-c", "source scripts/campaign_lines.sh && bridge_here \"$1\"", "-", env])
            .current_dir(&t.root)
            .env_remove("MUJOCO_BRIDGE")
            .output()
            .expect("bridge_here");
        assert!(o.status.success(), "{}", text(&o));
        String::from_utf8_lossy(&o.stdout).trim().to_string()
    };
    assert_eq!(here(OLD), "dm-env-rpc://127.0.0.1:50071");
    assert_eq!(here("dm-env-rpc://10.0.0.7:50061"), "dm-env-rpc://10.0.0.7:50061");
    assert_eq!(here("half-cheetah"), "half-cheetah");
    let _ = std::fs::remove_dir_all(t.root.parent().expect("base"));
}

/// `campaign_status.py` sizes a MuJoCo line by its robot's pace, looked up by the config's env:
/// the archived MuJoCo runs (the old address) are the same robot as the queue's config (the new).
#[test]
fn the_robots_pace_is_found_across_the_bridges_move() {
    let t = Tree::new("bridge-pace");
    // One episode a minute: the queue's 5 episodes (cfg.toml's schedule) are 300 s.
    let m: Vec<(u32, u32, f64)> = (0..10).map(|i| (0, i, 60.0 * f64::from(i + 1))).collect();
    t.archive_paced("m-fear-seed1", &m, 600.0);
    std::fs::write(t.path("docs/campaign/results/m-fear-seed1/config.toml"), format!("env = \"{OLD}\"\n")).expect("config");
    let cfg = std::fs::read_to_string(t.path("cfg.toml")).expect("cfg.toml");
    std::fs::write(t.path("m.toml"), format!("env = \"dm-env-rpc://127.0.0.1:50071\"\n{cfg}")).expect("m.toml");
    std::fs::write(t.path("q.queue"), "m-other m.toml 2\n").expect("queue");
    let o = Command::new("python3")
        .args(["scripts/campaign_status.py", "q.queue", "--seconds", "m-other", "2"])
        .current_dir(&t.root)
        .env_remove("MUJOCO_BRIDGE")
        .output()
        .expect("campaign_status.py --seconds");
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(String::from_utf8_lossy(&o.stdout).trim(), "300", "{}", text(&o));
    let _ = std::fs::remove_dir_all(t.root.parent().expect("base"));
}
