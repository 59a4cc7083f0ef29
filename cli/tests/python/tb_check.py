"""Reads a run directory's TensorBoard event files with TensorBoard's own reader (its
EventAccumulator, as `tensorboard --logdir` does) and checks them against the run's CSV files.

usage: tb_check.py RUN_DIR [--partial] [--xi NAME,NAME,...]
       tb_check.py TRAIN_DIR --train      (a `coadapt train` directory: episode/* against its CSV)
       tb_check.py OUT --latent | --search (run-R/ event files against episodes.csv / iterations.csv)

- every tag of the README's TensorBoard section is there (--partial: the episode tags only, for a
  run killed before its first design ended);
- each scalar tag's steps strictly increase (a resumed run wrote no step twice);
- episode/return and episode/eval_return equal episodes.csv at step = global_episode, and (with
  --partial, a killed run) the events are a prefix of the CSV's rows, none missing before the
  last;
- design/* equal designs.csv at step = the design's index (designs that ended), the coordinates
  read from design/xi/NAME in the order --xi gives;
- run/config holds config.toml's text and run/landscape is a PNG of the size the event says.
Prints `tb_check: ok ...` and exits 0, or raises.
"""
import csv
import io
import math
import os
import sys

from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

run = sys.argv[1]
PER_RUN = {
    # coadapt latent: run-R/ per run, step = episode.
    "--latent": ("episodes.csv", "episode", {"episode/return": "train_return", "episode/eval_return": "eval_return",
                                             "episode/env_steps": "train_steps", "loss/model": "model_loss"}),
    # coadapt search: run-R/ per run, step = iteration (0: the start's cost).
    "--search": ("iterations.csv", "iteration", {"iteration/mean_policy_cost": "mean_policy_cost",
                                                 "iteration/best_return": "best_return", "iteration/mean_return": "mean_return",
                                                 "iteration/best_cost": "best_cost", "iteration/rollouts": "rollouts"}),
}
for flag, (name, step_col, tags) in PER_RUN.items():
    if flag not in sys.argv[2:]:
        continue
    rows = list(csv.DictReader(open(os.path.join(run, name))))
    runs = sorted({int(r["run"]) for r in rows})
    for k in runs:
        ea = EventAccumulator(os.path.join(run, f"run-{k}"), size_guidance={"scalars": 0})
        ea.Reload()
        mine = [r for r in rows if int(r["run"]) == k]
        for tag, col in tags.items():
            got = {e.step: e.value for e in ea.Scalars(tag)}
            want = {int(r[step_col]): float(r[col]) for r in mine}
            assert set(want) <= set(got), (k, tag, sorted(got), sorted(want))
            steps = [e.step for e in ea.Scalars(tag)]
            assert all(a < b for a, b in zip(steps, steps[1:])), (k, tag, steps)
            for st, v in want.items():
                assert math.isclose(got[st], v, rel_tol=1e-5, abs_tol=1e-5), (k, tag, st, got[st], v)
    print(f"tb_check: ok, {flag[2:]}, {len(runs)} runs, {len(rows)} rows")
    sys.exit(0)
if "--train" in sys.argv[2:]:
    # `coadapt train`: episode/* at step = the episode's number (1-based), equal to episodes.csv.
    ea = EventAccumulator(run, size_guidance={"scalars": 0})
    ea.Reload()
    have = set(ea.Tags()["scalars"])
    want = {"episode/return", "episode/length", "episode/mean_return_last_10", "episode/env_steps", "train/updates",
            "time/seconds", "loss/critic", "loss/policy"}
    assert want <= have, sorted(want - have)
    rows = list(csv.DictReader(open(os.path.join(run, "episodes.csv"))))
    for tag, col in [("episode/return", "return"), ("episode/length", "length"), ("episode/env_steps", "step"),
                     ("episode/mean_return_last_10", "mean_return_last_10")]:
        got = [(e.step, e.value) for e in ea.Scalars(tag)]
        assert [s for s, _ in got] == [int(r["episode"]) for r in rows], (tag, got)
        assert all(math.isclose(v, float(r[col]), rel_tol=1e-6, abs_tol=1e-6) for (_, v), r in zip(got, rows)), (tag, got)
    print(f"tb_check: ok, train, {len(rows)} episodes")
    sys.exit(0)
partial = "--partial" in sys.argv[2:]
xi_names = sys.argv[sys.argv.index("--xi") + 1].split(",") if "--xi" in sys.argv else []
ea = EventAccumulator(run, size_guidance={"scalars": 0, "images": 0, "tensors": 0})
ea.Reload()
tags = ea.Tags()
scalars = set(tags["scalars"])

