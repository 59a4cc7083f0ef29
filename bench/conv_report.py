"""The convolution tables of BENCHMARKS.md ("Convolutions") from one compare_conv.sh file.

Cells: the median over rounds of each figure's median ms (min-max over rounds), model GFLOP/s at
the median; ratios (>1: ours is faster) taken round by round by bench/ratios.py, then their median
(min-max), n = the rounds. Ours f32 and bf16 against PyTorch f32 and PyTorch under bf16 autocast,
all with one thread.

usage: python3 bench/conv_report.py bench/results/conv-2026-11-27.jsonl
"""
import json
import statistics as st
import sys

NAMES = ["conv1-3to32-64to32", "conv2-32to32-32to16", "conv3-32to32-16to8", "deconv1-32to32-8to16",
         "deconv2-32to32-16to32", "deconv3-32to3-32to64", "encoder-3conv", "decoder-3deconv"]


def main(path):
    rows = [json.loads(l) for l in open(path) if l.startswith("{")]
    figs, rat = {}, {}
    for r in rows:
        if "round" in r:
            rat.setdefault((r["bench"], r["config"]), []).append(r["value"])
        elif r.get("unit") == "ms" and "impl" in r:
            figs.setdefault((r["impl"], r["bench"], r["config"]), []).append(r)

    def cell(impl, bench, cfg):
        v = [x["value"] for x in figs.get((impl, bench, cfg), [])]
        g = [x["gflop_s"] for x in figs.get((impl, bench, cfg), [])]
        if not v:
            return "-"
        return f"{st.median(v):.2f} ({min(v):.2f}-{max(v):.2f}) ({st.median(g):.0f})"

    def ratio(bench, ours, peer):
        v = rat.get((bench + "_ratio", f"{ours} vs peer {peer}"), [])
        return f"{st.median(v):.2f}x ({min(v):.2f}-{max(v):.2f})" if v else "-"

    for bench, what in [("conv_forward", "forward"), ("conv_forward_backward", "forward + backward")]:
        for b in ["b32", "b1"]:
            print(f"\nBatch {b[1:]}, {what}:\n")
            print("| figure | ours f32, ms (GFLOP/s) | ours bf16 | PyTorch f32 | PyTorch bf16 | ours f32 / PyTorch f32 "
                  "| ours bf16 / PyTorch f32 | ours bf16 / PyTorch bf16 |")
            print("|---|---|---|---|---|---|---|---|")
            for n in NAMES:
                c = f"{n}-{b}"
                bold = "**" if n.startswith(("encoder", "decoder")) else ""
                print(f"| {bold}{n}{bold} | {cell('coadapt', bench, c)} | {cell('coadapt', bench, c + '-bf16')} "
                      f"| {cell('pytorch', bench, c)} | {cell('pytorch', bench, c + '-bf16')} | {ratio(bench, c, c)} "
                      f"| {bold}{ratio(bench, c + '-bf16', c)}{bold} | {ratio(bench, c + '-bf16', c + '-bf16')} |")


if __name__ == "__main__":
    main(sys.argv[1])
