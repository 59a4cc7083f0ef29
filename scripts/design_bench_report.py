"""The design-choice benchmark, per robot (issue 28 section 2): does a method's chosen body beat a
random one?

usage: python3 scripts/design_bench_report.py [RUNS_ROOT, default docs/campaign/results]
           [--robots hc,walker-bench,...] [--tables methods,random,within,trend,bodies,calibration,verdict,everywhere,brief,edges,samebody]

Runs are RUNS_ROOT/PREFIX-METHOD-seedN (docs/campaign/design-bench.queue and
design-choice.queue): PREFIX names the robot (hc = HalfCheetah, walker-bench, hopper-bench,
daisy-bench, mujoco-bench), METHOD is fear, random, sim-pso or a method of section 3; the
retrained bodies are PREFIX-fear-body and PREFIX-random-body. Only finished runs (summary.json)
count. Per robot:

1. methods: per method, mean ± sample sd over seeds (n stated) of the quality of the chosen
   designs (the mean best evaluation return of the exploitation designs), of the best design
   found, the exploitation coordinates within 2 % of a bound, design rollouts and the learner's
   wall time (all starts of a resumed run; a fork's includes the designs it shares with its
   source; runs shared the machine's two cores with one to three others, so times are rough);
2. random: each method minus random designs only, paired by seed, with the exact two-sided
   sign-flip (permutation) test of the mean difference;
3. within: pooled over seeds, each exploitation design minus the exploration (random) design
   trained right after it in the same run: mean ± sd, wins, exact sign-flip test;
4. trend: the within table's pairs with the time trend removed. The random design of a pair
   trains one design later than the chosen one, from population networks that have seen one
   more body. (a) The random-designs run of the same seed (forked at the same design) gives that
   advantage at the same slots (its later minus its earlier random design), which is added back
   to each pair: mean ± sd of the trend and of the adjusted difference, wins, exact sign-flip;
   (b) each chosen design against the mean of the random designs just before and after it, in
   which a trend linear in time cancels: mean ± sd, wins, exact sign-flip;
5. bodies: the run's best exploitation design and its best random design, each trained from
   scratch with plain SAC (2 training seeds): the mean return of the last 10 episodes, and
   the difference paired by run seed and training seed, with the exact sign-flip test;
6. calibration: scripts/calibration_report.py over the robot's methods;
7. verdict (after the robots, with --tables verdict): section 3's rule, that a method becomes
   the default only if it beats FEAR on at least 3 of the 4 robots (HalfCheetah, Walker, Hopper,
   Daisy) without losing on HalfCheetah: per method and robot the quality of the chosen designs
   minus FEAR's, paired by seed (mean ± sd, n, exact sign-flip p); a robot counts only with 3
   paired seeds or more; the verdict is yes, no, or open (naming what is missing);
8. everywhere (after the robots, with --tables everywhere): the issue's bar for a design choice,
   that its chosen designs beat random designs on every robot, paired and pooled over seeds:
   per method and robot, each exploitation design minus the random design trained right after
   it in the same run (the within table; the random body trains one design later, so the test
   leans against the method), pooled over the robot's seeds, with the exact sign-flip p. A
   robot is decided at the grid's seeds (HalfCheetah 5, the others 3): shown when the mean is
   above 0 and p <= 0.05. The answer is yes (all five shown), no (naming the robots decided and
   not shown) or open (naming the seeds missing);
8b. brief (with --tables brief): table 8 in a line per method, for the README: per robot
   "beats", "not shown", "loses" (below the random body after it, p <= 0.05) or "open" (fewer
   seeds than the grid's), the pooled pairs' mean ± sd, n (pairs), p and the seeds;
9. dial (not in the default tables): FEAR, the screened variants (`screened`, `screened-MxR`) and
   the simulation baselines ordered by the simulation they spend on choosing designs: design
   rollouts and simulated steps per run (rollouts x the screen's steps, or x 1,000 for whole
   episodes: an upper bound where an episode can end early), against the quality of the chosen
   designs and its difference from random designs, paired by seed (section 3's dial);
10. edges (not in the default tables): per robot, every within-run pair (table 3's), pooled
   over methods and seeds, grouped by how many coordinates of the chosen design sit within 2 %
   of a bound (0, 1, 2, 3 or more): pairs (and methods), mean ± sd, wins, exact sign-flip p.
   Are the bodies at the box's edges, where a critic trained on few bodies extrapolates, worse?
11. samebody (after the robots, with --tables samebody): the same random body in two runs. The
   random-designs run, forked from FEAR's at its first chosen design, draws its random bodies
   from the same stream as FEAR's exploration designs, so FEAR's run trains some of the very
   bodies the random run trains, in another history: after FEAR's chosen bodies, and a few
   slots later. Per robot, pooled over seeds, each such body's best evaluation return in FEAR's
   run minus in the random run (mean ± sd, bodies higher in FEAR's run, exact sign-flip p), how
   many slots later FEAR's run trained it, the random run's own trend (the least-squares slope of
   its designs' best returns over the slots after the fork, per seed) and the difference with
   that trend times the slots removed. What it measures: how much of the gap between FEAR's
   chosen designs and a random-designs run comes with the controller a run's history trained,
   not with the bodies (the retrained bodies of table 5 take the controller out altogether).

Pure Python (no numpy), so it runs with the system python3.
"""
import csv
import itertools
import json
import math
import os
import random
import statistics
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import campaign_report as cr  # noqa: E402

