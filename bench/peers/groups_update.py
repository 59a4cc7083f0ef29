"""One GrouPS update in NumPy: the peer of `coadapt bench groups` (bench/src/groups.rs).

The same work as `Groups::update` + `Groups::resize` in policy_search/src/groups.rs (thesis
Alg. 1, Eq. 2.15-2.29 in the form of thesis-notes.md 1.3-1.4): the best-k reward weights, then
`inner` variational iterations in the order M, W, z, alpha, tau with E[tau], then W *= 1.5 and
tau /= 1.5. float64 throughout, as ours. Vectorised over rollouts, steps and each group's
actions; the loops left are the inner iterations and the 4 groups (as ours). Gamma alpha only
(alpha-rank 0, the config's).

Inputs are drawn (or read) once, outside the timed loop; each timed repetition starts from a
copy of the same state, made outside the timed region (garbage collection off while timing).

  usage: groups_update.py [--repetitions 200] [--warmup 20]
             [--inputs FILE]   time on the inputs `coadapt bench groups --dump FILE` wrote
                               (default: draw a state and rollouts of the same sizes here)
             [--check FILE]    recompute the dumped update and compare M, W, alpha, tau
                               (and the posterior covariances) to ours; exits 1 beyond 1e-4
prints one JSON line: {"bench": "groups_update", "config": ..., "value": median ms,
"unit": "ms", "impl": "numpy", "p10": ..., "p90": ..., ...}
"""
import argparse
import gc
import json
import sys
import time

import numpy as np

BENCH = "groups_update"


def defaults():
    # GroupsConfig::default() (policy_search/src/groups.rs), which planar-groups4.toml keeps.
    return {"latent": 6, "rollouts": 30, "best": 15, "inner": 20, "a-tau": 1000.0, "b-tau": 1000.0,
            "a-alpha": 1.0, "b-alpha": 1.0, "sigma2": 100.0, "resize": 1.5,
            "initial-variance": 10 ** 1.5, "priors": True, "alpha-rank": 0}


def time_features(steps, width=3.0):
    """TimeFeatures::thesis: normalised Gaussian RBFs, centres -width, 0, width, ... <= steps + width."""
    centres = np.arange(-width, steps + width + 1e-9, width)
    t = np.arange(1, steps + 1, dtype=np.float64)[:, None]
    v = np.exp(-0.5 * ((t - centres[None, :]) / width) ** 2)
    return v / v.sum(1, keepdims=True)


def spd_inverse(a):
    """The inverse of an SPD matrix by Cholesky; None when it is not positive definite."""
    try:
        chol = np.linalg.cholesky(a)
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(chol)):
        return None
    li = np.linalg.inv(chol)
    return li.T @ li


class State:
    """The learner's state (Groups' fields the update reads or writes)."""

    def __init__(self, m, w, w_hat, alpha, tau, sigma_m, sigma_w):
        self.m, self.w, self.w_hat, self.alpha, self.tau = m, w, w_hat, alpha, tau
        self.sigma_m, self.sigma_w = sigma_m, sigma_w

    def copy(self):
        return State(self.m.copy(), self.w.copy(), self.w_hat.copy(), self.alpha.copy(), self.tau.copy(),
                     self.sigma_m.copy(), self.sigma_w.copy())


