"""Plain PyTorch SAC gradient-step benchmark: the peer of `coadapt bench nn`.

One update = rlkit's SACTrainer.train_from_torch on a batch of 256: policy loss,
alpha loss and twin-Q losses, then zero_grad/backward/step for log_alpha, the
policy, q1 and q2 (four Adams, lr 3e-4), then Polyak averaging (tau 0.005) of
the two target Q networks.  Data are random (fixed seed), pre-generated and
cycled, so the timing covers only the update itself.

With --autocast the losses (every forward pass, so every product of the forward and backward
passes) run under `torch.autocast("cpu", dtype=torch.bfloat16)`: PyTorch's own mixed precision,
bf16 products with f32 master weights and Adam states (the peer of `coadapt bench nn
--precision bf16`); the lines then say "impl": "pytorch-bf16".

Run:  .venv-peers/bin/python bench/peers/sac_step.py [--seconds 10] [--threads 2] [--autocast]
Prints one JSON line per config, e.g.
  {"bench": "sac_update", "config": "3x256-obs17", "value": 38.9, "unit": "updates/s", "impl": "pytorch"}
"""
import argparse
import copy
import json
import math
import time

import torch
import torch.nn as nn
import torch.nn.functional as F

CONFIGS = {  # name: (hidden sizes, obs dim, act dim)
    "3x256-obs17": ((256, 256, 256), 17, 6),
    "3x200-obs23": ((200, 200, 200), 23, 6),
    "2x256-obs17": ((256, 256), 17, 6),
}
BATCH = 256
LR = 3e-4
TAU = 0.005
GAMMA = 0.99
LOG2 = math.log(2.0)


def mlp(sizes):
    layers = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


class QNet(nn.Module):
    def __init__(self, obs_dim, act_dim, hidden):
        super().__init__()
        self.net = mlp([obs_dim + act_dim, *hidden, 1])

    def forward(self, obs, act):
        return self.net(torch.cat([obs, act], dim=1))


class TanhGaussianPolicy(nn.Module):
    def __init__(self, obs_dim, act_dim, hidden):
        super().__init__()
        self.act_dim = act_dim
        self.net = mlp([obs_dim, *hidden, 2 * act_dim])

    def forward(self, obs):
        """Reparameterised tanh-Gaussian sample and its log-probability [B, 1]."""
        out = self.net(obs)
        mean, log_std = out[:, : self.act_dim], out[:, self.act_dim :].clamp(-20.0, 2.0)
        std = log_std.exp()
        normal = torch.distributions.Normal(mean, std)
        u = normal.rsample()
        # log(1 - tanh(u)^2) = 2 * (log 2 - u - softplus(-2u))  (rlkit's stable form)
        log_prob = normal.log_prob(u) - 2.0 * (LOG2 - u - F.softplus(-2.0 * u))
        return torch.tanh(u), log_prob.sum(dim=1, keepdim=True)


