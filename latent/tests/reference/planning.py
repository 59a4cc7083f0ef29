"""PyTorch float64 reference for latent/tests/planning.rs: the planning objective f_Q (thesis
Eq. 4.11, w_j = 1/H) through the latent dynamics Psi (Eq. 4.4) and its gradient w.r.t. actions.

Run: .venv-peers/bin/python latent/tests/reference/planning.py
"""
import math

import torch
from torch import nn

torch.set_default_dtype(torch.float64)
LATENT, FRAMES, ACT, H = 2, 3, 2, 3
model = nn.Sequential(nn.Linear(FRAMES * LATENT + ACT, 5), nn.ReLU(), nn.Linear(5, 4), nn.ReLU(), nn.Linear(4, LATENT))
critic = nn.Sequential(nn.Linear(FRAMES * LATENT + ACT, 6), nn.ReLU(), nn.Linear(6, 5), nn.ReLU(), nn.Linear(5, 1))
nm = sum(p.numel() for p in model.parameters())
nc = sum(p.numel() for p in critic.parameters())
nn.utils.vector_to_parameters(torch.tensor([0.5 * math.sin(0.31 * i + 0.2) for i in range(nm)]), model.parameters())
nn.utils.vector_to_parameters(torch.tensor([0.4 * math.cos(0.17 * i) for i in range(nc)]), critic.parameters())
z = torch.tensor([0.3 * math.sin(1.3 * i + 0.5) for i in range(FRAMES * LATENT)])
actions = torch.tensor([0.8 * math.cos(0.7 * i) for i in range((H + 1) * ACT)]).reshape(H + 1, ACT).requires_grad_(True)
f = 0.0
for j in range(H + 1):
    x = torch.cat([z, actions[j]])
    f = f + critic(x)[0] / H
    z = torch.cat([z[LATENT:], model(x)])
f.backward()
g = ", ".join(f"{v:.12e}" for v in actions.grad.reshape(-1).tolist())
print(f"const REFERENCE: (f64, [f64; {actions.numel()}]) = ({f.item():.12e}, [{g}]);")
