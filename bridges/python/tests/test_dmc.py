"""The DeepMind Control Suite backend (`--dmc cheetah-run`, coadapt_bridge/dmc.py): the frame
resize and the pinned requirements always; the served task only when dm_control imports and
renders headless here (otherwise skipped, with the reason)."""

import os
import pathlib
import re

import grpc
import numpy as np
import pytest
from dm_env_rpc.v1 import dm_env_rpc_pb2 as pb
from dm_env_rpc.v1 import error as dm_error
from dm_env_rpc.v1 import tensor_spec_utils, tensor_utils

from coadapt_bridge.dmc import FrameResizer, area_weights
from helpers import Client, StreamConnection

HERE = pathlib.Path(__file__).resolve().parent.parent
RUNNING, TERMINATED = pb.EnvironmentStateType.RUNNING, pb.EnvironmentStateType.TERMINATED
PIXELS = 64
OBS = 3 * PIXELS * PIXELS


# -- resize (numpy only) -------------------------------------------------------------------


def _reference(img: np.ndarray, out: int) -> np.ndarray:
    """Exact area averaging in float64, written independently: each output pixel is the mean
    of the input over its rectangle, fractional pixels weighted by the area covered."""
    h, w, _ = img.shape
    res = np.empty((3, out, out))
    sy, sx = h / out, w / out
    for oy in range(out):
        for ox in range(out):
            y0, y1, x0, x1 = oy * sy, (oy + 1) * sy, ox * sx, (ox + 1) * sx
            acc = np.zeros(3)
            for y in range(int(np.floor(y0)), int(np.ceil(y1))):
                cy = min(y1, y + 1) - max(y0, y)
                for x in range(int(np.floor(x0)), int(np.ceil(x1))):
                    cx = min(x1, x + 1) - max(x0, x)
                    acc += cy * cx * img[y, x]
            res[:, oy, ox] = acc / (sy * sx) / 255.0
    return res


@pytest.mark.parametrize("shape", [(240, 320, 64), (24, 32, 7), (5, 7, 8)])
def test_resize_is_area_average(shape):
    h, w, out = shape
    img = np.random.default_rng(1).integers(0, 256, (h, w, 3), dtype=np.uint8)
    got = FrameResizer(h, w, out)(img)
    assert got.dtype == np.float32 and got.shape == (3 * out * out,)
    if h * w <= 24 * 32:
        np.testing.assert_allclose(got.reshape(3, out, out), _reference(img, out), atol=1e-6)
    np.testing.assert_allclose(area_weights(h, out).sum(axis=1), 1.0)
    np.testing.assert_allclose(area_weights(w, out).sum(axis=1), 1.0)
    # The whole image's mean is kept (every input pixel has the same total weight when
    # downscaling by area).
    if h >= out and w >= out:
        np.testing.assert_allclose(got.reshape(3, -1).mean(axis=1), img.reshape(-1, 3).mean(axis=0) / 255.0, rtol=1e-5)


def test_resize_channel_major_and_bounds():
    img = np.empty((240, 320, 3), dtype=np.uint8)
    img[..., 0], img[..., 1], img[..., 2] = 255, 0, 128
    got = FrameResizer(240, 320, 64)(img)
    assert np.all(got[:4096] == 1.0) and np.all(got[4096:8192] == 0.0)
    np.testing.assert_allclose(got[8192:], 128 / 255, rtol=1e-6)
    # A left-to-right ramp: row-major inside each channel (values grow along a row).
    ramp = np.broadcast_to(np.linspace(0, 255, 320).astype(np.uint8)[None, :, None], (240, 320, 3)).copy()
    r = FrameResizer(240, 320, 64)(ramp).reshape(3, 64, 64)
    assert np.all(np.diff(r[0, 0]) > 0) and np.all(r[0, :, 0] == r[0, 0, 0])
    assert r.min() >= 0.0 and r.max() <= 1.0