class SAC:
    def __init__(self, obs_dim, act_dim, hidden):
        self.policy = TanhGaussianPolicy(obs_dim, act_dim, hidden)
        self.qf1 = QNet(obs_dim, act_dim, hidden)
        self.qf2 = QNet(obs_dim, act_dim, hidden)
        self.target_qf1 = copy.deepcopy(self.qf1)
        self.target_qf2 = copy.deepcopy(self.qf2)
        self.target_entropy = -float(act_dim)
        self.log_alpha = torch.zeros(1, requires_grad=True)
        self.alpha_optimizer = torch.optim.Adam([self.log_alpha], lr=LR)
        self.policy_optimizer = torch.optim.Adam(self.policy.parameters(), lr=LR)
        self.qf1_optimizer = torch.optim.Adam(self.qf1.parameters(), lr=LR)
        self.qf2_optimizer = torch.optim.Adam(self.qf2.parameters(), lr=LR)

    def update(self, obs, actions, rewards, next_obs, terminals, autocast=False):
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=autocast):
            losses = self.losses(obs, actions, rewards, next_obs, terminals)
        self.step(*(loss.float() for loss in losses))

    def losses(self, obs, actions, rewards, next_obs, terminals):
        # --- losses (rlkit SACTrainer.compute_loss) ---
        new_actions, log_pi = self.policy(obs)
        alpha_loss = -(self.log_alpha * (log_pi + self.target_entropy).detach()).mean()
        alpha = self.log_alpha.exp()
        q_new = torch.min(self.qf1(obs, new_actions), self.qf2(obs, new_actions))
        policy_loss = (alpha * log_pi - q_new).mean()

        q1_pred = self.qf1(obs, actions)
        q2_pred = self.qf2(obs, actions)
        next_actions, next_log_pi = self.policy(next_obs)
        target_q = torch.min(self.target_qf1(next_obs, next_actions),
                             self.target_qf2(next_obs, next_actions)) - alpha * next_log_pi
        q_target = (rewards + (1.0 - terminals) * GAMMA * target_q).detach()
        qf1_loss = F.mse_loss(q1_pred, q_target)
        qf2_loss = F.mse_loss(q2_pred, q_target)
        return alpha_loss, policy_loss, qf1_loss, qf2_loss

    def step(self, alpha_loss, policy_loss, qf1_loss, qf2_loss):
        # --- optimisation (rlkit SACTrainer.train_from_torch) ---
        for opt, loss in ((self.alpha_optimizer, alpha_loss), (self.policy_optimizer, policy_loss),
                          (self.qf1_optimizer, qf1_loss), (self.qf2_optimizer, qf2_loss)):
            opt.zero_grad()
            loss.backward()
            opt.step()

        # --- Polyak averaging of the targets ---
        with torch.no_grad():
            for src, dst in ((self.qf1, self.target_qf1), (self.qf2, self.target_qf2)):
                for p, tp in zip(src.parameters(), dst.parameters()):
                    tp.mul_(1.0 - TAU).add_(p, alpha=TAU)


def make_batches(obs_dim, act_dim, n, gen):
    return [(torch.randn(BATCH, obs_dim, generator=gen),
             torch.rand(BATCH, act_dim, generator=gen) * 2.0 - 1.0,
             torch.randn(BATCH, 1, generator=gen),
             torch.randn(BATCH, obs_dim, generator=gen),
             (torch.rand(BATCH, 1, generator=gen) < 0.05).float()) for _ in range(n)]


def bench(name, seconds, warmup, autocast=False):
    hidden, obs_dim, act_dim = CONFIGS[name]
    torch.manual_seed(0)
    sac = SAC(obs_dim, act_dim, hidden)
    batches = make_batches(obs_dim, act_dim, 8, torch.Generator().manual_seed(1))
    for i in range(warmup):
        sac.update(*batches[i % len(batches)], autocast=autocast)
    n, start = 0, time.perf_counter()
    while True:
        sac.update(*batches[n % len(batches)], autocast=autocast)
        n += 1
        elapsed = time.perf_counter() - start
        if elapsed >= seconds:
            return n / elapsed


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="timed duration per config")
    ap.add_argument("--threads", type=int, default=2, help="torch.set_num_threads")
    ap.add_argument("--warmup", type=int, default=10, help="untimed updates first")
    ap.add_argument("--config", action="append", choices=sorted(CONFIGS),
                    help="run only this config (repeatable); default: all")
    ap.add_argument("--autocast", action="store_true",
                    help="the losses under torch.autocast(cpu, bfloat16): bf16 products")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    for name in args.config or CONFIGS:
        rate = bench(name, args.seconds, args.warmup, args.autocast)
        impl = "pytorch-bf16" if args.autocast else "pytorch"
        print(json.dumps({"bench": "sac_update", "config": name, "value": round(rate, 2),
                          "unit": "updates/s", "impl": impl}), flush=True)


if __name__ == "__main__":
    main()
