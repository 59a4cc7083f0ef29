"""PyTorch float64 reference values for crates/nn/tests/conv.rs.

Run: .venv-peers/bin/python crates/nn/tests/reference/conv.py   (bench/peers/setup.sh makes the venv)

Inputs are deterministic: x[i] = sin(0.37 i), weight[i] = 0.3 cos(0.11 i), bias[j] = 0.05 j - 0.1
(flat indices in PyTorch's layouts); the loss is sum(out * r) with r[i] = sin(0.13 i + 1). For
each of out, dL/dweight, dL/dbias and dL/dx it prints three statistics: the sum, the sum of
v * (i + 1) over the flat index i (sensitive to layout), and the sum of squares.
"""
import torch

torch.set_default_dtype(torch.float64)


def fill(shape, f):
    n = 1
    for s in shape:
        n *= s
    return torch.tensor([f(i) for i in range(n)]).reshape(shape)


def stats(t):
    v = t.detach().reshape(-1)
    i = torch.arange(1, v.numel() + 1, dtype=torch.float64)
    return [float(v.sum()), float((v * i).sum()), float((v * v).sum())]


def case(name, layer, x_shape):
    with torch.no_grad():
        layer.weight.copy_(fill(layer.weight.shape, lambda i: 0.3 * torch.cos(torch.tensor(0.11 * i)).item()))
        layer.bias.copy_(fill(layer.bias.shape, lambda j: 0.05 * j - 0.1))
    x = fill(x_shape, lambda i: torch.sin(torch.tensor(0.37 * i)).item()).requires_grad_(True)
    out = layer(x)
    r = fill(out.shape, lambda i: torch.sin(torch.tensor(0.13 * i + 1.0)).item())
    (out * r).sum().backward()
    print(f"// {name}: out {list(out.shape)}")
    for label, t in [("out", out), ("dweight", layer.weight.grad), ("dbias", layer.bias.grad), ("dx", x.grad)]:
        s = stats(t)
        print(f"(\"{label}\", [{s[0]:.12e}, {s[1]:.12e}, {s[2]:.12e}]),")


case("conv", torch.nn.Conv2d(3, 4, 3, stride=2, padding=1), (2, 3, 7, 6))
case("conv_transpose", torch.nn.ConvTranspose2d(4, 3, 3, stride=2, padding=1, output_padding=1), (2, 4, 4, 3))