ROBOTS = [("HalfCheetah", "hc"), ("Walker", "walker-bench"), ("Hopper", "hopper-bench"), ("Daisy", "daisy-bench"),
          ("MuJoCo HalfCheetah (bridge)", "mujoco-bench")]
# Methods in this order; others after them, by name.
ORDER = ["fear", "random", "sim-pso", "cmaes-es", "openai-es", "pessimistic", "trust", "screened", "ensemble", "conservative", "conshead", "headonly"]


def option(name, default):
    return sys.argv[sys.argv.index(name) + 1] if name in sys.argv else default


def sign_flip(diffs):
    """Exact two-sided p of the sign-flip (paired permutation) test of mean(diffs) = 0: the share
    of the 2^n sign patterns whose |mean| is at least the observed one (Monte Carlo with 2^18
    draws and a fixed seed past n = 20). (p, exact?), or None without differences."""
    d = [x for x in diffs if not math.isnan(x)]
    n = len(d)
    if n == 0:
        return None
    obs = abs(sum(d)) - 1e-9 * max(1.0, max(abs(x) for x in d))
    if n <= 20:
        hits = sum(abs(sum(s * x for s, x in zip(signs, d))) >= obs for signs in itertools.product((1, -1), repeat=n))
        return hits / 2 ** n, True
    rng = random.Random(1)
    draws = 1 << 18
    hits = sum(abs(sum(x if rng.random() < 0.5 else -x for x in d)) >= obs for _ in range(draws))
    return hits / draws, False


def sign_flip_p(diffs):
    """sign_flip's p as the tables print it (Monte Carlo ones marked with ~), or -."""
    r = sign_flip(diffs)
    if r is None:
        return "-"
    return cr.p_value(r[0]) if r[1] else "~" + cr.p_value(r[0])


def runs_of(root, prefix):
    """{method: {seed: (facts, summary)}} of the finished co-adaptation runs of one robot."""
    out = {}
    if not os.path.isdir(root):
        return out
    for name in sorted(os.listdir(root)):
        if not name.startswith(prefix + "-") or "-seed" not in name:
            continue
        method, _, seed = name[len(prefix) + 1:].rpartition("-seed")
        path = os.path.join(root, name)
        if method.endswith("-body") or not seed.isdigit() or not os.path.exists(os.path.join(path, "summary.json")):
            continue
        if not os.path.exists(os.path.join(path, "designs.csv")):
            continue
        summary = json.load(open(os.path.join(path, "summary.json")))
        # The learner's wall clock over every start of the run (summary.json has the last
        # start's only): the seconds column of the last episode row.
        with open(os.path.join(path, "episodes.csv")) as f:
            last = None
            for last in csv.DictReader(f):
                pass
        summary = dict(summary, wall_seconds=float(last["seconds"]) if last and last.get("seconds") else float("nan"))
        env, rows = cr.read_run(path)
        n_init = sum(r["kind"] == "initial" for r in rows)
        f = dict(cr.facts(env, rows, summary, n_init, None), by_index={r["index"]: r for r in rows}, env=env)
        out.setdefault(method, {})[int(seed)] = (f, summary)
    return out


