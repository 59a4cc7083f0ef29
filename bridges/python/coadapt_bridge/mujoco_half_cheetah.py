"""Design-parameterised MuJoCo HalfCheetah (gymnasium ``HalfCheetah-v5``) for co-adaptation.

Usage with the bridge server::

    coadapt-gym-serve --factory coadapt_bridge.mujoco_half_cheetah:make

``make(design)`` returns a ``gymnasium.Env``: v5's ``HalfCheetahEnv`` built from a modified copy
of gymnasium's installed ``half_cheetah.xml``, wrapped with our reward and a 1000-step
``TimeLimit``. The observation is v5's 17-vector (the coadapt client appends the design itself).

Design
------
``design`` (ξ) is a vector of 6 factors in ``[0.8, 2.0]`` that scale the lengths of the leg
segments, in this order: back thigh, back shin, back foot, front thigh, front shin, front foot
(the XML bodies ``bthigh, bshin, bfoot, fthigh, fshin, ffoot``). ``[1] * 6`` is v5's model.

Geometry mapping
----------------
In v5's XML each leg segment is a body whose frame origin *is* its hinge joint (every leg joint
has ``pos="0 0 0"``). The body holds one capsule geom given by ``pos`` (its centre, in the body
frame), ``axisangle="0 1 0 θ"`` (its axis: the z axis turned by θ about y) and ``size="r h"``
(radius ``r``, half-length ``h``; the capsule's cylinder runs from ``pos - h·axis`` to
``pos + h·axis``, so its length is ``2h``). No lengths are written as ``fromto`` for the legs
(only the torso uses ``fromto``). The next segment's body sits at ``pos`` of the child body,
which is (to within 3 cm) the far end of the capsule.

Segment ``i`` is stretched by ``ξ_i`` about its own joint, radius kept:

* ``<geom name=SEG>`` inside ``<body name=SEG>``: ``pos ← ξ_i · pos`` and the half-length
  ``size[1] ← ξ_i · size[1]`` (a ``fromto`` geom would get both endpoints scaled by ``ξ_i``, the
  same map); ``axisangle`` and the radius ``size[0]`` are unchanged. The capsule therefore keeps
  its direction, its length becomes ``ξ_i`` times v5's, and its ends move away from the joint
  proportionally.
* The child ``<body>`` of SEG (bshin in bthigh, bfoot in bshin, fshin in fthigh, ffoot in
  fshin): ``pos ← ξ_i · pos``, so the next joint (at the child body's origin) sits at the scaled
  end of this segment exactly as it sat at the end of v5's segment. The child's own geometry is
  translated with it (and scaled by its own factor). The feet have no child body.

So both the capsule length and the joint-to-joint distance of each segment scale by exactly
``ξ_i``; v5's small offsets between capsule ends and joints (at most 3 cm, inside the capsule
radius of 4.6 cm) scale with it. Joint ranges, stiffness, damping, armature, gears, friction,
radii, torso and head are v5's.

Masses: v5 compiles with ``<compiler settotalmass="14">``, which rescales every body's mass and
inertia so that the whole robot weighs 14 kg (and MuJoCo 4 deprecates the attribute). With it,
longer legs would make the torso lighter. Instead we remove ``settotalmass`` and give every geom
the constant density that makes v5's geometry weigh exactly 14 kg (about 667 kg/m^3, computed
at runtime from the installed XML). Masses and inertias then follow the geometry: design
``[1] * 6`` has v5's masses, longer legs are heavier and the torso and head keep their mass (as
in our rapier HalfCheetah).

Initial height: v5 places the torso at z = 0.7, which leaves the lowest point of the robot
(a foot capsule) 7.6 cm above the floor in the nominal initial pose (all joints at 0). We keep
that clearance for every design: the model is compiled once with the torso at 0.7, the lowest
point of all geoms at ``qpos0`` is measured, and the torso's ``pos`` is shifted by the
difference to v5's clearance (higher for longer legs, lower for shorter ones; exactly 0.7 for
``[1] * 6``). As in v5, the reset noise (uniform ±0.1 on every ``qpos`` including the height
and pitch) can still start a foot a few centimetres inside the floor -- v5 itself does so by up
to about 8 cm -- and the soft contacts push it out within the first steps.

Reward
------
Ours (the thesis's Eq. 5.8 and our rapier HalfCheetah): ``max(vx / 10, 0)`` per step, where
``vx`` is the torso's forward velocity, the x displacement of the root over the env step divided
by ``dt`` (= 5 × 0.01 s), i.e. v5's ``info["x_velocity"]``. There is no control cost. v5's own
reward is kept in ``info["reward_v5"]`` next to its terms ``reward_forward``/``reward_ctrl``, and
ours in ``info["reward_coadapt"]``. No termination; truncation after 1000 steps.
"""

from __future__ import annotations

import functools
import hashlib
import os
import tempfile
import xml.etree.ElementTree as ET
from typing import Any, Sequence

