//! `coadapt bench sim`: env steps per second of each robot on one core, random actions, resets
//! included, and the simulated seconds per wall second.

use crate::figure::emit;
use coadapt_fleet::app::AppError;

#[derive(Debug, Clone)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct SimOptions {
    /// Seconds to time each robot for.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 10.0))]
    pub seconds: f64,
    /// Robots to time (default: all), comma-separated.
    #[cfg_attr(feature = "clap", arg(long, value_delimiter = ','))]
    pub env: Option<Vec<String>>,
}

pub fn run(a: &SimOptions) -> Result<(), AppError> {
    let names: Vec<String> = match &a.env {
        Some(n) => n.clone(),
        None => coadapt_robots::ENV_NAMES.iter().map(|s| s.to_string()).collect(),
    };
    for name in names {
        let rate = coadapt_robots::bench::env_steps_per_second(&name, a.seconds)?;
        emit("env_steps", &name, rate, "steps/s");
        if let Some(dt) = coadapt_robots::bench::control_dt(&name) {
            // Simulated time per wall second: a fair figure across control steps of
            // different lengths (MuJoCo HalfCheetah-v5's is 0.05 s, ours 0.0165 s).
            emit("sim_seconds", &name, rate * dt, "sim-s/s");
        }
    }
    Ok(())
}
