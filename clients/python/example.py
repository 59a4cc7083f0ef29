"""Asks a coadapt design service (`coadapt serve RUN_DIR`, or a learner serving it) what its
critic thinks of designs, from Python: the DesignService through the coadapt-client package
(`pip install ./clients/python`), and the same critic through Triton's Open Inference Protocol
client, to show that a client written for Triton works unchanged.

    python clients/python/example.py --server 127.0.0.1:50061 [--design 1,1,1,1,1,1 ...]

Prints one JSON object on stdout: the service's info, the scores of the designs (the
DesignService's and the Open Inference Protocol's), an optimised design, the design landscape,
the run's design history, and what Watch streamed (to the run's end, or --watch-rows rows).
"""

import argparse
import json
import os
import pathlib

import numpy as np
import tritonclient.grpc as triton

from coadapt_client import DesignClient


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
    c = DesignClient(a.server, tls_ca=a.tls_ca, token_file=a.token_file, timeout=a.timeout)
    # A learner serves from its first design request on: until then, UNAVAILABLE.
    info = c.wait_ready(timeout=6 * a.timeout)
    designs = [np.array([float(v) for v in d.split(",")], dtype=np.float32) for d in a.design]
    if not designs:
        designs = [(info.low + info.high) / 2, info.low, info.high]
    batch = np.stack(designs)

    # The same numbers through Triton's client: model design-critic, input design [N, D]. A
    # running learner changes its networks at each design request: both calls are made again
    # until they saw the same version.
    token = os.environ.get("COADAPT_TOKEN") or (pathlib.Path(a.token_file).read_text().strip() if a.token_file else None)
    headers = {"authorization": f"Bearer {token}"} if token else None
    client = triton.InferenceServerClient(url=a.server, ssl=a.tls_ca is not None, root_certificates=a.tls_ca)
    assert client.is_server_live(headers=headers) and client.is_model_ready("design-critic", headers=headers)
    for _ in range(10):
        scores = c.score(batch)
        meta = client.get_model_metadata("design-critic", headers=headers)
        inp = triton.InferInput("design", list(batch.shape), "FP32")
        inp.set_data_from_numpy(batch)
        result = client.infer("design-critic", [inp], outputs=[triton.InferRequestedOutput("value")], client_timeout=a.timeout,
                              headers=headers)
        values = result.as_numpy("value")
        if result.get_response().model_version == str(scores.weights_version):
            break

    # Optimize: a small PSO to the end (its answer), then a large one cancelled after its
    # first three iterations (on_progress returning False cancels it on the server).
    best = c.optimize(method="pso", particles=30, iterations=10, seed=1)
    answer = {"design": best.design.tolist(), "objective": best.value, "spread": best.spread, "evaluations": best.evaluations}
    first = []

    def three(p):
        first.append(p.best_value)
        return len(first) < 3

    cancelled = c.optimize(method="pso", particles=700, iterations=250, seed=2, on_progress=three, timeout=a.timeout * 10) is None

    history = [{"index": r.index, "kind": r.kind, "design": r.design.tolist(), "episodes": r.episodes, "method": r.method,
                "prototype": r.prototype, "best_eval_return": r.best_eval_return} for r in c.history(page=2)]
    land = c.landscape(grid=5)

    # Watch: the history, then every change, until the run ends (the stream ends) or enough rows.
    watched = []
    for r in c.watch():
        watched.append({"index": r.index, "kind": r.kind, "episodes": r.episodes, "prototype": r.prototype})
        if a.watch_rows and len(watched) >= a.watch_rows:
            break

    print(json.dumps({
        "robot": info.robot,
        "dimensions": [{"name": d.name, "low": d.low, "high": d.high} for d in info.dimensions],
        "weights_version": info.weights_version,
        "start_states": info.start_states,
        "designs": batch.tolist(),
        "objective": scores.value.tolist(),
        "spread": scores.spread.tolist(),
        "disagreement": None if scores.disagreement is None else scores.disagreement.tolist(),
        "oip_value": values.reshape(-1).tolist(),
        "oip_shape": list(values.shape),
        "oip_model_versions": list(meta.versions),
        "optimize_answer": answer,
        "optimize_first_before_cancel": first,
        "optimize_cancelled": cancelled,
        "history": history,
        "landscape": {"pc1": land.pc1.tolist(), "pc2": land.pc2.tolist(), "objective": land.objective.reshape(-1).tolist(),
                      "explained": list(land.explained),
                      "designs": [{"index": i, "kind": k, "pc1": p1, "pc2": p2} for i, k, p1, p2 in land.designs],
                      "weights_version": land.weights_version},
        "watched": watched,
    }))
    c.close()


if __name__ == "__main__":
    main()
