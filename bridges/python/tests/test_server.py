"""The coadapt profile as the bridge serves it: specs, settings, seeds, designs, episode ends,
errors, worlds' lifetimes, and DeepMind's DmEnvAdaptor on Pendulum-v1."""

import grpc
import numpy as np
import pytest
from dm_env_rpc.v1 import dm_env_adaptor
from dm_env_rpc.v1 import dm_env_rpc_pb2 as pb
from dm_env_rpc.v1 import error as dm_error
from dm_env_rpc.v1 import tensor_spec_utils, tensor_utils

import toys
from coadapt_bridge import design_space
from coadapt_bridge.backends import BackendError, GymBackend
from coadapt_bridge.server import BridgeServer
from helpers import Client, shared_server, wait_until

RUNNING, TERMINATED, INTERRUPTED = (
    pb.EnvironmentStateType.RUNNING,
    pb.EnvironmentStateType.TERMINATED,
    pb.EnvironmentStateType.INTERRUPTED,
)


def code_of(err: dm_error.DmEnvRpcError) -> grpc.StatusCode:
    return next(c for c in grpc.StatusCode if c.value[0] == err.code)


@pytest.fixture
def toy():
    with Client(shared_server("toy")) as c:
        yield c


@pytest.fixture
def pendulum():
    with Client(shared_server("pendulum")) as c:
        yield c


def test_specs_follow_the_profile(toy, pendulum):
    specs = toy.join(toy.create())
    assert {uid: s.name for uid, s in specs.actions.items()} == {1: "action"}
    assert {uid: s.name for uid, s in specs.observations.items()} == {
        1: "observation", 2: "reward", 3: "discount", 4: "design"}
    for s in list(specs.actions.values()) + list(specs.observations.values()):
        assert s.dtype == pb.DataType.FLOAT
    a = specs.actions[1]
    assert list(a.shape) == [2]
    b = tensor_spec_utils.bounds(a)
    np.testing.assert_array_equal(b.min, [-1, -1])
    np.testing.assert_array_equal(b.max, [1, 1])
    obs = specs.observations[1]
    assert list(obs.shape) == [3] and not obs.HasField("min") and not obs.HasField("max")  # infinite box
    assert list(specs.observations[2].shape) == [] and not specs.observations[2].HasField("min")
    d = tensor_spec_utils.bounds(specs.observations[3])
    assert (d.min, d.max) == (0.0, 1.0)
    design = specs.observations[4]
    assert list(design.shape) == [2]
    db = tensor_spec_utils.bounds(design)
    np.testing.assert_array_equal(db.min, [0.5, 0.5])
    np.testing.assert_array_equal(db.max, [2.0, 2.0])

    pspecs = pendulum.join(pendulum.create())
    po = pspecs.observations[1]
    pb_ = tensor_spec_utils.bounds(po)  # Pendulum's box is finite: published
    np.testing.assert_array_equal(pb_.min, [-1, -1, -8])
    pd = pspecs.observations[4]
    assert list(pd.shape) == [0] and not pd.HasField("min") and not pd.HasField("max")
    state, o = pendulum.step()
    assert state == RUNNING and o[4].shape == (0,) and o[4].dtype == np.float32


def test_first_step_reward_discount_and_default_design(toy):
    toy.join(toy.create())
    state, o = toy.step(uids=(1, 2, 3, 4))
    assert state == RUNNING
    assert o[1].dtype == np.float32 and o[1].shape == (3,)
    assert o[2] == 0.0 and o[3] == 1.0
    np.testing.assert_array_equal(o[4], [1.0, 1.0])  # the default design
    state, o = toy.step([0.5, -0.5])
    assert state == RUNNING and o[2] != 0.0 and o[3] == 1.0


def test_only_requested_observations_are_sent(toy):
    toy.join(toy.create())
    state, o = toy.step(uids=())
    assert o == {}
    state, o = toy.step([0.0, 0.0], uids=(2, 2, 3))
    assert set(o) == {2, 3}
    with pytest.raises(dm_error.DmEnvRpcError, match="uid 9") as e:
        toy.step([0.0, 0.0], uids=(9,))
    assert code_of(e.value) == grpc.StatusCode.INVALID_ARGUMENT
    # The stream goes on after an error.
    state, o = toy.step([0.0, 0.0], uids=(1,))
    assert state == RUNNING


