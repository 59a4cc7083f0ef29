#!/usr/bin/env python3
"""Issue 34's Pendulum learning check, from its archive: SAC with f32 products against SAC with
bf16 products, five seeds each (scripts/pendulum_seeds.sh), side by side.

    python3 scripts/precision_report.py [docs/campaign/results/pendulum-precision]

Reads <dir>/<precision>-summary.jsonl (one `coadapt train` summary line per seed) and prints a
Markdown table per seed and a summary: seeds reaching -200 within 20,000 steps, the median first
step, and the mean and sample sd (n stated) of the final mean-of-10 return and of the wall time.
"""
import json
import statistics
import sys

root = sys.argv[1] if len(sys.argv) > 1 else "docs/campaign/results/pendulum-precision"
runs = {}
for precision in ("f32", "bf16"):
    with open(f"{root}/{precision}-summary.jsonl") as f:
        runs[precision] = {s["seed"]: s for s in map(json.loads, filter(str.strip, f))}

print("| seed | f32: first step with mean10 > -200 | f32: mean10 at 20k | f32: wall s | bf16: first step | bf16: mean10 at 20k | bf16: wall s |")
print("|---|---|---|---|---|---|---|")
for seed in sorted(set(runs["f32"]) | set(runs["bf16"])):
    cells = []
    for precision in ("f32", "bf16"):
        s = runs[precision].get(seed)
        if s is None:
            cells += ["-", "-", "-"]
        else:
            first = s["first_step_reaching_target"]
            cells += [str(first) if first is not None else "never", f"{s['mean_return_last_10']:.1f}", f"{s['wall_s']:.0f}"]
    print(f"| {seed} | " + " | ".join(cells) + " |")
print()
for precision in ("f32", "bf16"):
    r = list(runs[precision].values())
    firsts = [s["first_step_reaching_target"] for s in r if s["first_step_reaching_target"] is not None]
    finals = [s["mean_return_last_10"] for s in r]
    walls = [s["wall_s"] for s in r]
    sd = lambda v: statistics.stdev(v) if len(v) > 1 else float("nan")
    median = statistics.median(firsts) if firsts else float("nan")
    print(f"- {precision}: {len(firsts)} of {len(r)} seeds reach -200, median first step {median:.0f}; "
          f"mean10 at 20k {statistics.mean(finals):.1f} ± {sd(finals):.1f}; wall {statistics.mean(walls):.0f} ± {sd(walls):.0f} s (n = {len(r)})")
