"""Reference values (PyTorch, float64) for the coadapt-nn tests.

Run from the repository root, after `bash bench/peers/setup.sh`:
    .venv-peers/bin/python crates/nn/tests/reference/make_reference.py \
        > crates/nn/tests/reference/reference_values.txt
and paste the printed Rust `const`s into the tests.

Conventions (the Rust side must match them):
  * MLP [n0, ..., nk] = Linear, ReLU, ..., Linear (no activation at the end); its
    flat parameter vector is parameters_to_vector: per layer weight [out, in]
    row-major, then bias [out].
  * Parameters of a network with offset o: p[i] = 0.1 * sin(0.37 * i + o).
  * Input matrix (rows b, width d, offset o): x[b][j] = cos(0.11 * (b * d + j) + o).
"""
import math

import torch
import torch.nn as nn
import torch.nn.functional as F
from torch.nn.utils import parameters_to_vector, vector_to_parameters

torch.set_default_dtype(torch.float64)
GAMMA, ALPHA, TAU = 0.99, 0.01, 0.005


def mlp(sizes, offset):
    layers = []
    for i in range(len(sizes) - 1):
        layers += [nn.Linear(sizes[i], sizes[i + 1]), nn.ReLU()]
    net = nn.Sequential(*layers[:-1])
    n = sum(p.numel() for p in net.parameters())
    vector_to_parameters(0.1 * torch.sin(0.37 * torch.arange(n) + offset), net.parameters())
    return net


def inputs(rows, d, offset):
    idx = torch.arange(rows * d).reshape(rows, d)
    return torch.cos(0.11 * idx + offset)


def tanh_gaussian(policy, obs, eps):
    """Tanh-squashed Gaussian sample with fixed noise; returns (action, log_prob[B])."""
    out = policy(obs)
    act_dim = out.shape[1] // 2
    mean, log_std = out[:, :act_dim], out[:, act_dim:].clamp(-20.0, 2.0)
    normal = torch.distributions.Normal(mean, log_std.exp())
    u = mean + log_std.exp() * eps
    # log(1 - tanh(u)^2) = 2 * (log 2 - u - softplus(-2u)), exact, no epsilon
    log_prob = normal.log_prob(u) - 2.0 * (math.log(2.0) - u - F.softplus(-2.0 * u))
    return torch.tanh(u), log_prob.sum(dim=1)


def q(net, obs, act):
    return net(torch.cat([obs, act], dim=1)).squeeze(1)


def grad(loss, net):
    net.zero_grad()
    loss.backward(retain_graph=True)
    g = parameters_to_vector(p.grad for p in net.parameters()).clone()
    net.zero_grad()
    return g


def flat(net):
    return parameters_to_vector(net.parameters()).detach()


def emit(name, value):
    value = torch.as_tensor(value).detach()
    if value.dim() == 0:
        print("const %s: f64 = %.16e;" % (name, value.item()))
        return
    value = value.flatten().tolist()
    print("const %s: [f64; %d] = [" % (name, len(value)))
    for i in range(0, len(value), 4):
        print("    " + " ".join("%.16e," % v for v in value[i:i + 4]))
    print("];")


def batch():
    obs = inputs(5, 4, 0.3)
    actions = 0.5 * inputs(5, 2, 1.1)
    rewards = torch.cos(0.11 * torch.arange(5) + 1.3)
    next_obs = inputs(5, 4, 1.7)
    done = (torch.arange(5) == 3).double()
    return obs, actions, rewards, next_obs, done


def case_mlp():
    print("// (a) MLP [5, 7, 7, 3], params offset 0.1, input 4x5 offset 0.0; output 4x3 row-major")
    emit("MLP_FORWARD", mlp([5, 7, 7, 3], 0.1)(inputs(4, 5, 0.0)))


def case_tanh_gaussian():
    print("// (b) tanh-Gaussian: policy [4, 8, 8, 4] offset 0.2, obs 5x4 offset 0.3, eps 5x2 offset 0.7")
    action, log_prob = tanh_gaussian(mlp([4, 8, 8, 4], 0.2), inputs(5, 4, 0.3), inputs(5, 2, 0.7))
    emit("TANH_GAUSSIAN_ACTIONS", action)
    emit("TANH_GAUSSIAN_LOG_PROB", log_prob)


