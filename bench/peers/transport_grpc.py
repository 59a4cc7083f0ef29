"""Python grpcio peer of `coadapt bench transport --transport grpc`.

The same two figures, over plain grpcio (sync API, what a lab would write), between processes:

- weights_broadcast: the learner (this process, a grpc server) publishes the acting policy
  (3 x 256, obs 23, act 6: 140,812 f32, 563 KB in a bytes field) to N actor processes that
  each watch a server-streaming RPC delivering the newest weights; each actor decodes the
  bytes (np.frombuffer) and acks the version with a unary call. The figure is publish -> all N
  acks, median and 99th percentile over `--seconds` of publishes (at least 20).
- experience: N actor processes stream (client-streaming RPC) 250-transition chunks (obs 23,
  act 6; bytes fields obs, actions, rewards, next_obs, terminated laid out like ours) for
  `--seconds`; the learner parses each into numpy arrays. transitions/s and MB/s counting
  213 bytes per transition ((2*23+6+1)*4+1, as ours counts). The clock starts at the first
  chunk (not counted) and stops at the last, as ours does.

The .proto below is compiled at run time with grpcio-tools into a temporary directory; the
actor processes are this script run again with `--peer echo|flood`.

usage: .venv-peers/bin/python bench/peers/transport_grpc.py [--seconds 5] [--actors 1,4,16] [--senders 1,4]
prints: {"bench": "weights_broadcast_median", "config": "grpc-4actors-563KB", "value": ..., "unit": "ms", "impl": "grpcio"}
"""
import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from concurrent import futures

import grpc
import numpy as np

OBS, ACT, ROWS = 23, 6, 250
BYTES_PER_ROW = (2 * OBS + ACT + 1) * 4 + 1  # 213, as `coadapt bench transport` counts
MAX_MSG = 64 * 1024 * 1024
OPTIONS = [("grpc.max_send_message_length", MAX_MSG), ("grpc.max_receive_message_length", MAX_MSG)]

PROTO = """
syntax = "proto3";
package coadapt_peer;

message Weights {
  uint64 version = 1;
  bytes policy = 2;  // f32 LE
}
message WatchRequest { uint64 actor = 1; }
message WeightsAck { uint64 actor = 1; uint64 version = 2; }
message Empty {}
message ExperienceChunk {
  uint64 actor = 1;
  uint64 weights_version = 2;
  uint32 rows = 3;
  bytes obs = 4;         // rows x 23 f32 LE
  bytes actions = 5;     // rows x 6 f32 LE
  bytes rewards = 6;     // rows f32 LE
  bytes next_obs = 7;    // rows x 23 f32 LE
  bytes terminated = 8;  // rows x u8
}
message Summary { uint64 chunks = 1; }

service Learner {
  rpc WatchWeights(WatchRequest) returns (stream Weights);
  rpc AckWeights(WeightsAck) returns (Empty);
  rpc PushExperience(stream ExperienceChunk) returns (Summary);
}
"""


def policy_len():
    n, fan_in = 0, OBS
    for h in (256, 256, 256):
        n += fan_in * h + h
        fan_in = h
    return n + fan_in * 2 * ACT + 2 * ACT


def compile_proto(out_dir):
    from grpc_tools import protoc

    path = os.path.join(out_dir, "transport_peer.proto")
    with open(path, "w") as f:
        f.write(PROTO)
    rc = protoc.main(["protoc", "-I", out_dir, "--python_out", out_dir, "--grpc_python_out", out_dir, path])
    if rc != 0:
        raise RuntimeError(f"protoc failed ({rc})")


def load(proto_dir):
    sys.path.insert(0, proto_dir)
    import transport_peer_pb2 as pb
    import transport_peer_pb2_grpc as pbg

    return pb, pbg


def emit(bench, config, value, unit):
    print(json.dumps({"bench": bench, "config": config, "value": round(value, 4), "unit": unit, "impl": "grpcio"}), flush=True)


# ---------------------------------------------------------------- learner (server) side


