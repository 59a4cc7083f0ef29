#!/usr/bin/env python3
"""Issue 34's second learning check, from its archive: FEAR's learner on one HalfCheetah body
(EXPERIMENTS 5.5's protocol: scripts/fear_vs_sac.sh with ONLY=fear, 30 episodes) with f32
products against the same with bf16 products, five seeds each, side by side.

    python3 scripts/precision_fear_report.py [docs/campaign/results/fear-precision]

Reads <dir>/<precision>/fear-seed<N>/{episodes.csv,summary.json} and prints a Markdown table
per seed (mean training return of the last 10 episodes, the best 10-episode mean, last and best
deterministic evaluation, the learner's training seconds) and a summary per precision: mean and
sample sd over the seeds (n stated), episodes under 5 after episode 10, and the per-seed
differences bf16 - f32 of the last-10 return.
"""
import csv
import json
import os
import statistics
import sys

root = sys.argv[1] if len(sys.argv) > 1 else "docs/campaign/results/fear-precision"
PRECISIONS = ("f32", "bf16")


def mean10(r):
    return [statistics.mean(r[max(0, i - 9):i + 1]) for i in range(len(r))]


def load(precision, seed):
    d = f"{root}/{precision}/fear-seed{seed}"
    if not os.path.exists(f"{d}/summary.json"):
        return None
    rows = list(csv.DictReader(open(f"{d}/episodes.csv")))
    ret = [float(x["return"]) for x in rows]
    ev = [float(x["eval_return"]) for x in rows if x["eval_return"]]
    s = json.load(open(f"{d}/summary.json"))
    m = mean10(ret)
    stuck = sum(1 for x in rows[10:] if float(x["return"]) < 5) + sum(
        1 for x in rows[10:] if x["eval_return"] and float(x["eval_return"]) < 5)
    return {"last10": m[-1], "best10": max(m), "eval_last": ev[-1], "eval_best": max(ev),
            "train_s": s["learner_training_seconds"], "stuck": stuck}


seeds = sorted({int(n[len("fear-seed"):]) for p in PRECISIONS if os.path.isdir(f"{root}/{p}")
                for n in os.listdir(f"{root}/{p}") if n.startswith("fear-seed") and n[9:].isdigit()})
runs = {p: {s: load(p, s) for s in seeds} for p in PRECISIONS}
print("| seed | f32: last 10 | f32: best 10-episode mean | f32: last / best eval | f32: training s "
      "| bf16: last 10 | bf16: best 10-episode mean | bf16: last / best eval | bf16: training s |")
print("|---|---|---|---|---|---|---|---|---|")
for seed in seeds:
    cells = []
    for p in PRECISIONS:
        r = runs[p][seed]
        cells += ["-"] * 4 if r is None else [
            f"{r['last10']:.1f}", f"{r['best10']:.1f}", f"{r['eval_last']:.1f} / {r['eval_best']:.1f}", f"{r['train_s']:.0f}"]
    print(f"| {seed} | " + " | ".join(cells) + " |")
print()
sd = lambda v: statistics.stdev(v) if len(v) > 1 else float("nan")
for p in PRECISIONS:
    r = [x for x in runs[p].values() if x]
    if not r:
        continue
    last, best, t = [x["last10"] for x in r], [x["eval_best"] for x in r], [x["train_s"] for x in r]
    print(f"- {p}: last-10 training return {statistics.mean(last):.1f} ± {sd(last):.1f}; best evaluation "
          f"{statistics.mean(best):.1f} ± {sd(best):.1f}; training {statistics.mean(t):.0f} ± {sd(t):.0f} s; "
          f"episodes under 5 after episode 10 (training and evaluation): {sum(x['stuck'] for x in r)} (n = {len(r)} seeds)")
pairs = [(s, runs["bf16"][s]["last10"] - runs["f32"][s]["last10"]) for s in seeds if runs["f32"][s] and runs["bf16"][s]]
if pairs:
    d = [x for _, x in pairs]
    print(f"- bf16 - f32, last-10 return per seed: " + ", ".join(f"{x:+.1f}" for _, x in pairs)
          + f"; mean {statistics.mean(d):+.1f} ± {sd(d):.1f} (n = {len(d)})")
