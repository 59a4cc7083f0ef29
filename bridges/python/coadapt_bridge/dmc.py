"""DeepMind Control Suite tasks from pixels (``--dmc cheetah-run``): the thesis's benchmark
(ch. 4) behind the coadapt profile.

Each agent step repeats the action for ``action_repeat`` control steps of the task (the reward
is their sum), then renders the scene once at 320x240 RGB (camera 0: for cheetah the one that
follows the torso) and resizes it to ``pixels`` x ``pixels`` by area averaging. The observation
is that one frame as ``FLOAT [3 * pixels * pixels]`` in [0, 1], channel-major: all R values row
by row, then G, then B (PyTorch's NCHW order for one image); the client stacks frames itself.
An episode is truncated (discount 1) after ``episode_steps`` agent steps; the task's own time
limit is switched off. No design (0 elements).

Rendering is headless: ``MUJOCO_GL`` defaults to ``egl`` (Mesa's EGL with the llvmpipe
software renderer works without a GPU or a display; Debian packages libegl1, libegl-mesa0 and
libgl1-mesa-dri). ``MUJOCO_GL=osmesa`` (libosmesa6) is the other headless choice. dm_control
is an optional dependency: ``pip install coadapt-bridge[dmc]`` or ``setup_venv.sh --dmc``.
"""

from __future__ import annotations

import logging
import os
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable, Optional

import numpy as np

from .backends import Backend, BackendError, Body, Profile
from .design import DesignSpace
from .driver import StepResult

log = logging.getLogger("coadapt_bridge")

RENDER_WIDTH = 320
RENDER_HEIGHT = 240
DEFAULT_PIXELS = 64
DEFAULT_ACTION_REPEAT = 2
DEFAULT_EPISODE_STEPS = 420
DEFAULT_CAMERA = 0

INSTALL_HINT = (
    "install the optional dependency: `pip install 'coadapt-bridge[dmc]'` or `bridges/python/setup_venv.sh --dmc VENV_DIR` "
    "(dm_control 1.0.50 with MuJoCo 3.17.0)"
)
GL_HINT = (
    "headless rendering needs EGL (Debian: apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri; MUJOCO_GL=egl, the "
    "default here) or OSMesa (apt-get install libosmesa6; MUJOCO_GL=osmesa)"
)


def area_weights(n_in: int, n_out: int) -> np.ndarray:
    """``[n_out, n_in]`` weights of an area (box) resize along one axis: output pixel ``o``
    averages the input over ``[o * s, (o + 1) * s)`` with ``s = n_in / n_out``, counting the
    pixels cut by the interval's ends by the fraction covered. Rows sum to 1."""
    scale = n_in / n_out
    lo = np.arange(n_out, dtype=np.float64)[:, None] * scale
    hi = lo + scale
    left = np.arange(n_in, dtype=np.float64)[None, :]
    w = np.clip(np.minimum(hi, left + 1.0) - np.maximum(lo, left), 0.0, None)
    return w / w.sum(axis=1, keepdims=True)


