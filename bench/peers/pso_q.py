"""PSO over Q in PyTorch: the peer of `coadapt bench pso`.

A global-best PSO (700 particles x 250 iterations, c1 0.5, c2 0.3, w 0.9, clamped to [0.8, 2.0]^6)
whose objective is Eq. 5.6 with 32 start states: actor 23-256-256-256-6 (mean head, tanh) and
critic 29-256-256-256-1, evaluated under no_grad in chunks of 1024 rows, 2 threads. Random
networks and states (the time does not depend on the weights).

With --autocast the objective's forward passes run under torch.autocast("cpu", bfloat16): bf16
products (PyTorch's mixed precision, the peer of `coadapt bench pso --precision bf16`), "impl":
"pytorch-bf16".

usage: .venv-peers/bin/python bench/peers/pso_q.py [--iterations 250] [--states 32] [--autocast]
prints: {"bench": "pso_over_q", "config": "700x250x32", "value": <s>, "unit": "s", "impl": "pytorch"}
"""
import argparse
import json
import time

import numpy as np
import torch
import torch.nn as nn


def mlp(sizes):
    layers = []
    for a, b in zip(sizes[:-1], sizes[1:]):
        layers += [nn.Linear(a, b), nn.ReLU()]
    return nn.Sequential(*layers[:-1])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--iterations", type=int, default=250)
    ap.add_argument("--states", type=int, default=32)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--chunk", type=int, default=1024)
    ap.add_argument("--autocast", action="store_true", help="bf16 products under torch.autocast")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    actor, critic = mlp([23, 256, 256, 256, 6]), mlp([29, 256, 256, 256, 1])
    states = torch.rand(args.states, 23) * 2 - 1
    n, dim, lo, hi = 700, 6, 0.8, 2.0

    @torch.no_grad()
    @torch.autocast("cpu", dtype=torch.bfloat16, enabled=args.autocast)
    def objective(xi):
        x = states.repeat(n, 1)
        x[:, 17:23] = torch.from_numpy(np.repeat(xi, args.states, axis=0)).float()
        q = torch.empty(x.shape[0])
        for i in range(0, x.shape[0], args.chunk):
            c = x[i:i + args.chunk]
            a = torch.tanh(actor(c))
            q[i:i + args.chunk] = critic(torch.cat([c, a.to(c.dtype)], 1)).squeeze(1).float()
        return q.view(n, args.states).mean(1).numpy()

    t0 = time.perf_counter()
    x = rng.uniform(lo, hi, (n, dim))
    v = rng.uniform(0, 1, (n, dim))
    pbest, pscore = x.copy(), np.full(n, -np.inf)
    for _ in range(args.iterations):
        f = objective(x)
        better = f > pscore
        pbest[better], pscore[better] = x[better], f[better]
        g = pbest[np.argmax(pscore)]
        r1, r2 = rng.random((n, dim)), rng.random((n, dim))
        v = 0.9 * v + 0.5 * r1 * (pbest - x) + 0.3 * r2 * (g - x)
        x = np.clip(x + v, lo, hi)
    secs = time.perf_counter() - t0
    print(json.dumps({"bench": "pso_over_q", "config": f"{n}x{args.iterations}x{args.states}", "value": round(secs, 3), "unit": "s", "impl": "pytorch-bf16" if args.autocast else "pytorch"}))


if __name__ == "__main__":
    main()