def update(st, actions, z, weights, phi, cfg, groups):
    """Groups::update: `inner` iterations of q(M), q(W) per group, q(z), q(alpha), q(tau) per group.

    actions (n, T, D), z (n, T, K): the rollouts' actions and latent draws; weights (n,)."""
    n, t_max, d = actions.shape
    k, p = cfg["latent"], phi.shape[1]
    priors = cfg["priors"]
    s = (phi * phi).sum(1)  # (T,)
    m_old = st.m.copy()
    mu_z = z.copy()  # q(z): the sampled draws, unit covariance, to start
    sigma_z = np.broadcast_to(np.eye(k), (t_max, k, k))
    inv_s2 = 1.0 / cfg["sigma2"] if priors else 0.0
    wsum = weights.sum()
    phiphi = wsum * (phi.T @ (phi / s[:, None]))  # sum_t phi phi' / s, times the weights' sum
    ws = weights[:, None] / s[None, :]  # (n, T): w_i / s_t
    eye_p, eye_k = np.eye(p), np.eye(k)
    tau_of_action = np.empty(d)
    for _ in range(cfg["inner"]):
        for g, idx in enumerate(groups):
            tau = st.tau[g]
            # q(M) (Eq. 2.19-2.21).
            sig = spd_inverse(tau * phiphi + inv_s2 * eye_p)
            if sig is None:
                continue
            r = actions[:, :, idx] - mu_z @ st.w[idx].T  # (n, T, D_m)
            c = ((tau * ws)[:, :, None] * r).sum(0)  # (T, D_m)
            st.m[idx] = (inv_s2 * m_old[idx] + c.T @ phi) @ sig.T
            st.sigma_m[g] = sig if priors else 0.0
            # q(W) (Eq. 2.22-2.24, prior centre W-hat).
            zw = (mu_z * ws[:, :, None]).reshape(-1, k)
            prec = tau * (zw.T @ mu_z.reshape(-1, k) + wsum * (sigma_z / s[:, None, None]).sum(0))
            if priors:
                prec = prec + np.diag(st.alpha[g])
            sig = spd_inverse(prec)
            if sig is None:
                continue
            r = actions[:, :, idx] - (phi @ st.m[idx].T)[None]  # (n, T, D_m)
            rhs = ((tau * ws)[:, :, None] * r).reshape(-1, len(idx)).T @ mu_z.reshape(-1, k)
            if priors:
                rhs += st.alpha[g] * st.w_hat[idx]
            st.w[idx] = rhs @ sig.T
            st.sigma_w[g] = sig if priors else 0.0
        # q(z) (Eq. 2.25-2.27), per rollout and step, not reward-weighted.
        a = eye_k.copy()
        for g, idx in enumerate(groups):
            wg = st.w[idx]
            a += st.tau[g] * (wg.T @ wg + len(idx) * st.sigma_w[g])
            tau_of_action[idx] = st.tau[g]
        a_inv = spd_inverse(a)
        if a_inv is None:
            continue
        sigma_z = s[:, None, None] * a_inv[None]
        resid = actions - (phi @ st.m.T)[None]  # (n, T, D)
        mu_z = ((resid * tau_of_action) @ st.w) @ a_inv.T
        for g, idx in enumerate(groups):
            # q(alpha) (Eq. 2.15-2.17, deviations from W-hat).
            wg, dm = st.w[idx], len(idx)
            gamma = ((wg - st.w_hat[idx]) ** 2).sum(0) + dm * np.diag(st.sigma_w[g])
            st.alpha[g] = (cfg["a-alpha"] + dm / 2.0) / (cfg["b-alpha"] + 0.5 * gamma)
            # q(tau) (Eq. 2.28-2.29): the expected squared residual, term by term.
            sm, sw = st.sigma_m[g], st.sigma_w[g]
            fsf = ((phi @ sm) * phi).sum(1)  # (T,)
            z_sw_z = ((mu_z @ sw) * mu_z).sum(2)  # (n, T)
            tr = s * (sw * a_inv.T).sum()  # tr(Sigma_W Sigma_z,t), (T,)
            w_sz_w = s * ((wg @ a_inv) * wg).sum()  # sum_j w_j' Sigma_z,t w_j, (T,)
            r = actions[:, :, idx] - mu_z @ wg.T - (phi @ st.m[idx].T)[None]
            e = (r * r).sum(2) + w_sz_w[None] + dm * (z_sw_z + (tr + fsf)[None])
            b = (ws * e).sum()
            a_tau, b_tau = (cfg["a-tau"], cfg["b-tau"]) if priors else (0.0, 0.0)
            shape = a_tau + 0.5 * dm * t_max * wsum
            if b > 0.0 or b_tau > 0.0:
                st.tau[g] = shape / (b_tau + 0.5 * b)


