"""Tests of the design-parameterised MuJoCo HalfCheetah (coadapt_bridge.mujoco_half_cheetah)."""

import math
import os
import warnings

import gymnasium
import mujoco
import numpy as np
import pytest

from coadapt_bridge import mujoco_half_cheetah as mhc

SEGMENTS = mhc.SEGMENTS
CHILD = {"bthigh": "bshin", "bshin": "bfoot", "fthigh": "fshin", "fshin": "ffoot"}
LEG_BODIES = list(SEGMENTS)
MIXED = [0.8, 1.0, 1.2, 1.4, 1.6, 2.0]


@pytest.fixture(scope="module")
def v5(tmp_path_factory):
    # MuJoCo 4 warns about v5's deprecated settotalmass and logs it to MUJOCO_LOG.TXT in the
    # working directory: build v5 from a scratch directory.
    cwd = os.getcwd()
    os.chdir(tmp_path_factory.mktemp("v5"))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            env = gymnasium.make("HalfCheetah-v5")
    finally:
        os.chdir(cwd)
    yield env
    env.close()


def _body(model, name):
    return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)


def _geom(model, name):
    return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, name)


def _capsule_length(model, name):
    g = _geom(model, name)
    assert model.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE
    return 2.0 * model.geom_size[g][1]


def _lowest(env):
    """Lowest z over all non-plane geoms in the env's current state."""
    model, data = env.unwrapped.model, env.unwrapped.data
    lowest = math.inf
    for g in range(model.ngeom):
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE:
            continue
        radius, half = model.geom_size[g][:2]
        axis_z = data.geom_xmat[g][8]
        lowest = min(lowest, data.geom_xpos[g][2] - abs(axis_z) * half - radius)
    return lowest


def test_factory_attributes():
    assert mhc.make.design_low == [0.8] * 6
    assert mhc.make.design_high == [2.0] * 6
    assert mhc.make.default_design == [1.0] * 6


def test_default_design_is_v5(v5):
    env = mhc.make(np.ones(6, dtype=np.float32))
    ours, ref = env.unwrapped.model, v5.unwrapped.model
    for field in ("geom_size", "geom_pos", "geom_quat", "body_pos", "body_quat", "jnt_pos", "jnt_range",
                  "actuator_gear", "dof_damping", "jnt_stiffness", "dof_armature", "geom_friction"):
        np.testing.assert_array_equal(getattr(ours, field), getattr(ref, field), err_msg=field)
    np.testing.assert_allclose(ours.body_mass, ref.body_mass, rtol=1e-12)
    np.testing.assert_allclose(ours.body_inertia, ref.body_inertia, rtol=1e-12)
    np.testing.assert_allclose(ours.body_mass.sum(), 14.0, rtol=1e-12)
    assert ours.opt.timestep == ref.opt.timestep and env.unwrapped.dt == v5.unwrapped.dt

    assert env.observation_space.shape == (17,) == v5.observation_space.shape
    assert env.action_space == v5.action_space
    for seed in (0, 7):
        obs, _ = env.reset(seed=seed)
        obs_ref, _ = v5.reset(seed=seed)
        np.testing.assert_array_equal(obs, obs_ref)
    action = np.linspace(-1, 1, 6).astype(np.float32)
    for _ in range(5):
        obs, _, _, _, info = env.step(action)
        obs_ref, reward_ref, _, _, _ = v5.step(action)
    np.testing.assert_allclose(obs, obs_ref, rtol=1e-9, atol=1e-9)
    assert info["reward_v5"] == pytest.approx(reward_ref, rel=1e-9, abs=1e-9)
    env.close()