def bodies_of(root, prefix):
    """{which: {seed: [last-10 mean return per training seed]}} of the retrained bodies."""
    out = {}
    for which in ("fear", "random"):
        for name in sorted(os.listdir(root)) if os.path.isdir(root) else []:
            head = f"{prefix}-{which}-body-seed"
            if not name.startswith(head) or not name[len(head):].isdigit():
                continue
            path = os.path.join(root, name, "summary.json")
            if not os.path.exists(path):
                continue
            s = json.load(open(path))
            seeds = s.get("seeds", {})
            out.setdefault(which, {})[int(name[len(head):])] = [seeds[k]["last10_mean_return"] for k in sorted(seeds)]
    return out


def rollout_steps(run):
    """Steps of one design rollout of RUN: the screen's `steps` for a screened run (0: a whole
    episode), else a whole episode (1,000 steps on every robot here)."""
    import tomllib
    cfg = tomllib.load(open(os.path.join(run, "config.toml"), "rb"))
    opt = cfg.get("optimizer", {})
    if opt.get("exploit") == "screened":
        steps = opt.get("screen", {}).get("steps", 250)
        return steps if steps > 0 else 1000
    return 1000


def slot_pairs(f):
    """(i, exploit best - next explore best) for each exploitation design i of a run followed by
    an exploration design (the pairs of the within table)."""
    by = f["by_index"]
    return [(i, r["best"] - by[i + 1]["best"]) for i, r in sorted(by.items())
            if r["kind"] == "exploit" and i + 1 in by and by[i + 1]["kind"] == "explore"]


def trend(random_run, i):
    """The random-designs run's later minus earlier design at slots i + 1 and i: what training
    one design later is worth when both bodies are random (None if the run lacks the slots)."""
    by = random_run["by_index"]
    return by[i + 1]["best"] - by[i]["best"] if i in by and i + 1 in by else None


def ordered(methods):
    return [m for m in ORDER if m in methods] + sorted(m for m in methods if m not in ORDER)


