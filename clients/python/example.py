"""Asks a coadapt design service (`coadapt serve RUN_DIR`, or a learner serving it) what its
critic thinks of designs, from Python: the DesignService through stubs generated from
coadapt's proto/ files, and the same critic through Triton's Open Inference Protocol client.

    python clients/python/example.py --server 127.0.0.1:50061 [--design 1,1,1,1,1,1 ...]

Prints one JSON object on stdout: the service's info, the scores of the designs (the
DesignService's and the Open Inference Protocol's), an optimised design, the design landscape,
the run's design history, and what Watch streamed (to the run's end, or --watch-rows rows).
"""

import argparse
import json
import os
import pathlib
import sys
import tempfile
import time

import grpc
import numpy as np
import tritonclient.grpc as triton
from grpc_tools import protoc

PROTO = pathlib.Path(__file__).resolve().parents[2] / "proto"


def stubs():
    """Generates the Python modules of proto/coadapt/v1/design.proto and imports them."""
    out = tempfile.mkdtemp(prefix="coadapt-stubs-")
    include = pathlib.Path(protoc.__file__).parent / "_proto"
    code = protoc.main(["protoc", f"-I{PROTO}", f"-I{include}", f"--python_out={out}", f"--grpc_python_out={out}",
                        str(PROTO / "coadapt/v1/design.proto")])
    if code != 0:
        sys.exit(f"protoc failed on design.proto ({code})")
    sys.path.insert(0, out)
    from coadapt.v1 import design_pb2, design_pb2_grpc  # noqa: E402 (generated just now)
    return design_pb2, design_pb2_grpc


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--server", required=True, help="host:port of the design service")
    ap.add_argument("--design", action="append", default=[], help="a design, comma-separated values (repeatable); "
                    "default: the middle of the design box and its two corners")
    ap.add_argument("--timeout", type=float, default=10.0, help="deadline of every call, seconds")
    ap.add_argument("--watch-rows", type=int, default=0, help="stop watching after this many rows (0: when the run ends)")
    ap.add_argument("--tls-ca", help="PEM of the CA that signed the server's certificate: speak TLS (else plaintext)")
    ap.add_argument("--token-file", help="a file holding a client token (COADAPT_TOKEN in the environment wins)")
    a = ap.parse_args()
    pb, rpc = stubs()
    token = os.environ.get("COADAPT_TOKEN") or (pathlib.Path(a.token_file).read_text().strip() if a.token_file else None)
    root = pathlib.Path(a.tls_ca).read_bytes() if a.tls_ca else None
    if root is not None:
        creds = grpc.ssl_channel_credentials(root_certificates=root)
        if token:
            # Sent as `authorization: Bearer <token>`, only ever over TLS.
            creds = grpc.composite_channel_credentials(creds, grpc.access_token_call_credentials(token))
        channel = grpc.secure_channel(a.server, creds)
    else:
        channel = grpc.insecure_channel(a.server)
    svc = rpc.DesignServiceStub(channel)
    headers = {"authorization": f"Bearer {token}"} if token else None
    # A learner serves from its first design request on: until then, UNAVAILABLE.
    deadline = time.monotonic() + 6 * a.timeout
    while True:
        try:
            info = svc.Info(pb.InfoRequest(), timeout=a.timeout)
            break
        except grpc.RpcError as e:
            if e.code() != grpc.StatusCode.UNAVAILABLE or time.monotonic() > deadline:
                raise
            time.sleep(0.2)
    low = np.array([d.low for d in info.dimensions], dtype=np.float32)
    high = np.array([d.high for d in info.dimensions], dtype=np.float32)
    designs = [np.array([float(v) for v in d.split(",")], dtype=np.float32) for d in a.design]
    if not designs:
        designs = [(low + high) / 2, low, high]
    batch = np.stack(designs)

    # The same numbers through Triton's client: model design-critic, input design [N, D]. A
    # running learner changes its networks at each design request: both calls are made again
    # until they saw the same version.
    client = triton.InferenceServerClient(url=a.server, ssl=root is not None, root_certificates=a.tls_ca)
    assert client.is_server_live(headers=headers) and client.is_model_ready("design-critic", headers=headers)
    for _ in range(10):
        scores = svc.Score(pb.ScoreRequest(designs=[pb.Design(values=d.tolist()) for d in batch]), timeout=a.timeout)
        meta = client.get_model_metadata("design-critic", headers=headers)
        inp = triton.InferInput("design", list(batch.shape), "FP32")
        inp.set_data_from_numpy(batch)
        result = client.infer("design-critic", [inp], outputs=[triton.InferRequestedOutput("value")], client_timeout=a.timeout,
                              headers=headers)
        values = result.as_numpy("value")
        if result.get_response().model_version == str(scores.weights_version):
            break

    # Optimize, streamed: a small PSO to the end (the last message is the answer), then a large
    # one cancelled after its first three iterations.
    answer = None
    for m in svc.Optimize(pb.OptimizeRequest(method="pso", particles=30, iterations=10, seed=1), timeout=a.timeout):
        if m.done:
            answer = {"design": list(m.best.values), "objective": m.best_objective, "spread": m.best_spread,
                      "evaluations": m.evaluations}
    big = svc.Optimize(pb.OptimizeRequest(method="pso", particles=700, iterations=250, seed=2), timeout=a.timeout * 10)
    first = []
    cancelled = False
    try:
        for m in big:
            first.append(m.best_objective)
            if len(first) == 3:
                big.cancel()
    except grpc.RpcError as e:
        cancelled = e.code() == grpc.StatusCode.CANCELLED

    history, start = [], 0
    while True:
        page = svc.History(pb.HistoryRequest(from_index=start, max_rows=2), timeout=a.timeout)
        history += [{"index": r.index, "kind": r.kind, "design": list(r.design.values), "episodes": r.episodes,
                     "method": r.method, "prototype": r.prototype,
                     "best_eval_return": r.best_eval_return if r.HasField("best_eval_return") else None}
                    for r in page.designs]
        if not page.more:
            break
        start = page.next_index
    land = svc.Landscape(pb.LandscapeRequest(grid=5), timeout=a.timeout)

    # Watch: the history, then every change, until the run ends (the stream ends) or enough rows.
    watched = []
    stream = svc.Watch(pb.WatchDesignsRequest(from_index=0), timeout=30 * a.timeout)
    try:
        for ev in stream:
            r = ev.design
            watched.append({"index": r.index, "kind": r.kind, "episodes": r.episodes, "prototype": r.prototype})
            if a.watch_rows and len(watched) >= a.watch_rows:
                stream.cancel()
    except grpc.RpcError as e:
        if e.code() != grpc.StatusCode.CANCELLED:
            raise

    print(json.dumps({
        "robot": info.robot,
        "dimensions": [{"name": d.name, "low": d.low, "high": d.high} for d in info.dimensions],
        "weights_version": info.weights_version,
        "start_states": info.start_states,
        "designs": batch.tolist(),
        "objective": [s.objective for s in scores.scores],
        "spread": [s.spread for s in scores.scores],
        "disagreement": [s.disagreement if s.HasField("disagreement") else None for s in scores.scores],
        "oip_value": values.reshape(-1).tolist(),
        "oip_shape": list(values.shape),
        "oip_model_versions": list(meta.versions),
        "optimize_answer": answer,
        "optimize_first_before_cancel": first,
        "optimize_cancelled": cancelled,
        "history": history,
        "landscape": {"pc1": list(land.pc1), "pc2": list(land.pc2), "objective": list(land.objective),
                      "explained": [land.explained1, land.explained2],
                      "designs": [{"index": d.index, "kind": d.kind, "pc1": d.pc1, "pc2": d.pc2} for d in land.designs],
                      "weights_version": land.weights_version},
        "watched": watched,
    }))


if __name__ == "__main__":
    main()
