"""What the report scripts (campaign_report.py, calibration_report.py) share: the run directories
of a campaign archive (RUNS_ROOT/METHOD-seedN holding a given file) and their flag parsing."""
import os
import re
import sys


def flag_value(name, default, prog):
    """The value after `name` on the command line, `default` without the flag; exits naming
    `prog` when the flag ends the line."""
    if name not in sys.argv:
        return default
    i = sys.argv.index(name)
    if i + 1 >= len(sys.argv):
        sys.exit(f"{prog}: {name} needs a value")
    return sys.argv[i + 1]


def run_dirs(root, needs, keep=None, partial=False):
    """Yields (method, seed, path) for every METHOD-seedN directory under `root` (sorted by name)
    that holds `needs`, whose method is in `keep` (all when None), and that finished (holds
    summary.json) unless `partial`."""
    for name in sorted(os.listdir(root)):
        m = re.fullmatch(r"(.+)-seed(\d+)", name)
        path = os.path.join(root, name)
        if not m or not os.path.exists(os.path.join(path, needs)):
            continue
        if keep is not None and m.group(1) not in keep:
            continue
        if not partial and not os.path.exists(os.path.join(path, "summary.json")):
            continue
        yield m.group(1), int(m.group(2)), path