def report(root, title, prefix, tables):
    runs = runs_of(root, prefix)
    bodies = bodies_of(root, prefix)
    if not runs and not bodies:
        return False
    print(f"#### {title} (`{prefix}-*`)\n")
    methods = ordered(runs)
    if "methods" in tables and runs:
        print("| method | seeds | quality of chosen designs | best design found | exploitation coordinates within 2 % of a bound | design rollouts per run | wall hours per run |")
        print("|---|---|---|---|---|---|---|")
        for m in methods:
            fs = [f for f, _ in runs[m].values()]
            near = sum(f["near"] for f in fs)
            coords = sum(f["coords"] for f in fs)
            hours = [s["wall_seconds"] / 3600 for _, s in runs[m].values()]
            hours_cell = f"{statistics.mean(hours):.2f} ± {statistics.stdev(hours):.2f}" if len(hours) > 1 else f"{hours[0]:.2f}"
            print(f"| {m} | {len(fs)} | {cr.mean_sd([f['exploit'] for f in fs])} | {cr.mean_sd([f['best'] for f in fs])} | "
                  f"{near}/{coords} | {statistics.mean(f['rollouts'] for f in fs):.0f} | {hours_cell} |")
        print()
    if "random" in tables and "random" in runs:
        print("| method minus random designs, paired by seed | seeds | quality of chosen designs | p | best design found | p |")
        print("|---|---|---|---|---|---|")
        for m in methods:
            if m == "random":
                continue
            seeds = sorted(set(runs[m]) & set(runs["random"]))
            q = [runs[m][s][0]["exploit"] - runs["random"][s][0]["exploit"] for s in seeds]
            b = [runs[m][s][0]["best"] - runs["random"][s][0]["best"] for s in seeds]
            print(f"| {m} | {len(seeds)} | {cr.signed_sd(q)} | {sign_flip_p(q)} | {cr.signed_sd(b)} | {sign_flip_p(b)} |")
        print()
    if "within" in tables and runs:
        print("| method: exploitation design minus the random design after it, pooled over seeds | seeds | pairs | mean ± sd | exploit wins | p |")
        print("|---|---|---|---|---|---|")
        for m in methods:
            d = [x for f, _ in runs[m].values() for x in f["next"]]
            if d:
                print(f"| {m} | {len(runs[m])} | {len(d)} | {cr.signed_sd(d)} | {sum(x > 0 for x in d)}/{len(d)} | {sign_flip_p(d)} |")
        print()
    if "trend" in tables and runs:
        # The within table sets each chosen design against the random design trained *after*
        # it, with one more design's experience in the population networks it starts from. Two
        # ways to take that out: (a) the random-designs run (forked from the same run at the same
        # design) measures the advantage at the same slots, where both bodies are random; adding
        # it back to each within-run difference, paired by seed and slot, removes it; (b) the
        # chosen design against the mean of the random designs just before and just after it,
        # in which a trend linear in time cancels (no other run needed; the first chosen design,
        # after the initial ones, has no random design before it and drops out).
        print("| method: within-run differences with the time trend removed, pooled over seeds | seeds | "
              "trend: random run's later minus earlier design at the same slots (pairs) | exploit minus next random + trend | wins | p | "
              "exploit minus the mean of the random designs before and after it (designs) | wins | p |")
        print("|---|---|---|---|---|---|---|---|---|")
        for m in methods:
            if m == "random":
                continue
            t, adj = [], []
            for seed, (f, _) in sorted(runs[m].items()):
                if seed not in runs.get("random", {}):
                    continue
                for i, d in slot_pairs(f):
                    x = trend(runs["random"][seed][0], i)
                    if x is not None:
                        t.append(x)
                        adj.append(d + x)
            both = [x for f, _ in runs[m].values() for x in f["both"]]
            if not adj and not both:
                continue
            a = (f"{cr.signed_sd(t)} ({len(t)}) | {cr.signed_sd(adj)} | {sum(x > 0 for x in adj)}/{len(adj)} | {sign_flip_p(adj)}"
                 if adj else "- | - | - | -")
            b = f"{cr.signed_sd(both)} ({len(both)}) | {sum(x > 0 for x in both)}/{len(both)} | {sign_flip_p(both)}" if both else "- | - | -"
            # The trend needs the random-designs run of the same seed; say when it had fewer.
            paired = sum(seed in runs.get("random", {}) for seed in runs[m])
            n = f"{len(runs[m])}" if paired == len(runs[m]) else f"{len(runs[m])} (trend: {paired})"
            print(f"| {m} | {n} | {a} | {b} |")
        print()
    if "bodies" in tables and bodies:
        print("| body, trained from scratch with plain SAC | run seeds | training runs | last-10-episode return |")
        print("|---|---|---|---|")
        for which in ("fear", "random"):
            v = [x for r in bodies.get(which, {}).values() for x in r]
            print(f"| {which} (best {'exploitation' if which == 'fear' else 'random'} design) | {len(bodies.get(which, {}))} | {len(v)} | {cr.mean_sd(v)} |")
        seeds = sorted(set(bodies.get("fear", {})) & set(bodies.get("random", {})))
        d = [a - b for s in seeds for a, b in zip(bodies["fear"][s], bodies["random"][s])]
        if d:
            print(f"| FEAR's body minus the random one, paired by run and training seed | {len(seeds)} | {len(d)} | {cr.signed_sd(d)} (p {sign_flip_p(d)}) |")
        print()
    if "dial" in tables and runs:
        dial = [m for m in methods if m == "fear" or m.startswith("screened") or m.startswith("sim-")]
        if dial:
            print("| method | seeds | design rollouts per run | simulated steps per run (thousands, at most) | quality of chosen designs | minus random designs, paired |")
            print("|---|---|---|---|---|---|")
            rows = []
            for m in dial:
                steps = []
                for seed, (f, _) in runs[m].items():
                    steps.append(f["rollouts"] * rollout_steps(os.path.join(root, f"{prefix}-{m}-seed{seed}")))
                seeds = sorted(set(runs[m]) & set(runs.get("random", {})))
                d = [runs[m][x][0]["exploit"] - runs["random"][x][0]["exploit"] for x in seeds]
                rows.append((statistics.mean(steps), m, len(runs[m]), statistics.mean(f["rollouts"] for f, _ in runs[m].values()),
                             cr.mean_sd([f["exploit"] for f, _ in runs[m].values()]), f"{cr.signed_sd(d)} (n = {len(d)})" if d else "-"))
            for k, m, n, r, q, d in sorted(rows):
                print(f"| {m} | {n} | {r:.0f} | {k / 1000:.1f} | {q} | {d} |")
            print()
    if "calibration" in tables and runs:
        names = [f"{prefix}-{m}" for m in methods]
        here = os.path.dirname(os.path.abspath(__file__))
        r = subprocess.run([sys.executable, os.path.join(here, "calibration_report.py"), root, "--methods", ",".join(names),
                            "--tables", "pairs"], capture_output=True, text=True)
        if r.returncode == 0 and r.stdout.strip():
            print(r.stdout.rstrip() + "\n")
    return True


