"""Design-objective forward throughput peer (plain PyTorch, no_grad, float32).

Per row: a = actor(x) with actor MLP 23-256-256-256-6, then q = critic([x, a])
with critic MLP 29-256-256-256-1 (ReLU between layers).  Rows are the
700 particles x 32 start states = 22,400 states of a design-objective pass
(optionally 256 start states = 179,200 rows).  Measured: one batched pass over
all rows, and the rows in chunks of --chunk (1024).  Each figure is the median
of --reps timed passes after one warm-up pass.

Run:  .venv-peers/bin/python bench/peers/forward.py [--threads 2] [--big]
Prints per config three JSON lines (s/pass, rows/s, GFLOP/s), e.g.
  {"bench": "forward_actor_critic", "config": "22400rows-chunk1024", "value": 0.115, "unit": "s/pass", "impl": "pytorch"}
GFLOP/s counts 2*in*out flops per Linear layer per row (biases/ReLU ignored).
"""
import argparse
import json
import statistics
import time

import torch
import torch.nn as nn

OBS, ACT, HIDDEN = 23, 6, (256, 256, 256)
PARTICLES = 700


def mlp(sizes):
    layers = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


def flops_per_row(*nets):
    return sum(2 * m.in_features * m.out_features for net in nets for m in net if isinstance(m, nn.Linear))


def run_pass(actor, critic, x, out, chunk):
    n = x.shape[0]
    step = chunk or n
    for s in range(0, n, step):
        xs = x[s:s + step]
        a = actor(xs)
        out[s:s + step] = critic(torch.cat([xs, a], dim=1)).squeeze(1)


def measure(actor, critic, rows, chunk, reps):
    x = torch.randn(rows, OBS, generator=torch.Generator().manual_seed(2))
    out = torch.empty(rows)
    run_pass(actor, critic, x, out, chunk)  # warm-up
    times = []
    for _ in range(reps):
        t = time.perf_counter()
        run_pass(actor, critic, x, out, chunk)
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--threads", type=int, default=2, help="torch.set_num_threads")
    ap.add_argument("--reps", type=int, default=9, help="timed passes per figure (median)")
    ap.add_argument("--chunk", type=int, default=1024, help="rows per chunk")
    ap.add_argument("--big", action="store_true", help="also 179,200 rows (256 start states), chunked")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    actor = mlp([OBS, *HIDDEN, ACT])
    critic = mlp([OBS + ACT, *HIDDEN, 1])
    fpr = flops_per_row(actor, critic)

    cases = [(PARTICLES * 32, None), (PARTICLES * 32, args.chunk)]
    if args.big:
        cases.append((PARTICLES * 256, args.chunk))
    with torch.no_grad():
        for rows, chunk in cases:
            sec = measure(actor, critic, rows, chunk, args.reps)
            config = "%drows-%s" % (rows, "chunk%d" % chunk if chunk else "batched")
            for value, unit in ((round(sec, 4), "s/pass"), (round(rows / sec), "rows/s"),
                                (round(rows * fpr / sec / 1e9, 2), "GFLOP/s")):
                print(json.dumps({"bench": "forward_actor_critic", "config": config, "value": value,
                                  "unit": unit, "impl": "pytorch"}), flush=True)


if __name__ == "__main__":
    main()
