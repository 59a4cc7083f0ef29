//! `--friction`, `--actuator-scale`, `--torso-mass-scale`: a `[world]` (thesis 6.1's dynamics)
//! from the command line, for the commands that build a robot (`run`, `train`, `render`).

use clap::Args;
use coadapt_robots::World;

/// Each flag, when given, replaces that key of the world the command would otherwise build (the
/// config file's `[world]`, or the robot's own). Values are checked where the robot is built, so a
/// bad one is the robot crate's error naming `world.<key>`.
#[derive(Debug, Default, Args)]
pub struct WorldArgs {
    /// Friction of the ground and of every part of the robot (world.friction; default the
    /// robot's own: half-cheetah 0.4, walker 0.9, hopper 1.0, daisy 0.8).
    #[arg(long, value_name = "F", allow_negative_numbers = true)]
    pub friction: Option<f32>,
    /// Every joint's torque at full action, times this (world.actuator-scale; default 1).
    #[arg(long, value_name = "X", allow_negative_numbers = true)]
    pub actuator_scale: Option<f32>,
    /// The torso's mass, times this (world.torso-mass-scale; default 1).
    #[arg(long, value_name = "X", allow_negative_numbers = true)]
    pub torso_mass_scale: Option<f32>,
}

impl WorldArgs {
    /// `world` with the flags given laid over it.
    pub fn apply(&self, world: &mut World) {
        if let Some(f) = self.friction {
            world.friction = Some(f);
        }
        if let Some(x) = self.actuator_scale {
            world.actuator_scale = x;
        }
        if let Some(x) = self.torso_mass_scale {
            world.torso_mass_scale = x;
        }
    }
}