VERDICT_ROBOTS = ROBOTS[:4]
SEEDS_TO_DECIDE = 3


def verdict(root):
    """Section 3's rule over every method run beside FEAR (see the module doc, table 7)."""
    runs = {prefix: runs_of(root, prefix) for _, prefix in VERDICT_ROBOTS}
    methods = ordered({m for r in runs.values() for m in r if m not in ("fear", "random")})
    if not methods:
        return
    print("#### Section 3's rule: does a method beat FEAR on 3 of the 4 robots without losing on HalfCheetah?\n")
    print("| method | " + " | ".join(f"{t}: minus FEAR, paired by seed (n, p)" for t, _ in VERDICT_ROBOTS) + " | verdict |")
    print("|---|" + "---|" * len(VERDICT_ROBOTS) + "---|")
    for m in methods:
        cells, beats, loses, open_ = [], 0, 0, []
        hc_lost = hc_open = False
        for title, prefix in VERDICT_ROBOTS:
            r = runs[prefix]
            seeds = sorted(set(r.get(m, {})) & set(r.get("fear", {})))
            d = [r[m][x][0]["exploit"] - r["fear"][x][0]["exploit"] for x in seeds]
            cells.append(f"{cr.signed_sd(d)} ({len(d)}, {sign_flip_p(d)})" if d else "-")
            if len(d) < SEEDS_TO_DECIDE:
                open_.append(f"{title} {len(d)}/{SEEDS_TO_DECIDE}")
                hc_open |= prefix == "hc"
            elif statistics.mean(d) > 0:
                beats += 1
            else:
                loses += 1
                hc_lost |= prefix == "hc"
        if hc_lost or beats + len(open_) < 3:
            v = "no" + (" (loses on HalfCheetah)" if hc_lost else f" (beats FEAR on {beats} of {beats + loses} decided)")
        elif beats >= 3 and not hc_open:
            v = f"yes (beats FEAR on {beats})"
        else:
            v = "open: seeds " + ", ".join(open_)
        print(f"| {m} | " + " | ".join(cells) + f" | {v} |")
    print()


# The grid: HalfCheetah 5 seeds, the other robots 3.
GRID_SEEDS = {"hc": 5}
ALPHA = 0.05


def decided(r, prefix):
    """One robot's pooled within-run pairs of a method's runs R ({seed: (facts, summary)}) and
    the bar's state there: "open" (fewer seeds than the grid's), else "shown" (mean above 0,
    p <= 0.05), "loses" (mean below 0, p <= 0.05: the random body after it is shown better) or
    "not shown" (neither)."""
    d = [x for f, _ in r.values() for x in f["next"]]
    if len(r) < GRID_SEEDS.get(prefix, 3):
        return d, "open"
    # Decided on the p itself, not on its printed rounding.
    if not d or sign_flip(d)[0] > ALPHA:
        return d, "not shown"
    mean = statistics.mean(d)
    return d, "shown" if mean > 0 else "loses" if mean < 0 else "not shown"


