"""A fake robot behind the bridge: the safety rules are the bridge's, whatever the driver does."""

import logging
import time

import grpc
import numpy as np
import pytest
from dm_env_rpc.v1 import dm_env_rpc_pb2 as pb
from dm_env_rpc.v1 import error as dm_error

from coadapt_bridge.backends import BackendError, DriverBackend
from coadapt_bridge.driver import RobotDriver
from coadapt_bridge.server import BridgeServer
from helpers import Client, wait_until
from toys import FakeDevice

RUNNING, TERMINATED, INTERRUPTED = (
    pb.EnvironmentStateType.RUNNING,
    pb.EnvironmentStateType.TERMINATED,
    pb.EnvironmentStateType.INTERRUPTED,
)


@pytest.fixture
def robot(request):
    """(device, server) with the device's declarations and the server's options from the
    test's `robot_options` marker."""
    marker = request.node.get_closest_marker("robot_options")
    opts = dict(marker.kwargs) if marker else {}
    step_timeout = opts.pop("step_timeout", 5.0)
    device = FakeDevice(**opts)
    server = BridgeServer(DriverBackend(device), step_timeout=step_timeout)
    server.start()
    yield device, server
    server.stop(grace=0)


def joined(server, design=None):
    c = Client(server)
    settings = {} if design is None else {"design": np.asarray(design, np.float32)}
    c.join(c.create(**settings))
    return c


def test_profile_of_a_driver(robot):
    device, server = robot
    with joined(server, design=[0.25]) as c:
        state, o = c.step()
        assert state == RUNNING
        np.testing.assert_array_equal(o[4], [0.25])
        assert device.of("reset")[0][2] == [0.25]
        state, o = c.step([0.5, -0.5])
        np.testing.assert_array_equal(o[1], [0.5, -0.5])


def test_out_of_box_actions_never_reach_the_driver(robot):
    device, server = robot
    with joined(server) as c:
        c.step()
        for bad in ([1.5, 0.0], [0.0, -1.01], [np.nan, 0.0]):
            with pytest.raises(dm_error.DmEnvRpcError, match="action"):
                c.step(bad)
        assert device.of("step") == []


def test_actions_are_clipped_to_the_declared_range_before_the_driver():
    # Behind the protocol check the bridge clips again: the driver sees nothing outside.
    device = FakeDevice()
    backend = DriverBackend(device)
    body = backend.new_body(np.array([0.2], np.float32))
    body.start_episode(np.array([0.2], np.float32), None)
    body.step(np.array([3.0, -7.0], np.float32))
    assert device.of("step")[-1][2] == [1.0, -1.0]


@pytest.mark.robot_options(max_action_change=0.25, rest_action=[0.0, 0.0])
def test_per_step_change_is_limited(robot):
    device, server = robot
    with joined(server) as c:
        c.step()
        c.step([1.0, -1.0])
        c.step([1.0, -1.0])
        c.step([-1.0, 1.0])
        sent = [s[2] for s in device.of("step")]
        np.testing.assert_allclose(sent, [[0.25, -0.25], [0.5, -0.5], [0.25, -0.25]])


@pytest.mark.robot_options(max_action_rate_hz=25.0)
def test_action_rate_is_limited(robot):
    device, server = robot
    with joined(server) as c:
        c.step()
        t0 = time.monotonic()
        for _ in range(8):
            c.step([0.1, 0.1])  # as fast as the client can
        elapsed = time.monotonic() - t0
    times = [s[0] for s in device.of("step")]
    intervals = np.diff(times)
    assert len(intervals) == 7
    assert intervals.min() >= 1 / 25.0 - 0.002, intervals
    assert elapsed >= 7 / 25.0 - 0.01


@pytest.mark.robot_options(step_timeout=0.3)
def test_missed_step_deadline_safe_stops_and_interrupts_the_episode(robot):
    device, server = robot
    with joined(server) as c:
        c.step()
        c.step([0.5, 0.5])
        t_last = device.of("step")[-1][0]
        assert wait_until(lambda: device.of("safe_stop"), timeout=2.0)
        waited = device.of("safe_stop")[0][0] - t_last
        assert 0.29 <= waited < 1.5, waited
        # The episode was cut: the next step says so, the one after starts a new episode.
        state, _ = c.step([0.5, 0.5])
        assert state == INTERRUPTED
        state, o = c.step([0.5, 0.5])
        assert state == RUNNING and o[2] == 0.0
        assert len(device.of("reset")) == 2
        assert device.names()[-3:] == ["step", "safe_stop", "reset"]
        # Steps in time: no stop.
        n = len(device.of("safe_stop"))
        for _ in range(5):
            time.sleep(0.02)
            assert c.step([0.0, 0.0])[0] == RUNNING
        assert len(device.of("safe_stop")) == n


