"""DeepMind's dm_env_rpc compliance suites against the bridge, for a plain gymnasium env
(Pendulum-v1, no design) and for a body factory with a 2-d design (tests/toys.py)."""

import numpy as np
from dm_env_rpc.v1 import dm_env_rpc_pb2 as pb
from dm_env_rpc.v1 import tensor_utils

# Modules, not classes: pytest would collect the abstract suites themselves.
from dm_env_rpc.v1.compliance import create_destroy_world as cdw_suite
from dm_env_rpc.v1.compliance import join_leave_world as jlw_suite
from dm_env_rpc.v1.compliance import reset as reset_suite
from dm_env_rpc.v1.compliance import reset_world as reset_world_suite
from dm_env_rpc.v1.compliance import step as step_suite

from helpers import Client, shared_server

f32 = lambda v: tensor_utils.pack_tensor(np.asarray(v, dtype=np.float32))  # noqa: E731

INVALID_WORLD_SETTINGS = {
    "pendulum": {
        "design": f32([1.0]),  # the design has 0 elements
        "seed": tensor_utils.pack_tensor(-1, dtype=np.int64),
        "unknown": f32(1.0),
    },
    "toy": {
        "design": f32([5.0, 1.0]),  # outside the box [0.5, 2]^2
        "seed": tensor_utils.pack_tensor(1.5),  # not an integer
        "unknown": f32(1.0),
    },
}
RESET_WORLD_SETTINGS = {
    "pendulum": {"seed": tensor_utils.pack_tensor(7, dtype=np.int64)},
    "toy": {"design": f32([1.5, 0.7]), "seed": tensor_utils.pack_tensor(3, dtype=np.uint32)},
}
ACTION_DIM = {"pendulum": 1, "toy": 2}


class _Connected:
    """A fresh connection per test case to the shared server of ``KIND``."""

    KIND = ""

    def setUp(self):
        super().setUp()
        self._client = Client(shared_server(self.KIND))

    def tearDown(self):
        try:
            super().tearDown()
        finally:
            self._client.close()

    @property
    def connection(self):
        return self._client.connection


class _WithWorld(_Connected):
    """...with a world created on that connection (it dies with the connection)."""

    def setUp(self):
        super().setUp()
        self._world_name = self._client.create()

    @property
    def world_name(self):
        return self._world_name


def _suites(kind):
    class CreateDestroyWorld(_Connected, cdw_suite.CreateDestroyWorld):
        KIND = kind

        @property
        def required_world_settings(self):
            return {}

        @property
        def invalid_world_settings(self):
            return INVALID_WORLD_SETTINGS[kind]

        @property
        def has_multiple_world_support(self):
            return True

    class JoinLeaveWorld(_WithWorld, jlw_suite.JoinLeaveWorld):
        KIND = kind

        @property
        def invalid_join_settings(self):
            # JoinWorld takes no settings at all, not even the world's.
            return {"design": f32([1.0, 1.0]), "seed": tensor_utils.pack_tensor(1)}

    class Reset(_WithWorld, reset_suite.Reset):
        KIND = kind

        def join_world(self):
            return self.connection.send(pb.JoinWorldRequest(world_name=self.world_name)).specs

    class ResetWorld(_WithWorld, reset_world_suite.ResetWorld):
        KIND = kind

        @property
        def required_reset_world_settings(self):
            return RESET_WORLD_SETTINGS[kind]

    class Step(_WithWorld, step_suite.Step):
        KIND = kind

        def setUp(self):
            super().setUp()
            self._specs = self.connection.send(pb.JoinWorldRequest(world_name=self.world_name)).specs

        def tearDown(self):
            try:
                self.connection.send(pb.LeaveWorldRequest())
            finally:
                super().tearDown()

        @property
        def specs(self):
            return self._specs

        @property
        def required_actions(self):
            # The profile requires `action` on every running step.
            return {1: f32(np.zeros(ACTION_DIM[kind]))}

    return CreateDestroyWorld, JoinLeaveWorld, Reset, ResetWorld, Step


(
    TestPendulumCreateDestroyWorld,
    TestPendulumJoinLeaveWorld,
    TestPendulumReset,
    TestPendulumResetWorld,
    TestPendulumStep,
) = _suites("pendulum")

(
    TestToyCreateDestroyWorld,
    TestToyJoinLeaveWorld,
    TestToyReset,
    TestToyResetWorld,
    TestToyStep,
) = _suites("toy")
