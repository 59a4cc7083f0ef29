"""PyTorch float64 reference for latent/tests/value.rs: the value critic through the learned
model (thesis Eq. 4.9, 4.10) on a small shape.

Run: .venv-peers/bin/python latent/tests/reference/value.py
"""
import math

import torch
from torch import nn

torch.set_default_dtype(torch.float64)
LATENT, FRAMES, ACT, N, GAMMA = 2, 3, 2, 3, 0.9
S = FRAMES * LATENT


def mlp(sizes):
    layers = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


def fill(net, f):
    n = sum(p.numel() for p in net.parameters())
    nn.utils.vector_to_parameters(torch.tensor([f(i) for i in range(n)]), net.parameters())


model, v, v_t, actor, actor_t = mlp([S + ACT, 5, 4, LATENT]), mlp([S, 6, 5, 1]), mlp([S, 6, 5, 1]), mlp([S, 5, ACT]), mlp([S, 5, ACT])
fill(model, lambda i: 0.5 * math.sin(0.31 * i + 0.2))
fill(v, lambda i: 0.4 * math.cos(0.17 * i))
fill(v_t, lambda i: 0.4 * math.cos(0.19 * i + 0.3))
fill(actor, lambda i: 0.6 * math.sin(0.23 * i))
fill(actor_t, lambda i: 0.6 * math.sin(0.29 * i + 0.1))
z = torch.tensor([0.3 * math.sin(1.3 * i + 0.5) for i in range(N * S)]).reshape(N, S)
r = torch.tensor([0.5, -0.2, 1.0])
done = torch.tensor([0.0, 1.0, 0.0])


def psi(z, a):
    return torch.cat([z[:, LATENT:], model(torch.cat([z, a], dim=1))], dim=1)


with torch.no_grad():
    y = r + GAMMA * (1 - done) * v_t(psi(z, torch.tanh(actor_t(z))))[:, 0]
def stats(net):
    g = torch.cat([p.grad.reshape(-1) for p in net.parameters()])
    i = torch.arange(1, g.numel() + 1, dtype=torch.float64)
    return f"[{float(g.sum()):.12e}, {float((g * i).sum()):.12e}, {float((g * g).sum()):.12e}]"


critic_loss = ((v(z)[:, 0] - y) ** 2).mean()
critic_loss.backward()
print(f"critic: {critic_loss.item():.12e} grad_v {stats(v)}")
actor_loss = -v(psi(z, torch.tanh(actor(z))))[:, 0].mean()
actor_loss.backward()
print(f"actor: {actor_loss.item():.12e} grad_actor {stats(actor)}")
