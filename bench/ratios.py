"""Ratios of coadapt's figures to the PyTorch peers' from one JSON-lines file (>1: coadapt is faster).

usage: python3 bench/ratios.py runs/bench-nn-*.jsonl
"""
import json
import sys

# (bench, our config, peer config, unit, higher is better)
PAIRS = [
    ("sac_update", "3x256-obs17", "3x256-obs17", "updates/s", True),
    ("sac_update", "3x200-obs23", "3x200-obs23", "updates/s", True),
    ("sac_update", "2x256-obs17", "2x256-obs17", "updates/s", True),
    ("forward_actor_critic", "22400rows", "22400rows-chunk1024", "s/pass", False),
    ("forward_actor_critic", "22400rows", "22400rows-batched", "s/pass", False),
    ("forward_actor_critic", "179200rows", "179200rows-chunk1024", "s/pass", False),
    ("env_steps", "half-cheetah", "half-cheetah", "steps/s", True),
    ("pso_over_q", "700x250x32", "700x250x32", "s", False),
    ("pso_over_q", "700x250x256", "700x250x256", "s", False),
]


def main(path):
    # A figure measured twice (before and after the peer) counts as the mean of both runs.
    runs = {}
    with open(path) as f:
        for line in f:
            line = line.strip()
            if line.startswith("{"):
                r = json.loads(line)
                runs.setdefault((r.get("impl"), r["bench"], r["config"], r["unit"]), []).append(r["value"])
    figures = {k: sum(v) / len(v) for k, v in runs.items()}
    for bench, ours_cfg, peer_cfg, unit, higher in PAIRS:
        ours = figures.get(("coadapt", bench, ours_cfg, unit))
        peer = figures.get(("pytorch", bench, peer_cfg, unit)) or figures.get(("mujoco", bench, peer_cfg, unit))
        if ours is None or peer is None:
            continue
        ratio = ours / peer if higher else peer / ours
        print(json.dumps({"bench": f"{bench}_ratio", "config": f"{ours_cfg} vs peer {peer_cfg}",
                          "value": round(ratio, 3), "unit": "x faster", "coadapt": ours, "peer": peer}))


if __name__ == "__main__":
    main(sys.argv[1])