import gymnasium
import mujoco
import numpy as np
from gymnasium.envs.mujoco import half_cheetah_v5
from gymnasium.wrappers import TimeLimit

__all__ = [
    "DESIGN_LOW",
    "DESIGN_HIGH",
    "DEFAULT_DESIGN",
    "SEGMENTS",
    "MAX_EPISODE_STEPS",
    "CoadaptForwardReward",
    "validate_design",
    "build_xml",
    "make_env",
    "make",
]

#: Leg segments scaled by the design, in design order (body and geom names in the XML).
SEGMENTS = ("bthigh", "bshin", "bfoot", "fthigh", "fshin", "ffoot")
DESIGN_LOW = [0.8] * 6
DESIGN_HIGH = [2.0] * 6
DEFAULT_DESIGN = [1.0] * 6
MAX_EPISODE_STEPS = 1000
#: v5's total mass (``settotalmass``), kept for design ``[1] * 6`` through a constant density.
TOTAL_MASS = 14.0
#: Tolerance on the design box, for float32 round-off of the bounds.
_BOX_TOL = 1e-6


def _source_xml_path() -> str:
    return os.path.join(os.path.dirname(half_cheetah_v5.__file__), "assets", "half_cheetah.xml")


def _fmt(values: Sequence[float]) -> str:
    return " ".join(repr(float(v)) for v in values)


def _floats(text: str) -> np.ndarray:
    return np.array([float(v) for v in text.split()], dtype=np.float64)