class FrameResizer:
    """``uint8 [H, W, 3]`` -> ``float32 [3 * out * out]`` in [0, 1], channel-major, by exact
    area averaging (OpenCV's ``INTER_AREA`` when downscaling; PIL's ``BOX`` filter gives the
    same for integer factors such as 320 -> 64, but weighs whole pixels for 240 -> 64).

    The weights are banded (at most ``ceil(n_in / n_out) + 1`` input pixels per output pixel),
    so each axis is a few gathers and a weighted sum: element-wise numpy, no BLAS (OpenBLAS's
    threads contend with the software renderer's: a matrix product took 70 ms instead of 0.5)."""

    def __init__(self, height: int, width: int, out: int):
        self.height, self.width, self.out = height, width, out
        self._iy, self._wy = self._band(area_weights(height, out))
        ix, wx = self._band(area_weights(width, out) / 255.0)  # scaled: the result lands in [0, 1]
        self._ix, self._wx = ix, wx[:, :, None]

    @staticmethod
    def _band(w: np.ndarray) -> tuple:
        """``[n_out, n_in]`` weights -> (indices, weights) ``[n_out, K]`` of the nonzero band."""
        nz = w > 0
        k = int(nz.sum(axis=1).max())
        first = nz.argmax(axis=1)
        idx = np.minimum(first[:, None] + np.arange(k)[None, :], w.shape[1] - 1)
        vals = np.take_along_axis(w, idx, axis=1)
        # A clamped index repeats the last pixel: give the repeat no weight.
        vals[first[:, None] + np.arange(k)[None, :] > w.shape[1] - 1] = 0.0
        return idx, vals.astype(np.float32)

    def __call__(self, frame: np.ndarray) -> np.ndarray:
        if frame.shape != (self.height, self.width, 3):
            raise RuntimeError(f"rendered frame has shape {frame.shape}, ({self.height}, {self.width}, 3) expected")
        x = frame.astype(np.float32)
        rows = np.einsum("okwc,ok->owc", x[self._iy], self._wy)  # [out, W, 3]
        out = np.einsum("hokc,okc->cho", rows[:, self._ix], self._wx)  # [3, out, out]
        # Rounding may leave a value a few ulps above 1.
        return np.clip(out, 0.0, 1.0, out=out).ravel()


def parse_task(spec: str) -> tuple:
    """``cheetah-run`` -> ``("cheetah", "run")`` (domain and task names use underscores)."""
    domain, sep, task = spec.partition("-")
    if not sep or not domain or not task:
        raise BackendError(f"--dmc `{spec}`: expected DOMAIN-TASK, e.g. cheetah-run")
    return domain, task


def _import_suite() -> Any:
    # dm_control reads MUJOCO_GL when it is imported.
    os.environ.setdefault("MUJOCO_GL", "egl")
    try:
        from dm_control import suite
    except Exception as e:  # noqa: BLE001 - anything the import raises
        raise BackendError(f"--dmc needs dm_control: {type(e).__name__}: {e}; {INSTALL_HINT}") from e
    return suite


class _EnvThread:
    """One thread that makes every call into one dm_control environment. A MuJoCo rendering
    context stays current on the thread that last rendered with it, and freeing it from
    another thread fails (EGL_BAD_ACCESS) once that thread has gone, as gRPC's worker threads
    do: so the environment is built, stepped, rendered and freed on its own thread."""

    def __init__(self, name: str):
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix=name)

    def call(self, fn: Callable[..., Any], *args: Any) -> Any:
        return self._pool.submit(fn, *args).result()

    def shutdown(self) -> None:
        self._pool.shutdown(wait=True)


class DmcBody(Body):
    """One world's dm_control environment (on its own thread)."""

    def __init__(self, backend: "DmcBackend"):
        self._backend = backend
        self.profile = backend.profile
        self._thread = _EnvThread("dmc-world")
        try:
            self.env = self._thread.call(backend.load)
        except BaseException:
            self._thread.shutdown()
            raise
        self.steps = 0

    def start_episode(self, design: np.ndarray, seed: Optional[int]) -> np.ndarray:
        return self._thread.call(self._start_episode, seed)

    def _start_episode(self, seed: Optional[int]) -> np.ndarray:
        if seed is not None:
            # The task draws the initial state from its own generator (dm_control's
            # `suite.load(..., task_kwargs={"random": seed})` sets the same one).
            self.env.task._random = np.random.RandomState(seed)
        self.env.reset()
        self.steps = 0
        return self._backend.frame(self.env)

    def step(self, action: np.ndarray) -> StepResult:
        return self._thread.call(self._step, np.asarray(action, dtype=np.float64))

    def _step(self, action: np.ndarray) -> StepResult:
        b = self._backend
        reward = 0.0
        terminated = ended = False
        for _ in range(b.action_repeat):
            ts = self.env.step(action)
            reward += float(ts.reward or 0.0)
            if ts.last():
                ended = True
                terminated = ts.discount is not None and float(ts.discount) == 0.0
                break
        self.steps += 1
        truncated = not terminated and (ended or self.steps >= b.episode_steps)
        return b.frame(self.env), reward, terminated, truncated

    def close(self) -> None:
        env, self.env = self.env, None
        if env is not None:
            self._thread.call(_close_env, env)
            self._thread.shutdown()


