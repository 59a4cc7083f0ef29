//! HalfCheetah in rapier2d: the reference's PyBullet HalfCheetahBulletEnv, with the design scaling
//! the six leg segments.
//!
//! # The body
//! MuJoCo's `half_cheetah.xml` in the plane: a torso capsule 1 m long with a head, and two legs
//! (thigh, shin, foot) hinged at its ends, every capsule of radius 0.046. Each segment is a capsule
//! from its joint to the next one, of length `design[i] x (0.29, 0.3, 0.188)` (back thigh, shin,
//! foot, then the front leg with the same base lengths, as the product brief says; the reference's
//! code keeps MuJoCo's shorter front leg, 0.266, 0.212, 0.14), pointing along MuJoCo's geom axis.
//! Masses are MuJoCo's density (14 kg over the original geoms) times the 3D capsule volume, so
//! longer legs weigh more. Joint ranges, armature and damping are MuJoCo's (the reference's XML
//! narrows a few ranges); MuJoCo's joint springs are left out, so a zero action leaves the legs
//! limp. Parts touch the ground only, not each other; friction 0.4. Torque
//! `0.9 x power x clip(a, -1, 1)` with powers 120/90/60/90/60/30 N m (the reference's front thigh
//! has 90, not MuJoCo's 120). See `body.rs` for the geometry and the sign conventions; the body
//! is built, and the episodes run, by the planar machinery all the planar robots share
//! ([`crate::planar`]).
//!
//! # Episodes
//! `reset` rebuilds the world for the design (about 15 us), puts the torso level above the longest
//! leg with joint angles uniform in +-0.5 rad (clamped to the limits), then settles the body as the
//! reference does: for [`SimConfig::settle_steps`] zero-torque control steps (50, 0.8 s) at a
//! gravity of [`SimConfig::settle_gravity`] (0.5 m/s^2) with every joint held at its drawn angle,
//! after which the joints are freed and full gravity returns. The episode starts with the body on
//! its feet or still a few centimetres above the ground, its joints where they were drawn.
//! (Before issue 28 the joints were limp while the body fell at full gravity for 60 steps: 96 % of
//! starts had a joint folded to its limit and 3-6 % rested on the torso or head, a crouch the
//! reference never starts from; trained policies stalled or flipped from it. EXPERIMENTS 5.12
//! has the measurements; `examples/cheetah_starts.rs` counts them.) A control step is 0.0165 s.
//! The observation is the 17-dim state, then the design: joint angles scaled to [-1, 1] by their
//! limits, joint velocities x 0.1, torso forward velocity, pitch rate, vertical velocity, pitch and
//! height change since the episode started (after settling). Reward `max(vx / 10, 0)`; no terminal
//! state (1000-step episodes are cut by [`coadapt_core::TimeLimit`]).
//!
//! # Simulation setting, from measurements
//! The bar is MuJoCo HalfCheetah-v5 through gymnasium per env step. Those figures (10,300 in
//! `peers.md`, 13,200-13,600 beside ours) timed gymnasium's `action_space.sample()` inside the
//! loop, about 40 us a step; with actions drawn before the loop, as `coadapt bench sim` and
//! `bench/peers/sim_mujoco.py` now do, MuJoCo runs 31,800 env steps/s on the machine where the
//! default setting below runs 18,400-19,600: we are at 0.6x per env step and 0.2x per simulated
//! second (MuJoCo's control step is 0.05 s, ours 0.0165 s). BENCHMARKS.md has the run and what
//! passing MuJoCo would take. The speed column below was timed with per-step random draws on an
//! older, slower machine: compare its rows with each other, not with MuJoCo.
//!
//! `cargo run --release -p coadapt-robots --example cheetah_speed -- --sweep` measures each
//! setting over 10,000 steps of random full-torque actions (each held for 1-20 steps, new episode
//! every 1000) per design: env steps/s (design `[1]*6`; timings on this shared machine vary by
//! +-20 %), the worst joint-limit violation in radians for designs `[0.8]*6` / `[1]*6` / `[2]*6`, and
//! the deepest any part went into the ground over the three designs. "Steps" are physics steps
//! per 0.0165 s control step, "iters" rapier's solver iterations (TGS substeps) per physics step,
//! "MuJoCo joints" MuJoCo's joint armature 0.1 kg m^2 and damping (6, 4.5, 3, 4.5, 3, 1.5 N m s).
//!
//! | joints | steps | iters | MuJoCo joints | env steps/s | worst violation (rad) | in ground (m) |
//! |---|---|---|---|---|---|---|
//! | multibody | 1 | 4 | no | 32,900 | 1.43 / 1.03 / 0.33 | 0.24 |
//! | multibody | 2 | 2 | no | 28,000 | 2.74 / 0.84 / 0.29 | blew up |
//! | multibody | 4 | 1 | no | 20,500 | 1.01 / 0.87 / 0.29 | 0.071 |
//! | multibody | 1 | 2 | yes | 49,800 | 0.24 / 0.22 / 0.16 | 0.126 |
//! | multibody | 1 | 4 | yes | 26,800 | 0.11 / 0.12 / 0.08 | 0.130 |
//! | multibody | 1 | 8 | yes | 17,000 | 0.046 / 0.054 / 0.043 | 0.148 |
//! | multibody | 1 | 12 | yes | 12,900 | 0.026 / 0.031 / 0.021 | 0.138 |
//! | multibody | 2 | 1 | yes | 42,100 | 0.21 / 0.24 / 0.18 | 0.074 |
//! | multibody | 2 | 2 | yes | 27,300 | 0.098 / 0.105 / 0.085 | 0.056 |
//! | **multibody** | **2** | **4** | **yes** | **14,700** | **0.049 / 0.057 / 0.038** | **0.058** |
//! | multibody | 2 | 6 | yes | 11,400 | 0.027 / 0.036 / 0.024 | 0.065 |
//! | multibody | 4 | 1 | yes | 20,200 | 0.11 / 0.11 / 0.08 | 0.054 |
//! | multibody | 4 | 2 | yes | 14,200 | 0.052 / 0.050 / 0.041 | 0.055 |
//! | impulse | 1 | 4 | - | 84,400 | 2.74 / 2.74 / 1.04 | 0.205 |
//! | impulse | 1 | 8 | - | 57,500 | 2.74 / 2.73 / 0.53 | 0.220 |
//! | impulse | 2 | 4 | - | 48,000 | 2.74 / 2.74 / 0.50 | 0.131 |
//! | impulse | 4 | 2 | - | 36,300 | 2.74 / 2.72 / 0.48 | 0.059 |
//! | impulse | 4 | 4 | - | 28,600 | 2.55 / 1.36 / 0.21 | 0.041 |
//! | impulse, warm-started | 4 | 4 | - | 26,700 | 2.62 / 1.31 / 0.20 | 0.056 |
//! | impulse | 8 | 2 | - | 20,900 | 2.57 / 1.24 / 0.22 | 0.013 |
//!
//! What the numbers say. rapier's limit constraints engage only once a joint is past its limit, so
//! the overshoot is the joint speed times a solver substep, and a foot of under 1 kg driven by
//! 54 N m is fast: impulse joints let light limbs swing right through their limits (2.7 rad is a
//! joint gone round the other side), at any affordable step count. Multibody joints alone do
//! little better, and without armature one configuration flung the body away. MuJoCo's own
//! model carries joint armature and damping for exactly this; with them, the overshoot falls with
//! the solver iterations. Two physics steps per control step halve how deep a foot lands in the
//! ground (contacts are found once per physics step) for the same solver work as one step with
//! twice the iterations.
//!
//! Chosen ([`SimConfig::default`]): multibody joints with MuJoCo's armature and damping, 2 physics
//! steps of 8.25 ms with 4 solver iterations each: limits hold to 0.06 rad under this abuse,
//! feet sink at most 6 cm on impact, at about 1.1x MuJoCo's speed measured in the same run
//! (1.45x the figure in `peers.md`). 1 x 8 is as fast with the same limits but lands feet 15 cm
//! deep; 2 x 6 holds limits to 0.036 rad but only matches MuJoCo's speed.