def test_design_setting_rebuilds_the_env_and_is_observed(toy):
    world = toy.create(design=np.array([1.5, 0.75], np.float32))
    toy.join(world)
    before = len(toys.BUILDS)
    _, o = toy.step()
    np.testing.assert_array_equal(o[4], [1.5, 0.75])
    assert o[1][2] == np.float32(1.5)  # the env really has that body
    # ResetWorld with another design (as doubles, which settings accept): rebuilt at the next episode.
    toy.reset_world(world, design=np.array([0.5, 2.0], np.float64))
    _, o = toy.step()
    assert len(toys.BUILDS) == before + 1 and toys.BUILDS[-1] == [0.5, 2.0]
    np.testing.assert_array_equal(o[4], [0.5, 2.0])
    assert o[1][2] == np.float32(0.5)
    # The same design again: no rebuild.
    toy.reset_world(world, design=np.array([0.5, 2.0], np.float32))
    toy.step()
    assert len(toys.BUILDS) == before + 1


@pytest.mark.parametrize(
    "settings, words",
    [
        ({"design": np.array([2.5, 1.0], np.float32)}, ["design", "element 0"]),
        ({"design": np.array([1.0, np.nan], np.float32)}, ["design", "not finite"]),
        ({"design": np.array([1.0, 1.0, 1.0], np.float32)}, ["design", "shape"]),
        ({"design": np.array([1, 1], np.int32)}, ["design", "int32"]),
        ({"seed": np.int64(-3)}, ["seed", "negative"]),
        ({"seed": np.array([1, 2], np.int64)}, ["seed", "scalar"]),
        ({"colour": np.float32(1.0)}, ["colour"]),
    ],
)
def test_bad_world_settings_are_refused_naming_them(toy, settings, words):
    for request in ("create", "reset_world"):
        world = toy.create() if request == "reset_world" else None
        with pytest.raises(dm_error.DmEnvRpcError) as e:
            if request == "create":
                toy.create(**settings)
            else:
                toy.reset_world(world, **settings)
        assert code_of(e.value) == grpc.StatusCode.INVALID_ARGUMENT
        for w in words:
            assert w in e.value.message


def test_join_and_reset_take_no_settings(toy):
    world = toy.create()
    with pytest.raises(dm_error.DmEnvRpcError, match="seed") as e:
        toy.send(pb.JoinWorldRequest(world_name=world, settings={"seed": tensor_utils.pack_tensor(1)}))
    assert code_of(e.value) == grpc.StatusCode.INVALID_ARGUMENT
    toy.join(world)
    with pytest.raises(dm_error.DmEnvRpcError, match="design"):
        toy.send(pb.ResetRequest(settings={"design": tensor_utils.pack_tensor([1.0, 1.0])}))


def test_error_codes(toy):
    with pytest.raises(dm_error.DmEnvRpcError) as e:
        toy.step()
    assert code_of(e.value) == grpc.StatusCode.FAILED_PRECONDITION
    with pytest.raises(dm_error.DmEnvRpcError) as e:
        toy.join("world-999999")
    assert code_of(e.value) == grpc.StatusCode.NOT_FOUND
    with pytest.raises(dm_error.DmEnvRpcError) as e:
        toy.reset_world("nope")
    assert code_of(e.value) == grpc.StatusCode.NOT_FOUND
    world = toy.create()
    toy.join(world)
    with pytest.raises(dm_error.DmEnvRpcError) as e:
        toy.send(pb.DestroyWorldRequest(world_name=world))
    assert code_of(e.value) == grpc.StatusCode.FAILED_PRECONDITION
    # One agent per world.
    with Client(shared_server("toy")) as other:
        with pytest.raises(dm_error.DmEnvRpcError) as e:
            other.join(world)
        assert code_of(e.value) == grpc.StatusCode.FAILED_PRECONDITION
    toy.step()
    with pytest.raises(dm_error.DmEnvRpcError, match="required") as e:
        toy.step(None)  # a running step without its action
    assert code_of(e.value) == grpc.StatusCode.INVALID_ARGUMENT
    with pytest.raises(dm_error.DmEnvRpcError, match="element 1") as e:
        toy.step([0.0, np.inf])
    with pytest.raises(dm_error.DmEnvRpcError, match="element 0"):
        toy.step([1.5, 0.0])
    # A one-element payload broadcasts to the shape; a -1 dimension is resolved.
    t = tensor_utils.pack_tensor(np.float32(0.25))
    t.shape[:] = [2]
    assert toy.send(pb.StepRequest(actions={1: t})).state == RUNNING
    t = tensor_utils.pack_tensor(np.array([0.1, 0.2], np.float32))
    t.shape[:] = [-1]
    assert toy.send(pb.StepRequest(actions={1: t})).state == RUNNING
    t.shape[:] = [1, 2]
    with pytest.raises(dm_error.DmEnvRpcError, match="shape"):
        toy.send(pb.StepRequest(actions={1: t}))


