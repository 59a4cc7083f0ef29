"""Tables for docs/EXPERIMENTS.md from a campaign's run directories (scripts/campaign.sh).

usage: python3 scripts/campaign_report.py [RUNS_ROOT, default runs/campaign] [--initial 5]
           [--methods a,b,...] [--baseline random-only] [--split K] [--tables t1,t2,...] [--columns c1,c2,...]

--methods keeps only those methods (e.g. one protocol's runs out of docs/campaign/results);
--baseline names the method the others are paired against (section 2); --split K adds a table
of the mean best return of chosen designs before design index K and from K on, per method and
paired against the baseline (does a gap open as the critic gets more data?). --tables prints only
the named tables (per-run, per-method, between, split, split-paired, within, faces, and the
three below), without headings: docs/EXPERIMENTS.md includes them that way (scripts/doc_tables.py).

Three tables are printed only when --tables names them, with the columns of --columns
(comma-separated, in order; see COLUMNS), their rows in the order of --methods:
- `runs`: one row per run;
- `methods`: one row per method, over its seeds: returns as mean ± sample sd over the seeds (the
  seeds column is n), within-run pairs and coordinates pooled, with a sign test;
- `paired`: each method minus --baseline, paired by seed: mean ± sample sd of the differences
  (n = the seeds paired) and each seed's difference, for the return columns.
Columns: method, seed, seeds, designs, best, chosen (mean best of the chosen designs, index >=
--initial), exploit (of the exploitation designs: in a run of random designs every chosen design),
explore (of the exploration designs), initial (each initial design's best, in index order),
rollouts, next (exploit minus the exploration design after it: mean ± sd, wins/pairs), both
(exploit minus the mean of the exploration designs on both sides), faces (exploitation designs
with a coordinate within 0.1 % of the box's width of a bound / with every one), bound (their
coordinates within 0.1 %), near (within 2 %), early and late (mean best of chosen designs before
index --split and from it on), gap (late - early), search (summary.json's
learner_waiting_seconds over the exploitation designs: seconds of design search per
exploitation design, the random designs' instant replies included).

Reads every RUN/designs.csv under RUNS_ROOT whose RUN is named METHOD-seedN (only finished runs,
with summary.json, unless --partial) and prints Markdown:

1. per run and per method (mean and sample standard deviation over seeds): the best evaluation
   return of any design, the mean over the chosen designs (after the initial ones) of each
   design's best evaluation return, the same over exploitation designs only, and the design
   rollouts spent;
2. between runs: each method against `random-only` seed by seed (the same seed gives the same
   initial designs and the same networks up to the first chosen design, so the seed pairs them);
3. within runs, for methods that alternate: each exploitation design's best return minus that
   of the exploration design after it (the issue's paired difference), and minus the mean of
   the exploration designs on both sides (which cancels a linear trend of the policy improving
   over time, which favours whichever design comes later), with a sign test;
4. where chosen designs sit in the box: how many exploitation designs have a coordinate on a
   face (within 0.1 % of the width of a bound) and how many have every coordinate on one
   (a corner).

Pure Python (no numpy), so it runs with the system python3.
"""
import csv
import json
import math
import os
import re
import statistics
import sys

from campaign_runs import flag_value, run_dirs

BOUNDS = {
    "half-cheetah": ([0.8] * 6, [2.0] * 6),
    "walker": ([0.5] * 6, [1.5] * 6),
    "hopper": ([0.5] * 5, [4.0, 2.0, 2.0, 2.0, 2.0]),
    "daisy": ([0.12] * 6 + [-0.2] * 3, [0.5] * 6 + [0.2] * 3),
}


def served_mujoco_box():
    """The design box of the MuJoCo cheetah the bridge serves, read from the bridge's own
    module (DESIGN_LOW, DESIGN_HIGH), so the report follows it."""
    src = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "bridges", "python", "coadapt_bridge", "mujoco_half_cheetah.py")
    text = open(src).read()
    vals = {}
    for name in ("DESIGN_LOW", "DESIGN_HIGH"):
        m = re.search(rf"^{name}\s*=\s*\[([-0-9.eE]+)\]\s*\*\s*(\d+)\s*$", text, re.M)
        if not m:
            raise SystemExit(f"campaign_report: {src} has no `{name} = [x] * n` line")
        vals[name] = [float(m.group(1))] * int(m.group(2))
    return vals["DESIGN_LOW"], vals["DESIGN_HIGH"]


