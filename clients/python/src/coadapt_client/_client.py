"""DesignClient: the DesignService and the Open Inference Protocol model ``design-critic``."""

from __future__ import annotations

import functools
import importlib.resources
import ipaddress
import os
import pathlib
import time
from typing import Callable, Iterator, Optional, Sequence

import grpc
import numpy as np
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

from ._errors import CoadaptError, wrap
from ._proto.coadapt.v1 import design_pb2 as pb
from ._proto.coadapt.v1 import design_pb2_grpc
from ._types import Dimension, Info, Landscape, Optimized, Progress, Record, Scores

MODEL = "design-critic"


@functools.lru_cache(maxsize=1)
def _oip():
    """The Open Inference Protocol's request and response classes, from the descriptor set built
    with the package, in a pool of their own (Triton's client registers the same names in the
    default pool; a second registration would refuse to load)."""
    data = importlib.resources.files("coadapt_client").joinpath("_proto/oip.pb").read_bytes()
    pool = descriptor_pool.DescriptorPool()
    for f in descriptor_pb2.FileDescriptorSet.FromString(data).file:
        pool.Add(f)
    get = lambda name: message_factory.GetMessageClass(pool.FindMessageTypeByName(name))  # noqa: E731
    return get("inference.ModelInferRequest"), get("inference.ModelInferResponse"), get("inference.InferTensorContents")


def _loopback(address: str) -> bool:
    host = address.rsplit(":", 1)[0].strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _token(token_file: Optional[str]) -> Optional[str]:
    env = os.environ.get("COADAPT_TOKEN", "").strip()
    if env:
        return env
    if token_file is None:
        return None
    try:
        t = pathlib.Path(token_file).read_text().strip()
    except OSError as e:
        raise ValueError(f"token_file: cannot read {token_file}: {e.strerror}") from None
    if not t:
        raise ValueError(f"token_file: {token_file} is empty")
    return t


def _opt(msg, name: str) -> Optional[float]:
    return getattr(msg, name) if msg.HasField(name) else None


def _record(r) -> Record:
    return Record(
        index=r.index,
        kind=r.kind,
        design=np.array(r.design.values, dtype=np.float32),
        episodes=r.episodes,
        best_eval_return=_opt(r, "best_eval_return"),
        last_eval_return=_opt(r, "last_eval_return"),
        predicted_objective=_opt(r, "predicted_objective"),
        design_rollouts=r.design_rollouts,
        method=r.method,
        prototype=r.prototype,
    )


