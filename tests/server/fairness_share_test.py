#!/usr/bin/python3
"""Fair share (#55, items 3, 6 and 9) against a daemon on default flags but
for --exact-landmarks 0 (their background fields would share the cores with
the clients timed here):

- two clients (told apart by their bearer tokens, each a line of the daemon's token file)
  each keep three exact Distance batches running, several seconds each, while
  a third client sends 20 light queries: at least 18 are answered and their
  p99 is under a second; the same with batches of 10,000 graph pairs;
- per-call caps: exact pairs past --max-exact-pairs and samples past
  --max-samples are refused, naming the flag;
- the build budget: a RequestGraph flood of one client is refused past
  --max-queued-builds-per-client, one of many clients past
  --max-queued-builds; epsilon below --min-epsilon and a bound below
  --min-max-error are refused naming the flag and the estimate; a query
  naming an epsilon nobody requested starts no build;
- small: max_distance -1 is refused, so is a JSON body giving a key twice
  (and a body of many empty objects within its timeout), and a mesh named
  "-rf".

Every daemon listens on 127.0.0.1 port 0, every call has a deadline.

Usage: fairness_share_test.py BUILD_BIN_DIR SOURCE_DIR"""
import math
import os
import signal
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.request

BIN, SRC = os.path.abspath(sys.argv[1]), os.path.abspath(sys.argv[2])
sys.path.insert(0, os.path.join(SRC, "client", "python"))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import grpc  # noqa: E402
from geodesic_client._stubs import pb, rpc  # noqa: E402
import daemon_ports  # noqa: E402
from checklist import Checklist  # noqa: E402
from daemon_ports import start_daemon  # noqa: E402

check = Checklist()
SPOT_VERTICES = 2930
# Exact pairs per heavy batch: within --max-exact-pairs' default, and
# seconds of work on spot.
HEAVY_PAIRS = 250
# Graph pairs per heavy batch: --max-pairs' default, about a second of work.
GRAPH_PAIRS = 10000
LIGHT_QUERIES = 20
# The clients: a token each (calls naming none are the light client's).
TOKENS = ["light", "heavy-a", "heavy-b", "small", "flood"] + [f"crowd-{k}" for k in range(12)]


def bearer(token):
    return [("authorization", f"Bearer {token}")]


def vertex(v):
    return pb.SurfacePoint(vertex=v)


def distance_request(pairs, exact=False, epsilon=0.0):
    req = pb.DistanceRequest(exact=exact)
    req.graph.mesh = "spot"
    req.graph.epsilon = epsilon
    for a, b in pairs:
        p = req.pairs.add()
        getattr(p, "from").CopyFrom(vertex(a))
        p.to.CopyFrom(vertex(b))
    return req


def far_pairs(n, offset):
    """n pairs of vertices at opposite ends of spot (along x): exact pairs
    that sweep most of the surface."""
    from geodesicd_runner import read_obj
    vertices, _ = read_obj(os.path.join(SRC, "data", "spot.obj"))
    by_x = sorted(range(len(vertices)), key=lambda v: vertices[v][0])
    return [(by_x[(offset + i) % 400], by_x[-1 - (offset * 3 + i) % 400]) for i in range(n)]


def call(method, req, timeout, token=None):
    """(code, message, response) of a unary call."""
    try:
        return grpc.StatusCode.OK, "", method(req, timeout=timeout,
                                               metadata=bearer(token) if token else None)
    except grpc.RpcError as e:
        return e.code(), e.details() or "", None


def wait_default_graph(stub, seconds=60):
    req = pb.GetGraphRequest()
    req.graph.mesh = "spot"
    deadline = time.time() + seconds
    while time.time() < deadline:
        code, _, g = call(stub.GetGraph, req, 10)
        if code == grpc.StatusCode.OK and g.state == pb.GRAPH_STATE_READY:
            return True
        time.sleep(0.1)
    return False


def exact_batch(k, token):
    return distance_request(far_pairs(HEAVY_PAIRS, 101 * k + len(token)), exact=True)


def graph_batch(k, token):
    """As many graph pairs as a call may carry (--max-pairs' default)."""
    return distance_request(far_pairs(GRAPH_PAIRS, 101 * k + len(token)))


