//! The bimanual planar reaching benchmark (thesis ch. 2.4.1, Fig. 2.3), and [`PlanarEnv`], the
//! benchmark as a robot an actor steps (policy search's rollouts through a fleet).
//!
//! Two planar arms of six revolute joints on a shared base at the origin; the action of a step is
//! the twelve joint angles (absolute positions, **degrees**: left arm's six then the right
//! arm's), 25 steps. Each end effector follows a goal path that starts on its own side and ends at (0, 4)
//! for both at the last step. Reward Eq. 2.31: `sum_t exp(-|eff_l - goal_l(t)|) + exp(-|eff_r -
//! goal_r(t)|)`; the thesis plots the summed end-effector distance `sum_t |eff_l - goal_l(t)| +
//! |eff_r - goal_r(t)|` (lower is better).
//!
//! **Choices the text leaves open** (fixed here, recorded with every result): unit links; both
//! arms start pointing up (joint angles 0 put each end effector at (0, 6)); a joint angle turns
//! its link and everything after it counter-clockwise; the goal paths run in a straight line at
//! constant speed from (-4, 2) (left) and (4, 2) (right) at step 1 to (0, 4) at step 25.
//!
//! **Degrees**, because of the thesis's exploration variance: every method starts from (PoWER
//! keeps) a variance of 10^1.5 per parameter. In radians that is a standard deviation of 5.6 rad
//! per parameter (about 2.8 rad per joint angle through the normalised features): exploration
//! all round the circle, under which PoWER's mean policy wanders and never improves (measured:
//! 184 -> 231 summed distance after 40 iterations). In degrees it is 5.6 degrees, and PoWER
//! improves steadily (184 -> 91 over the same 40 iterations; `coadapt_policy_search`'s PoWER test).

use coadapt_core::{BoxSpace, Env, EnvError, EnvSpec, Step};

/// The arms' shape: link lengths per arm and the goal paths' ends.
#[derive(Clone, Debug, PartialEq)]
pub struct ArmGeometry {
    pub links: [f64; 6],
    pub left_start: [f64; 2],
    pub right_start: [f64; 2],
    pub goal: [f64; 2],
    pub steps: usize,
    /// Degrees one unit of action turns a joint: 1 (degrees, the default; see the module doc
    /// for why), 180/pi (radians), or any scale between (a probe of the thesis's units).
    pub unit_degrees: f64,
}

impl Default for ArmGeometry {
    fn default() -> Self {
        Self { links: [1.0; 6], left_start: [-4.0, 2.0], right_start: [4.0, 2.0], goal: [0.0, 4.0], steps: 25, unit_degrees: 1.0 }
    }
}

/// The benchmark.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PlanarReaching {
    pub geometry: ArmGeometry,
}

impl PlanarReaching {
    /// The end effector of an arm at joint angles `q` (6 values, degrees).
    pub fn end_effector(&self, q: &[f32]) -> [f64; 2] {
        let (mut x, mut y, mut angle) = (0.0, 0.0, std::f64::consts::FRAC_PI_2);
        for (l, &qi) in self.geometry.links.iter().zip(q) {
            angle += (f64::from(qi) * self.geometry.unit_degrees).to_radians();
            x += l * angle.cos();
            y += l * angle.sin();
        }
        [x, y]
    }

    /// The goals of both arms at step `t` (0-based).
    pub fn goals(&self, t: usize) -> ([f64; 2], [f64; 2]) {
        let g = &self.geometry;
        let s = if g.steps > 1 { t as f64 / (g.steps - 1) as f64 } else { 1.0 };
        let lerp = |a: [f64; 2]| [a[0] + s * (g.goal[0] - a[0]), a[1] + s * (g.goal[1] - a[1])];
        (lerp(g.left_start), lerp(g.right_start))
    }

    /// The distances of both end effectors to their goals at every step of `actions`.
    pub fn distances(&self, actions: &[f32]) -> Vec<(f64, f64)> {
        actions
            .chunks_exact(12)
            .take(self.geometry.steps)
            .enumerate()
            .map(|(t, a)| {
                let (gl, gr) = self.goals(t);
                let (l, r) = (self.end_effector(&a[..6]), self.end_effector(&a[6..]));
                (((l[0] - gl[0]).powi(2) + (l[1] - gl[1]).powi(2)).sqrt(), ((r[0] - gr[0]).powi(2) + (r[1] - gr[1]).powi(2)).sqrt())
            })
            .collect()
    }
}

