//! The world a robot lives in, apart from its body: the ground's friction, the actuators'
//! strength, the torso's mass. Each defaults to the robot's own value, so a run without `[world]`
//! steps the robot as it always was; a transfer experiment (thesis section 6.1) changes them to
//! make a second world with the same states, actions and designs but other dynamics.

use serde::{Deserialize, Serialize};

/// `[world]`: the dynamics a robot's body meets (see the module doc).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct World {
    /// Friction coefficient of the ground and of every part of the robot (rapier combines two
    /// touching colliders' coefficients by their average, so ground and feet change together).
    /// Unset: the robot's own (half-cheetah 0.4, walker 0.9, hopper 1.0, daisy 0.8, as in the
    /// MuJoCo models they follow).
    pub friction: Option<f32>,
    /// Every joint's torque at full action, times this (a weaker or stronger motor); 1 is the
    /// robot's.
    pub actuator_scale: f32,
    /// The torso's mass, times this (a payload); 1 is the robot's.
    pub torso_mass_scale: f32,
}

impl Default for World {
    fn default() -> Self {
        Self { friction: None, actuator_scale: 1.0, torso_mass_scale: 1.0 }
    }
}

/// Why a `[world]` cannot be built.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum WorldError {
    /// A value out of its range; `key` as a config file spells it.
    #[error("world.{key}: {value} is not {want}")]
    Value { key: &'static str, value: f32, want: &'static str },
    /// The robot has nothing the key could change (a pendulum has no ground).
    #[error("world.{key}: {robot} has no {what} to change (leave it unset)")]
    Unsupported { key: &'static str, robot: &'static str, what: &'static str },
}

impl World {
    /// Whether every value is the robot's own.
    pub fn is_default(&self) -> bool {
        *self == Self::default()
    }

    /// Refuses values no robot can have: a friction below 0, a scale not above 0, anything not
    /// finite.
    pub fn check(&self) -> Result<(), WorldError> {
        if let Some(f) = self.friction
            && !(f.is_finite() && f >= 0.0)
        {
            return Err(WorldError::Value { key: "friction", value: f, want: "a finite number >= 0" });
        }
        for (key, value) in [("actuator-scale", self.actuator_scale), ("torso-mass-scale", self.torso_mass_scale)] {
            if !(value.is_finite() && value > 0.0) {
                return Err(WorldError::Value { key, value, want: "a finite number > 0" });
            }
        }
        Ok(())
    }

    /// Refuses any value but the defaults, for robot `robot` that has no ground, motors or
    /// torso to change.
    pub fn check_unchanged(&self, robot: &'static str) -> Result<(), WorldError> {
        let d = Self::default();
        if self.friction.is_some() {
            return Err(WorldError::Unsupported { key: "friction", robot, what: "ground" });
        }
        if self.actuator_scale != d.actuator_scale {
            return Err(WorldError::Unsupported { key: "actuator-scale", robot, what: "modelled actuators" });
        }
        if self.torso_mass_scale != d.torso_mass_scale {
            return Err(WorldError::Unsupported { key: "torso-mass-scale", robot, what: "torso" });
        }
        Ok(())
    }

    /// The friction to use where the robot's own is `own`.
    pub fn friction_or(&self, own: f32) -> f32 {
        self.friction.unwrap_or(own)
    }

    /// The world a served robot's CreateWorld settings describe ([`World::settings`] read
    /// back), refusing a name it does not know and values no robot can have.
    pub fn from_settings(settings: &[(String, f32)]) -> Result<Self, String> {
        let mut w = Self::default();
        for (name, v) in settings {
            match name.as_str() {
                "friction" => w.friction = Some(*v),
                "actuator-scale" => w.actuator_scale = *v,
                "torso-mass-scale" => w.torso_mass_scale = *v,
                other => {
                    return Err(format!(
                        "unknown world setting `{other}` (this robot's worlds take `design`, `seed`, `friction`, `actuator-scale` and `torso-mass-scale`)"
                    ));
                }
            }
        }
        w.check().map_err(|e| e.to_string())?;
        Ok(w)
    }

    /// The values that differ from the robot's own, named as in a config file: what a robot
    /// served over dm_env_rpc receives as CreateWorld settings.
    pub fn settings(&self) -> Vec<(&'static str, f32)> {
        let d = Self::default();
        let mut out = Vec::new();
        if let Some(f) = self.friction {
            out.push(("friction", f));
        }
        if self.actuator_scale != d.actuator_scale {
            out.push(("actuator-scale", self.actuator_scale));
        }
        if self.torso_mass_scale != d.torso_mass_scale {
            out.push(("torso-mass-scale", self.torso_mass_scale));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_the_robots_own_and_bad_values_are_named() {
        let w: World = toml::from_str("").unwrap();
        assert!(w.is_default() && w.check().is_ok() && w.settings().is_empty());
        assert_eq!(w.friction_or(0.4), 0.4);
        let w: World = toml::from_str("friction = 1.2\nactuator-scale = 0.5").unwrap();
        assert_eq!(w.friction_or(0.4), 1.2);
        assert_eq!(w.settings(), vec![("friction", 1.2), ("actuator-scale", 0.5)]);
        let bad = World { friction: Some(-0.1), ..World::default() };
        assert_eq!(bad.check().unwrap_err().to_string(), "world.friction: -0.1 is not a finite number >= 0");
        let bad = World { torso_mass_scale: 0.0, ..World::default() };
        assert!(bad.check().unwrap_err().to_string().starts_with("world.torso-mass-scale: 0 is not"));
        let e = World { friction: Some(1.0), ..World::default() }.check_unchanged("pendulum").unwrap_err();
        assert_eq!(e.to_string(), "world.friction: pendulum has no ground to change (leave it unset)");
        assert!(toml::from_str::<World>("gravity = 3").is_err());
        let w = World { friction: Some(0.7), torso_mass_scale: 2.0, ..World::default() };
        let named: Vec<(String, f32)> = w.settings().into_iter().map(|(k, v)| (k.to_string(), v)).collect();
        assert_eq!(World::from_settings(&named).unwrap(), w);
        assert!(World::from_settings(&[("gravity".into(), 1.0)]).unwrap_err().contains("`gravity`"));
        assert!(World::from_settings(&[("friction".into(), -1.0)]).unwrap_err().starts_with("world.friction: -1"));
    }
}