def case_sac():
    print("// (c) SAC losses (rlkit order), alpha 0.01 fixed, gamma 0.99; policy [4,8,8,4] off 0.2,")
    print("//     q1/q2/target q1/target q2 [6,8,8,1] off 0.4/0.5/0.6/0.7; eps off 0.7, next eps off 1.9")
    obs, actions, rewards, next_obs, done = batch()
    policy = mlp([4, 8, 8, 4], 0.2)
    q1, q2, tq1, tq2 = (mlp([6, 8, 8, 1], o) for o in (0.4, 0.5, 0.6, 0.7))

    new_a, log_pi = tanh_gaussian(policy, obs, inputs(5, 2, 0.7))
    policy_loss = (ALPHA * log_pi - torch.min(q(q1, obs, new_a), q(q2, obs, new_a))).mean()
    alpha_loss = -(math.log(ALPHA) * (log_pi.detach() - 2.0)).mean()
    next_a, next_log_pi = tanh_gaussian(policy, next_obs, inputs(5, 2, 1.9))
    next_v = torch.min(q(tq1, next_obs, next_a), q(tq2, next_obs, next_a)) - ALPHA * next_log_pi
    target = (rewards + (1.0 - done) * GAMMA * next_v).detach()
    q1_loss = ((q(q1, obs, actions) - target) ** 2).mean()
    q2_loss = ((q(q2, obs, actions) - target) ** 2).mean()
    emit("SAC_POLICY_LOSS", policy_loss)
    emit("SAC_Q1_LOSS", q1_loss)
    emit("SAC_Q2_LOSS", q2_loss)
    emit("SAC_ALPHA_LOSS", alpha_loss)

    grads = {net: grad(loss, net) for net, loss in ((policy, policy_loss), (q1, q1_loss), (q2, q2_loss))}
    emit("SAC_POLICY_GRAD", grads[policy])
    emit("SAC_Q1_GRAD", grads[q1])

    print("// one update: grads clamped to [-1, 1], Adam(lr 3e-4, betas 0.9/0.999, eps 1e-8) step on")
    print("// policy, q1, q2, then Polyak target = 0.005 * online + 0.995 * target")
    for net, g in grads.items():
        clamped = g.clamp(-1.0, 1.0).split([p.numel() for p in net.parameters()])
        for p, gp in zip(net.parameters(), clamped):
            p.grad = gp.view_as(p).clone()
        torch.optim.Adam(net.parameters(), lr=3e-4, betas=(0.9, 0.999), eps=1e-8).step()
    with torch.no_grad():
        for online, tgt in ((q1, tq1), (q2, tq2)):
            for p, tp in zip(online.parameters(), tgt.parameters()):
                tp.copy_(TAU * p + (1.0 - TAU) * tp)
    emit("SAC_POLICY_AFTER_STEP", flat(policy))
    emit("SAC_Q1_AFTER_STEP", flat(q1))
    emit("SAC_TARGET_Q1_AFTER_STEP", flat(tq1))


def case_ddpg():
    print("// (d) DDPG: actor [4,8,8,2] off 0.2 (+tanh), critic [6,8,8,1] off 0.4,")
    print("//     target actor off 0.8, target critic off 0.6, gamma 0.99; batch as in (c)")
    obs, actions, rewards, next_obs, done = batch()
    actor, critic = mlp([4, 8, 8, 2], 0.2), mlp([6, 8, 8, 1], 0.4)
    t_actor, t_critic = mlp([4, 8, 8, 2], 0.8), mlp([6, 8, 8, 1], 0.6)
    target = (rewards + (1.0 - done) * GAMMA * q(t_critic, next_obs, torch.tanh(t_actor(next_obs)))).detach()
    critic_loss = ((q(critic, obs, actions) - target) ** 2).mean()
    actor_loss = -q(critic, obs, torch.tanh(actor(obs))).mean()
    emit("DDPG_CRITIC_LOSS", critic_loss)
    emit("DDPG_ACTOR_LOSS", actor_loss)
    emit("DDPG_ACTOR_GRAD", grad(actor_loss, actor))
    emit("DDPG_CRITIC_GRAD", grad(critic_loss, critic))


if __name__ == "__main__":
    print("// Generated by crates/nn/tests/reference/make_reference.py (torch %s, float64)."
          % torch.__version__.split("+")[0])
    case_mlp()
    case_tanh_gaussian()
    case_sac()
    case_ddpg()
