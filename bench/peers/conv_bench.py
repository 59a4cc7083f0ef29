"""The image embedding's convolutions in PyTorch: the peer of `coadapt bench conv`
(bench/src/conv.rs).

The shapes are read from the file `coadapt bench conv --dump FILE` writes (the layers of
`Embedding::new(EmbeddingConfig::default())`: 3x3, stride 2, padding 1; conv 3->32 (64->32),
32->32 (32->16), 32->32 (16->8), and the transposed 32->32 (8->16), 32->32 (16->32), 32->3
(32->64) with output padding 1), so both sides time the same shapes. Figures: each layer alone,
then the encoder's three and the decoder's three chained (no activation, as ours), forward alone
(under torch.no_grad, as ours keeps nothing for autograd) and forward + backward
(torch.autograd.grad of the output against the input and every weight and bias, with a given
output gradient: the same three products per layer as ours), at each batch size.

Parameters, inputs and output gradients are drawn once per figure, outside the timed loop; each
repetition times one call (time.perf_counter), after untimed warm-up calls; median, p10, p90;
the garbage collector is off while timing. `--threads 1` (torch.set_num_threads(1)) is the
matched figure (ours is single-threaded); `--threads 0` keeps PyTorch's default and labels the
config `-threadsN`.

With --autocast every figure runs under `torch.autocast("cpu", dtype=torch.bfloat16)`
(PyTorch's own mixed precision: the convolutions' products in bf16), labelled `-bf16` and
"dtype": "bf16", the peer of `coadapt bench conv --precision bf16`.

  usage: conv_bench.py --shapes DUMP [--repetitions 100] [--warmup 10] [--batch 32,1]
                       [--threads 1] [--only NAME] [--autocast]
         conv_bench.py --check DUMP   recompute every dumped layer (forward, weight, bias and
                                      input gradients) in float64 and in float32 and compare
                                      to ours; exits 1 beyond 1e-4 relative. A dump of bf16
                                      products ("precision": "bf16", from `coadapt bench conv
                                      --precision bf16 --dump`) is compared to float64 and to
                                      PyTorch under bf16 autocast instead, and must be no
                                      further from float64 than twice autocast's error (and
                                      within 2^-6 relative)
prints one JSON line per figure: {"bench": "conv_forward" | "conv_forward_backward",
"config": ..., "value": median ms, "unit": "ms", "impl": "pytorch", "p10", "p90", "gflop_s", ...}
"""
import argparse
import gc
import json
import sys
import time

import numpy as np
import torch
import torch.nn.functional as F


def layer_fn(spec):
    if spec["transposed"]:
        return lambda x, w, b: F.conv_transpose2d(x, w, b, stride=spec["stride"], padding=spec["pad"],
                                                  output_padding=spec["output_padding"])
    return lambda x, w, b: F.conv2d(x, w, b, stride=spec["stride"], padding=spec["pad"])


def weight_shape(spec):
    k = spec["k"]
    # PyTorch's layouts (ours too): Conv2d [c_out, c_in, k, k], ConvTranspose2d [c_in, c_out, k, k].
    if spec["transposed"]:
        return (spec["c_in"], spec["c_out"], k, k)
    return (spec["c_out"], spec["c_in"], k, k)


def split_params(spec, flat, dtype):
    ws = weight_shape(spec)
    nw = int(np.prod(ws))
    flat = torch.tensor(np.asarray(flat, dtype=np.float32), dtype=dtype)
    return flat[:nw].reshape(ws).clone(), flat[nw:].clone()


def rel(ours, ref):
    ours = np.asarray(ours, dtype=np.float64).ravel()
    ref = np.asarray(ref, dtype=np.float64).ravel()
    return float(np.max(np.abs(ours - ref)) / max(np.max(np.abs(ref)), 1e-30))


