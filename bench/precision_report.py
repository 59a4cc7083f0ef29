"""The table of issue 34's figures from bench/compare_precision.sh's JSON lines.

Sides: ours in f32 and bf16, PyTorch in f32 and under bf16 autocast, and where the run has them
an older build's f32 figures ("coadapt-before"). Per figure and side: the median over the rounds and the range (min-max). Per pair of sides: the
ratio taken round by round (ours over the peer for a rate, the peer over ours for a time, so >1
always means ours is faster), its median and range over the rounds, n = the rounds.

usage: python3 bench/precision_report.py runs/bench-precision-*.jsonl
"""
import json
import statistics
import sys

# (bench, config without suffix, unit, higher is better)
FIGURES = [
    ("sac_update", "3x256-obs17", "updates/s", True),
    ("sac_update", "3x200-obs23", "updates/s", True),
    ("sac_update", "2x256-obs17", "updates/s", True),
    ("pso_over_q", "700x250x32", "s", False),
]
SIDES = [("coadapt-before", ""), ("coadapt", ""), ("coadapt", "-bf16"), ("pytorch", ""), ("pytorch-bf16", "")]
NAMES = {("coadapt-before", ""): "ours f32 before", ("coadapt", ""): "ours f32", ("coadapt", "-bf16"): "ours bf16",
         ("pytorch", ""): "PyTorch f32", ("pytorch-bf16", ""): "PyTorch bf16"}
# (faster side, slower side) pairs whose ratio the issue asks for
RATIOS = [(("coadapt", "-bf16"), ("coadapt-before", "")), (("coadapt", "-bf16"), ("coadapt", "")), (("coadapt", "-bf16"), ("pytorch", "")),
          (("coadapt", "-bf16"), ("pytorch-bf16", "")), (("coadapt", ""), ("pytorch", "")),
          (("pytorch-bf16", ""), ("pytorch", ""))]


def cell(values, digits=1):
    if not values:
        return "-"
    return f"{statistics.median(values):.{digits}f} ({min(values):.{digits}f}-{max(values):.{digits}f})"


def main(path):
    rows = [json.loads(line) for line in open(path) if line.strip()]
    value = {}  # (bench, config, unit, impl, suffix, round) -> value
    for d in rows:
        for bench, config, unit, _ in FIGURES:
            if d["bench"] != bench or d["unit"] != unit:
                continue
            for impl, suffix in SIDES:
                if d["impl"] == impl and d["config"] == config + suffix:
                    value[(bench, config, impl, suffix, d.get("round", 1))] = d["value"]
    rounds = sorted({k[-1] for k in value})
    print(f"{path}: {len(rounds)} rounds; cells are the median (min-max) over the rounds\n")
    sides = [s for s in SIDES if any(k[2:4] == s for k in value)]
    ratios = [(a, b) for a, b in RATIOS if a in sides and b in sides]
    print("| figure | " + " | ".join(NAMES[s] for s in sides) + " | "
          + " | ".join(f"{NAMES[a]} / {NAMES[b]}" for a, b in ratios) + " |")
    print("|---" * (1 + len(sides) + len(ratios)) + "|")
    for bench, config, unit, higher in FIGURES:
        vals = {s: [value[(bench, config, *s, r)] for r in rounds if (bench, config, *s, r) in value] for s in sides}
        if not any(vals.values()):
            continue
        digits = 2 if unit == "s" else 1
        cells = [cell(vals[s], digits) for s in sides]
        for a, b in ratios:
            per_round = []
            for r in rounds:
                x, y = value.get((bench, config, *a, r)), value.get((bench, config, *b, r))
                if x and y:
                    per_round.append(x / y if higher else y / x)
            cells.append(cell(per_round, 2) + "x" if per_round else "-")
        print(f"| {bench} {config} ({unit}) | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main(sys.argv[1])
