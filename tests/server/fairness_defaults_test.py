#!/usr/bin/python3
"""#55's "done when", on default flags (a bearer token set, so that token-less HTTP clients
get 401s): beside a client sending light queries (one-pair Distance and ListMeshes, with the
token), each of these leaves at least 18 of its 20 light queries answered, p99 under a second:

- (a) two MatrixRows of every pair of the bundled mesh, never read;
- (b) 125 GetGeometry streams of the 800K-vertex armadillo_loop2.ply, never read: past the
  client's share of --max-streams they are refused at once, naming it;
- (c) two Distance batches of 2,000 exact pairs: refused at once, naming --max-exact-pairs;
- (d) 576 token-less keep-alive HTTP connections, each asking again every 10 s: each 401
  closes its connection, so the authenticated HTTP client is answered too.

The other fairness tests run each case on small limits; this one runs them at the scale the
issue measured. Needs the shared meshes (../shared/meshes beside the source tree): without
them it fails. Every daemon listens on 127.0.0.1 port 0, and every wait is bounded.

Usage: fairness_defaults_test.py BUILD_BIN_DIR SOURCE_DIR
"""
import json
import os
import shutil
import socket
import sys
import tempfile
import threading
import time

BIN, SRC = sys.argv[1], sys.argv[2]
sys.path.insert(0, os.path.join(SRC, "client", "python"))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import grpc  # noqa: E402
from geodesic_client._stubs import pb, rpc  # noqa: E402
import daemon_ports  # noqa: E402
from checklist import Checklist  # noqa: E402
from daemon_ports import start_daemon  # noqa: E402
from fairness_clients import (SPOT_VERTICES, as_client, light_queries, p99,  # noqa: E402
                              refused_streams, unread_streams, wait_ready)
from raw_http import read_response  # noqa: E402

SHARED = os.environ.get("GEODESIC_SHARED_DIR", os.path.join(SRC, "..", "shared"))
MESHES = os.path.join(SHARED, "meshes")
BIG = "armadillo_loop2.ply"
BIG_VERTICES = 799810
TOKEN = "fairness-defaults-token"
AUTH = as_client(TOKEN)

check = Checklist()


def check_light(name, result):
    latencies, errors = result
    check(f"{name}: at least 18 of 20 light queries answered", len(latencies) >= 18,
          f"{len(latencies)} answered; errors {errors[:3]}")
    check(f"{name}: p99 of the light queries under 1 s", p99(latencies) < 1.0,
          f"p99 {p99(latencies):.3f} s")


def light(stub):
    """The well-behaved client: a one-pair Distance and a listing, 20 times."""
    def listing():
        assert stub.ListMeshes(pb.ListMeshesRequest(), timeout=3, metadata=AUTH).meshes
    return light_queries(stub, also=listing, metadata=AUTH)


def close_all(streams, channels):
    for s in streams:
        s.cancel()
    for ch in channels:
        ch.close()


def case_unread_matrices(address, stub):
    req = pb.MatrixRequest(all_sources=True, all_targets=True)
    req.graph.mesh = "spot"
    channels, streams = unread_streams(
        address, lambda s, r: s.MatrixRows(r, timeout=120, metadata=AUTH), [req] * 2)
    time.sleep(1)  # both started and blocked on their clients
    check("(a) the unread MatrixRows are still open",
          not any(s.done() for s in streams), [s.details() for s in streams if s.done()])
    check_light("(a) two unread MatrixRows", light(stub))
    close_all(streams, channels)


def case_unread_geometry(address, stub):
    n = 125
    channels, streams = unread_streams(
        address, lambda s, r: s.GetGeometry(r, timeout=120, metadata=AUTH),
        [pb.GetMeshRequest(name="big")] * n)
    refused = refused_streams(streams, n - 32, seconds=30)
    details = [s.details() for s in refused]
    check("(b) GetGeometry streams past the client's share are refused at once",
          len(refused) >= n - 32 and
          all(s.code() == grpc.StatusCode.RESOURCE_EXHAUSTED for s in refused),
          f"{len(refused)} of {n} ended; {details[:2]}")
    check("(b) the refusal names --max-streams-per-client",
          details and all("--max-streams-per-client" in d for d in details), details[:1])
    check_light("(b) 125 unread GetGeometry of an 800K-vertex mesh", light(stub))
    close_all(streams, channels)


