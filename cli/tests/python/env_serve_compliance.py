"""DeepMind's dm_env_rpc compliance suites and DmEnvAdaptor against `coadapt env-serve`.

usage: python env_serve_compliance.py dm-env-rpc://HOST:PORT DESIGN_DIM [absltest flags]

Run by cli/tests/env_rpc.rs with the robot served by the binary. Every suite class of
dm_env_rpc.v1.compliance is subclassed with our profile's settings; then DmEnvAdaptor runs a
whole episode (the served robot's time limit ends it with discount 1, a truncation).
"""
import sys

import grpc
import numpy as np
from absl.testing import absltest
from dm_env_rpc.v1 import compliance, connection as dm_connection, dm_env_adaptor, dm_env_rpc_pb2, tensor_utils

URL = sys.argv.pop(1)
DESIGN_DIM = int(sys.argv.pop(1))
ADDRESS = URL.removeprefix("dm-env-rpc://")


def connect():
    channel = grpc.insecure_channel(ADDRESS)
    grpc.channel_ready_future(channel).result(timeout=10)
    return dm_connection.Connection(channel)


class _Connected:
    """A fresh connection per test, closed after it."""

    def setUp(self):
        self._connection = connect()
        super().setUp()

    def tearDown(self):
        try:
            super().tearDown()
        finally:
            self._connection.close()

    @property
    def connection(self):
        return self._connection


def design(value):
    return tensor_utils.pack_tensor(np.full(DESIGN_DIM, value, dtype=np.float32))


class CreateDestroyWorld(_Connected, compliance.CreateDestroyWorld):
    required_world_settings = {}
    has_multiple_world_support = True

    @property
    def invalid_world_settings(self):
        return {
            "design": design(1e6),  # outside the design box
            "seed": tensor_utils.pack_tensor(-3, dtype=np.int64),
            "gravity": tensor_utils.pack_tensor(9.81),  # not a setting of the profile
        }


class _InWorld(_Connected):
    """A world created before each test and destroyed after it."""

    def setUp(self):
        super().setUp()
        self._world = self.connection.send(dm_env_rpc_pb2.CreateWorldRequest()).world_name

    def tearDown(self):
        try:
            self.connection.send(dm_env_rpc_pb2.LeaveWorldRequest())
            self.connection.send(dm_env_rpc_pb2.DestroyWorldRequest(world_name=self._world))
        finally:
            super().tearDown()

    @property
    def world_name(self):
        return self._world


class JoinLeaveWorld(_InWorld, compliance.JoinLeaveWorld):
    invalid_join_settings = {"team": tensor_utils.pack_tensor(1)}


class ResetWorld(_InWorld, compliance.ResetWorld):
    required_reset_world_settings = {"seed": tensor_utils.pack_tensor(7, dtype=np.uint64)}


class Reset(_InWorld, compliance.Reset):
    def join_world(self):
        return self.connection.send(dm_env_rpc_pb2.JoinWorldRequest(world_name=self._world)).specs


class Step(_InWorld, compliance.Step):
    def setUp(self):
        super().setUp()
        self._specs = self.connection.send(dm_env_rpc_pb2.JoinWorldRequest(world_name=self._world)).specs

    @property
    def specs(self):
        return self._specs

    @property
    def required_actions(self):
        # The profile makes `action` required on every running step (a robot must not guess).
        spec = self._specs.actions[1]
        return {1: tensor_utils.pack_tensor(np.zeros(list(spec.shape), dtype=np.float32))}


class Adaptor(absltest.TestCase):
    def test_dm_env_adaptor_runs_a_whole_episode(self):
        conn = connect()
        env, world = dm_env_adaptor.create_and_join_world(conn, create_world_settings={}, join_world_settings={})
        try:
            ts = env.reset()
            self.assertTrue(ts.first())
            spec = env.action_spec()["action"]
            rng = np.random.default_rng(0)
            steps, total = 0, 0.0
            while True:
                a = np.asarray(rng.uniform(spec.minimum, spec.maximum, size=spec.shape), dtype=np.float32)
                ts = env.step({"action": a})
                steps += 1
                total += float(ts.reward)
                self.assertTrue(np.all(np.isfinite(ts.observation["observation"])))
                if ts.last():
                    break
            print(f"DmEnvAdaptor: one episode of {steps} steps, return {total:.3f}, final discount {ts.discount}")
            self.assertEqual(ts.discount, 1.0, "a time limit is a truncation: discount 1")
            self.assertGreater(steps, 1)
        finally:
            env.close()
            conn.send(dm_env_rpc_pb2.DestroyWorldRequest(world_name=world))
            conn.close()


if __name__ == "__main__":
    absltest.main()
