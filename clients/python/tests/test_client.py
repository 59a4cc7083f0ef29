"""coadapt-client against a real server, run by cli/tests/serve.rs:

- ``COADAPT_TEST_SERVER=HOST:PORT COADAPT_TEST_RUN_DIR=DIR``: a finished run served by
  ``coadapt serve DIR`` (every call, its validation and its errors);
- ``COADAPT_TEST_LIVE=HOST:PORT``: a learner serving during its run (wait for the first design
  request, then watch the run to its end).

``COADAPT_TEST_TLS_CA`` (and ``COADAPT_TOKEN``) when the server speaks TLS with tokens.
"""

import csv
import os

import grpc
import numpy as np
import pytest

from coadapt_client import CoadaptError, DesignClient

SERVER = os.environ.get("COADAPT_TEST_SERVER")
LIVE = os.environ.get("COADAPT_TEST_LIVE")
CA = os.environ.get("COADAPT_TEST_TLS_CA")

finished = pytest.mark.skipif(not SERVER, reason="COADAPT_TEST_SERVER is not set")
live = pytest.mark.skipif(not LIVE, reason="COADAPT_TEST_LIVE is not set")


@pytest.fixture
def client():
    with DesignClient(SERVER, tls_ca=CA, server_name="localhost" if CA else None) as c:
        yield c


@finished
def test_info_names_the_dimensions_and_the_box(client):
    info = client.info()
    assert info.robot == "half-cheetah"
    assert info.names == ["back thigh", "back shin", "back foot", "front thigh", "front shin", "front foot"]
    assert (info.low < info.high).all() and info.weights_version >= 1 and info.start_states == 8


@finished
def test_score_and_the_open_inference_protocol_agree(client):
    designs = np.array([[1, 1, 1, 1, 1, 1], [2, 0.8, 1.5, 1.2, 2, 0.9]], dtype=np.float32)
    s = client.score(designs)
    assert s.value.shape == (2,) and np.isfinite(s.value).all() and s.value[0] != s.value[1]
    assert (s.spread >= 0).all() and s.disagreement is not None and (s.disagreement >= 0).all()
    o = client.infer(designs, outputs=("value", "spread", "disagreement"))
    np.testing.assert_array_equal(o["value"], s.value)
    np.testing.assert_array_equal(o["spread"], s.spread)
    np.testing.assert_array_equal(o["disagreement"], s.disagreement)
    assert int(o["model_version"]) == s.weights_version
    # One design as a vector is a batch of one.
    assert client.score(designs[0]).value[0] == s.value[0]


@finished
def test_malformed_designs_are_refused_before_sending_naming_row_and_column(client):
    with pytest.raises(ValueError, match=r"shape \(1, 5\), expected \(N, 6\)"):
        client.score([[1, 1, 1, 1, 1]])
    with pytest.raises(ValueError, match=r"designs\[1\]\[2\] \(back foot\) is nan"):
        client.score([[1, 1, 1, 1, 1, 1], [1, 1, np.nan, 1, 1, 1]])
    with pytest.raises(ValueError, match="N >= 1"):
        client.score(np.zeros((0, 6)))


@finished
def test_the_servers_refusals_name_the_field(client):
    with pytest.raises(CoadaptError) as e:
        client.score([[9, 1, 1, 1, 1, 1]])
    assert e.value.code == grpc.StatusCode.INVALID_ARGUMENT
    assert "designs[0].values[0] (back thigh): 9 is outside the design box [0.8, 2]" in e.value.message


@finished
def test_optimize_reports_progress_and_its_answer_scores_as_it_says(client):
    seen = []
    best = client.optimize(particles=30, iterations=10, seed=1, on_progress=seen.append)
    assert [p.iteration for p in seen] == list(range(10))
    assert [p.evaluations for p in seen] == [30 * (i + 1) for i in range(10)]
    assert all(a.best_value <= b.best_value for a, b in zip(seen, seen[1:])), "the best so far never gets worse"
    assert best.evaluations == 300 and best.iterations == 10
    info = client.info()
    assert ((best.design >= info.low) & (best.design <= info.high)).all()
    assert client.score(best.design).value[0] == pytest.approx(best.value, abs=0)
    # A coordinate held where it was asked.
    held = client.optimize(particles=20, iterations=5, seed=2, fixed={0: 1.5})
    assert held.design[0] == np.float32(1.5)
    with pytest.raises(ValueError, match="fixed: dimension 9"):
        client.optimize(fixed={9: 1.0})


@finished
def test_history_is_designs_csv_and_the_landscape_covers_it(client):
    with open(os.path.join(os.environ["COADAPT_TEST_RUN_DIR"], "designs.csv")) as f:
        rows = list(csv.DictReader(f))
    got = client.history(page=2)
    assert [(r.index, r.kind, r.method) for r in got] == [(int(r["index"]), r["kind"], r["method"]) for r in rows]
    assert all(r.design.shape == (6,) for r in got)
    land = client.landscape(grid=5)
    assert land.objective.shape == (5, 5) and np.isfinite(land.objective).all()
    assert len(land.designs) == len(rows)
    # A finished run's watch gives its designs and ends.
    assert [r.index for r in client.watch()] == [r.index for r in got]


@finished
def test_every_call_has_a_deadline(client):
    # The reference protocol's whole search (700 x 250) cannot finish in 50 ms.
    with pytest.raises(CoadaptError) as e:
        client.optimize(particles=700, iterations=250, timeout=0.05)
    assert e.value.code == grpc.StatusCode.DEADLINE_EXCEEDED and "deadline" in str(e.value)
    with pytest.raises(ValueError, match="timeout"):
        DesignClient(SERVER, timeout=0)


def test_a_token_never_crosses_the_network_in_the_clear(monkeypatch, tmp_path):
    monkeypatch.setenv("COADAPT_TOKEN", "coadapt-" + "1" * 64)
    with pytest.raises(ValueError, match="not sent in the clear"):
        DesignClient("10.0.0.1:50061")
    monkeypatch.delenv("COADAPT_TOKEN")
    empty = tmp_path / "t"
    empty.write_text("")
    with pytest.raises(ValueError, match="token_file: .* is empty"):
        DesignClient("127.0.0.1:1", token_file=str(empty))
    with pytest.raises(ValueError, match="address"):
        DesignClient("nowhere")


@live
def test_live_learner_is_watched_to_its_end():
    with DesignClient(LIVE, tls_ca=CA, server_name="localhost" if CA else None) as c:
        info = c.wait_ready(timeout=300)
        assert info.robot == "half-cheetah"
        last = {}
        for r in c.watch():
            last[r.index] = r
        # The tiny protocol's four designs, each trained to its end.
        assert sorted(last) == [0, 1, 2, 3]
        assert [last[i].episodes for i in range(4)] == [3, 3, 2, 2]
        assert last[2].kind == "exploit" and last[2].predicted_objective is not None