@pytest.mark.parametrize("design", [[2.0] * 6, [0.8] * 6, MIXED])
def test_segment_scaling(v5, design):
    env = mhc.make(design)
    ours, ref = env.unwrapped.model, v5.unwrapped.model
    for name, factor in zip(SEGMENTS, design):
        # Capsule length along its axis, its direction and its radius.
        assert _capsule_length(ours, name) == pytest.approx(factor * _capsule_length(ref, name), rel=1e-12)
        g_ours, g_ref = _geom(ours, name), _geom(ref, name)
        assert ours.geom_size[g_ours][0] == ref.geom_size[g_ref][0]
        np.testing.assert_allclose(ours.geom_quat[g_ours], ref.geom_quat[g_ref], atol=1e-12)
        np.testing.assert_allclose(ours.geom_pos[g_ours], factor * ref.geom_pos[g_ref], rtol=1e-12, atol=1e-15)
        # The next joint sits at the scaled end of the segment.
        if name in CHILD:
            child_ours, child_ref = _body(ours, CHILD[name]), _body(ref, CHILD[name])
            np.testing.assert_allclose(ours.body_pos[child_ours], factor * ref.body_pos[child_ref], rtol=1e-12, atol=1e-15)
        # Mass from a constant density: proportional to the capsule's volume.
        radius, half = ref.geom_size[g_ref][:2]
        volume = lambda h: math.pi * radius**2 * 2 * h + 4 / 3 * math.pi * radius**3  # noqa: E731
        ratio = volume(factor * half) / volume(half)
        assert ours.body_mass[_body(ours, name)] == pytest.approx(ratio * ref.body_mass[_body(ref, name)], rel=1e-9)
    # Joints stay at the body origins; hips and torso geometry unchanged.
    np.testing.assert_array_equal(ours.jnt_pos, ref.jnt_pos)
    for name in ("bthigh", "fthigh"):
        np.testing.assert_array_equal(ours.body_pos[_body(ours, name)], ref.body_pos[_body(ref, name)])
    for name in ("torso", "head"):
        np.testing.assert_array_equal(ours.geom_size[_geom(ours, name)], ref.geom_size[_geom(ref, name)])
    # Torso and head keep their mass; the legs' mass moves with their length.
    torso = _body(ours, "torso")
    assert ours.body_mass[torso] == pytest.approx(ref.body_mass[torso], rel=1e-12)
    leg_mass = sum(ours.body_mass[_body(ours, b)] for b in LEG_BODIES)
    leg_mass_ref = sum(ref.body_mass[_body(ref, b)] for b in LEG_BODIES)
    if min(design) >= 1.0:
        assert leg_mass > leg_mass_ref
    elif max(design) <= 1.0:
        assert leg_mass < leg_mass_ref
    env.close()


def test_leg_mass_grows_with_length():
    leg_masses = []
    for factor in (0.8, 1.0, 1.5, 2.0):
        model = mhc.make([factor] * 6).unwrapped.model
        leg_masses.append(sum(model.body_mass[_body(model, b)] for b in LEG_BODIES))
    assert all(a < b for a, b in zip(leg_masses, leg_masses[1:]))


@pytest.mark.parametrize("design", [[2.0] * 6, [0.8] * 6, [2.0, 0.8, 2.0, 0.8, 2.0, 0.8]])
def test_start_height_and_stability(v5, design):
    # Nominal initial pose (no reset noise): the lowest point is exactly as high as in v5 (7.6 cm).
    quiet = mhc.make_env(design, reset_noise_scale=0.0)
    quiet.reset(seed=0)
    v5.reset(seed=0)
    v5.unwrapped.set_state(v5.unwrapped.init_qpos, v5.unwrapped.init_qvel)
    assert _lowest(quiet) == pytest.approx(_lowest(v5), abs=1e-9)
    assert _lowest(quiet) >= 0.07
    if min(design) >= 1.0:
        assert quiet.unwrapped.model.body_pos[_body(quiet.unwrapped.model, "torso")][2] > 0.7
    quiet.close()

    # With v5's reset noise (uniform +-0.1 on height, pitch and joints) a foot may start slightly
    # inside the floor, as in v5 itself (down to about -0.08 m); bounded the same way here.
    env = mhc.make(design)
    for seed in range(10):
        env.reset(seed=seed)
        assert _lowest(env) >= -0.12
    env.reset(seed=0)
    env.action_space.seed(0)
    for _ in range(200):
        obs, reward, terminated, truncated, _ = env.step(env.action_space.sample())
        assert not terminated and not truncated
    assert np.all(np.isfinite(obs)) and np.abs(obs).max() < 100.0
    assert _lowest(env) > -0.1
    env.close()