def grads(spec, dtype, autocast=False):
    """Output, parameter gradient (weight then bias) and input gradient of one dumped layer."""
    n = spec["n"]
    c_out, oh, ow = spec["out_shape"]
    f = layer_fn(spec)
    w, b = split_params(spec, spec["params"], dtype)
    x = torch.tensor(np.asarray(spec["x"], dtype=np.float32), dtype=dtype).reshape(n, spec["c_in"], spec["h"], spec["w"])
    dy = torch.tensor(np.asarray(spec["dy"], dtype=np.float32), dtype=dtype).reshape(n, c_out, oh, ow)
    for t in (x, w, b):
        t.requires_grad_(True)
    with torch.autocast("cpu", dtype=torch.bfloat16, enabled=autocast):
        out = f(x, w, b)
    gx, gw, gb = torch.autograd.grad(out, (x, w, b), dy.to(out.dtype))
    grad = torch.cat([gw.reshape(-1), gb.reshape(-1)])
    return {"out": out.detach().float().numpy() if autocast else out.detach().numpy(),
            "grad": grad.float().numpy() if autocast else grad.numpy(),
            "dx": gx.float().numpy() if autocast else gx.numpy()}


def check(path):
    d = json.load(open(path))
    if any(spec.get("precision") == "bf16" for spec in d["layers"]):
        return check_bf16(d)
    worst64, worst32 = 0.0, 0.0
    rows = []
    for spec in d["layers"]:
        per = {}
        for dtype in (torch.float64, torch.float32):
            ref = grads(spec, dtype)
            per[dtype] = {k: rel(spec[k], ref[k]) for k in ("out", "grad", "dx")}
        worst64 = max(worst64, *per[torch.float64].values())
        worst32 = max(worst32, *per[torch.float32].values())
        rows.append({"layer": spec["config"], "vs_float64": per[torch.float64], "vs_float32": per[torch.float32]})
    for r in rows:
        print(json.dumps(r), file=sys.stderr)
    ok = worst64 <= 1e-4 and worst32 <= 1e-4
    print(json.dumps({"check": "conv", "layers": len(rows), "max_rel_vs_torch_float64": worst64,
                      "max_rel_vs_torch_float32": worst32, "tolerance": 1e-4, "ok": ok}))
    return 0 if ok else 1


def check_bf16(d):
    """Ours with bf16 products against float64, beside PyTorch's bf16 autocast against float64
    (max-abs relative errors, as rel()): ours must be within twice autocast's error, and 2^-6."""
    rows, ok, worst, worst_torch = [], True, 0.0, 0.0
    for spec in d["layers"]:
        ref = grads(spec, torch.float64)
        auto = grads(spec, torch.float32, autocast=True)
        ours = {k: rel(spec[k], ref[k]) for k in ("out", "grad", "dx")}
        theirs = {k: rel(auto[k], ref[k]) for k in ("out", "grad", "dx")}
        for k in ours:
            ok = ok and ours[k] <= max(2 * theirs[k], 1e-3) and ours[k] <= 2 ** -6
        worst, worst_torch = max(worst, *ours.values()), max(worst_torch, *theirs.values())
        rows.append({"layer": spec["config"], "ours_bf16_vs_float64": ours, "torch_autocast_vs_float64": theirs})
    for r in rows:
        print(json.dumps(r), file=sys.stderr)
    print(json.dumps({"check": "conv-bf16", "layers": len(rows), "max_rel_ours_vs_torch_float64": worst,
                      "max_rel_torch_autocast_vs_float64": worst_torch,
                      "tolerance": "ours <= max(2 x autocast's, 1e-3) and <= 2^-6, per layer and quantity", "ok": ok}))
    return 0 if ok else 1


def percentile(v, q):
    return float(np.percentile(np.asarray(v), q * 100))  # linear, as ours


def time_ms(reps, warmup, f):
    for _ in range(warmup):
        f()
    ms = []
    gc.disable()
    try:
        for _ in range(reps):
            t = time.perf_counter()
            f()
            ms.append((time.perf_counter() - t) * 1e3)
    finally:
        gc.enable()
    return sorted(ms)


