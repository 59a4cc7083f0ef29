"""Template of a robot driver for ``coadapt-gym-serve --driver``: copy this file, fill in the
TODOs where it talks to your hardware, and serve it::

    coadapt-gym-serve --driver my_robot_driver:MyRobotDriver --host 0.0.0.0 --port 50051 \\
        --step-timeout 0.5 --max-episode-steps 500

(the module must be importable: run from its directory or put it on PYTHONPATH). coadapt then
trains on the robot with ``--env dm-env-rpc://ROBOT_HOST:50051``.

What the bridge does for you, so the driver need not (and must not rely on doing it itself):

* actions outside ``[action_low, action_high]`` are refused at the protocol level, and every
  action is clipped to that box (and to ``max_action_change`` of the previous one) before
  ``step`` sees it;
* at most ``max_action_rate_hz`` actions per second reach ``step``; faster requests wait;
* ``safe_stop()`` is called when no step request arrives within ``--step-timeout`` seconds of
  a step, when the client's connection is lost, when it leaves or destroys its world, and when
  the server gets Ctrl-C or SIGTERM; an exception in ``safe_stop`` is logged, never fatal;
* calls into the driver never overlap (one at a time, from the server's threads);
* ``--max-episode-steps`` truncates episodes (discount 1) if ``step`` never does.

What remains yours: the hardware's own limits (joint limits, a hardware e-stop, a watchdog in
the motor controllers in case this process dies), the reward, and the end of an episode.
"""

from __future__ import annotations

import math
import time

import numpy as np

from coadapt_bridge import RobotDriver


class MyRobotDriver(RobotDriver):
    """TODO: one sentence on the robot: what it is, what an action and an observation mean."""

    # -- Declarations (read by the bridge when the server starts) ---------------------------

    # The action box, one entry per actuator (e.g. normalised torques or velocity targets).
    action_low = [-1.0, -1.0]
    action_high = [1.0, 1.0]
    # Length of the observation vector returned by reset() and step().
    observation_size = 4
    # The most actions per second the robot may receive (e.g. the control loop's rate).
    max_action_rate_hz = 50.0
    # Optional: the largest change of each action element from one step to the next.
    max_action_change = 0.2
    # Optional: the action the robot holds at rest (the first action of an episode is limited
    # relative to it). Remove to only clip an episode's first action to the box.
    rest_action = [0.0, 0.0]
    # Optional: the design box, if the body can be adjusted between episodes (link lengths,
    # spring stiffness, a gear setting...). Remove all three for a fixed body.
    design_low = [0.10]
    design_high = [0.30]
    default_design = [0.20]

    # Episode limits of this example.
    control_period_s = 1.0 / 50.0
    max_tilt_rad = 0.6

    def __init__(self) -> None:
        super().__init__()
        # TODO: connect to the robot (serial port, CAN bus, a vendor SDK, ROS...). Raising here
        # stops the server at start with the message, which is what you want when the robot
        # is unreachable.
        self.robot = None  # e.g. MyVendorSdk.connect("/dev/ttyUSB0")
        self._last_step_time = 0.0

    # -- Episode --------------------------------------------------------------------------

    def reset(self, design: np.ndarray) -> np.ndarray:
        """Adjust the body to ``design``, bring the robot to its start pose, return the first
        observation."""
        # TODO: apply the design, e.g. move an adjustable link to design[0] metres, or ask the
        # operator to swap a part and wait for confirmation. The design is inside the box.
        # TODO: move to the start pose slowly and wait until it is reached (this may take as
        # long as it needs: the step deadline only runs between steps).
        self._last_step_time = time.monotonic()
        return self._read_observation()

    def step(self, action: np.ndarray):
        """Send one action (already safe: inside the box, rate and change limited), wait for
        one control period, and report what happened."""
        # TODO: send the action, e.g. self.robot.set_torques(action * MAX_TORQUE).
        # Keep a steady control period: sleep what is left of it.
        wait = self._last_step_time + self.control_period_s - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        self._last_step_time = time.monotonic()
        obs = self._read_observation()

        # TODO: the reward of this step, e.g. forward velocity minus an effort penalty.
        reward = float(-0.01 * np.sum(np.square(action)))
        # terminated: a true end the learner must not bootstrap through (the robot fell, hit
        # something, left the workspace). The bridge does not call safe_stop for you here:
        # stop the robot yourself before returning True if it must not keep going.
        terminated = bool(abs(obs[0]) > self.max_tilt_rad)
        if terminated:
            self.safe_stop()
        # truncated: an end that is not the robot's doing (a time limit of your own). Or leave
        # it False and pass --max-episode-steps to the server.
        truncated = False
        return obs, reward, terminated, truncated

    # -- Safety ----------------------------------------------------------------------------

    def safe_stop(self) -> None:
        """Bring the robot to a standstill now. Called by the bridge on a missed step
        deadline, a lost connection, LeaveWorld, DestroyWorld and shutdown, possibly several
        times in a row, and possibly before any reset(): make it idempotent and quick."""
        # TODO: e.g. self.robot.set_torques([0, 0]); self.robot.engage_brakes()
        pass

    def close(self) -> None:
        """Release the robot (once, at server shutdown, after safe_stop)."""
        # TODO: e.g. self.robot.disconnect()
        pass

    # -- Helpers ---------------------------------------------------------------------------

    def _read_observation(self) -> np.ndarray:
        # TODO: read the sensors: joint angles, velocities, IMU... as observation_size floats.
        # Finite values only (the coadapt client drops an episode with a non-finite one).
        obs = np.zeros(self.observation_size, dtype=np.float32)
        assert all(math.isfinite(v) for v in obs)
        return obs
