"""Ratios of coadapt's figures to the peers' from one JSON-lines file (>1: coadapt is faster).

Peers: PyTorch (`"impl": "pytorch"`), MuJoCo (`"mujoco"`), Python grpcio (`"grpcio"`), NumPy
(`"numpy"`). Each pair says whether its unit is higher-is-better (updates/s, MB/s) or
lower-is-better (s, ms), so the ratio is always ours-is-better-by.

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
    ("sim_seconds", "half-cheetah", "half-cheetah", "sim-s/s", True),
    ("pso_over_q", "700x250x32", "700x250x32", "s", False),
    ("pso_over_q", "700x250x256", "700x250x256", "s", False),
    ("groups_update", "r30-b15-d12-p11-t25-k6-i20-g4", "r30-b15-d12-p11-t25-k6-i20-g4", "ms", False),
]
PEERS = ("pytorch", "mujoco", "grpcio", "numpy")

# `coadapt bench transport` (benches below) is paired with bench/peers/transport_grpc.py by
# config, found in the file: our grpc-* configs against the same grpcio config, and (for
# context) our shm-* configs against the grpcio figure of the same shape. ms: lower is better;
# transitions/s and MB/s: higher is better.
TRANSPORT_BENCHES = ("weights_broadcast_median", "weights_broadcast_p99", "experience")
HIGHER_IS_BETTER = {"ms": False, "s": False, "s/pass": False}


def transport_pairs(figures):
    pairs = []
    for impl, bench, cfg, unit in figures:  # in the order they were printed
        if impl == "coadapt" and bench in TRANSPORT_BENCHES and cfg.startswith(("grpc-", "shm-")):
            peer_cfg = "grpc-" + cfg.split("-", 1)[1]
            pairs.append((bench, cfg, peer_cfg, unit, HIGHER_IS_BETTER.get(unit, True)))
    return sorted(pairs, key=lambda p: not p[1].startswith("grpc-"))  # grpc rows first, then shm


# `coadapt bench conv` (bench/src/conv.rs) is paired with bench/peers/conv_bench.py by config:
# ours against the same config (PyTorch with one thread, the matched figure) and, for context,
# against `<config>-threadsN` (PyTorch's default threads) when the file has it; ours in bf16
# (`<config>-bf16`) against PyTorch under bf16 autocast (the same config) and PyTorch in f32
# (`<config>`). ms: lower is better.
CONV_BENCHES = ("conv_forward", "conv_forward_backward")


def conv_pairs(figures):
    pairs = []
    for impl, bench, cfg, unit in figures:
        if impl == "coadapt" and bench in CONV_BENCHES:
            pairs.append((bench, cfg, cfg, unit, False))
            if cfg.endswith("-bf16"):  # ours in bf16 against PyTorch in f32 too (issue 34's bar)
                pairs.append((bench, cfg, cfg[: -len("-bf16")], unit, False))
            pairs += [(bench, cfg, pc, unit, False) for pi, pb, pc, pu in figures
                      if pi == "pytorch" and pb == bench and pu == unit and pc.startswith(cfg + "-threads")]
    return pairs


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
    for bench, ours_cfg, peer_cfg, unit, higher in PAIRS + transport_pairs(figures) + conv_pairs(figures):
        ours = figures.get(("coadapt", bench, ours_cfg, unit))
        peer = next((figures[k] for k in ((p, bench, peer_cfg, unit) for p in PEERS) if k in figures), None)
        if ours is None or peer is None or ours == 0 or peer == 0:
            continue
        ratio = ours / peer if higher else peer / ours
        print(json.dumps({"bench": f"{bench}_ratio", "config": f"{ours_cfg} vs peer {peer_cfg}",
                          "value": round(ratio, 3), "unit": "x faster", "coadapt": ours, "peer": peer,
                          "figure_unit": unit}))


if __name__ == "__main__":
    main(sys.argv[1])
