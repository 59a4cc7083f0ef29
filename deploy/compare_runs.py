#!/usr/bin/env python3
"""Lock-step is deterministic: a run disturbed by faults (killed nodes, requeues, partitions,
deleted pods) must write the same rows as the same config run once, undisturbed, in one process,
but for the wall clock, which actor ran an episode, and its policy lag. Shared by the fault
tests (deploy/netns/multi-host-test.sh, deploy/slurm/slurm-test.sh, deploy/k8s/podman-test.sh).

    python3 deploy/compare_runs.py RUN_DIR UNDISTURBED_DIR [DESIGNS]

Prints one line per file to stderr; exit 0 when every row is equal (and designs.csv has DESIGNS
rows when given), 1 otherwise.
"""
import csv
import sys


def rows(d, name, drop):
    with open(f"{d}/{name}", newline="") as f:
        return [{k: v for k, v in r.items() if k not in drop} for r in csv.DictReader(f)]


def main():
    run, undisturbed = sys.argv[1], sys.argv[2]
    bad = 0
    for name, drop in (("designs.csv", ()), ("episodes.csv", ("seconds", "actor", "policy_lag"))):
        a, b = rows(run, name, drop), rows(undisturbed, name, drop)
        if a != b:
            bad += 1
            first = next((i for i, (x, y) in enumerate(zip(a, b)) if x != y), min(len(a), len(b)))
            print(f"  {name}: {len(a)} rows against {len(b)}; first difference at row {first}:"
                  f" {a[first] if first < len(a) else None} vs {b[first] if first < len(b) else None}", file=sys.stderr)
        else:
            print(f"  {name}: {len(a)} rows, equal to the undisturbed run's", file=sys.stderr)
    if len(sys.argv) > 3 and len(rows(run, "designs.csv", ())) != int(sys.argv[3]):
        bad += 1
        print(f"  designs.csv does not have the {sys.argv[3]} designs asked for", file=sys.stderr)
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