def test_seeds(toy):
    w1 = toy.create(seed=np.int64(5))
    toy.join(w1)
    _, first = toy.step()
    for _ in range(3):
        toy.step([1.0, 1.0])
    toy.reset_world(w1)  # no seed: gymnasium's generator goes on
    _, second = toy.step()
    assert not np.array_equal(first[1], second[1])
    toy.reset_world(w1, seed=np.uint64(5))
    _, again = toy.step()
    np.testing.assert_array_equal(first[1], again[1])
    with Client(shared_server("toy")) as other:
        w2 = other.create(seed=np.int32(5))
        other.join(w2)
        _, o = other.step()
        np.testing.assert_array_equal(first[1], o[1])


def test_terminated_gives_discount_0_and_a_new_episode_follows(toy):
    world = toy.create(design=np.array([2.0, 2.0], np.float32))
    toy.join(world)
    toy.step()
    for i in range(100):
        state, o = toy.step([1.0, 1.0])
        if state != RUNNING:
            break
    assert state == TERMINATED and o[3] == 0.0 and o[2] < -3.0
    # The next step ignores its action (even a bad one) and starts an episode.
    t = tensor_utils.pack_tensor(np.float64(7.0))
    r = toy.send(pb.StepRequest(actions={1: t}, requested_observations=[2, 3]))
    assert r.state == RUNNING
    assert tensor_utils.unpack_tensor(r.observations[2]) == 0.0
    assert tensor_utils.unpack_tensor(r.observations[3]) == 1.0


def test_max_episode_steps_truncates_with_discount_1():
    server = BridgeServer(GymBackend.from_factory("toys:make_toy"), max_episode_steps=5, seed=1)
    server.start()
    try:
        with Client(server) as c:
            c.join(c.create(design=np.array([0.5, 0.5], np.float32)))
            c.step()
            states = [c.step([0.0, 0.0]) for _ in range(5)]
            assert [s for s, _ in states] == [RUNNING] * 4 + [TERMINATED]
            assert states[-1][1][3] == 1.0
            assert c.step()[0] == RUNNING
    finally:
        server.stop()


def test_reset_world_from_another_connection_interrupts_the_agent(toy):
    world = toy.create()
    toy.join(world)
    toy.step()
    toy.step([0.0, 0.0])
    with Client(shared_server("toy")) as host:
        host.reset_world(world, seed=np.int64(3))
    state, o = toy.step([0.0, 0.0])
    assert state == INTERRUPTED
    state, o = toy.step([0.0, 0.0])
    assert state == RUNNING and o[2] == 0.0
    # The issuer of a ResetWorld starts the next episode at once.
    toy.step([0.0, 0.0])
    toy.reset_world(world)
    assert toy.step()[0] == RUNNING


def test_worlds_are_numbered_and_die_with_their_connection():
    server = BridgeServer(GymBackend.from_env_id("Pendulum-v1"))
    server.start()
    try:
        a = Client(server)
        names = [a.create() for _ in range(3)]
        assert names == ["world-1", "world-2", "world-3"]
        a.send(pb.DestroyWorldRequest(world_name="world-2"))
        assert sorted(server.service.worlds) == ["world-1", "world-3"]
        # Another connection joins world-3: it outlives its creator until that agent leaves.
        b = Client(server)
        b.join("world-3")
        a.close()
        assert wait_until(lambda: sorted(server.service.worlds) == ["world-3"])
        b.send(pb.LeaveWorldRequest())
        assert wait_until(lambda: not server.service.worlds)
        b.close()
    finally:
        server.stop()


def test_extension_requests_are_unimplemented(toy):
    from google.protobuf import any_pb2

    with pytest.raises(dm_error.DmEnvRpcError) as e:
        toy.send(any_pb2.Any(type_url="example.com/x"))
    assert code_of(e.value) == grpc.StatusCode.UNIMPLEMENTED