episode_tags = {"episode/return", "episode/policy_lag", "episode/design", "episode/env_steps", "episode/eval_return",
                "train/alpha_individual", "train/alpha_population", "time/waiting_seconds", "time/training_seconds"}
trained_tags = {"loss/critic1", "loss/critic2", "loss/policy", "loss/alpha", "train/updates_per_second"}
design_tags = {"design/best_eval_return", "design/last_eval_return", "design/episodes", "design/design_rollouts"}
missing = episode_tags - scalars
assert not missing, f"missing scalar tags {sorted(missing)}; have {sorted(scalars)}"
if not partial:
    missing = (trained_tags | design_tags) - scalars
    assert not missing, f"missing scalar tags {sorted(missing)}; have {sorted(scalars)}"
    assert any(t.startswith("design/xi/") for t in scalars), sorted(scalars)
    assert "design/kind" in tags["tensors"] and "run/config" in tags["tensors"], tags["tensors"]
    assert "run/landscape" in tags["images"], tags["images"]

for t in scalars:
    steps = [e.step for e in ea.Scalars(t)]
    assert all(a < b for a, b in zip(steps, steps[1:])), f"{t}: steps not strictly increasing: {steps}"

rows = list(csv.DictReader(open(os.path.join(run, "episodes.csv"))))
by_step = {int(r["global_episode"]): r for r in rows}
ret = {e.step: e.value for e in ea.Scalars("episode/return")}
assert ret, "no episode/return"
if partial:
    # Killed: the CSV row is written (and flushed) before the row's events.
    want = sorted(by_step)[: len(ret)]
    assert sorted(ret) == want and len(by_step) - len(ret) in (0, 1), (sorted(ret), sorted(by_step))
else:
    assert sorted(ret) == sorted(by_step), (sorted(ret), sorted(by_step))
for step, v in ret.items():
    want = float(by_step[step]["return"])
    assert math.isclose(v, want, rel_tol=1e-6, abs_tol=1e-6), (step, v, want)
evals = {e.step: e.value for e in ea.Scalars("episode/eval_return")}
want_evals = {s: float(r["eval_return"]) for s, r in by_step.items() if r["eval_return"] and s in ret}
assert set(evals) == set(want_evals), (sorted(evals), sorted(want_evals))
for s, v in evals.items():
    assert math.isclose(v, want_evals[s], rel_tol=1e-6, abs_tol=1e-6), (s, v, want_evals[s])

designs = [r for r in csv.DictReader(open(os.path.join(run, "designs.csv"))) if r["prototype"] != "rejected"]
if "design/best_eval_return" in scalars:
    best = {e.step: e.value for e in ea.Scalars("design/best_eval_return")}
    for r in designs:
        i = int(r["index"])
        if i in best and r["best_eval_return"]:
            assert math.isclose(best[i], float(r["best_eval_return"]), rel_tol=1e-6), (i, best[i], r["best_eval_return"])
    if not partial:
        assert sorted(best) == [int(r["index"]) for r in designs], (sorted(best), [r["index"] for r in designs])
        have = sorted(t for t in scalars if t.startswith("design/xi/"))
        assert have == sorted(f"design/xi/{n}" for n in xi_names), (have, xi_names)
        xi = [{e.step: e.value for e in ea.Scalars(f"design/xi/{n}")} for n in xi_names]
        for r in designs:
            got = [x[int(r["index"])] for x in xi]
            want = [float(v) for v in r["design"].split(";")]
            assert all(math.isclose(a, b, rel_tol=1e-6) for a, b in zip(got, want)), (r["index"], got, want)

if not partial:
    text = ea.Tensors("run/config")[0].tensor_proto.string_val[0].decode()
    assert open(os.path.join(run, "config.toml")).read() in text, text[:200]
    kinds = {e.step: e.tensor_proto.string_val[0].decode() for e in ea.Tensors("design/kind")}
    for r in designs:
        assert kinds[int(r["index"])].startswith(r["kind"] + " ("), (r["index"], kinds)
    image = ea.Images("run/landscape")[-1]
    from PIL import Image
    png = Image.open(io.BytesIO(image.encoded_image_string))
    assert png.format == "PNG" and png.size == (image.width, image.height) and png.mode == "RGB", (png.format, png.size, png.mode)

print(f"tb_check: ok, {len(ret)} episodes, {len(scalars)} scalar tags, {len(designs)} designs")
