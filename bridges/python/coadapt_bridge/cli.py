"""``coadapt-gym-serve``: serve a gymnasium environment, a body factory or a robot driver over
DeepMind's dm_env_rpc v1 gRPC protocol, following the coadapt profile."""

from __future__ import annotations

import argparse
import logging
import math
import signal
import sys
import threading
from typing import Optional, Sequence

from .backends import Backend, BackendError, DriverBackend, GymBackend

PROG = "coadapt-gym-serve"

DESCRIPTION = """\
Serve one environment over DeepMind's dm_env_rpc v1 gRPC protocol (service
dm_env_rpc.v1.Environment, one bidirectional Process stream per connection),
following the coadapt profile of proto/README.md. Any dm_env_rpc client can
drive it; coadapt drives it with the environment name dm-env-rpc://HOST:PORT.

What is served (exactly one of):
  --env ID                 gymnasium.make(ID); no design (the design has 0
                           elements). Continuous Box action spaces only.
  --factory module:func    func(design: np.ndarray[float32]) -> gymnasium.Env
                           builds the body for a design. The design box is read
                           from the function's attributes design_low,
                           design_high and default_design, which the decorator
                           @coadapt_bridge.design_space(low, high, default)
                           sets. The env is rebuilt when an episode starts with
                           a different design.
  --driver module:Class    a coadapt_bridge.RobotDriver subclass for a real
                           robot, instantiated once with no arguments; one
                           world at a time. The bridge enforces the safety
                           rules (see below).
  --dmc DOMAIN-TASK        a DeepMind Control Suite task from pixels, e.g.
                           cheetah-run (the optional dm_control dependency:
                           setup_venv.sh --dmc). Each step repeats the action
                           --action-repeat times (reward: their sum), renders
                           320x240 RGB from camera --camera and resizes it to
                           --pixels x --pixels by area averaging: observation
                           FLOAT [3*P*P] in [0, 1], channel-major (all R rows,
                           then G, then B). Episodes are truncated (discount 1)
                           after --episode-steps steps; no design. Headless
                           rendering: MUJOCO_GL defaults to egl.

The profile (uids):
  action       1  FLOAT [A] with min/max (the action box). Required on every
                  running step; out-of-box, non-finite, wrongly typed (doubles)
                  or wrongly shaped actions are refused with an error.
  observation  1  FLOAT [S], the state (bounds only when all finite)
  reward       2  FLOAT scalar (0 on an episode's first observation)
  discount     3  FLOAT scalar: 0 at a true end (gymnasium `terminated`),
                  1 otherwise, also when an episode is truncated
  design       4  FLOAT [D], min/max = the design box: the body in use
  World settings (CreateWorld, ResetWorld), both optional: `design` (floats
  or doubles, shape [D], inside the box) and `seed` (integer scalar; the next
  episode calls env.reset(seed=seed), later ones env.reset()). CreateWorld
  also takes a float scalar for each keyword argument the factory has after
  the design (mujoco_half_cheetah:make takes `friction`; `actuator-scale`
  names `actuator_scale`): the world's dynamics, fixed for its life. Other
  settings are refused; JoinWorld and Reset take none. Worlds are named world-1,
  world-2, ...; one agent per world; a world is destroyed by DestroyWorld or
  when the connection that created it closes. The first Step after JoinWorld,
  Reset, ResetWorld or a TERMINATED step ignores its actions and starts an
  episode.

Robot safety (--driver), enforced by the bridge: actions clipped to the
declared box (and to max_action_change of the previous one), at most
max_action_rate_hz actions per second (faster requests wait), and
safe_stop() when no StepRequest arrives within --step-timeout seconds of a
step, when the connection is lost, the world is left or destroyed, and when
the server stops (SIGINT/SIGTERM). safe_stop() failures are logged only.

On start the server prints one line to stdout,
  coadapt-gym-serve listening on HOST:PORT
(the bound port when --port 0), then logs to stderr only. SIGINT or SIGTERM
stop it cleanly, closing every world.
"""

EPILOG = """\
examples:
  coadapt-gym-serve --env Pendulum-v1 --port 50051
  coadapt-gym-serve --factory coadapt_bridge.mujoco_half_cheetah:make --port 0
  coadapt-gym-serve --driver my_robot:MyArm --step-timeout 0.5
  coadapt-gym-serve --dmc cheetah-run --port 50051
"""