def everywhere(root):
    """Does a method's chosen design beat the random one after it on every robot (table 8)?"""
    runs = {prefix: runs_of(root, prefix) for _, prefix in ROBOTS}
    methods = ordered({m for r in runs.values() for m in r if m != "random"})
    if not methods:
        return
    print("#### Do the chosen designs beat random designs on every robot? (pooled over seeds, p <= 0.05)\n")
    print("| method | " + " | ".join(f"{t}: chosen minus the random design after it (seeds, pairs, p)" for t, _ in ROBOTS) + " | beats random designs everywhere? |")
    print("|---|" + "---|" * len(ROBOTS) + "---|")
    for m in methods:
        cells, failed, open_ = [], [], []
        for title, prefix in ROBOTS:
            r = runs[prefix].get(m, {})
            d, state = decided(r, prefix)
            cells.append(f"{cr.signed_sd(d)} ({len(r)}, {len(d)}, {sign_flip_p(d)})" if d else "-")
            if state == "open":
                open_.append(f"{title} {len(r)}/{GRID_SEEDS.get(prefix, 3)}")
            elif state != "shown":
                failed.append(title)
        if failed:
            v = "no (not shown on " + ", ".join(failed) + ")"
        elif open_:
            v = "open: seeds " + ", ".join(open_)
        else:
            v = "yes"
        print(f"| {m} | " + " | ".join(cells) + f" | {v} |")
    print()


def brief(root):
    """Table 8 in brief, for the README: per method and robot whether its chosen designs beat
    the random design after them (pooled over seeds, p <= 0.05), with the seeds behind it."""
    runs = {prefix: runs_of(root, prefix) for _, prefix in ROBOTS}
    methods = ordered({m for r in runs.values() for m in r if m != "random"})
    if not methods:
        return
    names = {"MuJoCo HalfCheetah (bridge)": "MuJoCo cheetah"}
    print("| method | " + " | ".join(names.get(t, t) for t, _ in ROBOTS) + " |")
    print("|---|" + "---|" * len(ROBOTS))
    for m in methods:
        cells = []
        for _, prefix in ROBOTS:
            r = runs[prefix].get(m, {})
            d, state = decided(r, prefix)
            if not d:
                cells.append("-")
                continue
            word = "**beats**" if state == "shown" else state
            cells.append(f"{word}: {cr.signed_sd(d)}, n = {len(d)}, p {sign_flip_p(d)} ({len(r)}/{GRID_SEEDS.get(prefix, 3)} seeds)")
        print(f"| {m} | " + " | ".join(cells) + " |")
    print()


def slope(points):
    """Least-squares slope of y over x for [(x, y), ...] (None with fewer than two x values)."""
    if len({x for x, _ in points}) < 2:
        return None
    mx = statistics.mean(x for x, _ in points)
    my = statistics.mean(y for _, y in points)
    return sum((x - mx) * (y - my) for x, y in points) / sum((x - mx) ** 2 for x, _ in points)


def same_bodies(fear, rnd):
    """[(FEAR's slot, the random run's slot, FEAR's best minus the random run's best)] for every
    body trained both as an exploration design of FEAR's run and after the fork in the random run."""
    at = {tuple(r["design"]): i for i, r in fear["by_index"].items() if r["kind"] == "explore"}
    out = []
    for j, r in sorted(rnd["by_index"].items()):
        i = at.get(tuple(r["design"])) if r["kind"] != "initial" else None
        if i is not None:
            out.append((i, j, fear["by_index"][i]["best"] - r["best"]))
    return out