mod body;

pub use crate::planar::{CONTROL_DT, JointKind, SimConfig};
pub use body::{BASE_LENGTHS, JOINT_LIMITS, POWERS, RADIUS, plan, start_height};

use crate::planar::{BodyPlan, PlanarEnv, Robot, Torso};

/// The HalfCheetah environment (see the module documentation).
pub type HalfCheetah = PlanarEnv<Cheetah>;

/// HalfCheetah's [`Robot`] description.
#[derive(Debug)]
pub struct Cheetah;

fn lengths(design: &[f32]) -> [f32; 6] {
    std::array::from_fn(|i| design[i] * BASE_LENGTHS[i])
}

impl Robot for Cheetah {
    const NAME: &'static str = "half-cheetah";
    const JOINT_LIMITS: &'static [[f32; 2]] = &JOINT_LIMITS;
    const POWERS: &'static [f32] = &POWERS;
    const DESIGN_LOW: &'static [f32] = &[0.8; 6];
    const DESIGN_HIGH: &'static [f32] = &[2.0; 6];
    const DEFAULT_DESIGN: &'static [f32] = &[1.0; 6];
    const DESIGN_NAMES: &'static [&'static str] = &["back thigh", "back shin", "back foot", "front thigh", "front shin", "front foot"];

    /// The measured physics setting, and the reference's reset: the joints held at their drawn
    /// angles while the body settles for 50 control steps (0.8 s) at a gravity of 0.5.
    fn default_config() -> SimConfig {
        SimConfig { hold_while_settling: true, settle_steps: 50, settle_gravity: 0.5, ..SimConfig::default() }
    }

    fn plan(design: &[f32]) -> BodyPlan {
        plan(&lengths(design))
    }

    fn start_height(design: &[f32], _plan: &BodyPlan, _angles: &[f32]) -> f32 {
        start_height(&lengths(design))
    }

    /// Forward velocity, pitch rate, vertical velocity, pitch, height change.
    fn torso_state(t: &Torso, height_change: f32) -> [f32; 5] {
        [t.vel[0], t.pitch_rate, t.vel[1], t.pitch, height_change]
    }

    fn reward(t: &Torso) -> f32 {
        (t.vel[0] / 10.0).max(0.0)
    }
}
