"""The peer of `coadapt bench env`: DeepMind's own Python dm_env_rpc client stepping a server.

usage: python bench/peers/env_client.py dm-env-rpc://HOST:PORT [SECONDS] [NAME]

The same work as the Rust client (bench/src/env.rs): one world, actions drawn before the
timed loop (uniform in the action box), every step requesting observation, reward and
discount, each step timed on its own; at an episode's end a ResetWorld (design, seed) and the
first step of the next episode, inside the time. Prints one JSON line per figure. Runs in the
bridge's virtualenv (bridges/python/setup_venv.sh), which has dm-env-rpc.
"""
import json
import sys
import time

import grpc
import numpy as np
from dm_env_rpc.v1 import connection as dm_connection, dm_env_rpc_pb2 as pb, tensor_spec_utils, tensor_utils

url = sys.argv[1]
seconds = float(sys.argv[2]) if len(sys.argv) > 2 else 5.0
name = sys.argv[3] if len(sys.argv) > 3 else url
channel = grpc.insecure_channel(url.removeprefix("dm-env-rpc://"))
grpc.channel_ready_future(channel).result(timeout=10)
conn = dm_connection.Connection(channel)
world = conn.send(pb.CreateWorldRequest()).world_name
specs = conn.send(pb.JoinWorldRequest(world_name=world)).specs
uid = {s.name: u for u, s in specs.observations.items()}
(action_uid, action_spec), = [(u, s) for u, s in specs.actions.items() if s.name == "action"]
bounds = tensor_spec_utils.bounds(action_spec)
rng = np.random.default_rng(1)
actions = [
    tensor_utils.pack_tensor(rng.uniform(bounds.min, bounds.max, size=action_spec.shape).astype(np.float32))
    for _ in range(4096)
]
design = conn.send(pb.StepRequest(requested_observations=[uid["design"]])).observations[uid["design"]]
requested = [uid["observation"], uid["reward"], uid["discount"]]


def reset(episode):
    settings = {"design": design, "seed": tensor_utils.pack_tensor(episode, dtype=np.uint64)}
    conn.send(pb.ResetWorldRequest(world_name=world, settings=settings))
    conn.send(pb.StepRequest(requested_observations=requested))


episode = 0
reset(episode)
latencies = []
steps = 0
start = time.perf_counter()
while time.perf_counter() - start < seconds:
    t = time.perf_counter()
    r = conn.send(pb.StepRequest(actions={action_uid: actions[steps % len(actions)]}, requested_observations=requested))
    if r.state != pb.EnvironmentStateType.RUNNING:
        episode += 1
        reset(episode)
    latencies.append((time.perf_counter() - t) * 1e6)
    steps += 1
elapsed = time.perf_counter() - start
conn.send(pb.LeaveWorldRequest())
conn.send(pb.DestroyWorldRequest(world_name=world))
conn.close()
lat = np.sort(np.array(latencies))
config = {"env": name, "transport": "dm_env_rpc loopback", "steps": steps, "client": "dm_env_rpc (Python)"}
print(json.dumps({"bench": "env_steps_per_second", "config": config, "value": steps / elapsed, "unit": "steps/s"}))
for label, p in [("median", 0.5), ("p99", 0.99)]:
    v = float(lat[int(round((len(lat) - 1) * p))])
    print(json.dumps({"bench": f"env_step_latency_{label}", "config": config, "value": v, "unit": "us"}))
