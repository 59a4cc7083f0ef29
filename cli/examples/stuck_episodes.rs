//! Where does the HalfCheetah stop? (issue 28, section 4.) Plays a trained policy on many start
//! states and records every episode whose return stays under a threshold: per step the torso
//! (height, pitch, velocities), each joint's angle against its limits, the actions, and the
//! height of each capsule's lowest point (which parts rest on the ground). Prints, for the stuck
//! episodes and for the others, how their last 500 steps look, so the two can be told apart.
//!
//! ```sh
//! cargo run --release -p coadapt --example stuck_episodes -- \
//!     --weights runs/stuck/sac-seed5/checkpoint.safetensors --episodes 200 [--stochastic] \
//!     [--threshold 5] [--design 1,1,1,1,1,1] [--out runs/stuck/episodes] [--limp-reset]
//! ```
//! Writes `OUT/seed-S.csv` for each stuck episode (and `OUT/seed-S.csv` for the first two that
//! are not, as a contrast) and one summary line per episode class to stdout.

use std::io::Write;
use std::path::PathBuf;

use anyhow::{Context, bail};
use coadapt_core::Env;
use coadapt_learner::render::Policy;
use coadapt_robots::half_cheetah::{HalfCheetah, JOINT_LIMITS, SimConfig};
use rand_distr::{Distribution, StandardNormal};

const PARTS: [&str; 8] = ["torso", "head", "bthigh", "bshin", "bfoot", "fthigh", "fshin", "ffoot"];

struct Args {
    weights: PathBuf,
    episodes: u64,
    stochastic: bool,
    threshold: f32,
    design: Vec<f32>,
    out: PathBuf,
    limp: bool,
}

fn args() -> anyhow::Result<Args> {
    let mut a = Args {
        weights: PathBuf::new(),
        episodes: 100,
        stochastic: false,
        threshold: 5.0,
        design: vec![1.0; 6],
        out: PathBuf::from("runs/stuck/episodes"),
        limp: false,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().with_context(|| format!("{flag} needs a value"));
        match flag.as_str() {
            "--weights" => a.weights = value()?.into(),
            "--episodes" => a.episodes = value()?.parse().context("--episodes")?,
            "--stochastic" => a.stochastic = true,
            "--threshold" => a.threshold = value()?.parse().context("--threshold")?,
            "--design" => a.design = value()?.split(',').map(str::parse).collect::<Result<_, _>>().context("--design")?,
            "--out" => a.out = value()?.into(),
            // The reset before issue 28: joints limp while the body falls at full gravity.
            "--limp-reset" => a.limp = true,
            _ => bail!("unknown argument {flag}"),
        }
    }
    if a.weights.as_os_str().is_empty() {
        bail!("--weights CHECKPOINT is required");
    }
    Ok(a)
}

/// What the last steps of an episode looked like.
#[derive(Default)]
struct Tally {
    episodes: usize,
    steps: usize,
    vx: f64,
    height: f64,
    pitch: f64,
    upside_down: usize,
    touching: [usize; 8],
    at_limit: [usize; 6],
    saturated: [usize; 6],
    abs_action: f64,
}

impl Tally {
    fn line(&self, name: &str) -> String {
        let n = self.steps.max(1) as f64;
        let pct = |c: usize| format!("{:.0}", 100.0 * c as f64 / n);
        let parts: Vec<String> = PARTS.iter().zip(self.touching).map(|(p, c)| format!("{p} {}", pct(c))).collect();
        let limits: Vec<String> = (0..6).map(|j| format!("{} {}", PARTS[j + 2], pct(self.at_limit[j]))).collect();
        let sat: Vec<String> = (0..6).map(|j| format!("{} {}", PARTS[j + 2], pct(self.saturated[j]))).collect();
        format!(
            "{name}: {} episodes; last 500 steps: vx {:.3} m/s, torso height {:.3} m, |pitch| {:.2} rad, upside down {}% | \
             touching ground (% of steps): {} | joint within 0.02 rad of a limit: {} | |action| > 0.95: {} | mean |action| {:.2}",
            self.episodes,
            self.vx / n,
            self.height / n,
            self.pitch / n,
            pct(self.upside_down),
            parts.join(", "),
            limits.join(", "),
            sat.join(", "),
            self.abs_action / (6.0 * n),
        )
    }
}