# A served robot's address says nothing of its box: the runs of the MuJoCo cheetah through the
# bridge (named mujoco-*, scripts/mujoco_lane.sh) are told by their directory's name.
MUJOCO = "mujoco-half-cheetah (served)"
BOUNDS[MUJOCO] = served_mujoco_box()


def read_run(path):
    with open(os.path.join(path, "designs.csv")) as f:
        # A proposal rejected at the prototype step (schedule.confirm-designs) was never trained
        # on: the row after it holds the design built for that index.
        rows = [r for r in csv.DictReader(f) if r.get("prototype") != "rejected"]
    env = "half-cheetah"
    cfg = os.path.join(path, "config.toml")
    if os.path.exists(cfg):
        m = re.search(r'^env\s*=\s*"([^"]+)"', open(cfg).read(), re.M)
        if m:
            env = m.group(1)
    if env.startswith("dm-env-rpc") and os.path.basename(os.path.normpath(path)).startswith("mujoco"):
        env = MUJOCO
    out = []
    for r in rows:
        out.append({
            "index": int(r["index"]),
            "kind": r["kind"],
            "design": [float(x) for x in r["design"].split(";")],
            "best": float(r["best_eval_return"]) if r["best_eval_return"] else float("nan"),
            "rollouts": int(r["design_rollouts"] or 0),
            "method": r["method"],
        })
    return env, out


def mean_sd(v, sign=""):
    """Mean ± sample sd of the finite values (the mean alone for one, `-` for none); `sign="+"`
    writes the mean's sign always (differences)."""
    v = [x for x in v if not math.isnan(x)]
    if not v:
        return "-"
    if len(v) == 1:
        return f"{v[0]:{sign}.1f}"
    return f"{statistics.mean(v):{sign}.1f} ± {statistics.stdev(v):.1f}"


def sign_test(diffs):
    """Two-sided sign test p-value (ties dropped)."""
    pos = sum(d > 0 for d in diffs)
    neg = sum(d < 0 for d in diffs)
    n = pos + neg
    if n == 0:
        return float("nan")
    k = min(pos, neg)
    p = sum(math.comb(n, i) for i in range(k + 1)) / 2 ** n
    return min(1.0, 2 * p)


def on_face(design, low, high, tol=1e-3):
    flags = [min(abs(x - lo), abs(x - hi)) <= tol * (hi - lo) for x, lo, hi in zip(design, low, high)]
    return any(flags), all(flags)


def option(name, default):
    return flag_value(name, default, "campaign_report")


class Out:
    """Prints the report's tables, or only those named in --tables (then without headings: the
    document that includes them has its own, see scripts/doc_tables.py)."""

    def __init__(self, only):
        self.only = only
        self.on = True
        self.first = True

    def section(self, name, heading):
        self.on = self.only is None or name in self.only
        if self.on and self.only is None:
            print(("" if self.first else "\n") + heading + "\n")
        elif self.on and not self.first:
            print()
        if self.on:
            self.first = False

    def __call__(self, line=""):
        if self.on:
            print(line)


TABLES = ["per-run", "per-method", "between", "split", "split-paired", "within", "faces", "runs", "methods", "paired"]
COLUMNS = {
    "runs": ["method", "seed", "designs", "best", "chosen", "exploit", "explore", "initial", "rollouts", "next", "both",
             "faces", "bound", "near", "early", "late", "gap", "search"],
    "methods": ["method", "seeds", "best", "chosen", "exploit", "explore", "rollouts", "next", "both", "faces", "bound",
                "near", "early", "late", "gap", "search"],
    "paired": ["method", "seeds", "best", "chosen", "exploit", "explore", "early", "late", "gap"],
}


def near_bound(design, low, high, tol):
    return sum(min(abs(x - lo), abs(x - hi)) <= tol * (hi - lo) for x, lo, hi in zip(design, low, high))


