"""A dm_env_rpc server that knows nothing of coadapt: gymnasium's Pendulum-v1 served as the
public protocol describes it (github.com/google-deepmind/dm_env_rpc, docs/v1/reference.md), with
the observations `observation`, `reward` and `discount` and the action `torque` (uids chosen
here, not coadapt's), no `design`, no settings of any kind: a CreateWorld, Reset or ResetWorld
with settings is refused with INVALID_ARGUMENT, as a strict server would. Written for
cli/tests/env_rpc.rs from the protocol's text, not from coadapt's bridge.

    python plain_dm_env_server.py [--pixels SIDE]   (prints `listening on 127.0.0.1:PORT` once it is)

With --pixels SIDE the observation is a camera frame instead of the state: SIDE x SIDE RGB,
channel-major, in [0, 1] (the pendulum's rod drawn from the centre), as `coadapt latent` learns
from.

Sequences: the first Step after JoinWorld, Reset or ResetWorld ignores its actions and answers
the first observation (RUNNING); Pendulum's 200-step limit ends a sequence TERMINATED with
discount 1 (a truncation), and the next Step starts the next sequence.
"""

import argparse
import sys
from concurrent import futures

import grpc
import gymnasium as gym
import numpy as np
from dm_env_rpc.v1 import dm_env_rpc_pb2 as pb
from dm_env_rpc.v1 import dm_env_rpc_pb2_grpc
from google.rpc import code_pb2, status_pb2

ACTION, OBSERVATION, REWARD, DISCOUNT = 7, 11, 12, 13


def floats(values, shape):
    return pb.Tensor(floats=pb.Tensor.FloatArray(array=[float(v) for v in values]), shape=shape)


def spec(name, shape, lo=None, hi=None):
    s = pb.TensorSpec(name=name, shape=shape, dtype=pb.DataType.FLOAT)
    if lo is not None:
        s.min.floats.array.extend(lo)
        s.max.floats.array.extend(hi)
    return s


PIXELS = 0  # --pixels: the side of the camera frame (0: the state)


def obs_dim():
    return 3 * PIXELS * PIXELS if PIXELS else 3


def specs():
    return pb.ActionObservationSpecs(
        actions={ACTION: spec("torque", [1], [-2.0], [2.0])},
        observations={
            OBSERVATION: spec("observation", [obs_dim()]),
            REWARD: spec("reward", []),
            DISCOUNT: spec("discount", [], [0.0], [1.0]),
        },
    )


def frame(state):
    """The pendulum seen from the front: a white rod from the centre towards its tip."""
    cos, sin = float(state[0]), float(state[1])
    img = np.zeros((3, PIXELS, PIXELS), dtype=np.float32)
    c = (PIXELS - 1) / 2.0
    for t in np.linspace(0.0, 1.0, 4 * PIXELS):
        x, y = int(round(c + t * c * sin)), int(round(c - t * c * cos))
        img[:, y, x] = 1.0
    return img.reshape(-1)


class Refused(Exception):
    def __init__(self, code, message):
        super().__init__(message)
        self.code = code