def parse_args(argv: Optional[Sequence[str]] = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog=PROG,
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--env", metavar="ID", help="a registered gymnasium environment id, e.g. Pendulum-v1")
    what.add_argument(
        "--factory",
        metavar="MODULE:FUNCTION",
        help="a body factory: FUNCTION(design) -> gymnasium.Env, with its design box declared by "
        "@coadapt_bridge.design_space",
    )
    what.add_argument("--driver", metavar="MODULE:CLASS", help="a coadapt_bridge.RobotDriver subclass (a real robot)")
    what.add_argument(
        "--dmc",
        metavar="DOMAIN-TASK",
        help="a DeepMind Control Suite task from pixels, e.g. cheetah-run (needs dm_control: setup_venv.sh --dmc)",
    )
    dmc = p.add_argument_group("--dmc options")
    dmc.add_argument("--pixels", type=int, metavar="P", help="observation frames are P x P RGB (default: 64)")
    dmc.add_argument(
        "--action-repeat", type=int, metavar="K", help="control steps per agent step; the reward is their sum (default: 2)"
    )
    dmc.add_argument(
        "--episode-steps", type=int, metavar="N", help="agent steps per episode, then truncation (discount 1) (default: 420)"
    )
    dmc.add_argument("--camera", type=int, metavar="ID", help="the camera rendered (default: 0, cheetah's tracking camera)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default: %(default)s; 0.0.0.0 for all)")
    p.add_argument("--port", type=int, default=0, help="port to listen on; 0 picks a free one (default: %(default)s)")
    p.add_argument(
        "--max-episode-steps",
        type=int,
        metavar="N",
        help="truncate episodes after N steps (discount 1). With --env it replaces the registered time limit",
    )
    p.add_argument(
        "--seed",
        type=int,
        metavar="S",
        help="seed of the first episode of every world created without a `seed` setting (default: "
        "gymnasium seeds from the OS)",
    )
    p.add_argument(
        "--step-timeout",
        type=float,
        default=1.0,
        metavar="SECONDS",
        help="--driver only: safe_stop() the robot when no StepRequest arrives within this long after a step "
        "(default: %(default)s)",
    )
    p.add_argument(
        "--max-connections",
        type=int,
        default=32,
        metavar="N",
        help="simultaneous connections served; more are refused with RESOURCE_EXHAUSTED (default: %(default)s)",
    )
    p.add_argument("--tls-cert", metavar="PEM", help="serve TLS with this certificate (with --tls-key; `coadapt tls new`)")
    p.add_argument("--tls-key", metavar="PEM", help="the private key of --tls-cert")
    p.add_argument(
        "--tokens-file",
        metavar="FILE",
        help="accept only calls with these tokens (`ROLE SHA256` lines, `coadapt token new`); actors and operators may step",
    )
    p.add_argument(
        "--insecure",
        action="store_true",
        help="serve plaintext on an address other than loopback (a network you trust: anyone who reaches it drives the robot)",
    )
    p.add_argument(
        "--log-level",
        default="INFO",
        choices=["DEBUG", "INFO", "WARNING", "ERROR"],
        help="stderr log level (default: %(default)s)",
    )
    args = p.parse_args(argv)
    if not 0 <= args.port <= 65535:
        p.error(f"--port {args.port} is not in 0-65535")
    if args.max_episode_steps is not None and args.max_episode_steps < 1:
        p.error("--max-episode-steps must be at least 1")
    if args.seed is not None and args.seed < 0:
        p.error("--seed must be non-negative")
    if not (args.step_timeout > 0 and math.isfinite(args.step_timeout)):
        p.error("--step-timeout must be a positive number of seconds")
    dmc_options = {"pixels": args.pixels, "action_repeat": args.action_repeat, "episode_steps": args.episode_steps}
    for name, value in dmc_options.items():
        if value is not None and args.dmc is None:
            p.error(f"--{name.replace('_', '-')} goes with --dmc")
        if value is not None and value < 1:
            p.error(f"--{name.replace('_', '-')} must be at least 1")
    if args.camera is not None and args.dmc is None:
        p.error("--camera goes with --dmc")
    if args.max_connections < 1:
        p.error("--max-connections must be at least 1")
    if (args.tls_cert is None) != (args.tls_key is None):
        p.error("--tls-cert and --tls-key go together")
    from .auth import is_loopback

    if not is_loopback(args.host) and not args.insecure and (args.tls_cert is None or args.tokens_file is None):
        missing = " and ".join(
            what
            for what, absent in (("no TLS (--tls-cert, --tls-key)", args.tls_cert is None),
                                 ("no role tokens (--tokens-file)", args.tokens_file is None))
            if absent
        )
        p.error(
            f"--host {args.host}: not a loopback address, and {missing}: anyone who reaches the port would drive the "
            "environment. Off loopback a server needs TLS and tokens; listen on 127.0.0.1, or pass --insecure on a "
            "network you trust"
        )
    return args


def make_backend(args: argparse.Namespace) -> Backend:
    if args.env is not None:
        return GymBackend.from_env_id(args.env, args.max_episode_steps)
    if args.factory is not None:
        return GymBackend.from_factory(args.factory)
    if args.dmc is not None:
        from .dmc import DmcBackend

        options = {
            name: getattr(args, name)
            for name in ("pixels", "action_repeat", "episode_steps", "camera")
            if getattr(args, name) is not None
        }
        return DmcBackend(args.dmc, **options)
    return DriverBackend.from_spec(args.driver)


def main(argv: Optional[Sequence[str]] = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(
        stream=sys.stderr,
        level=getattr(logging, args.log_level),
        format=f"{PROG}: %(asctime)s %(levelname)s %(message)s",
    )
    log = logging.getLogger("coadapt_bridge")

    # Ask to stop from the first signal on (also while the backend is being built).
    stop = threading.Event()

    def on_signal(signum, _frame):
        log.info("received %s: stopping", signal.Signals(signum).name)
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)

    from .server import BridgeServer

    from .auth import AuthError, load_tokens, read_pem

    try:
        tls = (read_pem("--tls-cert", args.tls_cert), read_pem("--tls-key", args.tls_key)) if args.tls_cert else None
        tokens = load_tokens(args.tokens_file) if args.tokens_file else None
    except AuthError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    try:
        backend = make_backend(args)
    except BackendError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    server = BridgeServer(
        backend,
        host=args.host,
        port=args.port,
        max_episode_steps=args.max_episode_steps,
        seed=args.seed,
        step_timeout=args.step_timeout,
        max_connections=args.max_connections,
        tls=tls,
        tokens=tokens,
    )
    try:
        server.start()
    except OSError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        server.stop(grace=0)
        return 1
    log.info("serving %s: %s", getattr(backend, "what", type(backend).__name__), backend.profile.describe())
    print(f"{PROG} listening on {server.address}", flush=True)
    try:
        while not stop.wait(0.5):
            pass
    finally:
        server.stop()
        log.info("stopped")
    return 0


if __name__ == "__main__":
    sys.exit(main())