def line(bench, config, batch, ms, flops, threads, dtype="f32"):
    med = percentile(ms, 0.5)
    return json.dumps({"bench": bench, "config": config, "value": round(med, 4), "unit": "ms", "impl": "pytorch",
                       "p10": round(percentile(ms, 0.1), 4), "p90": round(percentile(ms, 0.9), 4),
                       "gflop_s": round(flops / (med * 1e-3) / 1e9, 4), "batch": batch, "repetitions": len(ms),
                       "threads": threads, "dtype": dtype, "torch": torch.__version__,
                       "mkldnn": torch.backends.mkldnn.is_available()})


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--shapes", help="the JSON `coadapt bench conv --dump` wrote")
    ap.add_argument("--check")
    ap.add_argument("--repetitions", type=int, default=100)
    ap.add_argument("--warmup", type=int, default=10)
    ap.add_argument("--batch", default="32,1")
    ap.add_argument("--threads", type=int, default=1, help="torch.set_num_threads; 0: PyTorch's default")
    ap.add_argument("--only")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--autocast", action="store_true",
                    help="every figure under torch.autocast(cpu, bfloat16): bf16 products; configs end in -bf16")
    a = ap.parse_args()
    if a.check:
        sys.exit(check(a.check))
    if not a.shapes:
        ap.error("--shapes DUMP (or --check DUMP) is required")
    if a.threads > 0:
        torch.set_num_threads(a.threads)
    threads = torch.get_num_threads()
    suffix = ("" if a.threads == 1 else f"-threads{threads}") + ("-bf16" if a.autocast else "")
    dtype = "bf16" if a.autocast else "f32"
    d = json.load(open(a.shapes))
    layers = d["layers"]
    g = torch.Generator().manual_seed(a.seed)
    for n in (int(b) for b in a.batch.split(",")):
        for fig in d["figures"]:
            name = fig["name"]
            if a.only and a.only not in name:
                continue
            specs = [layers[i] for i in fig["layers"]]
            params = []
            for s in specs:
                fan_in = (s["c_out"] if s["transposed"] else s["c_in"]) * s["k"] ** 2
                bound = 1.0 / fan_in ** 0.5
                ws = weight_shape(s)
                w = (torch.rand(ws, generator=g) * 2 - 1) * bound
                b = (torch.rand(ws[1] if s["transposed"] else ws[0], generator=g) * 2 - 1) * bound
                params += [w.requires_grad_(True), b.requires_grad_(True)]
            fns = [layer_fn(s) for s in specs]
            s0 = specs[0]
            x = torch.rand((n, s0["c_in"], s0["h"], s0["w"]), generator=g).requires_grad_(True)
            c_out, oh, ow = specs[-1]["out_shape"]
            dy = torch.rand((n, c_out, oh, ow), generator=g) * 2 - 1
            leaves = [x] + params
            macs = n * sum(s["macs"] for s in specs)

            def forward():
                h = x
                for i, f in enumerate(fns):
                    h = f(h, params[2 * i], params[2 * i + 1])
                return h

            def fwd():
                with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16, enabled=a.autocast):
                    forward()

            def fwd_bwd():
                with torch.autocast("cpu", dtype=torch.bfloat16, enabled=a.autocast):
                    out = forward()
                torch.autograd.grad(out, leaves, dy.to(out.dtype))

            config = f"{name}-b{n}{suffix}"
            print(line("conv_forward", config, n, time_ms(a.repetitions, a.warmup, fwd), 2.0 * macs, threads, dtype), flush=True)
            print(line("conv_forward_backward", config, n, time_ms(a.repetitions, a.warmup, fwd_bwd), 6.0 * macs, threads, dtype),
                  flush=True)


if __name__ == "__main__":
    main()