def make_servicer(pb, pbg):
    class Learner(pbg.LearnerServicer):
        def __init__(self):
            self.cond = threading.Condition()
            self.weights = None  # newest pb.Weights
            self.closed = False
            self.acks = {}  # version -> set of actors
            self.exp_lock = threading.Lock()
            self.rows = 0
            self.first = None
            self.last = None
            self.streams_done = 0

        # weights
        def publish(self, msg):
            with self.cond:
                self.weights = msg
                self.cond.notify_all()

        def close(self):
            with self.cond:
                self.closed = True
                self.cond.notify_all()

        def WatchWeights(self, request, context):
            sent = 0
            while context.is_active():
                with self.cond:
                    self.cond.wait_for(lambda: self.closed or (self.weights is not None and self.weights.version > sent), timeout=1.0)
                    if self.closed:
                        return
                    w = self.weights
                if w is not None and w.version > sent:
                    sent = w.version
                    yield w

        def AckWeights(self, request, context):
            with self.cond:
                self.acks.setdefault(request.version, set()).add(request.actor)
                self.cond.notify_all()
            return pb.Empty()

        def wait_acks(self, version, actors, timeout):
            with self.cond:
                return self.cond.wait_for(lambda: len(self.acks.get(version, ())) >= actors, timeout=timeout)

        def seen_actors(self):
            with self.cond:
                return set().union(*self.acks.values()) if self.acks else set()

        # experience
        def PushExperience(self, request_iterator, context):
            n = 0
            for c in request_iterator:
                rows = c.rows
                obs = np.frombuffer(c.obs, dtype="<f4").reshape(rows, OBS)
                actions = np.frombuffer(c.actions, dtype="<f4").reshape(rows, ACT)
                rewards = np.frombuffer(c.rewards, dtype="<f4")
                next_obs = np.frombuffer(c.next_obs, dtype="<f4").reshape(rows, OBS)
                terminated = np.frombuffer(c.terminated, dtype=np.bool_)
                assert rewards.shape[0] == rows and terminated.shape[0] == rows and obs.shape == next_obs.shape
                del actions
                now = time.perf_counter()
                with self.exp_lock:
                    # The clock starts at the first chunk, so process start-up is not counted.
                    if self.first is None:
                        self.first = now
                    else:
                        self.rows += rows
                    self.last = now
                n += 1
            with self.exp_lock:
                self.streams_done += 1
            return pb.Summary(chunks=n)

    return Learner


def start_server(pb, pbg, n):
    servicer = make_servicer(pb, pbg)()
    # One worker per streaming RPC plus room for the acks.
    server = grpc.server(futures.ThreadPoolExecutor(max_workers=2 * n + 8), options=OPTIONS)
    pbg.add_LearnerServicer_to_server(servicer, server)
    port = server.add_insecure_port("127.0.0.1:0")
    server.start()
    return server, servicer, f"127.0.0.1:{port}"


def spawn_peers(proto_dir, addr, peer, n, seconds):
    return [
        subprocess.Popen(
            [sys.executable, os.path.abspath(__file__), "--peer", peer, "--proto-dir", proto_dir, "--connect", addr,
             "--id", str(i), "--seconds", str(seconds)],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL)
        for i in range(n)
    ]


def reap(children):
    deadline = time.monotonic() + 10
    for c in children:
        try:
            c.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            c.kill()
            c.wait()


