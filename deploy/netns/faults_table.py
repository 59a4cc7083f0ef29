"""The table of deploy/netns/faults-bench.sh's JSON lines: per fault, the run's wall time, the
learner's waiting time and the experience throughput, median and sample sd over the runs (n)."""

import json
import statistics
import sys

by = {}
for line in open(sys.argv[1]):
    r = json.loads(line)
    by.setdefault(r["config"], []).append(r)
print("| faults | n | wall s | learner waiting s | transitions/s | episodes reissued |")
print("|---|---|---|---|---|---|")
for config, rs in by.items():
    def cell(key):
        v = [r[key] for r in rs]
        sd = statistics.stdev(v) if len(v) > 1 else 0.0
        return f"{statistics.median(v):.1f} ± {sd:.1f}"
    print(f"| {config} | {len(rs)} | {cell('seconds')} | {cell('learner_waiting_seconds')} | {cell('transitions_per_second')} |"
          f" {', '.join(str(r['episodes_reissued']) for r in rs)} |")
