//! The tanh-squashed diagonal Gaussian policy head of SAC.
//!
//! The policy network outputs `[mean (act), log_std (act)]` per row. With noise `eps ~ N(0, I)`:
//! `u = mean + exp(clamp(log_std)) * eps`, `a = tanh(u)` and
//! `log pi(a|s) = sum_j [ -eps_j^2 / 2 - log_std_j - log(2 pi) / 2 - log(1 - tanh(u_j)^2) ]`,
//! with `log(1 - tanh(u)^2) = 2 (log 2 - u - softplus(-2u))`, exact and stable for any `u`
//! (no `+1e-6` fudge, which biases the log-probability of saturated actions).

/// Log-std clamp of the reference policy.
pub const LOG_STD_MIN: f32 = -20.0;
pub const LOG_STD_MAX: f32 = 2.0;

const HALF_LOG_2PI: f32 = 0.918_938_5;

fn softplus(x: f32) -> f32 {
    if x > 20.0 { x } else { x.exp().ln_1p() }
}

/// `log(1 - tanh(u)^2)` without cancellation.
pub fn log1m_tanh_sq(u: f32) -> f32 {
    2.0 * (std::f32::consts::LN_2 - u - softplus(-2.0 * u))
}

/// Samples actions and their log-probabilities for every row.
///
/// `head` is `rows x 2*act` (mean then log_std), `eps` is `rows x act`; writes `action`
/// (`rows x act`) and `log_prob` (`rows`).
pub fn sample(head: &[f32], eps: &[f32], act: usize, action: &mut [f32], log_prob: &mut [f32]) {
    let rows = log_prob.len();
    assert_eq!(head.len(), rows * 2 * act);
    assert_eq!(eps.len(), rows * act);
    assert_eq!(action.len(), rows * act);
    for r in 0..rows {
        let h = &head[r * 2 * act..(r + 1) * 2 * act];
        let (mean, log_std) = h.split_at(act);
        let mut lp = 0.0;
        for j in 0..act {
            let ls = log_std[j].clamp(LOG_STD_MIN, LOG_STD_MAX);
            let e = eps[r * act + j];
            let u = mean[j] + ls.exp() * e;
            action[r * act + j] = u.tanh();
            lp += -0.5 * e * e - ls - HALF_LOG_2PI - log1m_tanh_sq(u);
        }
        log_prob[r] = lp;
    }
}

/// The deterministic action `tanh(mean)` of every row (evaluation and the design objective).
pub fn mean_action(head: &[f32], act: usize, action: &mut [f32]) {
    for (h, a) in head.chunks_exact(2 * act).zip(action.chunks_exact_mut(act)) {
        for (m, out) in h[..act].iter().zip(a) {
            *out = m.tanh();
        }
    }
}

/// Backward through [`sample`]: given dL/d(action) and dL/d(log_prob) per row, writes
/// dL/d(head) (`rows x 2*act`). `action` is the output of [`sample`] for the same `head`, `eps`.
///
/// With `u` as above: d(a)/du = 1 - a^2, d(log pi)/du = 2a (from d/du log(1 - tanh^2 u) = -2a),
/// du/d(mean) = 1, du/d(log_std) = std * eps, and log pi has a direct -1 in log_std. The clamp
/// passes gradient only inside `[LOG_STD_MIN, LOG_STD_MAX]`, as `torch.clamp` does.
pub fn backward(head: &[f32], eps: &[f32], action: &[f32], d_action: &[f32], d_log_prob: &[f32], act: usize, d_head: &mut [f32]) {
    let rows = d_log_prob.len();
    assert_eq!(d_head.len(), rows * 2 * act);
    for r in 0..rows {
        let dlp = d_log_prob[r];
        let (dmean, dls) = d_head[r * 2 * act..(r + 1) * 2 * act].split_at_mut(act);
        let log_std = &head[r * 2 * act + act..(r + 1) * 2 * act];
        for j in 0..act {
            let a = action[r * act + j];
            let du = d_action[r * act + j] * (1.0 - a * a) + dlp * 2.0 * a;
            dmean[j] = du;
            let raw = log_std[j];
            dls[j] = if (LOG_STD_MIN..=LOG_STD_MAX).contains(&raw) { du * raw.exp() * eps[r * act + j] - dlp } else { 0.0 };
        }
    }
}