def spd_inverse_stack(a):
    """spd_inverse of each matrix of the stack a (G, n, n): (inverses, ok per matrix)."""
    try:
        chol = np.linalg.cholesky(a)
        ok = np.isfinite(chol).all(axis=(1, 2))
        li = np.linalg.inv(chol)
        return np.swapaxes(li, 1, 2) @ li, ok
    except np.linalg.LinAlgError:  # one of them is not positive definite: one at a time
        inv = [spd_inverse(x) for x in a]
        ok = np.array([x is not None for x in inv])
        return np.array([x if x is not None else np.zeros_like(a[0]) for x in inv]), ok


def update_batched(st, actions, z, weights, phi, cfg, groups):
    """The same update with the loops over groups batched: each group's q(M) and q(W) depend
    only on its own rows of M and W (and on mu_z, tau, alpha, which the group loop does not
    change), and q(alpha), q(tau) of a group only on its own rows, so doing every group's step
    at once computes exactly what update() computes group after group. The weighted moments of
    q(z) are computed once per inner iteration instead of once per group. What the timed run
    uses; update() is the line-by-line transcription, checked against ours too."""
    n, t_max, d = actions.shape
    k, p, ng = cfg["latent"], phi.shape[1], len(groups)
    priors = cfg["priors"]
    gid = np.empty(d, dtype=np.intp)
    for g, idx in enumerate(groups):
        gid[idx] = g
    ind = (gid[None, :] == np.arange(ng)[:, None]).astype(np.float64)  # (G, D)
    sizes = ind.sum(1)
    s = (phi * phi).sum(1)
    m_old = st.m.copy()
    mu_z = z.copy()
    inv_s2 = 1.0 / cfg["sigma2"] if priors else 0.0
    wsum = weights.sum()
    phiphi = wsum * (phi.T @ (phi / s[:, None]))
    ws = weights[:, None] / s[None, :]
    sz_sum = wsum * np.eye(k) * (1.0 / s).sum()  # wsum sum_t Sigma_z,t / s_t, Sigma_z,t = I to start
    eye_p, eye_k = np.eye(p), np.eye(k)
    a_alpha = cfg["a-alpha"] + sizes / 2.0
    a_tau, b_tau = (cfg["a-tau"], cfg["b-tau"]) if priors else (0.0, 0.0)
    tau_shape = a_tau + 0.5 * sizes * t_max * wsum
    for _ in range(cfg["inner"]):
        tau_d = st.tau[gid]
        # q(M), every group.
        sig_m, ok_m = spd_inverse_stack(st.tau[:, None, None] * phiphi + inv_s2 * eye_p)
        c = (ws[:, :, None] * (actions - mu_z @ st.w.T)).sum(0) * tau_d  # (T, D)
        rhs = inv_s2 * m_old + c.T @ phi
        m_new = (sig_m[gid] @ rhs[:, :, None])[:, :, 0]
        st.m = np.where(ok_m[gid][:, None], m_new, st.m)
        st.sigma_m = np.where(ok_m[:, None, None], sig_m if priors else 0.0, st.sigma_m)
        # q(W), every group whose q(M) went through.
        zz = (mu_z * ws[:, :, None]).reshape(-1, k).T @ mu_z.reshape(-1, k)
        prec = st.tau[:, None, None] * (zz + sz_sum)
        if priors:
            prec = prec + st.alpha[:, :, None] * eye_k
        sig_w, ok_w = spd_inverse_stack(prec)
        ok_w &= ok_m
        resid = actions - (phi @ st.m.T)[None]  # (n, T, D)
        rhs = ((ws[:, :, None] * resid).reshape(-1, d).T @ mu_z.reshape(-1, k)) * tau_d[:, None]
        if priors:
            rhs += st.alpha[gid] * st.w_hat
        w_new = (sig_w[gid] @ rhs[:, :, None])[:, :, 0]
        st.w = np.where(ok_w[gid][:, None], w_new, st.w)
        st.sigma_w = np.where(ok_w[:, None, None], sig_w if priors else 0.0, st.sigma_w)
        # q(z).
        a = eye_k + st.w.T @ (st.w * tau_d[:, None]) + ((st.tau * sizes)[:, None, None] * st.sigma_w).sum(0)
        a_inv = spd_inverse(a)
        if a_inv is None:
            continue
        sz_sum = wsum * t_max * a_inv
        mu_z = ((resid * tau_d) @ st.w) @ a_inv.T
        # q(alpha), every group.
        gamma = ind @ (st.w - st.w_hat) ** 2 + sizes[:, None] * np.diagonal(st.sigma_w, axis1=1, axis2=2)
        st.alpha = a_alpha[:, None] / (cfg["b-alpha"] + 0.5 * gamma)
        # q(tau), every group.
        fsf = ((phi[None] @ st.sigma_m) * phi[None]).sum(2)  # (G, T)
        zf = mu_z.reshape(-1, k)
        z_sw_z = ((zf[None] @ st.sigma_w) * zf[None]).sum(2).reshape(ng, n, t_max)
        tr = (st.sigma_w * a_inv.T[None]).sum((1, 2))[:, None] * s[None]  # (G, T)
        w_sz_w = (ind @ ((st.w @ a_inv) * st.w).sum(1))[:, None] * s[None]  # (G, T)
        r = resid - mu_z @ st.w.T
        r2 = ((r * r).reshape(-1, d) @ ind.T).T.reshape(ng, n, t_max)
        e = r2 + (w_sz_w + sizes[:, None] * (tr + fsf))[:, None, :] + sizes[:, None, None] * z_sw_z
        b = (ws[None] * e).sum((1, 2))
        st.tau = np.where((b > 0.0) | (b_tau > 0.0), tau_shape / (b_tau + 0.5 * b), st.tau)