class DesignClient:
    """A connection to a design service at ``address`` (``host:port``).

    ``tls_ca``: the PEM file of the CA that signed the server's certificate (then TLS; else
    plaintext, which only loopback servers speak unless told ``--insecure``). ``server_name``:
    the name to check the certificate for (default: the host of ``address``). The token comes
    from ``COADAPT_TOKEN`` or ``token_file``; a token to a non-loopback address without TLS is
    refused (it would cross the network in the clear). ``timeout``: the deadline of every call in
    seconds (a search or a watch takes its own).
    """

    def __init__(self, address: str, *, tls_ca: Optional[str] = None, token_file: Optional[str] = None,
                 server_name: Optional[str] = None, timeout: float = 10.0):
        if not (timeout > 0):
            raise ValueError(f"timeout: {timeout} is not a positive number of seconds")
        if ":" not in address:
            raise ValueError(f"address: {address!r} is not host:port")
        self.address = address
        self.timeout = float(timeout)
        token = _token(token_file)
        options = [("grpc.max_receive_message_length", 64 << 20), ("grpc.max_send_message_length", 64 << 20)]
        if server_name:
            options.append(("grpc.ssl_target_name_override", server_name))
        if tls_ca is not None:
            try:
                root = pathlib.Path(tls_ca).read_bytes()
            except OSError as e:
                raise ValueError(f"tls_ca: cannot read {tls_ca}: {e.strerror}") from None
            creds = grpc.ssl_channel_credentials(root_certificates=root)
            if token:
                creds = grpc.composite_channel_credentials(creds, grpc.access_token_call_credentials(token))
            self._channel = grpc.secure_channel(address, creds, options=options)
            self._metadata = None
        else:
            if token and not _loopback(address):
                raise ValueError(f"token: not sent in the clear to {address}; give tls_ca (the server's CA) to speak TLS")
            self._channel = grpc.insecure_channel(address, options=options)
            # Over loopback plaintext grpc refuses call credentials: the header goes by hand.
            self._metadata = (("authorization", f"Bearer {token}"),) if token else None
        self._svc = design_pb2_grpc.DesignServiceStub(self._channel)
        request, response, _ = _oip()
        self._infer = self._channel.unary_unary(
            "/inference.GRPCInferenceService/ModelInfer",
            request_serializer=request.SerializeToString,
            response_deserializer=response.FromString,
        )
        self._info: Optional[Info] = None

    # -- plumbing -------------------------------------------------------------------------

    def close(self) -> None:
        self._channel.close()

    def __enter__(self) -> "DesignClient":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _call(self, name: str, method, request, timeout: Optional[float] = None):
        try:
            return method(request, timeout=timeout or self.timeout, metadata=self._metadata)
        except grpc.RpcError as e:
            raise wrap(name, e) from None

    def _designs(self, designs, what: str = "designs") -> np.ndarray:
        """``designs`` as float32 ``[N, D]`` with D this server's design dimension, finite;
        a ValueError names the first bad row and column."""
        d = np.asarray(designs, dtype=np.float32)
        if d.ndim == 1:
            d = d[None, :]
        dim = len(self.info().dimensions)
        if d.ndim != 2 or d.shape[1] != dim or d.shape[0] == 0:
            raise ValueError(f"{what}: shape {tuple(np.shape(designs))}, expected (N, {dim}) with N >= 1 "
                             f"({', '.join(self.info().names)})")
        bad = np.argwhere(~np.isfinite(d))
        if len(bad):
            r, c = bad[0]
            raise ValueError(f"{what}[{r}][{c}] ({self.info().names[c]}) is {d[r, c]}, not a finite number")
        return d

    # -- the DesignService ----------------------------------------------------------------

    def info(self, refresh: bool = False) -> Info:
        """The robot, its named design dimensions and box, and the networks' version."""
        if self._info is None or refresh:
            r = self._call("Info", self._svc.Info, pb.InfoRequest())
            self._info = Info(
                robot=r.robot,
                dimensions=[Dimension(d.name, d.unit, d.low, d.high) for d in r.dimensions],
                weights_version=r.weights_version,
                start_states=r.start_states,
                max_score_batch=r.max_score_batch,
                max_optimize_evaluations=r.max_optimize_evaluations,
                run_id=r.run_id,
            )
        return self._info

    def wait_ready(self, timeout: float = 60.0) -> Info:
        """Waits until the server has networks to score with (a learner serves from its first
        design request on; until then it answers UNAVAILABLE), then returns :meth:`info`."""
        deadline = time.monotonic() + timeout
        while True:
            try:
                return self.info(refresh=True)
            except CoadaptError as e:
                if e.code != grpc.StatusCode.UNAVAILABLE or time.monotonic() > deadline:
                    raise
                time.sleep(0.2)

    def score(self, designs) -> Scores:
        """Eq. 5.6 of each design (rows of ``designs``, ``[N, D]``): value, spread over the start
        states, and the critics' disagreement."""
        d = self._designs(designs)
        r = self._call("Score", self._svc.Score, pb.ScoreRequest(designs=[pb.Design(values=row.tolist()) for row in d]))
        dis = [_opt(s, "disagreement") for s in r.scores]
        return Scores(
            value=np.array([s.objective for s in r.scores], dtype=np.float32),
            spread=np.array([s.spread for s in r.scores], dtype=np.float32),
            disagreement=None if any(v is None for v in dis) else np.array(dis, dtype=np.float32),
            weights_version=r.weights_version,
            start_states=r.start_states,
        )

    def optimize(self, *, method: str = "pso", particles: int = 0, iterations: int = 0,
                 low: Optional[Sequence[float]] = None, high: Optional[Sequence[float]] = None,
                 fixed: Optional[dict[int, float]] = None, seed: int = 0,
                 on_progress: Optional[Callable[[Progress], Optional[bool]]] = None,
                 timeout: float = 600.0) -> Optional[Optimized]:
        """A search over the critic on the server (``pso`` or ``cmaes``; 0 particles or
        iterations: the server's defaults), within ``low``/``high`` (default the design box) with
        the coordinates in ``fixed`` ({dimension: value}) held. ``on_progress`` is called with
        each iteration's best; if it returns ``False`` the search is cancelled on the server and
        ``optimize`` returns ``None``. The answer is the last message. ``timeout`` bounds the
        whole search."""
        info = self.info()
        fixed = fixed or {}
        for k in fixed:
            if not (0 <= int(k) < len(info.dimensions)):
                raise ValueError(f"fixed: dimension {k} is not in 0..{len(info.dimensions) - 1}")
        req = pb.OptimizeRequest(
            method=method, particles=particles, iterations=iterations, seed=seed,
            low=[] if low is None else self._designs(low, "low")[0].tolist(),
            high=[] if high is None else self._designs(high, "high")[0].tolist(),
            fixed=[pb.FixedCoordinate(dimension=int(k), value=float(v)) for k, v in fixed.items()],
        )
        last = None
        stream = self._svc.Optimize(req, timeout=timeout, metadata=self._metadata)
        try:
            for m in stream:
                if m.done:
                    last = m
                elif on_progress is not None:
                    go_on = on_progress(Progress(m.iteration, m.evaluations, np.array(m.best.values, dtype=np.float32), m.best_objective))
                    if go_on is False:
                        stream.cancel()
                        return None
        except grpc.RpcError as e:
            raise wrap("Optimize", e) from None
        finally:
            stream.cancel()
        if last is None:
            raise CoadaptError("Optimize", grpc.StatusCode.UNKNOWN, "the stream ended without an answer")
        return Optimized(np.array(last.best.values, dtype=np.float32), last.best_objective, last.best_spread,
                         last.evaluations, last.iteration + 1, last.weights_version)

    def history(self, start: int = 0, page: int = 0) -> list[Record]:
        """The run's designs from index ``start`` on, every page (``page`` rows a call; 0: the
        server's page)."""
        rows: list[Record] = []
        while True:
            r = self._call("History", self._svc.History, pb.HistoryRequest(from_index=start, max_rows=page))
            rows += [_record(x) for x in r.designs]
            if not r.more:
                return rows
            start = r.next_index

    def landscape(self, grid: int = 21) -> Landscape:
        """Thesis Fig. 5.9 on a ``grid`` x ``grid`` grid (at most the server's score batch)."""
        r = self._call("Landscape", self._svc.Landscape, pb.LandscapeRequest(grid=grid))
        n1, n2 = len(r.pc1), len(r.pc2)
        return Landscape(
            mean=np.array(r.mean.values, dtype=np.float32),
            axes=np.array([r.axis1.values, r.axis2.values], dtype=np.float32),
            explained=(r.explained1, r.explained2),
            pc1=np.array(r.pc1, dtype=np.float32),
            pc2=np.array(r.pc2, dtype=np.float32),
            objective=np.array(r.objective, dtype=np.float32).reshape(n2, n1),
            designs=[(d.index, d.kind, d.pc1, d.pc2) for d in r.designs],
            weights_version=r.weights_version,
        )

    def watch(self, start: int = 0, timeout: float = 7 * 24 * 3600.0) -> Iterator[Record]:
        """The run's designs from ``start`` on, then each change (chosen, done, confirmed,
        rejected) as it happens, until the run ends. Stop early by closing the generator (or
        leaving the loop): the stream is cancelled."""
        stream = self._svc.Watch(pb.WatchDesignsRequest(from_index=start), timeout=timeout, metadata=self._metadata)
        try:
            for ev in stream:
                yield _record(ev.design)
        except grpc.RpcError as e:
            if e.code() != grpc.StatusCode.CANCELLED:
                raise wrap("Watch", e) from None
        finally:
            stream.cancel()

    # -- the Open Inference Protocol ------------------------------------------------------

    def infer(self, designs, outputs: Sequence[str] = ("value", "spread")) -> dict[str, np.ndarray]:
        """The same critic through the Open Inference Protocol (model ``design-critic``, input
        ``design`` FP32 [N, D]): the asked outputs, each ``[N]`` (``value``, ``spread``,
        ``disagreement``), and ``model_version`` (the networks' version)."""
        d = self._designs(designs)
        request, _, contents = _oip()
        req = request(
            model_name=MODEL,
            inputs=[request.InferInputTensor(name="design", datatype="FP32", shape=list(d.shape),
                                             contents=contents(fp32_contents=d.reshape(-1).tolist()))],
            outputs=[request.InferRequestedOutputTensor(name=o) for o in outputs],
        )
        r = self._call("ModelInfer", self._infer, req)
        out: dict[str, np.ndarray] = {}
        for i, o in enumerate(r.outputs):
            if i < len(r.raw_output_contents):
                values = np.frombuffer(r.raw_output_contents[i], dtype="<f4")
            else:
                values = np.array(o.contents.fp32_contents, dtype=np.float32)
            out[o.name] = values.reshape(-1)
        out["model_version"] = np.array(int(r.model_version or 0))
        return out