def test_resize_matches_pil_box_for_integer_factor():
    Image = pytest.importorskip("PIL.Image")
    # Constant along y: only the x axis (320 -> 64, factor 5) matters, where PIL's BOX filter
    # is the area average too.
    row = np.random.default_rng(2).integers(0, 256, (1, 320, 3), dtype=np.uint8)
    img = np.broadcast_to(row, (240, 320, 3)).copy()
    pil = np.asarray(Image.fromarray(img).resize((64, 64), Image.BOX), dtype=np.float32) / 255.0
    ours = FrameResizer(240, 320, 64)(img).reshape(3, 64, 64).transpose(1, 2, 0)
    np.testing.assert_allclose(ours, pil, atol=0.5 / 255 + 1e-6)


def _pins(name):
    pins = {}
    for line in (HERE / name).read_text().splitlines():
        m = re.match(r"^([A-Za-z0-9_.-]+)==(\S+)$", line.strip())
        if m:
            pins[m.group(1).lower().replace("_", "-")] = m.group(2)
    return pins


def test_dmc_requirements_keep_the_other_pins():
    base, dmc = _pins("requirements.txt"), _pins("requirements-dmc.txt")
    mujoco4 = {"mujoco", "mujoco-core", "mujoco-studio"}
    for name, version in base.items():
        if name not in mujoco4:
            assert dmc.get(name) == version, f"requirements-dmc.txt: {name}=={dmc.get(name)}, requirements.txt has {version}"
    assert dmc["dm-control"] == "1.0.50" and dmc["mujoco"] == "3.17.0"
    assert "mujoco-core" not in dmc and "mujoco-studio" not in dmc
    pyproject = (HERE / "pyproject.toml").read_text()
    assert 'dmc = ["dm_control==1.0.50", "mujoco==3.17.0"]' in pyproject


# -- the served task (dm_control + headless GL) -------------------------------------------


@pytest.fixture(scope="module")
def dmc_server():
    os.environ.setdefault("MUJOCO_GL", "egl")
    suite = pytest.importorskip("dm_control.suite", reason="dm_control is not installed (setup_venv.sh --dmc)")
    try:
        env = suite.load("cheetah", "run")
        env.reset()
        frame = env.physics.render(height=240, width=320, camera_id=0)
        env.physics.free()
    except Exception as e:  # noqa: BLE001 - whatever stops dm_control from rendering here
        pytest.skip(f"dm_control cannot load or render cheetah-run here (MUJOCO_GL={os.environ['MUJOCO_GL']}): {type(e).__name__}: {e}")
    assert frame.shape == (240, 320, 3)

    from coadapt_bridge.dmc import DmcBackend
    from coadapt_bridge.server import BridgeServer

    with BridgeServer(DmcBackend("cheetah-run"), port=0) as server:
        yield server


@pytest.fixture
def client(dmc_server):
    with Client(dmc_server) as c:
        yield c


def code_of(err):
    return next(c for c in grpc.StatusCode if c.value[0] == err.code)


def test_specs(client):
    specs = client.join(client.create())
    obs = specs.observations
    assert (obs[1].name, list(obs[1].shape), obs[1].dtype) == ("observation", [OBS], pb.DataType.FLOAT)
    b = tensor_spec_utils.bounds(obs[1])
    assert np.all(b.min == 0.0) and np.all(b.max == 1.0)
    act = specs.actions[1]
    assert (act.name, list(act.shape), act.dtype) == ("action", [6], pb.DataType.FLOAT)
    b = tensor_spec_utils.bounds(act)
    assert np.all(b.min == -1.0) and np.all(b.max == 1.0)
    assert (obs[2].name, list(obs[2].shape)) == ("reward", [])
    assert (obs[3].name, list(obs[3].shape)) == ("discount", [])
    assert (obs[4].name, list(obs[4].shape)) == ("design", [0])
    assert not obs[4].HasField("min") and not obs[4].HasField("max")