class Heavy:
    """A client keeping `calls` batches (`batch(k, token)`) running until stopped."""

    def __init__(self, stub, token, calls, batch=exact_batch):
        self.stub, self.token, self.stop = stub, token, threading.Event()
        self.batch, self.answered = batch, 0
        self.threads = [threading.Thread(target=self.run, args=(k,)) for k in range(calls)]

    def run(self, k):
        req = self.batch(k, self.token)
        while not self.stop.is_set():
            f = self.stub.Distance.future(req, timeout=60, metadata=bearer(self.token))
            while not f.done() and not self.stop.is_set():
                time.sleep(0.05)
            if not f.done():
                f.cancel()
            elif f.code() == grpc.StatusCode.OK:
                self.answered += 1

    def __enter__(self):
        for t in self.threads:
            t.start()
        return self

    def __exit__(self, *exc):
        self.stop.set()
        for t in self.threads:
            t.join(timeout=30)


def light_queries(stub):
    """Latencies of the answered light queries, and the errors of the others."""
    latencies, errors = [], []
    for i in range(LIGHT_QUERIES):
        req = distance_request([(i, (i * 131 + 1500) % SPOT_VERTICES)])
        start = time.time()
        code, message, _ = call(stub.Distance, req, 5)
        if code == grpc.StatusCode.OK:
            latencies.append(time.time() - start)
        else:
            errors.append(f"{code.name}: {message}")
        time.sleep(0.2)
    return latencies, errors


def p99(values):
    ordered = sorted(values)
    return ordered[max(0, math.ceil(0.99 * len(ordered)) - 1)] if ordered else math.inf


def fair_share(stub, batch, what):
    with Heavy(stub, "heavy-a", 3, batch) as a, Heavy(stub, "heavy-b", 3, batch) as b:
        time.sleep(1)  # every heavy batch started
        latencies, errors = light_queries(stub)
    print(f"{what}: heavy batches answered meanwhile: {a.answered + b.answered}; light queries "
          f"answered {len(latencies)}, p99 {p99(latencies):.3f} s", flush=True)
    check(f"{what}: a light client beside them is answered (at least 18 of {LIGHT_QUERIES})",
          len(latencies) >= 18, f"{len(latencies)} answered; {errors[:3]}")
    check(f"{what}: its p99 is under a second", p99(latencies) < 1.0,
          f"p99 {p99(latencies):.2f} s, latencies {sorted(round(x, 2) for x in latencies)}")


def caps(stub):
    code, message, _ = call(stub.Distance, distance_request(far_pairs(300, 3), exact=True), 3)
    check("exact pairs past --max-exact-pairs are refused naming it",
          code == grpc.StatusCode.RESOURCE_EXHAUSTED and "--max-exact-pairs" in message,
          (code, message))
    req = pb.SamplePointsRequest(count=2000)
    req.graph.mesh = "spot"
    code, message, _ = call(stub.SamplePoints, req, 3)
    check("samples past --max-samples are refused naming it",
          code == grpc.StatusCode.RESOURCE_EXHAUSTED and "--max-samples" in message,
          (code, message))


def request_graph(stub, token, epsilon=0.0, max_error=0.0):
    req = pb.RequestGraphRequest()
    req.graph.mesh = "spot"
    req.graph.epsilon = epsilon
    req.graph.max_error = max_error
    return call(stub.RequestGraph, req, 10, token)


