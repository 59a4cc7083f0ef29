"""Reference values (PyTorch, float64) for the action autoencoder of thesis Eq. 6.1
(learner/src/action_space.rs, tested in learner/tests/action_space.rs).

Run from the repository root, after `bash bench/peers/setup.sh`:
    .venv-peers/bin/python learner/tests/reference/action_space.py \
        > learner/tests/reference/action_space_values.txt

Conventions (the Rust side matches them):
  * MLP [n0, ..., nk] = Linear, ReLU, ..., Linear; parameters flattened by
    parameters_to_vector (per layer weight [out, in] row-major, then bias).
  * Encoder e([a, o]) -> z (linear output); decoder tanh(d([z, o])) -> a~.
  * Parameters with scale c and offset o: p[i] = c * sin(0.37 * i + o).
  * L = mean_i max(Q_i, 0) * || a_i - a~_i ||_2.
"""
import torch
import torch.nn as nn
from torch.nn.utils import parameters_to_vector, vector_to_parameters

torch.set_default_dtype(torch.float64)
ROWS, OBS, ACT, LATENT, HIDDEN = 6, 4, 3, 2, [8, 6]


def mlp(sizes, scale, offset):
    layers = []
    for i in range(len(sizes) - 1):
        layers += [nn.Linear(sizes[i], sizes[i + 1]), nn.ReLU()]
    net = nn.Sequential(*layers[:-1])
    n = sum(p.numel() for p in net.parameters())
    vector_to_parameters(scale * torch.sin(0.37 * torch.arange(n) + offset), net.parameters())
    return net


def rows(r, d, scale, offset):
    return scale * torch.cos(0.11 * torch.arange(r * d).reshape(r, d) + offset)


enc = mlp([ACT + OBS, *HIDDEN, LATENT], 0.5, 0.4)
dec = mlp([LATENT + OBS, *HIDDEN, ACT], 0.5, 0.9)
obs = rows(ROWS, OBS, 1.0, 0.3)
act = rows(ROWS, ACT, 0.8, 1.1)
q = 2.0 * torch.cos(0.7 * torch.arange(ROWS) + 0.2)
w = q.clamp(min=0.0)

z = enc(torch.cat([act, obs], dim=1))
decoded = torch.tanh(dec(torch.cat([z, obs], dim=1)))
loss = (w * (act - decoded).norm(dim=1)).mean()
loss.backward()


def const(name, t):
    values = ", ".join(repr(float(v)) for v in t.reshape(-1))
    print(f"pub const {name}: [f64; {t.numel()}] = [{values}];")


print("// Produced by learner/tests/reference/action_space.py (PyTorch float64); do not edit.")
print(f"pub const AE_LOSS: f64 = {float(loss.detach())!r};")
const("AE_Z", z.detach())
const("AE_DECODED", decoded.detach())
const("AE_GRAD_ENCODER", parameters_to_vector(p.grad for p in enc.parameters()))
const("AE_GRAD_DECODER", parameters_to_vector(p.grad for p in dec.parameters()))
