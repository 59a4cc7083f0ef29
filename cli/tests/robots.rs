//! Every robot trains for a few episodes and renders, through the `coadapt` binary.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::process::Command;

fn coadapt(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_coadapt")).args(args).output().expect("coadapt runs")
}

#[test]
fn every_robot_trains_a_few_episodes_and_renders() {
    let dir = std::env::temp_dir().join(format!("coadapt-robots-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for name in coadapt_robots::ENV_NAMES {
        let env = coadapt_robots::make(name).unwrap();
        let len = env.spec().max_episode_steps;
        let steps = (2 * len).to_string();
        let out = dir.join(name);
        let o = coadapt(&[
            "train",
            "--env",
            name,
            "--steps",
            &steps,
            "--hidden",
            "32,32",
            "--learning-starts",
            "200",
            "--quiet",
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{name}: {}", String::from_utf8_lossy(&o.stderr));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(v["episodes"], 2, "{name}");
        assert!(v["mean_return_last_10"].as_f64().unwrap().is_finite(), "{name}");

        let gif = dir.join(format!("{name}.gif"));
        let ckpt = out.join("checkpoint.safetensors");
        let o = coadapt(&["render", "--env", name, "--weights", ckpt.to_str().unwrap(), "--steps", "40", "--out", gif.to_str().unwrap()]);
        assert!(o.status.success(), "{name}: {}", String::from_utf8_lossy(&o.stderr));
        let bytes = std::fs::read(&gif).unwrap();
        assert!(bytes.starts_with(b"GIF89a"), "{name}: not a GIF");
        // 20 frames of the body: the file holds more than a header and a palette.
        assert!(bytes.len() > 2000, "{name}: {} bytes", bytes.len());
    }
}

#[test]
fn render_refuses_bad_input_clearly() {
    let dir = std::env::temp_dir().join(format!("coadapt-render-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let gif = dir.join("x.gif");
    let cases: &[(&[&str], &str)] = &[
        (&["render", "--env", "nope", "--out", gif.to_str().unwrap()], "unknown environment"),
        (&["render", "--env", "half-cheetah", "--design", "3,3,3,3,3,3", "--out", gif.to_str().unwrap()], "design[0] = 3"),
        (
            &["render", "--env", "pendulum", "--weights", "/nonexistent.safetensors", "--out", gif.to_str().unwrap()],
            "cannot read weights file",
        ),
        (&["render", "--env", "pendulum", "--every", "0", "--out", gif.to_str().unwrap()], "--every"),
        (&["render", "--env", "half-cheetah", "--friction", "-1", "--out", gif.to_str().unwrap()], "world.friction: -1"),
        (&["render", "--env", "pendulum", "--friction", "0.5", "--out", gif.to_str().unwrap()], "world.friction: pendulum has no"),
    ];
    for (args, needle) in cases {
        let o = coadapt(args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?}");
        assert!(err.contains(needle), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
}

/// `render --friction` (thesis 6.1's worlds): the same random actions from the same start meet
/// another ground, and the robot's own friction is the default world.
#[test]
fn render_puts_the_robot_in_the_world_asked_for() {
    let dir = std::env::temp_dir().join(format!("coadapt-render-world-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let gif = dir.join("x.gif");
    let ret = |extra: &[&str]| -> String {
        let mut args = vec!["render", "--env", "half-cheetah", "--random", "--seed", "3", "--steps", "200", "--every", "50"];
        args.extend_from_slice(extra);
        args.extend_from_slice(&["--out", gif.to_str().unwrap()]);
        let o = coadapt(&args);
        let err = String::from_utf8_lossy(&o.stderr).to_string();
        assert!(o.status.success(), "{args:?}: {err}");
        err.rsplit_once("return ").map(|(_, r)| r.trim().trim_end_matches(')').to_string()).unwrap_or_else(|| panic!("no return in {err}"))
    };
    let own = ret(&[]);
    assert_eq!(ret(&["--friction", "0.4"]), own, "half-cheetah's own friction is 0.4");
    assert_ne!(ret(&["--friction", "0.05"]), own, "an icy floor changes the episode");
    assert_ne!(ret(&["--actuator-scale", "0.5"]), own, "weaker motors change the episode");
}

/// `train --friction` and the config's `[world]`: plain RL in another world (thesis 6.1). The
/// same seed's random-action episodes meet another ground, the robot's own friction is the
/// default, the resolved config.toml records the world, and a world the robot cannot have is
/// refused before a run directory exists.
#[test]
fn train_puts_the_robot_in_the_world_asked_for() {
    let dir = std::env::temp_dir().join(format!("coadapt-train-world-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let train = |name: &str, extra: &[&str]| -> (f64, String, Option<serde_json::Value>) {
        let out = dir.join(name);
        let mut args = vec![
            "train",
            "--env",
            "half-cheetah",
            "--steps",
            "1000",
            "--learning-starts",
            "1000",
            "--hidden",
            "8,8",
            "--seed",
            "5",
            "--quiet",
        ];
        args.extend_from_slice(extra);
        args.extend_from_slice(&["--out", out.to_str().unwrap()]);
        let o = coadapt(&args);
        assert!(o.status.success(), "{args:?}: {}", String::from_utf8_lossy(&o.stderr));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        let world = v.get("world").cloned();
        (v["mean_return_last_10"].as_f64().unwrap(), std::fs::read_to_string(out.join("config.toml")).unwrap(), world)
    };
    let (own, own_cfg, own_world) = train("own", &[]);
    assert_eq!(own_world, None, "the robot's own world is left out of the summary");
    assert!(!own_cfg.contains("friction"), "the default world leaves friction unset:\n{own_cfg}");
    let (same, ..) = train("own-explicit", &["--friction", "0.4"]);
    assert_eq!(same, own, "half-cheetah's own friction is 0.4");
    let (icy, icy_cfg, icy_summary) = train("icy", &["--friction", "0.05", "--actuator-scale", "0.5"]);
    let icy_summary = icy_summary.unwrap();
    assert_eq!(icy_summary["actuator-scale"], 0.5, "the summary names the world: {icy_summary}");
    assert!((icy_summary["friction"].as_f64().unwrap() - 0.05).abs() < 1e-6, "{icy_summary}");
    assert_ne!(icy, own, "an icy floor and weak motors change the episode");
    let world: toml::Table = toml::from_str::<toml::Table>(&icy_cfg).unwrap()["world"].as_table().unwrap().clone();
    assert_eq!(world["friction"].as_float(), Some(0.05), "{icy_cfg}");
    assert_eq!(world["actuator-scale"].as_float(), Some(0.5), "{icy_cfg}");

    // The resolved config is a valid config: it trains in the same world again.
    let cfg_path = dir.join("icy").join("config.toml");
    let (again, ..) = train("icy-again", &["--config", cfg_path.to_str().unwrap()]);
    assert_eq!(again, icy, "the config's [world] is the world trained in");

    let refused = dir.join("refused");
    let o = coadapt(&["train", "--env", "pendulum", "--friction", "0.5", "--steps", "10", "--out", refused.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("world.friction: pendulum has no"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(!refused.exists(), "a refused command leaves no run directory");
}