def test_reward_and_truncation():
    env = mhc.make([1.3, 0.9, 1.1, 1.7, 1.0, 0.8])
    inner = env.unwrapped
    # qpos[0] is the torso's x: the slide joint rootx along x on the torso body.
    assert inner.model.jnt_type[0] == mujoco.mjtJoint.mjJNT_SLIDE and inner.model.jnt_bodyid[0] == _body(inner.model, "torso")
    np.testing.assert_array_equal(inner.model.jnt_axis[0], [1.0, 0.0, 0.0])
    env.reset(seed=3)
    env.action_space.seed(3)
    rewards_seen = []
    truncated = False
    steps = 0
    while not truncated:
        x_before = float(inner.data.qpos[0])
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        steps += 1
        vx = (float(inner.data.qpos[0]) - x_before) / inner.dt
        assert reward == pytest.approx(max(vx / 10.0, 0.0), abs=1e-12)
        assert info["reward_coadapt"] == reward
        assert info["reward_v5"] == pytest.approx(info["reward_forward"] + info["reward_ctrl"], abs=1e-12)
        assert not terminated
        assert obs.shape == (17,)
        rewards_seen.append(reward)
        assert steps <= 1000
    assert steps == 1000
    assert any(r > 0 for r in rewards_seen) and all(r >= 0 for r in rewards_seen)
    env.close()


@pytest.mark.parametrize(
    "design",
    [
        [1.0] * 5,
        [1.0] * 7,
        [[1.0] * 6],
        [1.0, 1.0, float("nan"), 1.0, 1.0, 1.0],
        [1.0, 1.0, 1.0, float("inf"), 1.0, 1.0],
        [0.79, 1.0, 1.0, 1.0, 1.0, 1.0],
        [1.0, 1.0, 1.0, 1.0, 1.0, 2.01],
        "not a design",
        None,
    ],
)
def test_invalid_design(design):
    with pytest.raises(ValueError, match="design"):
        mhc.make(design)


def test_box_edges_accepted():
    for design in (np.full(6, 0.8, dtype=np.float32), np.full(6, 2.0, dtype=np.float32)):
        xi = mhc.validate_design(design)
        assert xi.dtype == np.float64 and np.all(xi >= 0.8) and np.all(xi <= 2.0)


def test_friction_sets_every_geoms_sliding_friction_and_changes_the_run():
    default = mujoco.MjModel.from_xml_string(mhc.build_xml([1.0] * 6))
    slippery = mujoco.MjModel.from_xml_string(mhc.build_xml([1.0] * 6, friction=0.05))
    np.testing.assert_allclose(default.geom_friction[:, 0], 0.4)
    np.testing.assert_allclose(slippery.geom_friction[:, 0], 0.05)
    # Torsional and rolling friction stay v5's.
    np.testing.assert_allclose(slippery.geom_friction[:, 1:], default.geom_friction[:, 1:])
    # Same start and actions, another ground: another run.
    def run(friction):
        env = mhc.make(MIXED, friction=friction)
        env.reset(seed=3)
        x = 0.0
        for t in range(100):
            _, _, _, _, info = env.step(np.sin(np.arange(6) + 0.3 * t).astype(np.float32))
            x = info["x_position"]
        env.close()
        return x
    assert abs(run(None) - run(0.05)) > 0.05
    assert run(None) == run(0.4)
    for bad in (-0.1, float("nan"), "grippy"):
        with pytest.raises(ValueError, match="friction"):
            mhc.build_xml([1.0] * 6, friction=bad)