def test_lost_connection_safe_stops_and_frees_the_robot(robot):
    device, server = robot
    c = Client(server, own_channel=True)
    world = c.create()
    c.join(world)
    c.step()
    c.step([0.3, 0.3])
    c.channel.close()  # mid-episode, without LeaveWorld or DestroyWorld
    # Well before the step deadline (5 s): it is the lost connection that stops the robot.
    assert wait_until(lambda: device.of("safe_stop"), timeout=2.0)
    assert wait_until(lambda: not server.service.worlds, timeout=5.0)
    with joined(server) as again:  # the robot serves a new world
        assert again.step()[0] == RUNNING


def test_leave_world_safe_stops(robot):
    device, server = robot
    with joined(server) as c:
        c.step()
        c.step([0.2, 0.2])
        assert device.of("safe_stop") == []
        c.send(pb.LeaveWorldRequest())
        assert device.names()[-1] == "safe_stop"


def test_destroy_world_safe_stops_and_one_world_at_a_time(robot):
    device, server = robot
    with Client(server) as c:
        world = c.create()
        with pytest.raises(dm_error.DmEnvRpcError, match="one world at a time") as e:
            c.create()
        assert e.value.code == grpc.StatusCode.FAILED_PRECONDITION.value[0]
        c.send(pb.DestroyWorldRequest(world_name=world))
        assert device.names()[-1] == "safe_stop"
        c.create()  # free again


def test_server_shutdown_safe_stops_then_closes():
    device = FakeDevice()
    server = BridgeServer(DriverBackend(device), step_timeout=5.0)
    server.start()
    c = joined(server)
    c.step()
    c.step([0.1, 0.1])
    server.stop()
    names = device.names()
    assert names[-2:] == ["safe_stop", "close"]
    assert names.count("safe_stop") == 1
    c.close()


@pytest.mark.robot_options(fail_safe_stop=True, step_timeout=0.2)
def test_safe_stop_exceptions_are_logged_not_fatal(robot, caplog):
    device, server = robot
    with caplog.at_level(logging.ERROR, logger="coadapt_bridge"):
        with joined(server) as c:
            c.step()
            assert wait_until(lambda: device.of("safe_stop"), timeout=2.0)  # the watchdog's
            assert c.step([0.1, 0.1])[0] == INTERRUPTED
            assert c.step()[0] == RUNNING
            c.send(pb.LeaveWorldRequest())  # safe_stop raises again: still only logged
            assert len(device.of("safe_stop")) == 2
            (world,) = server.service.worlds  # the server goes on: rejoin and step
            c.join(world)
            assert c.step()[0] == RUNNING
    assert "brake is stuck" in caplog.text
    assert server.service.watchdog._thread.is_alive()


def test_driver_declarations_are_checked():
    class NoRate(FakeDevice):
        max_action_rate_hz = None

    with pytest.raises(BackendError, match="max_action_rate_hz"):
        DriverBackend(NoRate())

    class NoStop(RobotDriver):
        action_low, action_high, observation_size, max_action_rate_hz = [-1], [1], 1, 10.0

        def reset(self, design):
            return [0.0]

        def step(self, action):
            return [0.0], 0.0, False, False

    with pytest.raises(BackendError, match="safe_stop"):
        DriverBackend(NoStop())
    with pytest.raises(BackendError, match="not below"):
        DriverBackend(FakeDevice(action_low=[1.0, 0.0], action_high=[1.0, 1.0]))
    with pytest.raises(TypeError, match="unknown declaration"):
        FakeDevice(max_rate=3)


def test_the_robot_driver_template_is_servable(monkeypatch):
    import pathlib

    monkeypatch.syspath_prepend(str(pathlib.Path(__file__).resolve().parent.parent / "examples"))
    backend = DriverBackend.from_spec("robot_driver_template:MyRobotDriver")
    assert backend.profile.action_dim == 2 and backend.profile.design.dim == 1
    server = BridgeServer(backend)
    server.start()
    try:
        with joined(server, design=[0.15]) as c:
            assert c.step()[0] == RUNNING
            state, o = c.step([0.1, -0.1])
            assert state == RUNNING and o[1].shape == (4,)
    finally:
        server.stop()