def test_frames_rewards_and_refusals(client):
    client.join(client.create(seed=3))
    state, first = client.step()
    assert state == RUNNING
    f0 = first[1]
    assert f0.shape == (OBS,) and f0.dtype == np.float32
    assert f0.min() >= 0.0 and f0.max() <= 1.0 and f0.max() > 0.2  # not a blank frame
    assert first[2] == 0.0 and first[3] == 1.0 and first[4].shape == (0,)

    action = np.array([0.9, -0.9, 0.9, -0.9, 0.9, -0.9], dtype=np.float32)
    for i in range(8):
        state, o = client.step(action if i % 4 < 2 else -action)
        assert state == RUNNING
        assert np.isfinite(o[2]) and 0.0 <= o[2] <= 2.0  # two control steps, each in [0, 1]
        assert o[3] == 1.0
        assert o[1].shape == (OBS,) and o[1].min() >= 0.0 and o[1].max() <= 1.0
    diff = np.abs(o[1] - f0)
    assert diff.max() > 0.2 and diff.mean() > 1e-3, (diff.max(), diff.mean())

    for bad in ([1.5] * 6, [0.0] * 5 + [-1.01], [np.nan] * 6):
        with pytest.raises(dm_error.DmEnvRpcError) as e:
            client.step(bad)
        assert code_of(e.value) == grpc.StatusCode.INVALID_ARGUMENT
    with pytest.raises(dm_error.DmEnvRpcError) as e:
        client.step([0.5] * 5)
    assert code_of(e.value) == grpc.StatusCode.INVALID_ARGUMENT
    state, o = client.step(action)  # the episode goes on after refusals
    assert state == RUNNING


def test_seed_decides_the_first_frame(client):
    firsts = []
    for seed in (7, 7, 8):  # one stream, worlds one after another
        world = client.create(seed=seed)
        client.join(world)
        firsts.append(client.step()[1][1])
        client.send(pb.LeaveWorldRequest())
        client.send(pb.DestroyWorldRequest(world_name=world))
    np.testing.assert_array_equal(firsts[0], firsts[1])
    assert np.abs(firsts[0] - firsts[2]).max() > 0.0


def test_episode_ends_after_420_steps(client):
    """A whole episode (420 renders: about 15 s of CPU)."""
    client.join(client.create(seed=1))
    state, _ = client.step()
    assert state == RUNNING
    rng = np.random.default_rng(0)
    total = 0.0
    for i in range(1, 421):
        state, o = client.step(rng.uniform(-1, 1, 6).astype(np.float32), uids=(2, 3))
        total += float(o[2])
        if i < 420:
            assert state == RUNNING, i
    assert state == TERMINATED and o[3] == 1.0
    assert np.isfinite(total) and 0.0 <= total <= 840.0
    state, o = client.step()  # a new episode
    assert state == RUNNING and o[1].shape == (OBS,) and o[2] == 0.0


def test_command_line(dmc_server):  # the fixture skips when dm_control cannot render here
    import test_cli

    proc = test_cli.start("--dmc", "cheetah-run", "--pixels", "32", "--episode-steps", "3", env={"MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")})
    line = test_cli.read_line(proc, timeout=60)
    m = test_cli.LINE.match(line)
    assert m, line
    try:
        channel = grpc.insecure_channel(f"{m.group(1)}:{m.group(2)}")
        grpc.channel_ready_future(channel).result(timeout=10)
        conn = StreamConnection(channel)
        world = conn.send(pb.CreateWorldRequest()).world_name
        specs = conn.send(pb.JoinWorldRequest(world_name=world)).specs
        assert list(specs.observations[1].shape) == [3 * 32 * 32]
        states = []
        for _ in range(4):
            r = conn.send(pb.StepRequest(actions={1: tensor_utils.pack_tensor(np.zeros(6, np.float32))}, requested_observations=[1, 3]))
            states.append(r.state)
            assert len(r.observations[1].floats.array) == 3 * 32 * 32
        assert states == [RUNNING, RUNNING, RUNNING, TERMINATED]
        conn.close()
        channel.close()
    finally:
        test_cli.stop(proc)


def test_dmc_options_need_dmc():
    from coadapt_bridge import cli

    for args in (["--env", "Pendulum-v1", "--pixels", "64"], ["--env", "Pendulum-v1", "--action-repeat", "2"]):
        with pytest.raises(SystemExit) as e:
            cli.parse_args(args)
        assert e.value.code == 2
    with pytest.raises(SystemExit):
        cli.parse_args(["--dmc", "cheetah-run", "--episode-steps", "0"])
    args = cli.parse_args(["--dmc", "cheetah-run"])
    assert args.dmc == "cheetah-run" and args.pixels is None