def _close_env(env: Any) -> None:
    try:
        env.close()
        env.physics.free()  # the rendering context
    except Exception:  # noqa: BLE001
        log.exception("closing a dm_control environment failed")


class DmcBackend(Backend):
    """``--dmc DOMAIN-TASK``: a DeepMind Control Suite task from pixels."""

    def __init__(
        self,
        spec: str = "cheetah-run",
        pixels: int = DEFAULT_PIXELS,
        action_repeat: int = DEFAULT_ACTION_REPEAT,
        episode_steps: int = DEFAULT_EPISODE_STEPS,
        camera: int = DEFAULT_CAMERA,
    ):
        for name, value in (("pixels", pixels), ("action_repeat", action_repeat), ("episode_steps", episode_steps)):
            if int(value) < 1:
                raise BackendError(f"--dmc: {name} must be at least 1, not {value}")
        self.domain, self.task = parse_task(spec)
        self.pixels = int(pixels)
        self.action_repeat = int(action_repeat)
        self.episode_steps = int(episode_steps)
        self.camera = int(camera)
        self._suite = _import_suite()
        self.what = (
            f"dm_control {self.domain}-{self.task} from pixels ({RENDER_WIDTH}x{RENDER_HEIGHT} camera {self.camera} -> "
            f"{self.pixels}x{self.pixels}, action repeat {self.action_repeat}, {self.episode_steps} steps, "
            f"MUJOCO_GL={os.environ.get('MUJOCO_GL')})"
        )
        if (self.domain, self.task) not in set(self._suite.ALL_TASKS):
            raise BackendError(f"--dmc {spec}: dm_control's suite has no task {self.task!r} in domain {self.domain!r}")
        self.resize = FrameResizer(RENDER_HEIGHT, RENDER_WIDTH, self.pixels)

        # Build and render once now: missing GL fails at start, with its reason.
        thread = _EnvThread("dmc-probe")
        try:
            low, high = thread.call(self._probe, spec)
        finally:
            thread.shutdown()
        n = 3 * self.pixels * self.pixels
        self.profile = Profile(
            action_low=low,
            action_high=high,
            obs_dim=n,
            obs_low=np.zeros(n, dtype=np.float32),
            obs_high=np.ones(n, dtype=np.float32),
            design=DesignSpace.empty(),
        )

    def _probe(self, spec: str) -> tuple:
        """Loads the task, renders a frame and returns the action box (on one thread)."""
        probe = self.load()
        try:
            aspec = probe.action_spec()
            low = np.broadcast_to(np.asarray(aspec.minimum, dtype=np.float32), aspec.shape).ravel().copy()
            high = np.broadcast_to(np.asarray(aspec.maximum, dtype=np.float32), aspec.shape).ravel().copy()
            if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high)) and np.all(low < high)):
                raise BackendError(f"--dmc {spec}: action spec {aspec} is not a finite box")
            probe.reset()
            try:
                self.frame(probe)
            except Exception as e:
                raise BackendError(
                    f"--dmc {spec}: rendering failed with MUJOCO_GL={os.environ.get('MUJOCO_GL')}: "
                    f"{type(e).__name__}: {e}; {GL_HINT}"
                ) from e
        finally:
            _close_env(probe)
        return low, high

    def load(self) -> Any:
        """A new environment of the task, without its time limit (episodes are cut here)."""
        try:
            return self._suite.load(self.domain, self.task, task_kwargs={"time_limit": float("inf")})
        except Exception as e:
            raise BackendError(
                f"dm_control {self.domain}-{self.task}: loading failed: {type(e).__name__}: {e} (dm_control and MuJoCo "
                f"versions must match: {INSTALL_HINT}; {GL_HINT})"
            ) from e

    def frame(self, env: Any) -> np.ndarray:
        """Renders ``env`` (320x240, the camera) and resizes: the observation."""
        return self.resize(env.physics.render(height=RENDER_HEIGHT, width=RENDER_WIDTH, camera_id=self.camera))

    def new_body(self, design: np.ndarray, world: Optional[dict] = None) -> Body:
        return DmcBody(self)