def test_dm_env_adaptor_runs_a_pendulum_episode_truncated_with_discount_1(pendulum):
    specs = pendulum.join(pendulum.create(seed=np.int64(0)))
    env = dm_env_adaptor.DmEnvAdaptor(pendulum.connection, specs)
    assert set(env.observation_spec()) == {"observation", "design"}
    ts = env.reset()
    assert ts.first() and ts.observation["observation"].shape == (3,)
    rewards = []
    steps = 0
    while True:
        ts = env.step({"action": np.array([1.0], np.float32)})
        steps += 1
        if ts.last():
            break
        assert ts.discount == 1.0
        rewards.append(ts.reward)
    assert steps == 200  # Pendulum-v1's TimeLimit
    assert ts.discount == 1.0  # truncated, not terminal
    assert all(r <= 0.0 for r in rewards) and min(rewards) < -0.1
    # The next step starts a new episode.
    ts = env.step({"action": np.array([0.0], np.float32)})
    assert ts.first()


def test_unsupported_envs_fail_at_start_with_a_clear_error():
    with pytest.raises(BackendError, match="continuous Box"):
        GymBackend.from_factory("toys:make_discrete")
    with pytest.raises(BackendError, match="module:name"):
        GymBackend.from_factory("toys")
    with pytest.raises(BackendError, match="no_such_module"):
        GymBackend.from_factory("no_such_module:make")


def test_design_space_decorator():
    @design_space(low=[0, 1], high=[1, 3])
    def f(design):
        return None

    assert f.design_low == [0.0, 1.0] and f.design_high == [1.0, 3.0] and f.default_design == [0.5, 2.0]
    with pytest.raises(ValueError, match="outside"):
        design_space(low=[0], high=[1], default=[2])
    with pytest.raises(ValueError, match="elements"):
        design_space(low=[0, 0], high=[1])


def test_an_empty_design_is_accepted_without_a_design_box(pendulum):
    world = pendulum.create()
    # As coadapt's Rust client sends it (an empty `floats` payload) and as numpy packs it (none).
    rust_style = pb.Tensor(floats=pb.Tensor.FloatArray(), shape=[0])
    assert rust_style.WhichOneof("payload") == "floats"
    numpy_style = tensor_utils.pack_tensor(np.zeros(0, np.float32))
    for t in (rust_style, numpy_style):
        pendulum.reset_world(world, design=t, seed=tensor_utils.pack_tensor(np.uint64(9)))
    with pytest.raises(dm_error.DmEnvRpcError, match="design"):
        pendulum.reset_world(world, design=np.array([0.5], np.float32))


def test_world_settings_reach_the_factory_at_create_and_only_there():
    backend = GymBackend.from_factory("toys:make_toy_world")
    assert backend.world_settings == frozenset({"friction"})
    server = BridgeServer(backend, port=0)
    server.start()
    try:
        with Client(server, own_channel=True) as c:
            slow = c.create(friction=np.float32(4.0), seed=np.uint64(3))
            assert toys.WORLD_BUILDS[-1] == ([1.0, 1.0], 4.0)
            c.join(slow)
            c.step()
            _, a = c.step([1.0, 1.0])
            _, b = c.step([1.0, 1.0])
            # A quarter of the push of the default world (0.1 per unit action).
            np.testing.assert_allclose(b[1][:2] - a[1][:2], [0.025, 0.025], rtol=1e-5)
            # A new design keeps the world's friction.
            c.reset_world(slow, design=np.array([2.0, 2.0], np.float32))
            c.step()
            assert toys.WORLD_BUILDS[-1] == ([2.0, 2.0], 4.0)
            # The dynamics are fixed for the world's life; a value the factory refuses and an
            # unknown name are the request's fault, each named.
            for send, words in [
                (lambda: c.reset_world(slow, friction=np.float32(1.0)), ["friction", "CreateWorld"]),
                (lambda: c.create(friction=np.float32(-1.0)), ["friction must be > 0"]),
                (lambda: c.create(friction=np.array([1.0, 2.0], np.float32)), ["friction", "one float"]),
                (lambda: c.create(gravity=np.float32(1.0)), ["gravity", "`friction`"]),
            ]:
                with pytest.raises(dm_error.DmEnvRpcError) as e:
                    send()
                assert code_of(e.value) == grpc.StatusCode.INVALID_ARGUMENT, e.value.message
                for w in words:
                    assert w in e.value.message, e.value.message
    finally:
        server.stop()