def samebody(root, robots):
    """Table 11: the same random body in FEAR's run and in the random-designs run."""
    rows, pooled, pooled_adj = [], [], []
    for title, prefix in robots:
        runs = runs_of(root, prefix)
        seeds = sorted(set(runs.get("fear", {})) & set(runs.get("random", {})))
        d, adj, later, trends = [], [], [], []
        for seed in seeds:
            fear, rnd = runs["fear"][seed][0], runs["random"][seed][0]
            pairs = same_bodies(fear, rnd)
            if not pairs:
                continue
            t = slope([(j, r["best"]) for j, r in rnd["by_index"].items() if r["kind"] != "initial"])
            trends.append(t)
            for i, j, x in pairs:
                d.append(x)
                later.append(i - j)
                if t is not None:
                    adj.append(x - t * (i - j))
        if d:
            rows.append((title, len(trends), d, later, trends, adj))
            pooled += d
            pooled_adj += adj
    if not rows:
        return
    print("#### The same random body in FEAR's run and in the random-designs run (pooled over seeds)\n")
    print("| robot | seeds | bodies | slots later in FEAR's run (mean) | FEAR's run minus the random run | higher in FEAR's run | p | "
          "random run's trend per slot (mean over seeds) | minus trend x slots later | higher | p |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for title, n, d, later, trends, adj in rows:
        t = [x for x in trends if x is not None]
        trend_cell = f"{statistics.mean(t):+.1f}" if t else "-"
        adj_cell = f"{cr.signed_sd(adj)} | {sum(x > 0 for x in adj)}/{len(adj)} | {sign_flip_p(adj)}" if adj else "- | - | -"
        print(f"| {title} | {n} | {len(d)} | {statistics.mean(later):.1f} | {cr.signed_sd(d)} | {sum(x > 0 for x in d)}/{len(d)} | "
              f"{sign_flip_p(d)} | {trend_cell} | {adj_cell} |")
    if len(rows) > 1:
        adj_cell = (f"{cr.signed_sd(pooled_adj)} | {sum(x > 0 for x in pooled_adj)}/{len(pooled_adj)} | {sign_flip_p(pooled_adj)}"
                    if pooled_adj else "- | - | -")
        print(f"| all robots | {sum(r[1] for r in rows)} | {len(pooled)} | {statistics.mean(x for r in rows for x in r[3]):.1f} | "
              f"{cr.signed_sd(pooled)} | {sum(x > 0 for x in pooled)}/{len(pooled)} | {sign_flip_p(pooled)} | - | {adj_cell} |")
    print()


def edges(root, title, prefix):
    """Table 10: are the bodies at the box's edges worse? Every within-run pair of the robot
    (each exploitation design minus the random design after it), pooled over methods and seeds,
    grouped by how many of the chosen design's coordinates sit within 2 % of a bound."""
    groups = {}
    for m, by_seed in runs_of(root, prefix).items():
        for f, _ in by_seed.values():
            low, high = cr.BOUNDS.get(f["env"], (None, None))
            if low is None:
                continue
            for i, d in slot_pairs(f):
                k = min(cr.near_bound(f["by_index"][i]["design"], low, high, 2e-2), 3)
                groups.setdefault(k, []).append((m, d))
    if not groups:
        return
    print(f"#### {title} (`{prefix}-*`): chosen bodies by how many coordinates sit at the box's edge\n")
    print("| coordinates of the chosen design within 2 % of a bound | pairs (methods) | chosen minus the random design after it | wins | p |")
    print("|---|---|---|---|---|")
    for k in sorted(groups):
        d = [x for _, x in groups[k]]
        label = "3 or more" if k == 3 else str(k)
        print(f"| {label} | {len(d)} ({len({m for m, _ in groups[k]})}) | {cr.signed_sd(d)} | "
              f"{sum(x > 0 for x in d)}/{len(d)} | {sign_flip_p(d)} |")
    print()


def main():
    args = [a for i, a in enumerate(sys.argv[1:], 1) if not a.startswith("--") and sys.argv[i - 1] not in {"--robots", "--tables"}]
    root = args[0] if args else "docs/campaign/results"
    keep = option("--robots", None)
    tables = option("--tables", "methods,random,within,trend,bodies,calibration").split(",")
    robots = [r for r in ROBOTS if keep is None or r[1] in keep.split(",")]
    per_robot = [t for t in tables if t not in ("verdict", "everywhere", "brief", "edges", "samebody")]
    if per_robot and not any([report(root, title, prefix, per_robot) for title, prefix in robots]):
        sys.exit(f"design_bench_report: no finished benchmark run under {root}")
    if "verdict" in tables:
        verdict(root)
    if "everywhere" in tables:
        everywhere(root)
    if "brief" in tables:
        brief(root)
    if "edges" in tables:
        for title, prefix in robots:
            edges(root, title, prefix)
    if "samebody" in tables:
        samebody(root, robots)


if __name__ == "__main__":
    main()