/// The planar robot's joint-angle limit (action units: degrees by default); beyond it actions
/// are clipped, as every robot clips.
pub const MAX_ANGLE: f32 = 720.0;

/// The planar benchmark as a robot an actor steps: the action is the twelve joint angles
/// (degrees), the observation `[step / steps, distance of the left end effector to its goal,
/// distance of the right one]` after the step, the reward Eq. 2.31's term of the step. No
/// design (its body is fixed). The same kinematics as [`PlanarReaching`], so a rollout's return
/// through a fleet equals its in-process return (up to the f32 rewards).
#[derive(Debug)]
pub struct PlanarEnv {
    task: PlanarReaching,
    spec: EnvSpec,
    t: Option<usize>,
    obs: [f32; 3],
}

impl Default for PlanarEnv {
    fn default() -> Self {
        Self::new(PlanarReaching::default())
    }
}

impl PlanarEnv {
    /// The robot of `task` (its geometry and units).
    pub fn new(task: PlanarReaching) -> Self {
        let steps = task.geometry.steps;
        // Two turns each way: wide enough that the searches never reach it (their angles stay
        // within tens of units), narrow enough that a robot server mapping [-1, 1] onto it
        // (dm_env_rpc's coadapt profile) keeps f32 precision (4e-5 units).
        let action = BoxSpace::new(vec![-MAX_ANGLE; 12], vec![MAX_ANGLE; 12]).unwrap_or_else(|_| unreachable!("a valid box"));
        let design = BoxSpace::new(vec![], vec![]).unwrap_or_else(|_| unreachable!("a valid box"));
        let spec = EnvSpec {
            name: "planar".into(),
            state_dim: 3,
            action,
            design,
            design_names: vec![],
            default_design: vec![],
            max_episode_steps: steps,
        };
        Self { task, spec, t: None, obs: [0.0; 3] }
    }

    /// Each step's cost from its observation: the summed end-effector distance.
    pub fn step_cost(obs: &[f32]) -> f64 {
        obs.get(1..3).map_or(f64::NAN, |d| f64::from(d[0]) + f64::from(d[1]))
    }
}

impl Env for PlanarEnv {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn reset(&mut self, _seed: u64, design: &[f32]) -> Result<&[f32], EnvError> {
        self.spec.design.check("design", design).map_err(EnvError::Design)?;
        // Before the first step: both arms straight up, measured against the first goals.
        let d = self.task.distances(&[0.0; 12]);
        self.obs = [0.0, d[0].0 as f32, d[0].1 as f32];
        self.t = Some(0);
        Ok(&self.obs)
    }

    fn step(&mut self, action: &[f32]) -> Result<Step<'_>, EnvError> {
        let t = self.t.ok_or(EnvError::NotRunning)?;
        if action.len() != 12 {
            return Err(EnvError::Action(coadapt_core::SpaceError::Dim { what: "action", expected: 12, got: action.len() }));
        }
        if let Some(index) = action.iter().position(|a| !a.is_finite()) {
            return Err(EnvError::Action(coadapt_core::SpaceError::NonFinite { what: "action", index, value: action[index] }));
        }
        let mut a = [0.0f32; 12];
        a.iter_mut().zip(action).for_each(|(c, v)| *c = v.clamp(-MAX_ANGLE, MAX_ANGLE));
        let action = &a;
        let steps = self.task.geometry.steps;
        let (gl, gr) = self.task.goals(t);
        let (l, r) = (self.task.end_effector(&action[..6]), self.task.end_effector(&action[6..12]));
        let dl = ((l[0] - gl[0]).powi(2) + (l[1] - gl[1]).powi(2)).sqrt();
        let dr = ((r[0] - gr[0]).powi(2) + (r[1] - gr[1]).powi(2)).sqrt();
        self.obs = [(t + 1) as f32 / steps as f32, dl as f32, dr as f32];
        let done = t + 1 >= steps;
        self.t = if done { None } else { Some(t + 1) };
        Ok(Step { observation: &self.obs, reward: ((-dl).exp() + (-dr).exp()) as f32, terminated: false, truncated: done })
    }
}
