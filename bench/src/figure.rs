//! What the benchmarks share: the one-line figure (`{"bench", "config", "value", "unit",
//! "impl"}`), a rate over a timed loop, and percentiles of sorted timings.

use std::time::Instant;

use serde_json::json;

/// Prints one figure's JSON line, its value rounded to three decimals.
pub fn emit(bench: &str, config: &str, value: f64, unit: &str) {
    let line = json!({"bench": bench, "config": config, "value": (value * 1000.0).round() / 1000.0, "unit": unit, "impl": "coadapt"});
    coadapt_log::print_stdout_line(&line.to_string());
}

/// Calls `f` repeatedly for about `seconds` after a short warm-up; returns calls per second.
pub fn rate(seconds: f64, mut f: impl FnMut()) -> f64 {
    for _ in 0..3 {
        f();
    }
    let start = Instant::now();
    let mut n = 0u64;
    while start.elapsed().as_secs_f64() < seconds {
        f();
        n += 1;
    }
    n as f64 / start.elapsed().as_secs_f64()
}

/// Linear interpolation between order statistics of the sorted `v` (NumPy's default).
pub fn percentile(v: &[f64], q: f64) -> f64 {
    let x = q * (v.len() - 1) as f64;
    let (lo, hi) = (x.floor() as usize, x.ceil() as usize);
    v[lo] + (v[hi] - v[lo]) * (x - lo as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_interpolate_as_numpy_does() {
        assert!(percentile(&[1.0, 2.0, 3.0, 4.0, 5.0], 0.5) == 3.0 && percentile(&[1.0, 2.0], 0.9) == 1.9);
    }
}
