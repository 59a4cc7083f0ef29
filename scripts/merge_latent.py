"""Joins `coadapt latent` runs of the same config made in pieces (a campaign continued with
later seeds under another name) into one run directory's episodes.csv, runs renumbered in
order; unfinished runs are left out (said on stderr). The pieces' seeds must follow each other
(seed, seed + 1, ...): a run is deterministic given its seed, so the joined file is the one a
single `--seed FIRST --runs N` would have written (apart from latency and times).

usage: python3 scripts/merge_latent.py OUT_DIR CONFIG_TOML SRC [SRC ...]
  SRC: a run directory (its episodes.csv) or an episodes CSV file
  CONFIG_TOML: the config of the joined run (written to OUT_DIR/config.toml as it is)
"""
import csv
import os
import shutil
import sys


def main():
    out, config, srcs = sys.argv[1], sys.argv[2], sys.argv[3:]
    header, runs = None, []
    for src in srcs:
        path = src if src.endswith(".csv") else os.path.join(src, "episodes.csv")
        with open(path) as f:
            reader = csv.reader(f)
            h = next(reader)
            if header is None:
                header = h
            elif h != header:
                sys.exit(f"{path}: another header than {srcs[0]}'s")
            by_run = {}
            for row in reader:
                by_run.setdefault(int(row[0]), []).append(row)
        runs += [by_run[k] for k in sorted(by_run)]
    n = max(len(r) for r in runs)
    kept = [r for r in runs if len(r) == n]
    if len(kept) < len(runs):
        print(f"{len(runs) - len(kept)} unfinished run(s) left out", file=sys.stderr)
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, "episodes.csv"), "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(header)
        for i, run in enumerate(kept):
            for row in run:
                w.writerow([str(i)] + row[1:])
    shutil.copy(config, os.path.join(out, "config.toml"))
    print(f"{out}: {len(kept)} runs x {n} episodes")


if __name__ == "__main__":
    main()