def one_update(st, best_actions, best_z, best_returns, phi, cfg, groups, batched=True):
    """What Groups::iterate does once the rollouts are evaluated and sorted (best first)."""
    ret = np.maximum(best_returns, 0.0)
    weights = ret / ret.sum()
    (update_batched if batched else update)(st, best_actions, best_z, weights, phi, cfg, groups)
    st.w *= cfg["resize"]  # Groups::resize
    st.tau /= cfg["resize"]


def from_dump(data):
    cfg = data["config"]
    if cfg.get("alpha-rank", 0) != 0 or cfg.get("pool", 0) != 0:
        sys.exit("groups_update.py: only Gamma alpha (alpha-rank 0) without a pool")
    d, p, t_max, k = data["d"], data["p"], data["steps"], cfg["latent"]
    groups = [np.array(g) for g in data["groups"]]
    phi = np.array(data["phi"], dtype=np.float64).reshape(t_max, p)
    ro = data["rollouts"]
    actions = np.array([r["actions"] for r in ro], dtype=np.float64).reshape(len(ro), t_max, d)
    z = np.array([r["z"] for r in ro], dtype=np.float64).reshape(len(ro), t_max, k)
    returns = np.array([r["ret"] for r in ro], dtype=np.float64)
    b = data["before"]
    st = State(np.array(b["m"]).reshape(d, p), np.array(b["w"]).reshape(d, k), np.array(b["w_hat"]).reshape(d, k),
               np.array(b["alpha"], dtype=np.float64), np.array(b["tau"], dtype=np.float64),
               np.array(b["sigma_m"], dtype=np.float64).reshape(len(groups), p, p),
               np.array(b["sigma_w"], dtype=np.float64).reshape(len(groups), k, k))
    return cfg, groups, phi, actions, z, returns, st, data["config_name"]


def draw_inputs(seed):
    """A state and rollouts of the same sizes, drawn here: W ~ N(0, 1), M ~ N(0, 1), rollouts
    sampled from the policy with Z drawn once per rollout, positive returns."""
    rng = np.random.default_rng(seed)
    cfg = defaults()
    groups = [np.array(g) for g in ([0, 1, 2, 3], [4, 5], [6, 7, 8, 9], [10, 11])]
    d, t_max, k, n = 12, 25, cfg["latent"], cfg["rollouts"]
    phi = time_features(t_max)
    p = phi.shape[1]
    st = State(rng.standard_normal((d, p)), rng.standard_normal((d, k)), np.zeros((d, k)), np.ones((len(groups), k)),
               np.full(len(groups), 1.0 / cfg["initial-variance"]), np.array([np.eye(p)] * len(groups)),
               np.array([np.eye(k)] * len(groups)))
    zmat = rng.standard_normal((n, k, p))
    z = np.einsum("nkp,tp->ntk", zmat, phi)
    sd = np.empty(d)
    for g, idx in enumerate(groups):
        sd[idx] = np.sqrt(1.0 / st.tau[g])
    noise = np.einsum("ntdp,tp->ntd", rng.standard_normal((n, t_max, d, p)), phi) * sd
    actions = z @ st.w.T + (phi @ st.m.T)[None] + noise
    returns = np.sort(rng.uniform(1.0, 20.0, n))[::-1].copy()
    name = f"r{n}-b{cfg['best']}-d{d}-p{p}-t{t_max}-k{k}-i{cfg['inner']}-g{len(groups)}"
    return cfg, groups, phi, actions, z, returns, st, name