def facts(env, rows, summary, n_init, split):
    """What the column tables (runs, methods, paired) say about one run."""
    chosen = [r for r in rows if r["index"] >= n_init]
    exploit = [r for r in chosen if r["kind"] == "exploit"]
    explore = [r for r in chosen if r["kind"] == "explore"]
    avg = lambda rs: statistics.mean(r["best"] for r in rs) if rs else float("nan")
    by_index = {r["index"]: r for r in rows}
    d_next, d_both = [], []
    for r in exploit:
        nxt, prv = by_index.get(r["index"] + 1), by_index.get(r["index"] - 1)
        if nxt and nxt["kind"] == "explore":
            d_next.append(r["best"] - nxt["best"])
            if prv and prv["kind"] == "explore":
                d_both.append(r["best"] - (nxt["best"] + prv["best"]) / 2)
    low, high = BOUNDS.get(env, (None, None))
    face = corner = on = near = total = 0
    if low is not None:
        for r in exploit:
            f, c = on_face(r["design"], low, high)
            face += f
            corner += c
            on += near_bound(r["design"], low, high, 1e-3)
            near += near_bound(r["design"], low, high, 2e-2)
            total += len(r["design"])
    out = {
        "designs": len(rows), "best": max(r["best"] for r in rows), "chosen": avg(chosen), "exploit": avg(exploit),
        "explore": avg(explore), "initial": [r["best"] for r in rows if r["index"] < n_init],
        "rollouts": sum(r["rollouts"] for r in rows), "next": d_next, "both": d_both, "n_exploit": len(exploit),
        "face": face, "corner": corner, "on": on, "near": near, "coords": total,
        "waiting": summary.get("learner_waiting_seconds"),
    }
    if split is not None:
        out["early"] = avg([r for r in chosen if r["index"] < split])
        out["late"] = avg([r for r in chosen if r["index"] >= split])
        out["gap"] = out["late"] - out["early"]
    return out


def signed_sd(v):
    return mean_sd(v, sign="+")


def p_value(p):
    return f"{p:.2f}" if p >= 0.01 else f"{p:.2g}"