def validate_design(design: Any) -> np.ndarray:
    """The design as a float64 array of 6 in the box, or a ValueError naming ``design``."""
    try:
        xi = np.asarray(design, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise ValueError(f"design must be 6 numbers, got {design!r}") from err
    if xi.shape != (6,):
        raise ValueError(f"design must have shape (6,), got shape {xi.shape}: {design!r}")
    if not np.all(np.isfinite(xi)):
        raise ValueError(f"design must be finite, got {xi.tolist()}")
    low, high = np.array(DESIGN_LOW), np.array(DESIGN_HIGH)
    if np.any(xi < low - _BOX_TOL) or np.any(xi > high + _BOX_TOL):
        raise ValueError(
            f"design must lie in [{DESIGN_LOW[0]}, {DESIGN_HIGH[0]}]^6 "
            f"(back thigh, shin, foot, front thigh, shin, foot), got {xi.tolist()}"
        )
    return np.clip(xi, low, high)


def _lowest_point(model: mujoco.MjModel) -> float:
    """Lowest z of all non-plane geoms at ``qpos0`` (capsules exactly, others by bounding sphere)."""
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    lowest = np.inf
    for g in range(model.ngeom):
        gtype = model.geom_type[g]
        if gtype == mujoco.mjtGeom.mjGEOM_PLANE:
            continue
        centre_z = data.geom_xpos[g][2]
        if gtype == mujoco.mjtGeom.mjGEOM_CAPSULE:
            radius, half = model.geom_size[g][:2]
            axis_z = data.geom_xmat[g].reshape(3, 3)[2, 2]
            low = centre_z - abs(axis_z) * half - radius
        else:
            low = centre_z - model.geom_rbound[g]
        lowest = min(lowest, low)
    return float(lowest)


def _load_tree() -> ET.ElementTree:
    return ET.parse(_source_xml_path())


def _drop_settotalmass(root: ET.Element) -> ET.Element:
    compiler = root.find("compiler")
    if compiler is not None and "settotalmass" in compiler.attrib:
        del compiler.attrib["settotalmass"]
    return compiler


@functools.lru_cache(maxsize=1)
def _reference() -> tuple[float, float]:
    """(density giving v5's geometry 14 kg, v5's lowest point at qpos0), from the installed XML."""
    root = _load_tree().getroot()
    compiler = root.find("compiler")
    total = float(compiler.get("settotalmass", TOTAL_MASS)) if compiler is not None else TOTAL_MASS
    _drop_settotalmass(root)
    model = mujoco.MjModel.from_xml_string(ET.tostring(root, encoding="unicode"))
    # Without settotalmass MuJoCo uses its default density of 1000 kg/m^3 (v5 sets none).
    density = 1000.0 * total / float(model.body_mass.sum())
    return density, _lowest_point(model)


def _scale_segment(body: ET.Element, name: str, factor: float) -> None:
    geoms = [g for g in body.findall("geom") if g.get("name") == name] or body.findall("geom")
    if len(geoms) != 1:
        raise RuntimeError(f"half_cheetah.xml: expected one geom in body {name!r}, found {len(geoms)}")
    geom = geoms[0]
    if geom.get("fromto") is not None:
        geom.set("fromto", _fmt(factor * _floats(geom.get("fromto"))))
    else:
        pos = _floats(geom.get("pos", "0 0 0"))
        size = _floats(geom.get("size"))
        if geom.get("type") not in ("capsule", "cylinder") or size.size < 2:
            raise RuntimeError(f"half_cheetah.xml: geom {name!r} is not a capsule with a half-length")
        size[1] *= factor
        geom.set("pos", _fmt(factor * pos))
        geom.set("size", _fmt(size))
    for child in body.findall("body"):
        child.set("pos", _fmt(factor * _floats(child.get("pos", "0 0 0"))))


def validate_friction(friction: Any) -> float:
    """The sliding friction as a finite float >= 0, or a ValueError naming ``friction``."""
    try:
        f = float(friction)
    except (TypeError, ValueError) as err:
        raise ValueError(f"friction must be a number, got {friction!r}") from err
    if not (np.isfinite(f) and f >= 0.0):
        raise ValueError(f"friction must be a finite number >= 0, got {f}")
    return f


def build_xml(design: Any, friction: Any = None) -> str:
    """The MuJoCo XML of the cheetah with leg-segment scale factors ``design`` (see module doc),
    with every geom's sliding friction ``friction`` (the floor's too; v5's 0.4 when ``None``;
    MuJoCo takes the larger of two touching geoms' values, so the contact gets exactly this)."""
    xi = validate_design(design)
    f = None if friction is None else validate_friction(friction)
    density, reference_low = _reference()
    tree = _load_tree()
    root = tree.getroot()
    _drop_settotalmass(root)
    default_geom = root.find("default/geom")
    if default_geom is None:
        default = root.find("default")
        if default is None:
            default = ET.SubElement(root, "default")
        default_geom = ET.SubElement(default, "geom")
    default_geom.set("density", repr(density))
    if f is not None:
        for geom in [default_geom, *root.iter("geom")]:
            if geom is default_geom or geom.get("friction") is not None:
                rest = _floats(geom.get("friction", default_geom.get("friction", "0.4 0.1 0.1")))[1:]
                geom.set("friction", _fmt([f, *rest]))

    bodies = {b.get("name"): b for b in root.iter("body")}
    for name, factor in zip(SEGMENTS, xi):
        if name not in bodies:
            raise RuntimeError(f"half_cheetah.xml: no body named {name!r}")
        _scale_segment(bodies[name], name, float(factor))

    # Keep v5's clearance between the lowest point and the floor at the nominal initial pose.
    model = mujoco.MjModel.from_xml_string(ET.tostring(root, encoding="unicode"))
    shift = reference_low - _lowest_point(model)
    if shift != 0.0:
        torso = bodies["torso"]
        pos = _floats(torso.get("pos", "0 0 0"))
        pos[2] += shift
        torso.set("pos", _fmt(pos))
    return ET.tostring(root, encoding="unicode")


_XML_DIR: tempfile.TemporaryDirectory | None = None


def _write_xml(xml: str) -> str:
    """Write ``xml`` to a per-process temporary directory (removed at exit) and return its path.

    The file is kept for the life of the process because ``HalfCheetahEnv`` records the path for
    ``EzPickle`` (copying or pickling the env rebuilds it from the file).
    """
    global _XML_DIR
    if _XML_DIR is None:
        _XML_DIR = tempfile.TemporaryDirectory(prefix="coadapt_half_cheetah_")
    digest = hashlib.sha1(xml.encode()).hexdigest()[:16]
    path = os.path.join(_XML_DIR.name, f"half_cheetah_{digest}.xml")
    if not os.path.exists(path):
        tmp = f"{path}.{os.getpid()}.{id(xml)}.tmp"
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(xml)
        os.replace(tmp, path)
    return path


class CoadaptForwardReward(gymnasium.Wrapper):
    """Replace v5's reward by ``max(vx / 10, 0)``; keep v5's in ``info["reward_v5"]``."""

    def step(self, action):
        obs, reward_v5, terminated, truncated, info = self.env.step(action)
        reward = max(float(info["x_velocity"]) / 10.0, 0.0)
        info = dict(info)
        info["reward_v5"] = float(reward_v5)
        info["reward_coadapt"] = reward
        return obs, reward, terminated, truncated, info


def make_env(design: Any, max_episode_steps: int = MAX_EPISODE_STEPS, friction: Any = None, **kwargs: Any) -> gymnasium.Env:
    """The cheetah for ``design`` (and ``friction``, v5's when ``None``); ``kwargs`` go to v5's
    ``HalfCheetahEnv`` (v5 defaults otherwise)."""
    path = _write_xml(build_xml(design, friction))
    env = half_cheetah_v5.HalfCheetahEnv(xml_file=path, **kwargs)
    return TimeLimit(CoadaptForwardReward(env), max_episode_steps=max_episode_steps)


def make(design: Any, friction: Any = None) -> gymnasium.Env:
    """Factory for ``coadapt-gym-serve``: the cheetah for a design of 6 leg-segment scale factors;
    ``friction`` (the world setting of a client's ``[world] friction``) is every geom's sliding
    friction, v5's 0.4 by default."""
    return make_env(design, friction=friction)


# What ``coadapt_bridge.design_space(low=..., high=..., default=...)`` would set.
make.design_low = list(DESIGN_LOW)
make.design_high = list(DESIGN_HIGH)
make.default_design = list(DEFAULT_DESIGN)
