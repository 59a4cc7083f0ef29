"""PyTorch float64 reference for latent/tests/embedding.rs: the time-contrastive autoencoder's
loss (Eq. 4.1, 4.2 as latent/src/embedding.rs defines it) and its gradients on a small shape.

Run: .venv-peers/bin/python latent/tests/reference/embedding.py   (bench/peers/setup.sh makes the venv)
"""
import math

import torch
from torch import nn

torch.set_default_dtype(torch.float64)
IMAGE, CIN, CH, LATENT, MARGIN, N = 8, 2, (3, 3, 2), 4, 1.9, 2

enc = nn.Sequential(
    nn.Conv2d(CIN, CH[0], 3, 2, 1), nn.ReLU(),
    nn.Conv2d(CH[0], CH[1], 3, 2, 1), nn.ReLU(),
    nn.Conv2d(CH[1], CH[2], 3, 2, 1), nn.ReLU(),
    nn.Flatten(), nn.Linear(CH[2] * 1 * 1, LATENT),
)
dec = nn.Sequential(
    nn.Linear(LATENT, CH[2] * 1 * 1), nn.ReLU(), nn.Unflatten(1, (CH[2], 1, 1)),
    nn.ConvTranspose2d(CH[2], CH[1], 3, 2, 1, output_padding=1), nn.ReLU(),
    nn.ConvTranspose2d(CH[1], CH[0], 3, 2, 1, output_padding=1), nn.ReLU(),
    nn.ConvTranspose2d(CH[0], CIN, 3, 2, 1, output_padding=1),
)
ne = sum(p.numel() for p in enc.parameters())
nd = sum(p.numel() for p in dec.parameters())
nn.utils.vector_to_parameters(torch.tensor([0.4 * math.sin(0.37 * i + 0.1) for i in range(ne)]), enc.parameters())
nn.utils.vector_to_parameters(torch.tensor([0.3 * math.cos(0.23 * i) for i in range(nd)]), dec.parameters())
px = CIN * IMAGE * IMAGE
frames = torch.tensor([0.5 + 0.5 * math.sin(0.11 * i) for i in range(3 * N * px)]).reshape(3 * N, CIN, IMAGE, IMAGE)

h = enc(frames)
z = h / h.norm(dim=1, keepdim=True).clamp_min(1e-12)
zt, zp, zr = z[:N], z[N:2 * N], z[2 * N:]
rec = ((frames[:N] - dec(zt)) ** 2).mean(dim=(1, 2, 3)).mean()
pull = ((zt - zp) ** 2).sum(dim=1).mean()
push = (MARGIN - (zt - zr).norm(dim=1)).clamp_min(0.0).mean()
(rec + pull + push).backward()


def stats(v):
    i = torch.arange(1, v.numel() + 1, dtype=torch.float64)
    return [float(v.sum()), float((v * i).sum()), float((v * v).sum())]


print(f"encoder {ne} params, decoder {nd} params")
print(f"parts: [{rec.item():.12e}, {pull.item():.12e}, {push.item():.12e}]")
ge = torch.cat([p.grad.reshape(-1) for p in enc.parameters()])
gd = torch.cat([p.grad.reshape(-1) for p in dec.parameters()])
print("grad_enc: [{:.12e}, {:.12e}, {:.12e}]".format(*stats(ge)))
print("grad_dec: [{:.12e}, {:.12e}, {:.12e}]".format(*stats(gd)))