class Agent:
    """One connection's world and sequence."""

    def __init__(self):
        self.env = None
        self.obs = None
        self.running = False
        self.reward = 0.0
        self.discount = 1.0
        self.episodes = 0

    def observations(self, requested):
        seen = frame(self.obs) if PIXELS else self.obs
        values = {OBSERVATION: floats(seen, [obs_dim()]), REWARD: floats([self.reward], []), DISCOUNT: floats([self.discount], [])}
        out = {}
        for uid in requested:
            if uid not in values:
                raise Refused(code_pb2.INVALID_ARGUMENT, f"no observation with uid {uid}")
            out[uid] = values[uid]
        return out

    def step(self, req):
        if self.env is None:
            raise Refused(code_pb2.FAILED_PRECONDITION, "join a world first")
        if not self.running:
            # A new sequence: the actions are ignored.
            self.obs, _ = self.env.reset(seed=self.episodes)
            self.episodes += 1
            self.reward, self.discount, self.running = 0.0, 1.0, True
            return pb.StepResponse(state=pb.EnvironmentStateType.RUNNING, observations=self.observations(req.requested_observations))
        if set(req.actions) != {ACTION}:
            raise Refused(code_pb2.INVALID_ARGUMENT, f"expected the action uid {ACTION} (torque), got {sorted(req.actions)}")
        t = req.actions[ACTION]
        if t.WhichOneof("payload") != "floats" or len(t.floats.array) != 1:
            raise Refused(code_pb2.INVALID_ARGUMENT, "torque: one float expected")
        torque = float(t.floats.array[0])
        if not (np.isfinite(torque) and -2.0 <= torque <= 2.0):
            raise Refused(code_pb2.INVALID_ARGUMENT, f"torque {torque} is outside [-2, 2]")
        self.obs, reward, terminated, truncated, _ = self.env.step(np.array([torque], dtype=np.float32))
        self.reward = float(reward)
        self.discount = 0.0 if terminated else 1.0
        state = pb.EnvironmentStateType.RUNNING
        if terminated or truncated:
            state, self.running = pb.EnvironmentStateType.TERMINATED, False
        return pb.StepResponse(state=state, observations=self.observations(req.requested_observations))


def no_settings(settings, what):
    if settings:
        raise Refused(code_pb2.INVALID_ARGUMENT, f"{what}: this server takes no settings (got {sorted(settings)})")


class Server(dm_env_rpc_pb2_grpc.EnvironmentServicer):
    def Process(self, request_iterator, context):  # noqa: N802 - the protocol's name
        agent = Agent()
        world = None
        for request in request_iterator:
            kind = request.WhichOneof("payload")
            try:
                if kind == "create_world":
                    no_settings(request.create_world.settings, "CreateWorld")
                    if world is not None:
                        raise Refused(code_pb2.FAILED_PRECONDITION, "one world per connection")
                    world = "pendulum"
                    yield pb.EnvironmentResponse(create_world=pb.CreateWorldResponse(world_name=world))
                elif kind == "join_world":
                    no_settings(request.join_world.settings, "JoinWorld")
                    if request.join_world.world_name != world:
                        raise Refused(code_pb2.NOT_FOUND, f"no world {request.join_world.world_name!r}")
                    agent.env = gym.make("Pendulum-v1")
                    yield pb.EnvironmentResponse(join_world=pb.JoinWorldResponse(specs=specs()))
                elif kind == "step":
                    yield pb.EnvironmentResponse(step=agent.step(request.step))
                elif kind == "reset":
                    no_settings(request.reset.settings, "Reset")
                    agent.running = False
                    yield pb.EnvironmentResponse(reset=pb.ResetResponse(specs=specs()))
                elif kind == "reset_world":
                    no_settings(request.reset_world.settings, "ResetWorld")
                    agent.running = False
                    yield pb.EnvironmentResponse(reset_world=pb.ResetWorldResponse())
                elif kind == "leave_world":
                    agent = Agent()
                    yield pb.EnvironmentResponse(leave_world=pb.LeaveWorldResponse())
                elif kind == "destroy_world":
                    if agent.env is not None:
                        raise Refused(code_pb2.FAILED_PRECONDITION, "leave the world before destroying it")
                    world = None
                    yield pb.EnvironmentResponse(destroy_world=pb.DestroyWorldResponse())
                else:
                    raise Refused(code_pb2.UNIMPLEMENTED, f"{kind} is not supported")
            except Refused as e:
                yield pb.EnvironmentResponse(error=status_pb2.Status(code=e.code, message=str(e)))


def main():
    global PIXELS
    ap = argparse.ArgumentParser()
    ap.add_argument("--pixels", type=int, default=0)
    PIXELS = ap.parse_args().pixels
    server = grpc.server(futures.ThreadPoolExecutor(max_workers=8))
    dm_env_rpc_pb2_grpc.add_EnvironmentServicer_to_server(Server(), server)
    port = server.add_insecure_port("127.0.0.1:0")
    server.start()
    print(f"listening on 127.0.0.1:{port}", flush=True)
    server.wait_for_termination()


if __name__ == "__main__":
    sys.exit(main())