def check(path):
    """Both NumPy versions (batched: the timed one; loop: the transcription) against ours."""
    with open(path) as f:
        data = json.load(f)
    after = data["after"]
    out = {"check": path, "dtype": "float64"}
    ok = True
    for batched in (True, False):
        cfg, groups, phi, actions, z, returns, st, _ = from_dump(data)
        kb = cfg["best"]
        one_update(st, actions[:kb], z[:kb], returns[:kb], phi, cfg, groups, batched=batched)
        ours = {"m": st.m, "w": st.w, "alpha": st.alpha, "tau": st.tau, "sigma_m": st.sigma_m, "sigma_w": st.sigma_w}
        worst, res = 0.0, {}
        for key, mine in ours.items():
            ref = np.array(after[key], dtype=np.float64).reshape(mine.shape)
            diff = np.abs(mine - ref)
            # Relative to each element, floored at 1e-8 of the array's largest (no 0/0 blow-ups).
            rel = diff / np.maximum(np.abs(ref), 1e-8 * np.abs(ref).max())
            res[key] = {"max_abs": float(diff.max()), "max_rel": float(rel.max()), "max_ref": float(np.abs(ref).max())}
            if key in ("m", "w", "alpha", "tau"):
                worst = max(worst, float(rel.max()))
        res["max_rel_m_w_alpha_tau"] = worst
        ok &= worst < 1e-4
        out["batched" if batched else "loop"] = res
    out["ok"] = bool(ok)
    print(json.dumps(out))
    return ok


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repetitions", type=int, default=200)
    ap.add_argument("--warmup", type=int, default=20)
    ap.add_argument("--inputs", help="time on the inputs of `coadapt bench groups --dump FILE`")
    ap.add_argument("--check", help="compare one update with the one `coadapt bench groups --dump FILE` wrote")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--loop", action="store_true", help="time update() (groups one after the other) instead")
    a = ap.parse_args()
    if a.check:
        sys.exit(0 if check(a.check) else 1)
    if a.inputs:
        with open(a.inputs) as f:
            cfg, groups, phi, actions, z, returns, state, name = from_dump(json.load(f))
    else:
        cfg, groups, phi, actions, z, returns, state, name = draw_inputs(a.seed)
    kb = cfg["best"]
    best = (np.ascontiguousarray(actions[:kb]), np.ascontiguousarray(z[:kb]), returns[:kb].copy())
    for _ in range(a.warmup):
        one_update(state.copy(), *best, phi, cfg, groups, batched=not a.loop)
    ms = []
    gc.collect()
    gc.disable()
    try:
        for _ in range(a.repetitions):
            st = state.copy()
            t0 = time.perf_counter()
            one_update(st, *best, phi, cfg, groups, batched=not a.loop)
            ms.append((time.perf_counter() - t0) * 1e3)
    finally:
        gc.enable()
    ms = np.array(ms)
    print(json.dumps({"bench": BENCH, "config": name, "value": round(float(np.percentile(ms, 50)), 4), "unit": "ms",
                      "impl": "numpy", "p10": round(float(np.percentile(ms, 10)), 4),
                      "p90": round(float(np.percentile(ms, 90)), 4), "repetitions": a.repetitions,
                      "dtype": "float64", "version": "loop" if a.loop else "batched",
                      "inputs": a.inputs or f"drawn, seed {a.seed}", "numpy": np.__version__}))


if __name__ == "__main__":
    main()