def broadcast(pb, pbg, proto_dir, n, seconds):
    server, s, addr = start_server(pb, pbg, n)
    peers = spawn_peers(proto_dir, addr, "echo", n, seconds)
    base = np.arange(policy_len(), dtype=np.float32) * np.float32(1e-4)

    def publish(version):
        policy = base + np.float32(version)
        s.publish(pb.Weights(version=version, policy=policy.astype("<f4").tobytes()))

    version = 0
    ready_by = time.monotonic() + 60
    while len(s.seen_actors()) < n:  # until every peer has answered once, they are still starting
        version += 1
        publish(version)
        time.sleep(0.2)
        if time.monotonic() > ready_by:
            raise RuntimeError(f"the {n} peer processes did not all answer within 60 s")
    times = []
    start = time.perf_counter()
    while time.perf_counter() - start < seconds or len(times) < 20:
        version += 1
        t = time.perf_counter()
        publish(version)
        if not s.wait_acks(version, n, timeout=10):
            raise RuntimeError(f"a peer did not answer version {version} within 10 s")
        times.append((time.perf_counter() - t) * 1e3)
    s.close()
    server.stop(grace=1).wait()
    reap(peers)
    times.sort()
    config = f"grpc-{n}actors-{policy_len() * 4 // 1000}KB"
    emit("weights_broadcast_median", config, times[len(times) // 2], "ms")
    emit("weights_broadcast_p99", config, times[min(len(times) * 99 // 100, len(times) - 1)], "ms")


def experience(pb, pbg, proto_dir, n, seconds):
    server, s, addr = start_server(pb, pbg, n)
    peers = spawn_peers(proto_dir, addr, "flood", n, seconds)
    idle_since = time.monotonic()
    last_seen = None
    while True:
        time.sleep(0.05)
        with s.exp_lock:
            done, last = s.streams_done, s.last
        if done >= n:
            break
        if last != last_seen:
            last_seen, idle_since = last, time.monotonic()
        if time.monotonic() - idle_since > (2 if last is not None else 60):
            break
    server.stop(grace=1).wait()
    reap(peers)
    if s.first is None:
        raise RuntimeError(f"no experience arrived from {n} peer processes")
    secs = max(s.last - s.first, 1e-9)
    config = f"grpc-{n}senders-{ROWS}rows"
    emit("experience", config, s.rows / secs, "transitions/s")
    emit("experience", config, s.rows * BYTES_PER_ROW / secs / 1e6, "MB/s")


# ---------------------------------------------------------------- actor (client) side


def run_peer(a):
    pb, pbg = load(a.proto_dir)
    channel = grpc.insecure_channel(a.connect, options=OPTIONS)
    grpc.channel_ready_future(channel).result(timeout=60)
    stub = pbg.LearnerStub(channel)
    if a.peer == "echo":
        try:
            for w in stub.WatchWeights(pb.WatchRequest(actor=a.id)):
                policy = np.frombuffer(w.policy, dtype="<f4")
                assert policy.shape[0] == policy_len()
                stub.AckWeights(pb.WeightsAck(actor=a.id, version=w.version))
        except grpc.RpcError:
            pass  # the learner has gone: the figure is done
    else:
        obs = (np.arange(ROWS * OBS) % 97).astype("<f4") * np.float32(0.01)
        next_obs = (np.arange(ROWS * OBS) % 89).astype("<f4") * np.float32(0.01)
        chunk = pb.ExperienceChunk(
            actor=a.id, weights_version=0, rows=ROWS, obs=obs.tobytes(),
            actions=np.full(ROWS * ACT, 0.5, dtype="<f4").tobytes(),
            rewards=np.full(ROWS, 0.1, dtype="<f4").tobytes(), next_obs=next_obs.tobytes(),
            terminated=np.zeros(ROWS, dtype=np.uint8).tobytes())

        def chunks():
            start = time.perf_counter()
            while time.perf_counter() - start < a.seconds:
                yield chunk

        try:
            stub.PushExperience(chunks())
        except grpc.RpcError:
            pass
    channel.close()


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=5.0, help="seconds per figure")
    p.add_argument("--actors", default="1,4,16", help="actor processes for the weight broadcast")
    p.add_argument("--senders", default="1,4", help="actor processes sending experience")
    p.add_argument("--peer", choices=["echo", "flood"], help=argparse.SUPPRESS)
    p.add_argument("--proto-dir", help=argparse.SUPPRESS)
    p.add_argument("--connect", help=argparse.SUPPRESS)
    p.add_argument("--id", type=int, default=0, help=argparse.SUPPRESS)
    a = p.parse_args()
    if a.peer:
        return run_peer(a)
    proto_dir = tempfile.mkdtemp(prefix="coadapt-grpc-peer-")
    try:
        compile_proto(proto_dir)
        pb, pbg = load(proto_dir)
        for n in (int(x) for x in a.actors.split(",") if x):
            broadcast(pb, pbg, proto_dir, n, a.seconds)
        for n in (int(x) for x in a.senders.split(",") if x):
            experience(pb, pbg, proto_dir, n, a.seconds)
    finally:
        shutil.rmtree(proto_dir, ignore_errors=True)


if __name__ == "__main__":
    main()