def build_budget(stub):
    code, message, _ = request_graph(stub, "small", epsilon=1e-5)
    check("epsilon below --min-epsilon is refused naming it and the estimate",
          code == grpc.StatusCode.INVALID_ARGUMENT and "--min-epsilon" in message and
          "estimated at" in message, (code, message))
    code, message, _ = request_graph(stub, "small", max_error=1e-5)
    check("a bound below --min-max-error is refused naming it",
          code == grpc.StatusCode.INVALID_ARGUMENT and "--min-max-error" in message,
          (code, message))
    code, message, _ = call(stub.Distance, distance_request([(0, 1500)], epsilon=0.2), 5)
    check("a query naming an epsilon nobody requested starts no build",
          code == grpc.StatusCode.FAILED_PRECONDITION and "RequestGraph" in message,
          (code, message))

    # Graphs that take a while to build on one worker: queued, not gone.
    results = [request_graph(stub, "flood", epsilon=2e-4 + k * 1e-6) for k in range(6)]
    refused = [m for c, m, _ in results if c == grpc.StatusCode.RESOURCE_EXHAUSTED]
    check("one client's RequestGraph flood is refused past its share, naming the flag",
          len(refused) >= 3 and all("--max-queued-builds-per-client" in m for m in refused),
          [(c.name, m) for c, m, _ in results])
    results = [request_graph(stub, f"crowd-{k}", epsilon=3e-4 + k * 1e-6) for k in range(12)]
    refused = [m for c, m, _ in results if c == grpc.StatusCode.RESOURCE_EXHAUSTED]
    check("many clients' requests are refused past the queue's bound, naming the flag",
          len(refused) >= 3 and all("--max-queued-builds" in m for m in refused),
          [(c.name, m) for c, m, _ in results])


def post_distance(http_port, body, timeout):
    """(status, text) of an HTTP distance request on spot with this JSON body; no status if
    it timed out."""
    request = urllib.request.Request(f"http://127.0.0.1:{http_port}/v1/meshes/spot/distance",
                                     data=body, method="POST",
                                     headers={"Content-Type": "application/json",
                                              "Authorization": "Bearer light"})
    try:
        with urllib.request.urlopen(request, timeout=timeout) as r:
            return r.status, r.read().decode()
    except urllib.error.HTTPError as e:
        return e.code, e.read().decode()
    except OSError as e:
        return None, str(e)


def small_things(stub, http_port):
    req = pb.DistanceFieldRequest(max_distance=-1)
    req.graph.mesh = "spot"
    req.sources.add().vertex = 0
    try:
        for _ in stub.DistanceField(req, timeout=10):
            pass
        code, message = grpc.StatusCode.OK, ""
    except grpc.RpcError as e:
        code, message = e.code(), e.details() or ""
    check("max_distance -1 is refused naming it",
          code == grpc.StatusCode.INVALID_ARGUMENT and "max_distance -1" in message,
          (code, message))

    status, answer = post_distance(
        http_port, b'{"pairs": [["v:0", "v:1500"]], "pairs": [["v:0", "v:7"]]}', 10)
    check("a JSON body giving a key twice is refused naming it",
          status == 400 and "pairs" in answer and "more than once" in answer,
          (status, answer))

    # 2 MiB of empty objects: the duplicate-key check once took quadratic time on these
    # (half a MiB: 11 s), holding an HTTP worker; now the body is refused as soon as read.
    status, answer = post_distance(
        http_port, b'{"pairs": [' + b",".join([b"{}"] * (700 * 1024)) + b"]}", 20)
    check("an array of many empty objects is refused within the request's timeout",
          status == 400 and "pair 0" in answer, (status, answer[:200]))

    code, message, _ = call(stub.RegisterMesh, pb.RegisterMeshRequest(name="-rf",
                                                                       path="spot.obj"), 10)
    check("a mesh name read as a flag is refused",
          code == grpc.StatusCode.INVALID_ARGUMENT and "'-'" in message, (code, message))


def main():
    work = tempfile.mkdtemp(prefix="fairness-share-")
    log = open(os.path.join(work, "daemon.log"), "w")
    daemon, ports = start_daemon(BIN, work, ["--graph-dir", f"{work}/graphs", "--log-level",
                                             "warning", "--exact-landmarks", "0"],
                                 stderr=log, http=True, tokens=TOKENS)
    try:
        stub = rpc.GeodesicStub(daemon_ports.authed(
            grpc.insecure_channel(f"127.0.0.1:{ports['grpc']}"), "light"))
        if not check("the sample mesh's default graph is ready", wait_default_graph(stub)):
            check.finish()
        started = time.time()
        fair_share(stub, exact_batch, "exact batches")
        fair_share(stub, graph_batch, "graph batches")
        print(f"fair share part: {time.time() - started:.1f} s", flush=True)
        caps(stub)
        small_things(stub, ports["http"])
        build_budget(stub)
    finally:
        # Queued builds would only slow a graceful stop down.
        daemon_ports.stop(daemon, sig=signal.SIGKILL)
    check.finish()


if __name__ == "__main__":
    main()
