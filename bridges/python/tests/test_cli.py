"""The `coadapt-gym-serve` command, run as a separate process as a test harness would."""

import json
import os
import pathlib
import re
import select
import shutil
import signal
import subprocess
import sys
import time

import grpc
import numpy as np
from dm_env_rpc.v1 import connection as dm_connection
from dm_env_rpc.v1 import dm_env_rpc_pb2 as pb
from dm_env_rpc.v1 import tensor_utils

TESTS = pathlib.Path(__file__).resolve().parent
LINE = re.compile(r"^coadapt-gym-serve listening on (127\.0\.0\.1):(\d+)\n$")


def command():
    script = pathlib.Path(sys.executable).parent / "coadapt-gym-serve"
    if script.exists():
        return [str(script)]
    found = shutil.which("coadapt-gym-serve")
    return [found] if found else [sys.executable, "-m", "coadapt_bridge.cli"]


def start(*args, env=None):
    environ = dict(os.environ)
    environ["PYTHONPATH"] = os.pathsep.join([str(TESTS), environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    environ.update(env or {})
    return subprocess.Popen(
        command() + list(args),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=environ,
    )


def read_line(proc, timeout=30.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        ready, _, _ = select.select([proc.stdout], [], [], 0.1)
        if ready:
            return proc.stdout.readline()
        if proc.poll() is not None:
            break
    proc.kill()
    raise AssertionError(f"no listening line; stderr:\n{proc.stderr.read()}")


def stop(proc, sig=signal.SIGTERM, timeout=10.0):
    proc.send_signal(sig)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise
    return proc.returncode, out, err


class Conn:
    def __init__(self, port):
        self.channel = grpc.insecure_channel(f"127.0.0.1:{port}")
        grpc.channel_ready_future(self.channel).result(timeout=10)
        self.c = dm_connection.Connection(self.channel)

    def close(self):
        self.c.close()
        self.channel.close()


def test_help_explains_everything():
    out = subprocess.run(command() + ["--help"], capture_output=True, text=True, timeout=30)
    assert out.returncode == 0
    for word in ("--env", "--factory", "--driver", "--host", "--port", "--max-episode-steps", "--seed",
                 "--step-timeout", "design_space", "safe_stop", "listening on", "SIGTERM", "seed", "design"):
        assert word in out.stdout, word


def test_serves_pendulum_and_stops_on_sigterm():
    proc = start("--env", "Pendulum-v1", "--port", "0", "--max-episode-steps", "3", "--seed", "11")
    line = read_line(proc)
    m = LINE.match(line)
    assert m, line
    conn = Conn(int(m.group(2)))
    try:
        world = conn.c.send(pb.CreateWorldRequest()).world_name
        assert world == "world-1"
        conn.c.send(pb.JoinWorldRequest(world_name=world))
        r = conn.c.send(pb.StepRequest(requested_observations=[1, 3]))
        assert r.state == pb.EnvironmentStateType.RUNNING
        action = {1: tensor_utils.pack_tensor(np.array([0.0], np.float32))}
        states = [conn.c.send(pb.StepRequest(actions=action, requested_observations=[3])) for _ in range(3)]
        assert [s.state for s in states][-1] == pb.EnvironmentStateType.TERMINATED  # --max-episode-steps 3
        assert tensor_utils.unpack_tensor(states[-1].observations[3]) == 1.0
    finally:
        conn.close()
    code, out, err = stop(proc)
    assert code == 0, err
    assert out == ""  # nothing after the one line
    assert "stopped" in err


def test_serves_a_robot_driver_and_safe_stops_on_sigint(tmp_path):
    log_file = tmp_path / "device.jsonl"
    proc = start("--driver", "toys:FileLoggingDevice", "--step-timeout", "5",
                 env={"COADAPT_FAKE_DEVICE_LOG": str(log_file)})
    m = LINE.match(read_line(proc))
    assert m
    conn = Conn(int(m.group(2)))
    try:
        world = conn.c.send(pb.CreateWorldRequest()).world_name
        conn.c.send(pb.JoinWorldRequest(world_name=world))
        conn.c.send(pb.StepRequest())
        action = {1: tensor_utils.pack_tensor(np.array([0.5, -0.5], np.float32))}
        conn.c.send(pb.StepRequest(actions=action))
        code, _, err = stop(proc, signal.SIGINT)  # mid-episode
    finally:
        conn.close()
    assert code == 0, err
    calls = [json.loads(l)["call"] for l in log_file.read_text().splitlines()]
    assert calls == ["reset", "step", "safe_stop", "close"], calls


def test_refuses_discrete_actions_at_start():
    proc = start("--factory", "toys:make_discrete")
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 2
    assert out == ""
    assert "continuous Box" in err