def column_tables(out, only, columns, runs, n_init, split, baseline, order):
    """The tables `runs`, `methods` and `paired` (only when --tables names them), their rows in
    the order of --methods when it is given."""
    if order:
        runs = {m: runs[m] for m in order if m in runs}
    last = max((r["index"] for seeds in runs.values() for _, rows, _ in seeds.values() for r in rows), default=0)
    head = {
        "method": "method", "seed": "seed", "seeds": "seeds", "designs": "designs", "best": "best",
        "chosen": "mean best of chosen designs", "exploit": "of exploitation designs",
        "explore": "of exploration designs", "initial": "initial designs' best", "rollouts": "design rollouts",
        "next": "exploit - next explore (wins)", "both": "exploit - mean of neighbouring explores (wins)",
        "faces": "exploitation designs on a face / corner", "bound": "coordinates on a bound",
        "near": "coordinates within 2 % of a bound",
        "early": f"chosen designs {n_init}-{split - 1 if split else '?'}",
        "late": f"chosen designs {split}-{last}" if split else "chosen designs later",
        "gap": "later - earlier", "search": "design search per exploitation design (s)",
    }
    if any(c in columns for c in ("early", "late", "gap")) and split is None:
        sys.exit("campaign_report: columns early, late and gap need --split K")
    data = {m: {s: facts(env, rows, summary, n_init, split) for s, (env, rows, summary) in sorted(seeds.items())}
            for m, seeds in runs.items()}
    one = lambda x: "-" if math.isnan(x) else f"{x:.1f}"
    wins = lambda d: f"{sum(x > 0 for x in d)}/{len(d)}"

    def run_cell(c, method, seed, f):
        if c == "method":
            return method
        if c == "seed":
            return str(seed)
        if c in ("best", "chosen", "exploit", "explore", "early", "late"):
            return one(f[c])
        if c == "gap":
            return f"{f[c]:+.1f}"
        if c == "designs":
            return str(f["designs"])
        if c == "initial":
            return ", ".join(f"{x:.0f}" for x in f["initial"])
        if c == "rollouts":
            return f"{f['rollouts']:,}"
        if c in ("next", "both"):
            return f"{signed_sd(f[c])} ({wins(f[c])})" if f[c] else "-"
        if c == "faces":
            return f"{f['face']} of {f['n_exploit']} / {f['corner']}"
        if c in ("bound", "near"):
            return f"{f['on' if c == 'bound' else 'near']}/{f['coords']}" if f["coords"] else "-"
        if c == "search":
            return f"{f['waiting'] / f['n_exploit']:.0f}" if f["waiting"] is not None and f["n_exploit"] else "-"
        sys.exit(f"campaign_report: column {c} is not one of the runs table's ({', '.join(COLUMNS['runs'])})")

    def method_cell(c, method, fs):
        if c == "method":
            return method
        if c == "seeds":
            return str(len(fs))
        if c in ("best", "chosen", "exploit", "explore", "early", "late"):
            return mean_sd([f[c] for f in fs])
        if c == "gap":
            return signed_sd([f[c] for f in fs])
        if c == "rollouts":
            return f"{statistics.mean(f['rollouts'] for f in fs):,.0f}"
        if c in ("next", "both"):
            d = [x for f in fs for x in f[c]]
            return f"{signed_sd(d)} ({wins(d)}, p = {p_value(sign_test(d))})" if d else "-"
        if c == "faces":
            return f"{sum(f['face'] for f in fs)} of {sum(f['n_exploit'] for f in fs)} / {sum(f['corner'] for f in fs)}"
        if c in ("bound", "near"):
            n = sum(f["coords"] for f in fs)
            return f"{sum(f['on' if c == 'bound' else 'near'] for f in fs)}/{n}" if n else "-"
        if c == "search":
            w = [f for f in fs if f["waiting"] is not None]
            n = sum(f["n_exploit"] for f in w)
            return f"{sum(f['waiting'] for f in w) / n:.0f}" if n else "-"
        sys.exit(f"campaign_report: column {c} is not one of the methods table's ({', '.join(COLUMNS['methods'])})")

    def paired_cell(c, method, pairs):
        if c == "method":
            return method
        if c == "seeds":
            return str(len(pairs))
        if c in ("best", "chosen", "exploit", "explore", "early", "late", "gap"):
            d = [a[c] - b[c] for _, a, b in pairs]
            if any(math.isnan(x) for x in d):
                return "-"
            return f"{signed_sd(d)} ({', '.join(f'{x:+.1f}' for x in d)})" if len(d) > 1 else signed_sd(d)
        sys.exit(f"campaign_report: column {c} is not one of the paired table's ({', '.join(COLUMNS['paired'])})")

    def header(cols, rename=None):
        names = [head[c] for c in cols]
        if rename:
            names = [rename.get(c, n) for c, n in zip(cols, names)]
        out("| " + " | ".join(names) + " |")
        out("|" + "---|" * len(cols))

    for name in only:
        bad = [c for c in columns if name in COLUMNS and c not in COLUMNS[name]]
        if bad:
            sys.exit(f"campaign_report: the {name} table has no column {', '.join(bad)} (its columns: {', '.join(COLUMNS[name])})")
    for name in only:
        if name not in ("runs", "methods", "paired"):
            continue
        out.section(name, "")
        if name == "runs":
            header(columns)
            for method, seeds in data.items():
                for seed, f in seeds.items():
                    out("| " + " | ".join(run_cell(c, method, seed, f) for c in columns) + " |")
        elif name == "methods":
            header(columns)
            for method, seeds in data.items():
                out("| " + " | ".join(method_cell(c, method, list(seeds.values())) for c in columns) + " |")
        else:
            if baseline not in data:
                sys.exit(f"campaign_report: paired: no runs of the baseline {baseline}")
            header(columns, {"seeds": "seeds paired", "gap": "change of the gap (later - earlier)"})
            for method, seeds in data.items():
                if method == baseline:
                    continue
                pairs = [(s, f, data[baseline][s]) for s, f in seeds.items() if s in data[baseline]]
                if pairs:
                    out("| " + " | ".join(paired_cell(c, method, pairs) for c in columns) + " |")