fn main() -> anyhow::Result<()> {
    let a = args()?;
    let mut env = if a.limp {
        HalfCheetah::with_config(SimConfig { hold_while_settling: false, settle_steps: 60, settle_gravity: 9.81, ..SimConfig::default() })
    } else {
        HalfCheetah::new()
    };
    let spec = env.spec().clone();
    let mut policy = Policy::load(&a.weights, spec.obs_dim(), spec.act_dim())?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let (mut stuck, mut moving) = (Tally::default(), Tally::default());
    let mut contrast = 0;
    let mut heights = Vec::new();
    let mut returns = Vec::new();
    for seed in 0..a.episodes {
        let mut obs = env.reset(seed, &a.design)?.to_vec();
        let mut rng = coadapt_core::rng(seed, 11);
        let (mut action, mut eps) = (vec![0.0f32; 6], vec![0.0f32; 6]);
        let mut rows = Vec::with_capacity(1000);
        let mut ret = 0.0f32;
        for t in 0..1000 {
            if a.stochastic {
                eps.iter_mut().for_each(|e| *e = StandardNormal.sample(&mut rng));
                policy.sample(&obs, &eps, &mut action);
            } else {
                policy.act(&obs, &mut action);
            }
            let s = env.step(&action)?;
            let (reward, done) = (s.reward, s.truncated || s.terminated);
            obs.copy_from_slice(s.observation);
            ret += reward;
            let torso = env.torso().context("no body")?;
            let q = env.joint_angles().context("no body")?;
            env.part_heights(&mut heights);
            rows.push((t, torso, q, action.clone(), heights.clone(), reward));
            if done {
                break;
            }
        }
        returns.push(ret);
        let is_stuck = ret < a.threshold;
        let tally = if is_stuck { &mut stuck } else { &mut moving };
        tally.episodes += 1;
        for (_, torso, q, act, h, _) in rows.iter().skip(rows.len().saturating_sub(500)) {
            tally.steps += 1;
            tally.vx += torso.vel[0] as f64;
            tally.height += torso.pos[1] as f64;
            tally.pitch += torso.pitch.abs() as f64;
            tally.upside_down += usize::from(torso.pitch.abs() > std::f32::consts::FRAC_PI_2);
            for (i, y) in h.iter().enumerate() {
                tally.touching[i] += usize::from(*y < 0.005);
            }
            for j in 0..6 {
                let [lo, hi] = JOINT_LIMITS[j];
                tally.at_limit[j] += usize::from(q[j] < lo + 0.02 || q[j] > hi - 0.02);
                tally.saturated[j] += usize::from(act[j].abs() > 0.95);
                tally.abs_action += act[j].abs() as f64;
            }
        }
        if is_stuck || contrast < 2 {
            if !is_stuck {
                contrast += 1;
            }
            let path = a.out.join(format!("seed-{seed}.csv"));
            let mut f = std::io::BufWriter::new(std::fs::File::create(&path).with_context(|| format!("creating {}", path.display()))?);
            write!(f, "t,x,z,pitch,vx,vz,pitch_rate,reward")?;
            for p in &PARTS[2..] {
                write!(f, ",q_{p}")?;
            }
            for p in &PARTS[2..] {
                write!(f, ",a_{p}")?;
            }
            for p in &PARTS {
                write!(f, ",low_{p}")?;
            }
            writeln!(f)?;
            for (t, torso, q, act, h, r) in &rows {
                write!(
                    f,
                    "{t},{},{},{},{},{},{},{r}",
                    torso.pos[0], torso.pos[1], torso.pitch, torso.vel[0], torso.vel[1], torso.pitch_rate
                )?;
                for v in q.iter().chain(act).chain(h) {
                    write!(f, ",{v}")?;
                }
                writeln!(f)?;
            }
            f.flush()?;
            eprintln!("seed {seed}: return {ret:.2}{} -> {}", if is_stuck { " (stuck)" } else { "" }, path.display());
        }
    }
    let mean = returns.iter().sum::<f32>() / returns.len().max(1) as f32;
    println!(
        "{} episodes ({}), mean return {mean:.1}, {} under {}",
        a.episodes,
        if a.stochastic { "stochastic" } else { "deterministic" },
        stuck.episodes,
        a.threshold
    );
    println!("{}", stuck.line("stuck"));
    println!("{}", moving.line("moving"));
    Ok(())
}
