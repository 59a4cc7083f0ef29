"""PyTorch's bf16 autocast on the network of tests/bf16_mlp.rs: how far its output and gradients
are from float64, layer by layer, on fixed weights and inputs. The Rust test holds coadapt's bf16
path to errors no larger than these (PyTorch's own mixed precision is the bar a user compares
with).

Run from the repository root, after `bash bench/peers/setup.sh`:
    .venv-peers/bin/python crates/nn/tests/reference/bf16_reference.py
and paste the printed Rust `const`s into tests/bf16_mlp.rs.

Conventions (the Rust side must match them): MLP [40, 200, 200, 1] as in make_reference.py
(Linear, ReLU, ..., Linear; flat parameters per layer weight [out, in] then bias); parameters
p[i] = 0.1 * sin(0.37 * i + 0.3); inputs x[b][j] = cos(0.11 * (b * 40 + j)), 64 rows; the
output gradient dy[b] = cos(0.7 * b + 0.2). Autocast: torch.autocast("cpu", dtype=torch.bfloat16)
around the forward, f32 master weights, backward through the autocast graph (what a PyTorch user
of mixed precision on CPU runs). Errors: ||ours - f64|| / ||f64|| over all entries of each
quantity.
"""
import math

import torch
import torch.nn as nn
from torch.nn.utils import vector_to_parameters

SIZES = [40, 200, 200, 1]
ROWS = 64


def mlp(dtype):
    layers = []
    for i in range(len(SIZES) - 1):
        layers += [nn.Linear(SIZES[i], SIZES[i + 1]), nn.ReLU()]
    net = nn.Sequential(*layers[:-1]).to(dtype)
    n = sum(p.numel() for p in net.parameters())
    p = 0.1 * torch.sin(0.37 * torch.arange(n, dtype=torch.float64) + 0.3)
    vector_to_parameters(p.to(dtype), net.parameters())
    return net


def run(dtype, autocast):
    net = mlp(dtype)
    idx = torch.arange(ROWS * SIZES[0], dtype=torch.float64).reshape(ROWS, SIZES[0])
    x = torch.cos(0.11 * idx).to(dtype).requires_grad_(True)
    dy = torch.cos(0.7 * torch.arange(ROWS, dtype=torch.float64) + 0.2).reshape(ROWS, 1).to(dtype)
    if autocast:
        with torch.autocast("cpu", dtype=torch.bfloat16):
            y = net(x)
    else:
        y = net(x)
    y.float().backward(dy.float()) if autocast else y.backward(dy)
    weights = [m.weight.grad.double() for m in net if isinstance(m, nn.Linear)]
    return y.double().detach(), weights, x.grad.double()


def rel(a, b):
    return (torch.linalg.norm(a - b) / torch.linalg.norm(b)).item()


exact_y, exact_w, exact_dx = run(torch.float64, False)
auto_y, auto_w, auto_dx = run(torch.float32, True)
print(f"// torch {torch.__version__}, bf16 autocast on CPU against float64; {ROWS} rows, {SIZES}")
print(f"const TORCH_BF16_OUTPUT_ERROR: f64 = {rel(auto_y, exact_y):.6e};")
print(f"const TORCH_BF16_INPUT_GRAD_ERROR: f64 = {rel(auto_dx, exact_dx):.6e};")
errs = ", ".join(f"{rel(a, e):.6e}" for a, e in zip(auto_w, exact_w))
print(f"const TORCH_BF16_WEIGHT_GRAD_ERRORS: [f64; {len(auto_w)}] = [{errs}];")
assert all(math.isfinite(rel(a, e)) for a, e in zip(auto_w, exact_w))