def case_exact_batches(stub):
    req = pb.DistanceRequest(exact=True)
    req.graph.mesh = "spot"
    for k in range(2000):
        p = req.pairs.add()
        getattr(p, "from").vertex = k % SPOT_VERTICES
        p.to.vertex = (k * 7 + 1500) % SPOT_VERTICES
    calls = [stub.Distance.future(req, timeout=120, metadata=AUTH) for _ in range(2)]
    result = light(stub)
    errors = [(c.code(), c.details()) for c in calls]
    check("(c) 2,000-pair exact batches are refused naming --max-exact-pairs",
          all(code == grpc.StatusCode.RESOURCE_EXHAUSTED and "--max-exact-pairs" in details
              for code, details in errors), errors)
    check_light("(c) two 2,000-pair exact batches", result)


def http_light(port):
    """The authenticated HTTP client: 20 one-pair distances, each on its own connection."""
    body = json.dumps({"pairs": [["v:0", "v:100"]]}).encode()
    latencies, errors = [], []
    for _ in range(20):
        start = time.monotonic()
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
                s.sendall((f"POST /v1/meshes/spot/distance HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                           f"Authorization: Bearer {TOKEN}\r\nContent-Type: application/json\r\n"
                           f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n").encode()
                          + body)
                response = read_response(s, 5)
            if response and response[0] == 200:
                latencies.append(time.monotonic() - start)
            else:
                errors.append(response[0] if response else "no answer")
        except OSError as e:
            errors.append(str(e))
        time.sleep(0.1)
    return latencies, errors


def case_tokenless_connections(port):
    stop = threading.Event()
    asked = [0]

    def flood():
        # A keep-alive connection asking without a token every 10 s; once closed, it is
        # opened again for the next ask.
        s = None
        while not stop.is_set():
            try:
                if s is None:
                    s = socket.create_connection(("127.0.0.1", port), timeout=5)
                s.sendall(b"GET /v1/meshes HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
                asked[0] += 1
                response = read_response(s, 5)
                # Kept open unless the server said it closes it.
                if response is None or response[1].get("connection", "").lower() == "close":
                    s.close()
                    s = None
            except (OSError, TimeoutError):
                if s is not None:
                    s.close()
                s = None
            stop.wait(10)
        if s is not None:
            s.close()

    flooders = [threading.Thread(target=flood, daemon=True) for _ in range(576)]
    for t in flooders:
        t.start()
    try:
        time.sleep(2)
        result = http_light(port)
    finally:
        stop.set()
        for t in flooders:
            t.join(timeout=15)
    check("(d) the token-less connections asked", asked[0] >= 576, asked[0])
    check_light("(d) 576 token-less keep-alive HTTP connections", result)


def main():
    if not os.path.exists(os.path.join(MESHES, "MANIFEST.md")):
        check(f"the shared meshes are at {MESHES}", False, "missing")
        check.finish()
    work = tempfile.mkdtemp(prefix="fairness-defaults-")
    with open(os.path.join(work, "token"), "w") as f:
        f.write(TOKEN + "\n")
    log = open(os.path.join(work, "daemon.log"), "w")
    daemon, ports = start_daemon(BIN, work, ["--graph-dir", os.path.join(work, "graphs"),
                                             "--auth-token-file", os.path.join(work, "token"),
                                             "--mesh-root", MESHES, "--log-level", "warning"],
                                 stderr=log, http=True)
    started = time.monotonic()
    try:
        address = f"127.0.0.1:{ports['grpc']}"
        with grpc.insecure_channel(address) as channel:
            stub = rpc.GeodesicStub(channel)
            stub.RequestGraph(pb.RequestGraphRequest(mesh="spot"), timeout=10, metadata=AUTH)
            if not check("spot's default graph ready", wait_ready(stub, "spot", metadata=AUTH)):
                check.finish()
            case_unread_matrices(address, stub)
            big = stub.RegisterMesh(pb.RegisterMeshRequest(name="big", path=BIG), timeout=120,
                                    metadata=AUTH)
            if check("the 800K-vertex mesh registered",
                     big.diagnostics.vertices == BIG_VERTICES, big.diagnostics.vertices):
                case_unread_geometry(address, stub)
            case_exact_batches(stub)
        case_tokenless_connections(ports["http"])
    finally:
        daemon_ports.stop(daemon)
        print(f"{time.monotonic() - started:.1f} s")
        shutil.rmtree(work, ignore_errors=True)
    check.finish()


if __name__ == "__main__":
    main()