def main():
    valued = {"--initial", "--methods", "--baseline", "--split", "--tables", "--columns"}
    args = [a for i, a in enumerate(sys.argv[1:], 1) if not a.startswith("--") and sys.argv[i - 1] not in valued]
    root = args[0] if args else "runs/campaign"
    partial = "--partial" in sys.argv
    n_init = int(option("--initial", 5))
    keep = option("--methods", None)
    keep = set(keep.split(",")) if keep else None
    baseline = option("--baseline", "random-only")
    split = option("--split", None)
    split = int(split) if split is not None else None
    only = option("--tables", None)
    if only is not None:
        only = only.split(",")
        bad = [t for t in only if t not in TABLES]
        if bad:
            sys.exit(f"campaign_report: --tables: unknown table {', '.join(bad)} (known: {', '.join(TABLES)})")
    columns = option("--columns", None)
    columns = columns.split(",") if columns else None
    if only is not None and any(t in ("runs", "methods", "paired") for t in only) and not columns:
        sys.exit("campaign_report: the tables runs, methods and paired need --columns")
    out = Out(only)
    runs = {}
    summaries = {}
    for method, seed, path in run_dirs(root, "designs.csv", keep, partial):
        env, rows = read_run(path)
        if not rows:
            continue
        runs.setdefault(method, {})[seed] = (env, rows)
        summary = os.path.join(path, "summary.json")
        summaries[(method, seed)] = json.load(open(summary)) if os.path.exists(summary) else {}

    if only is not None and any(t in ("runs", "methods", "paired") for t in only):
        column_tables(out, only, columns,
                      {m: {s: (env, rows, summaries[(m, s)]) for s, (env, rows) in seeds.items()} for m, seeds in runs.items()},
                      n_init, split, baseline, option("--methods", "").split(",") if keep else None)
        if all(t in ("runs", "methods", "paired") for t in only):
            return

    def metrics(rows):
        chosen = [r for r in rows if r["index"] >= n_init]
        exploit = [r for r in chosen if r["kind"] == "exploit"]
        return {
            "best": max(r["best"] for r in rows),
            "chosen": statistics.mean(r["best"] for r in chosen) if chosen else float("nan"),
            "exploit": statistics.mean(r["best"] for r in exploit) if exploit else float("nan"),
            "rollouts": sum(r["rollouts"] for r in rows),
            "designs": len(rows),
        }

    out.section("per-run", "### Per run")
    out("| method | seed | designs | best | mean best of chosen designs | mean best of exploitation designs | design rollouts |")
    out("|---|---|---|---|---|---|---|")
    per_method = {}
    for method, seeds in runs.items():
        for seed, (env, rows) in sorted(seeds.items()):
            mt = metrics(rows)
            per_method.setdefault(method, []).append((seed, mt))
            out(f"| {method} | {seed} | {mt['designs']} | {mt['best']:.1f} | {mt['chosen']:.1f} | {mt['exploit']:.1f} | {mt['rollouts']:,} |")

    out.section("per-method", "### Per method (mean ± sample standard deviation over seeds)")
    out("| method | seeds | best | mean best of chosen designs | mean best of exploitation designs | design rollouts per run |")
    out("|---|---|---|---|---|---|")
    for method, ms in per_method.items():
        col = lambda k: [m[k] for _, m in ms]
        out(f"| {method} | {len(ms)} | {mean_sd(col('best'))} | {mean_sd(col('chosen'))} | {mean_sd(col('exploit'))} | {statistics.mean(col('rollouts')):,.0f} |")

    if baseline in per_method:
        base = dict(per_method[baseline])
        out.section("between", f"### Between runs: each method minus {baseline}, paired by seed")
        out("| method | seeds paired | best | mean best of chosen designs |")
        out("|---|---|---|---|")
        for method, ms in per_method.items():
            if method == baseline:
                continue
            pairs = [(m, base[s]) for s, m in ms if s in base]
            if not pairs:
                continue
            d_best = [a["best"] - b["best"] for a, b in pairs]
            d_chosen = [a["chosen"] - b["chosen"] for a, b in pairs]
            out(f"| {method} | {len(pairs)} | {mean_sd(d_best)} | {mean_sd(d_chosen)} |")

    if split is not None:
        out.section("split", f"### Mean best return of chosen designs, indices {n_init}-{split - 1} and {split} on")
        out(f"| method | seed | {n_init}-{split - 1} | {split} on | later - earlier |")
        out("|---|---|---|---|---|")
        halves = {}
        for method, seeds in runs.items():
            for seed, (env, rows) in sorted(seeds.items()):
                a = [r["best"] for r in rows if n_init <= r["index"] < split]
                b = [r["best"] for r in rows if r["index"] >= split]
                if not a or not b:
                    continue
                halves.setdefault(method, {})[seed] = (statistics.mean(a), statistics.mean(b))
                out(f"| {method} | {seed} | {statistics.mean(a):.1f} | {statistics.mean(b):.1f} | {statistics.mean(b) - statistics.mean(a):+.1f} |")
        if baseline in halves:
            out.section("split-paired", f"Minus {baseline}, paired by seed (mean ± sd over seeds):")
            out(f"| method | seeds paired | {n_init}-{split - 1} | {split} on |")
            out("|---|---|---|---|")
            for method, hs in halves.items():
                if method == baseline:
                    continue
                pairs = [(h, halves[baseline][s]) for s, h in hs.items() if s in halves[baseline]]
                if pairs:
                    out(f"| {method} | {len(pairs)} | {mean_sd([h[0] - b[0] for h, b in pairs])} | {mean_sd([h[1] - b[1] for h, b in pairs])} |")

    out.section("within", "### Within runs: exploitation design minus exploration designs (best evaluation return)")
    out("| method | pairs | exploit - next explore: mean ± sd | exploit wins | sign test p | exploit - mean of neighbouring explores: mean ± sd | exploit wins | sign test p |")
    out("|---|---|---|---|---|---|---|---|")
    for method, seeds in runs.items():
        d_next, d_both = [], []
        for seed, (env, rows) in seeds.items():
            by_index = {r["index"]: r for r in rows}
            for r in rows:
                if r["index"] < n_init or r["kind"] != "exploit":
                    continue
                nxt = by_index.get(r["index"] + 1)
                prv = by_index.get(r["index"] - 1)
                if nxt and nxt["kind"] == "explore":
                    d_next.append(r["best"] - nxt["best"])
                    if prv and prv["kind"] == "explore":
                        d_both.append(r["best"] - (nxt["best"] + prv["best"]) / 2)
        if not d_next:
            continue
        wins = lambda d: f"{sum(x > 0 for x in d)}/{len(d)}"
        out(f"| {method} | {len(d_next)} | {mean_sd(d_next)} | {wins(d_next)} | {sign_test(d_next):.2f} | "
              f"{mean_sd(d_both) if d_both else '-'} | {wins(d_both) if d_both else '-'} | {sign_test(d_both) if d_both else float('nan'):.2f} |")

    out.section("faces", "### Where the exploitation designs sit (face: a coordinate within 0.1 % of the box's width of a bound; corner: every coordinate; near: within 2 %)")
    out("| method | exploitation designs | on a face | on a corner | coordinates on a bound | coordinates near a bound |")
    out("|---|---|---|---|---|---|")
    for method, seeds in runs.items():
        n = face = corner = coords = near = total = 0
        for seed, (env, rows) in seeds.items():
            low, high = BOUNDS.get(env, (None, None))
            if low is None:
                continue
            for r in rows:
                if r["index"] < n_init or r["kind"] != "exploit":
                    continue
                f, c = on_face(r["design"], low, high)
                n += 1
                face += f
                corner += c
                coords += sum(min(abs(x - lo), abs(x - hi)) <= 1e-3 * (hi - lo) for x, lo, hi in zip(r["design"], low, high))
                near += sum(min(abs(x - lo), abs(x - hi)) <= 2e-2 * (hi - lo) for x, lo, hi in zip(r["design"], low, high))
                total += len(r["design"])
        if n:
            out(f"| {method} | {n} | {face} | {corner} | {coords}/{total} | {near}/{total} |")


if __name__ == "__main__":
    main()
